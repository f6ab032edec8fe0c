"""The update-count metric (SEAL Appendix B): a task's transitions used by updates until it is learned.

Appendix B counts, per task, the network updates it took to reach 90% success for the first time,
as C x GS x BS (epoch x gradient steps per epoch x that task's samples per step). Run directories
record that product exactly in `metrics.csv`'s `updates` column (millions of the task's
transitions consumed by gradient updates so far), which also stays exact when the batch
composition changes (data-ratio schedules, schedulers). This module reads that column; it never
recomputes C x GS x BS.

Everything here is a pure function of pandas DataFrames, so it can be tested on hand-written
tables and reused by `seal report` and the benches.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, Literal

import numpy as np
import pandas as pd

from seal.errors import SealError
from seal.evaluation import SUCCESS_TOLERANCE

DEFAULT_THRESHOLD = 0.9
"""Success rate a task must reach (Appendix B: 90%)."""

NEVER_REACHED = "—"
"""How a task that never reached the threshold is rendered in its own cell."""

AT_LEAST = "≥"
"""Marks a total that holds a censored task: a lower bound on what reaching 90% would cost."""

CensoredRule = Literal["run-total", "zero"]
"""How a total counts a censored task (one that some seed never brought to the threshold):
`run-total` at what that seed consumed in the whole run, a lower bound, so the total is "≥ x";
`zero` as 0 and its other seeds' mean (Tables 4-7's rule, which makes a failed arm look cheap)."""

CENSORED_RULES: tuple[str, ...] = ("run-total", "zero")


# metrics.csv columns without which no update count can be made; `return` and `wall_s` are only shown.
REQUIRED_METRICS_COLUMNS = (
    "seed",
    "phase",
    "epoch",
    "env",
    "task",
    "success",
    "grad_steps",
    "env_steps",
    "updates",
)

Style = Literal["plain", "markdown", "latex"]


def _require_columns(frame: pd.DataFrame, columns: Sequence[str], what: str) -> None:
    missing = [c for c in columns if c not in frame.columns]
    if missing:
        raise SealError(f"{what} lacks column(s) {missing}; it has {list(frame.columns)}")


def check_consecutive(consecutive: object) -> None:
    """SealError unless `consecutive` (K successive evaluations >= threshold) is a whole number >= 1."""
    if isinstance(consecutive, bool) or not isinstance(consecutive, int) or consecutive < 1:
        raise SealError(
            f"consecutive = {consecutive!r}: expected a whole number of evaluations >= 1 "
            f"(1 = the paper's first evaluation >= threshold)"
        )


def _hit_streaks(ordered: pd.DataFrame, hit: pd.Series, keys: Sequence[str]) -> np.ndarray:
    """Per row of `ordered` (sorted by `keys`, then in training order): how many successive
    evaluations of its (seed, phase, env, task) run hit, from this one on (0 where it misses).

    One pass over the rows whatever K is asked for, so a K larger than any run's evaluations
    costs no more than a small one: no streak reaches it.
    """
    flags = hit.to_numpy(dtype=bool)
    if not len(flags):
        return np.zeros(0, dtype=np.int64)
    # Rows of a run are contiguous (sorted by keys); NaN keys form runs of their own.
    run_id = ordered.groupby(list(keys), sort=False, dropna=False).ngroup().to_numpy()
    # Walk backwards: a streak restarts at a miss and at the last row of each run.
    backwards, ids = flags[::-1], run_id[::-1]
    starts = np.ones(len(flags), dtype=bool)
    starts[1:] = ids[1:] != ids[:-1]
    segment = np.cumsum(starts | ~backwards)
    streak = pd.Series(backwards.astype(np.int64)).groupby(segment).cumsum().to_numpy()
    return streak[::-1]


def first_reach(
    metrics: pd.DataFrame, threshold: float = DEFAULT_THRESHOLD, consecutive: int = 1
) -> pd.DataFrame:
    """Per (seed, phase, env, task): the first evaluation with success >= threshold.

    Returns one row per (seed, phase, env, task) present in `metrics`, in order of first
    appearance, with columns `reached` (bool), `epoch`, `updates` (millions of the task's
    transitions), `grad_steps` and `env_steps` at that evaluation. A task that never reached the
    threshold has `reached=False` and 0 in the numeric columns (Tables 4-7 write 0 for it).
    Phases are kept apart: update counts restart at each phase (pre-train / fine-tune).

    `paper_updates` is Appendix B's C x GS x BS at that evaluation, the phase's gradient steps
    times the task's batch in force then (metrics.csv's `batch`; NaN for runs written before it):
    equal to `updates` under a constant batch, and what the paper would report under a changing one.

    `consecutive` = K > 1 is a robust criterion: a task has reached when K successive evaluations
    (in training order) are all >= threshold, and the row reported is the first of those K, so a
    single lucky evaluation does not count. K = 1 is the paper's criterion.
    """
    check_consecutive(consecutive)
    _require_columns(metrics, REQUIRED_METRICS_COLUMNS, "metrics table")
    keys = ["seed", "phase", "env", "task"]
    values = ["epoch", "updates", "grad_steps", "env_steps", "paper_updates"]
    metrics = metrics.assign(
        paper_updates=metrics["grad_steps"] * metrics["batch"] / 1e6
        if "batch" in metrics.columns
        else math.nan
    )
    # Evaluations in training order; "first" is the earliest epoch of the phase.
    ordered = metrics.sort_values([*keys, "epoch", "grad_steps"], kind="stable")
    hit = ordered["success"] >= threshold - SUCCESS_TOLERANCE  # as evaluation.reaches
    # Default K = 1, the paper's criterion (Appendix B: the first evaluation at 90%). For K > 1
    # an evaluation starts a reach when it and the K - 1 after it in the same task's run all hit.
    # No streak is longer than the rows, so a larger K is "never": clamped to fit an int64.
    hits = ordered[_hit_streaks(ordered, hit, keys) >= min(consecutive, len(ordered) + 1)]
    first = hits.groupby(keys, sort=False).head(1)[keys + values]
    last = ordered.groupby(keys, sort=False).tail(1)[keys + ["updates", "grad_steps", "env_steps"]]
    last = last.rename(columns={c: f"run_{c}" for c in ("updates", "grad_steps", "env_steps")})
    all_tasks = metrics[keys].drop_duplicates().merge(last, on=keys, how="left")
    out = all_tasks.merge(first, on=keys, how="left", indicator=True)
    out["reached"] = out.pop("_merge") == "both"
    for column in values[:-1]:
        out[column] = out[column].fillna(0)
    out["epoch"] = out["epoch"].astype(np.int64)
    out["grad_steps"] = out["grad_steps"].astype(np.int64)
    out["env_steps"] = out["env_steps"].astype(np.int64)
    out["updates"] = out["updates"].astype(float)
    run_totals = ["run_updates", "run_grad_steps", "run_env_steps"]
    return out[[*keys, "reached", *values, *run_totals]].reset_index(drop=True)


def decompose_first_reach(first: pd.DataFrame) -> pd.DataFrame:
    """`first_reach`'s output with the update count split into gradient steps x per-step batch.

    Adds `transitions` (the task's transitions consumed until it first reached, `updates` x 1e6),
    `steps` (gradient steps until then) and `per_step` (transitions / steps: the task's mean
    per-step batch over that span; NaN when steps is 0, as for a task never reached). So
    transitions = steps x per_step, and the ratio of two arms' transitions is the ratio of their
    steps times the ratio of their per-step batches: fewer transitions may come from learning in
    fewer steps or from a smaller share of each batch.
    """
    _require_columns(first, ["updates", "grad_steps"], "first-reach table")
    # Transitions are whole counts; rounding undoes the float error of metrics.csv's millions.
    transitions = np.round(first["updates"].to_numpy(dtype=float) * 1e6)
    steps = first["grad_steps"].to_numpy(dtype=np.int64)
    with np.errstate(divide="ignore", invalid="ignore"):
        per_step = np.where(steps > 0, transitions / np.maximum(steps, 1), math.nan)
    return first.assign(transitions=transitions, steps=steps, per_step=per_step)


def batch_share(per_step: float | np.ndarray | pd.Series, total_batch: float) -> Any:
    """A task's share of the whole batch: its per-step batch / the transitions of one update.

    `total_batch` is one gradient step's batch over all tasks (and envs) of the run, e.g. 40 per
    task x 8 tasks = 320. Works elementwise on arrays and Series.
    """
    if not (
        isinstance(total_batch, int | float) and math.isfinite(total_batch) and total_batch > 0
    ):
        raise SealError(f"total_batch {total_batch!r}: expected a positive number of transitions")
    return per_step / float(total_batch)


def aggregate_seeds(
    per_seed: pd.DataFrame, keys: Sequence[str] = ("phase", "env", "task")
) -> pd.DataFrame:
    """Across seeds: mean ± std of the update count over the seeds that reached it, and k of n.

    `per_seed` is `first_reach`'s output (possibly with extra key columns such as a report
    column). Returns one row per `keys` with `updates_mean`, `updates_std`, `grad_steps_mean`,
    `per_step_mean` (the task's mean per-step batch over those steps: updates_mean x 1e6 /
    grad_steps_mean; NaN if never reached), `env_steps_mean` (over reaching seeds), `reached` (k) and `seeds` (n). With k = 0 the means
    are 0 (never reached); with k < 2 the std is NaN, since one seed has no spread.

    `updates_bound` is the mean over all n seeds with each censored seed (one that never reached
    it) at its run total (`first_reach`'s `run_updates`): the task's term in a total under the
    `run-total` rule, equal to `updates_mean` when every seed reached it, else a lower bound
    (NaN where a censored seed's run total is unknown).
    """
    keys = list(keys)
    _require_columns(
        per_seed, [*keys, "reached", "updates", "grad_steps", "env_steps"], "per-seed table"
    )
    if "paper_updates" not in per_seed.columns:
        per_seed = per_seed.assign(paper_updates=math.nan)
    run_updates = per_seed["run_updates"] if "run_updates" in per_seed.columns else math.nan
    per_seed = per_seed.assign(
        bound_=per_seed["updates"].where(per_seed["reached"].astype(bool), run_updates)
    )
    groups = per_seed.groupby(keys, sort=False)
    counts = pd.DataFrame(
        {
            "reached": groups["reached"].sum().astype(np.int64),
            "seeds": groups.size(),
            # skipna=False: a censored seed with no known run total leaves the bound unknown.
            "updates_bound": groups["bound_"].agg(lambda v: v.mean(skipna=False)),
        }
    )
    reached = per_seed[per_seed["reached"]]
    # Sample std (ddof=1): the spread of seeds drawn from the run's distribution, as in Fig. 2 shading.
    stats = reached.groupby(keys, sort=False).agg(
        updates_mean=("updates", "mean"),
        updates_std=("updates", "std"),
        grad_steps_mean=("grad_steps", "mean"),
        env_steps_mean=("env_steps", "mean"),
        paper_updates_mean=("paper_updates", "mean"),
    )
    out = counts.join(stats, how="left")
    for column in ("updates_mean", "grad_steps_mean", "env_steps_mean"):
        out[column] = out[column].fillna(0.0)
    out = out.reset_index()
    # Ratio of the means, so that updates_mean x 1e6 = grad_steps_mean x per_step_mean exactly.
    steps = out["grad_steps_mean"].to_numpy(dtype=float)
    out["per_step_mean"] = np.where(
        steps > 0, out["updates_mean"].to_numpy(dtype=float) * 1e6 / np.maximum(steps, 1), math.nan
    )
    return out[
        [
            *keys,
            "updates_mean",
            "updates_std",
            "grad_steps_mean",
            "per_step_mean",
            "env_steps_mean",
            "paper_updates_mean",
            "updates_bound",
            "reached",
            "seeds",
        ]
    ]


def env_totals(
    aggregated: pd.DataFrame,
    keys: Sequence[str] = ("phase", "env"),
    censored: CensoredRule = "run-total",
) -> pd.DataFrame:
    """Totals per environment, as the "Total Network Updates" rows of Tables 4-7.

    The total is the sum over tasks of each task's mean. A task is censored when some seed never
    brought it to the threshold (`reached` < `seeds`); `censored_tasks` counts them. Under the
    `run-total` rule (`CensoredRule`) a task's term is its `updates_bound` (censored seeds at
    their run totals), so a total with a censored task is a lower bound ("≥ x"); under `zero` it
    is the mean over the seeds that reached it, a never-reached task counting 0 as in the paper.
    `tasks_reached` says how many tasks were reached by at least one seed, of `tasks`.
    """
    if censored not in CENSORED_RULES:
        raise SealError(
            f"censored rule {censored!r} is not valid; expected one of {', '.join(CENSORED_RULES)}"
        )
    keys = list(keys)
    term = "updates_bound" if censored == "run-total" else "updates_mean"
    _require_columns(aggregated, [*keys, term, "reached", "seeds"], "aggregated table")
    groups = aggregated.groupby(keys, sort=False)
    out = pd.DataFrame(
        {
            "updates_total": groups[term].agg(lambda v: v.sum(skipna=False)),
            "tasks_reached": groups["reached"].apply(lambda k: int((k > 0).sum())),
            "tasks": groups.size(),
            "censored_tasks": (aggregated["reached"] < aggregated["seeds"])
            .groupby([aggregated[k] for k in keys], sort=False)
            .sum()
            .astype(np.int64),
        }
    )
    return out.reset_index()


def percent_change(
    value: float, baseline: float, value_reached: bool = True, baseline_reached: bool = True
) -> float | None:
    """(value - baseline) / baseline in percent; None where either side never reached the threshold.

    Negative means fewer updates than the single-environment baseline (Table 1's bold entries).
    A baseline that never reached it gives "n/a"; so does a variant that never reached it, since
    "0 updates" there means "not learned", not "learned for free".
    """
    if not (baseline_reached and value_reached) or not math.isfinite(baseline) or baseline <= 0:
        return None
    return 100.0 * (value - baseline) / baseline


def add_percent_change(
    aggregated: pd.DataFrame,
    baseline_column: str,
    column_key: str = "column",
    on: Sequence[str] = ("env", "task"),
) -> pd.DataFrame:
    """Add `pct_change` (vs. the rows whose `column_key` is `baseline_column`, matched on `on`).

    Baseline rows and rows without a matching baseline get NaN, as do rows where either side was
    never reached.
    """
    on = list(on)
    _require_columns(aggregated, [column_key, *on, "updates_mean", "reached"], "aggregated table")
    base = aggregated[aggregated[column_key] == baseline_column][[*on, "updates_mean", "reached"]]
    base = base.rename(columns={"updates_mean": "baseline_mean_", "reached": "baseline_reached_"})
    merged = aggregated.merge(base, on=on, how="left")
    pct = []
    for row in merged.itertuples(index=False):
        is_baseline = getattr(row, column_key) == baseline_column
        base_reached = row.baseline_reached_
        if is_baseline or pd.isna(base_reached):
            pct.append(math.nan)
            continue
        change = percent_change(
            row.updates_mean, row.baseline_mean_, row.reached > 0, base_reached > 0
        )
        pct.append(math.nan if change is None else change)
    merged["pct_change"] = pct
    return merged.drop(columns=["baseline_mean_", "baseline_reached_"])


# --------------------------------------------------------------------------- rendering


def format_number(value: float) -> str:
    """Four significant digits without exponent: 0.192, 6.4, 42.7, 211.2, 1536."""
    if not math.isfinite(value):
        return "nan"
    return np.format_float_positional(value, precision=4, unique=True, fractional=False, trim="-")


def format_percent(pct: float | None) -> str:
    """Signed percent with one decimal ("-62.5%", "+12.0%"), or "n/a"."""
    if pct is None or not math.isfinite(pct):
        return "n/a"
    return f"{pct:+.1f}%"


def format_total(total: float, censored: bool, style: Style = "plain") -> str:
    """A total's number, "≥ 1.23" when it holds a censored task (a lower bound), "$\\geq$ 1.23" in LaTeX."""
    if not censored:
        return format_number(total)
    mark = r"$\geq$" if style == "latex" else AT_LEAST
    return f"{mark} {format_number(total)}"


def format_ci(ci: tuple[float, float]) -> str:
    """A relative change's CI (fractions) in percent: "[-71.2, -8.4]"; "[n/a]" if not finite."""
    low, high = ci
    if not (math.isfinite(low) and math.isfinite(high)):
        return "[n/a]"
    return f"[{100 * low:+.1f}, {100 * high:+.1f}]"


def format_count(
    mean: float,
    std: float,
    reached: int,
    seeds: int,
    pct: float | None = None,
    show_pct: bool = False,
    style: Style = "plain",
    bold: bool | None = None,
    ci: tuple[float, float] | None = None,
    vs: str = "",
    also: str = "",
) -> str:
    """One table cell: "mean ± std (pct) [k/n]", "—" if never reached; bold (md/LaTeX) when pct < 0.

    `show_pct` adds the percent change ("n/a" when it is undefined); the baseline column leaves it off.
    `ci` (a relative change's CI, as fractions) is shown after the percent as "[lo, hi]" when
    finite; `vs` labels the change ("-20.0% vs Single Env") and `also` is written after it inside
    the parentheses (a second, labelled change). `bold` overrides the rule: a report passes
    pct < 0 and the CI excluding 0, so a change within the noise of its seeds is not bold.
    """
    pm = r"$\pm$" if style == "latex" else "±"
    dash = "---" if style == "latex" else NEVER_REACHED
    seeds_part = f"[{reached}/{seeds}]"
    if reached == 0:
        return f"{dash} {seeds_part}"
    text = format_number(mean)
    if std is not None and math.isfinite(std):
        text += f" {pm} {format_number(std)}"
    if show_pct:
        pct_text = format_percent(pct)
        if style == "latex":
            pct_text = pct_text.replace("%", r"\%")
        if ci is not None and math.isfinite(ci[0]) and math.isfinite(ci[1]):
            pct_text += f" {format_ci(ci)}"
        if vs:
            pct_text += f" vs {vs}"
        text += f" ({pct_text}{also})"
    if bold is None:
        bold = pct is not None and math.isfinite(pct) and pct < 0
    if bold:
        if style == "markdown":
            text = f"**{text}**"
        elif style == "latex":
            text = rf"\textbf{{{text}}}"
    return f"{text} {seeds_part}"
