"""Read run directories and lay them out as the paper's tables and figures (`seal report`).

A run directory is `reports/<protocol>/<group-id>/seed-<n>/` with `config.toml`,
`provenance.json`, `metrics.csv` (one row per evaluation and task) and `train.csv` (training
curves, long format). A group directory holds several `seed-<n>/` runs. This package reads those
files only, never live objects, so a report can be rebuilt from any copy of the directories.

`report` lays groups out as Table 1 (Task x {Single Env, 50/50, High FK, High MW}) and Tables 6-7
("Pre-train on X" / "Fine-tune on Y"), with the update-count metric of `seal.metrics`, writes
every change against a reference as a row of its own (count, change and steps are each a table),
and draws the success curves of Figs. 2-4 (with a bootstrap band), the changes with their CIs and
minimum detectable effects, and the critic-loss curves of Fig. 7.

The package splits by idea: `seal.reports.load` reads run directories, `seal.reports.groups`
labels columns and gathers groups, `seal.reports.tables` and `seal.reports.plots` write the
tables and figures; this module holds `report`, which ties them together.
"""

from __future__ import annotations

import os
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from seal.errors import SealError
from seal.files import check_inside, check_output_dir
from seal.metrics import (
    CENSORED_RULES,
    DEFAULT_THRESHOLD,
    CensoredRule,
    add_percent_change,
    aggregate_seeds,
    check_consecutive,
    decompose_first_reach,
    env_totals,
    first_reach,
)
from seal.reports.by_task import write_by_task
from seal.reports.changes import _with_uncertainty, change_rows, few_seeds, pairing
from seal.reports.groups import (
    BASELINE_COLUMN,
    _column_rank,
    _disambiguate,
    _gather,
    _Group,
    _labelled,
    column_label,
)
from seal.reports.load import RunData, _is_run_dir, load_run, run_dirs
from seal.reports.plots import (
    XAxis,
    _plot_critic_loss,
    _plot_overestimation,
    _plot_schedulers,
    _safe,
    column_colours,
    plot_changes,
    plot_success,
)
from seal.reports.tables import (
    ReportResult,
    _comparability_warnings,
    _notes,
    _paper_suffix,
    _row_order,
    _steps_cell,
    _success_tables,
    _update_count_table,
    _write_table,
    change_sections,
    changes_display,
    write_document,
)
from seal.run.rundir import METRICS_COLUMNS, TRAIN_COLUMNS  # defined once, by the writer
from seal.stats import MIN_SEEDS_RESOLVED


def _resolve_threshold(groups: Sequence[_Group], threshold: float | None) -> float:
    if threshold is None:
        configured = {
            float(run.config.get("evaluation", {}).get("threshold", DEFAULT_THRESHOLD))
            for g in groups
            for run in g.runs
        }
        # One protocol-configured threshold is honoured; mixed ones fall back to the paper's 0.9.
        threshold = configured.pop() if len(configured) == 1 else DEFAULT_THRESHOLD
    return check_threshold(threshold)


def check_threshold(threshold: object) -> float:
    """A success threshold as a float, or a one-line SealError saying what is valid."""
    if not (isinstance(threshold, int | float) and 0.0 < threshold <= 1.0):
        raise SealError(
            f"threshold {threshold!r} is not a success rate; expected 0 < threshold <= 1 (default 0.9)"
        )
    return float(threshold)


def check_report_inputs(
    paths: Sequence[str | os.PathLike[str]],
    out: str | os.PathLike[str] | None,
    threshold: float | None,
    consecutive: int = 1,
) -> None:
    """What `report` would refuse, checked before anything is written or locked: the output
    directory, each path as a run or group directory, the threshold and `consecutive`."""
    check_consecutive(consecutive)
    if out is not None:
        check_output_dir(out)
    for path in paths:
        run_dirs(path)
    if threshold is not None:
        check_threshold(threshold)


def _default_out(paths: Sequence[str | os.PathLike[str]], groups: Sequence[_Group]) -> Path:
    """One path, a run or a group -> itself; several (even runs of one group) -> a new directory
    of their own, <reports root>/comparison/<protocols>/<time>-<random>, made here.

    `seal report` locks the one path while it writes into it (`DirLock`); a comparison's
    directory is made new and unique (`tempfile.mkdtemp`: an exclusive create), so no other
    process writes into it and it needs no lock.
    """
    if len(paths) == 1:
        return Path(paths[0]) if _is_run_dir(Path(paths[0])) else groups[0].path
    root = Path(os.path.commonpath([str(g.path.parent.parent) for g in groups]))
    names = "+".join(dict.fromkeys(g.runs[0].protocol for g in groups))
    parent = root / "comparison" / _safe(names)[:150]
    try:
        parent.mkdir(parents=True, exist_ok=True)
        made = Path(tempfile.mkdtemp(prefix=time.strftime("%Y%m%d-%H%M%S-"), dir=parent))
    except OSError as exc:
        raise SealError(
            f"cannot make the comparison directory in {parent}: {exc.strerror}; pass --out DIR"
        ) from None
    made.chmod(0o755)  # mkdtemp's 0700 would hide the report from the rest of the group
    return made


def _frames(groups: Sequence[_Group]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The groups' evaluation rows (labels disambiguated) and training rows, in one column space."""
    metrics = _labelled(groups, "metrics")
    if metrics.empty:
        files = [str(run.path / "metrics.csv") for g in groups for run in g.runs]
        shown = ", ".join(files[:5]) + (f" and {len(files) - 5} more" if len(files) > 5 else "")
        runs, verb = ("this run", "is") if len(files) == 1 else ("these runs", "are")
        raise SealError(
            f"{shown}: no evaluation rows, so there is nothing to report: {runs} stopped before "
            f"the first evaluation (see the log, then resume or rerun) or {verb} still running "
            "(report after the first evaluation)"
        )
    metrics = _disambiguate(metrics)
    train = _labelled(groups, "train")
    if not train.empty:
        # Training rows take their evaluation rows' column (disambiguated labels included).
        column_of = metrics.drop_duplicates(["source", "phase", "env"]).set_index(
            ["source", "phase", "env"]
        )["column"]
        keys = list(zip(train["source"], train["phase"], train["env"], strict=True))
        train["column"] = [column_of.get(k, c) for k, c in zip(keys, train["column"], strict=True)]
    return metrics, train


def _output_dirs(out_dir: Path) -> tuple[Path, Path]:
    """`out_dir`'s tables/ and plots/, created; SealError if they cannot be.

    Nothing is written through a symlink: tables/ or plots/ leading out of `out_dir` is refused
    before anything is written, and a symlinked file in them is removed, so the report writes a
    file of its own in its place instead of overwriting where the link points.
    """
    tables_dir, plots_dir = out_dir / "tables", out_dir / "plots"
    for folder in (tables_dir, plots_dir):
        check_inside(folder, out_dir, what=f"report's {folder.name}/ folder")
    for folder in (tables_dir, plots_dir):
        if folder.is_dir():
            for entry in folder.iterdir():
                if entry.is_symlink():
                    entry.unlink()
    try:
        tables_dir.mkdir(parents=True, exist_ok=True)
        plots_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SealError(
            f"cannot write the report to {out_dir}: {exc.strerror}; pass --out DIR"
        ) from None
    return tables_dir, plots_dir


@dataclass
class _Layout:
    """The tables' columns (protocols), rows (tasks) and env labels."""

    columns: list[str]
    rows: list[tuple[str, str]]
    labels: dict[str, str]

    @classmethod
    def of(cls, metrics: pd.DataFrame) -> _Layout:
        columns = sorted(dict.fromkeys(metrics["column"]), key=_column_rank)
        labels = dict(zip(metrics["env"], metrics["env_label"], strict=False))
        return cls(columns, _row_order(metrics), labels)


def _update_counts(
    metrics: pd.DataFrame,
    threshold: float,
    consecutive: int = 1,
    censored: CensoredRule = "run-total",
) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame]:
    """The update-count metric: (per seed, across seeds with changes and CIs, env totals).

    Per seed, `first_reach` split into gradient steps x per-step batch; across seeds, the change
    against Single Env (and against a column's batch-matched alone arm) with Fieller CIs; the
    totals count censored tasks by the `censored` rule.
    """
    per_seed = []
    for (column, source), frame in metrics.groupby(["column", "source"], sort=False):
        reach = decompose_first_reach(first_reach(frame, threshold, consecutive))
        reach.insert(0, "column", column)
        reach.insert(1, "source", source)
        per_seed.append(reach)
    per_seed_frame = pd.concat(per_seed, ignore_index=True)
    counts = aggregate_seeds(per_seed_frame, keys=("column", "env", "task"))
    counts = add_percent_change(counts, BASELINE_COLUMN, column_key="column", on=("env", "task"))
    totals = env_totals(counts, keys=("column", "env"), censored=censored)
    counts, totals = _with_uncertainty(per_seed_frame, counts, totals)
    return per_seed_frame, counts, totals


def _count_notes(
    counts: pd.DataFrame,
    threshold: float,
    warnings: Sequence[str],
    consecutive: int = 1,
    censored: CensoredRule = "run-total",
) -> list[str]:
    """The update-count tables' notes: definitions, steps x batch, the paper's product, warnings."""
    notes = _notes(threshold, with_change=False, censored=censored)
    if consecutive > 1:
        notes.insert(
            1,
            f"Reached = {consecutive} successive evaluations >= {threshold:.0%}; counted at the "
            f"first of them (the paper's criterion is 1).",
        )
    if (counts["reference"] != "").any() or (counts["matched_reference"] != "").any():
        notes.append(
            "Bold = fewer updates than every reference of the column (Single Env, its "
            "batch-matched alone arm), each change resolved; the changes, their CIs and seeds are "
            "in update_changes.md."
        )
    notes.append(
        "Steps × batch = gradient steps to the threshold × the task's mean per-step batch over "
        "them (transitions / steps), means over the seeds that reached it; their product is the "
        "count above. A lower count with as many steps is a smaller batch share, not transfer."
    )
    if (counts["reached"] > 0).any() and any(
        _paper_suffix(r.updates_mean, r.paper_updates_mean, int(r.reached), "plain")
        for r in counts.itertuples(index=False)
    ):
        notes.append(
            "{C×GS×BS: x} = Appendix B's product (gradient steps × the task's batch in force at that "
            "evaluation), shown where the batch changed during the run and it differs from the exact count."
        )
    notes.extend(f"WARNING: {w}; these columns are not the same experiment." for w in warnings)
    return notes


def _change_notes(
    per_seed: pd.DataFrame, counts: pd.DataFrame, labels: dict[str, str], threshold: float
) -> list[str]:
    """How to read the changes table: the change, the CIs (paired or not), n, the MDE, few seeds."""
    notes = [
        f"Change = mean(Arm) / mean(reference) - 1 of the updates to {threshold:.0%}, over the "
        "seeds that reached the task; vs matched = against the arm's batch-matched alone arm, "
        "Single Env (<arm> batch): the same per-task batch without the other environment's data.",
        "95% CI = Fieller's interval of the ratio of means with Student's t quantiles, paired "
        "by seed where the seeds pair (seal.stats.change_ci), in percent; a total's change is "
        "over the tasks both columns reached (tasks), with the tasks as strata. [n/a] = the "
        "reference's mean is not resolved from 0 at these seeds, so no ratio is excluded. Bold "
        "= resolved: the CI excludes 0 and both columns reached it in >= "
        f"{MIN_SEEDS_RESOLVED} seeds.",
        "n = the seeds behind a change: one number when paired by seed (both reached it in the "
        "same seeds), else the arm's vs the reference's (a total: the seeds run).",
        "update_changes.csv adds, for a paired change, the SD of its per-seed relative changes and "
        "the minimum detectable effect at its seeds (seal.stats.mde: two-sided 0.05, power 0.8), "
        "in percent; plots/changes_<env>.png draws every change with its CI and that MDE.",
    ]
    pairs = pairing(counts, labels)
    if pairs["paired"]:
        notes.append("Paired by seed: " + ", ".join(pairs["paired"]) + ".")
    if pairs["unpaired"]:
        notes.append(
            "Unpaired (different seeds, or seeds that reached the task in one column only): "
            + ", ".join(pairs["unpaired"])
            + "."
        )
    few = few_seeds(per_seed, counts)
    if few:
        listed = ", ".join(f"{column} ({n})" for column, n in few.items())
        notes.append(
            f"Fewer than {MIN_SEEDS_RESOLVED} seeds in {listed}: no change against or of "
            f"{'it' if len(few) == 1 else 'them'} is resolved, whatever its CI (none is bold)."
        )
    return notes


def _write_tables(
    tables_dir: Path,
    metrics: pd.DataFrame,
    counts: tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame],
    changes: pd.DataFrame,
    layout: _Layout,
    title: str,
    notes: tuple[list[str], list[str]],
    censored: CensoredRule = "run-total",
) -> dict[str, Path]:
    """update_counts.{csv,md,tex} (counts, then steps x batch), update_counts_per_seed.csv,
    update_changes.{csv,md,tex} (when a column has a reference), success.{csv,md,tex} and
    success_by_task.{csv,md,tex} (SMT Table 1's layout: `seal.reports.by_task`).

    update_counts.csv holds a row per (column, env, task), then one per (column, env) whose task is
    "Total", with the Markdown's total (`updates_total`), `tasks_reached`, `tasks` and `censored_tasks`.
    """
    per_seed, aggregated, totals = counts
    count_notes, change_notes = notes
    tables: dict[str, Path] = {}
    total_rows = totals[["column", "env", "updates_total", "tasks_reached", "tasks"]].assign(
        task="Total", censored_tasks=totals["censored_tasks"]
    )
    with_totals = pd.concat(
        [
            aggregated.assign(
                censored_tasks=(aggregated["reached"] < aggregated["seeds"]).astype(int)
            ),
            total_rows,
        ],
        ignore_index=True,
    )
    # Counts stay whole numbers where the other kind of row leaves them empty.
    counts_columns = ["reached", "seeds", "tasks_reached", "tasks", "censored_tasks"]
    with_totals[counts_columns] = with_totals[counts_columns].astype("Int64")
    frames = [("update_counts", with_totals), ("update_counts_per_seed", per_seed)]
    if len(changes):
        frames.append(("update_changes", changes))
    for name, frame in frames:
        path = tables_dir / f"{name}.csv"
        frame.to_csv(path, index=False)
        tables[path.name] = path
    cols, rows, labels = layout.columns, layout.rows, layout.labels

    def table(style: str, steps: bool = False) -> pd.DataFrame:
        if steps:  # no total: a sum of steps over tasks counts nothing
            return _update_count_table(
                aggregated, None, cols, rows, labels, style, cell=_steps_cell
            )
        return _update_count_table(aggregated, totals, cols, rows, labels, style, censored=censored)

    sections = [
        ("", table("markdown"), table("latex")),
        (
            "Gradient steps × per-step batch",
            table("markdown", steps=True),
            table("latex", steps=True),
        ),
    ]
    tables.update(write_document(tables_dir / "update_counts", title, sections, count_notes))
    if len(changes):
        display = changes_display(changes, labels, "markdown")
        latex = changes_display(changes, labels, "latex")
        tables.update(
            write_document(
                tables_dir / "update_changes",
                "Changes against the reference columns",
                change_sections(display, latex),
                change_notes,
            )
        )
    success_long, success_display = _success_tables(metrics, cols, rows, labels)
    success_csv = tables_dir / "success.csv"
    success_long.to_csv(success_csv, index=False)
    tables[success_csv.name] = success_csv
    success_notes = ["Success rate at each run's last evaluation; mean ± sample std over seeds."]
    tables.update(
        _write_table(success_display, tables_dir / "success", "Final success rate", success_notes)
    )
    tables.update(write_by_task(tables_dir, metrics, cols, rows, labels))
    return tables


def report(
    paths: Sequence[str | os.PathLike[str]],
    out: str | os.PathLike[str] | None = None,
    threshold: float | None = None,
    x: XAxis = "grad_steps",
    consecutive: int = 1,
    censored: CensoredRule = "run-total",
) -> ReportResult:
    """Merge runs and groups into the paper's tables and plots; write them under `out`.

    `paths` are run directories and/or group directories (e.g. the baseline groups and the joint
    groups). Writes `tables/update_counts.{md,csv,tex}` (the counts, then steps x batch),
    `tables/update_counts_per_seed.csv`, `tables/update_changes.{md,csv,tex}` (one row per task,
    column and reference, when a column has one), `tables/success.{md,csv,tex}`,
    `tables/success_by_task.{md,csv,tex}` (learners x task ids, SMT Table 1's layout),
    `plots/success_<env>.png`, `plots/changes_<env>.png` and `plots/critic_loss.png` under
    `out` (default: the run or group directory when there is one, else a new directory
    `<reports root>/comparison/<protocols>/<time>-<random>/`). `threshold` defaults to the runs' configured
    [evaluation].threshold when they agree, else 0.9. `x` is the plots' x axis. `consecutive` = K
    counts a task as reached at the first of K successive evaluations >= threshold
    (`seal.metrics.first_reach`; 1, the default, is the paper's criterion). `censored` is how the
    totals count a task some seed never brought to the threshold (`seal.metrics.CensoredRule`):
    at its run total, the total then printed as a lower bound "≥ x" (default), or as 0 ("zero").
    """
    if isinstance(paths, str | os.PathLike):
        paths = [paths]
    if censored not in CENSORED_RULES:
        raise SealError(
            f"censored rule {censored!r} is not valid; expected one of {', '.join(CENSORED_RULES)}"
        )
    if x not in ("grad_steps", "epoch"):
        raise SealError(f"x axis {x!r} is not valid; expected 'grad_steps' or 'epoch'")
    check_report_inputs(paths, out, threshold)
    groups = _gather(paths)
    threshold = _resolve_threshold(groups, threshold)
    metrics, train = _frames(groups)
    out_dir = Path(out) if out is not None else _default_out(paths, groups)
    tables_dir, plots_dir = _output_dirs(out_dir)

    per_seed, counts, totals = _update_counts(metrics, threshold, consecutive, censored)
    layout = _Layout.of(metrics)
    warnings = _comparability_warnings(groups)
    changes = change_rows(per_seed, counts, totals, layout.rows, layout.columns)
    notes = (
        _count_notes(counts, threshold, warnings, consecutive, censored),
        _change_notes(per_seed, counts, layout.labels, threshold),
    )
    title = f"Millions of updates to reach {threshold:.0%} success"
    tables = _write_tables(
        tables_dir, metrics, (per_seed, counts, totals), changes, layout, title, notes, censored
    )

    colours = column_colours(layout.columns)
    # A seed with no evaluation row (stopped before its first evaluation) counts in no table.
    skipped = [
        f"{run.path}: metrics.csv has no evaluation rows (a run that stopped before its first "
        "evaluation); it is left out of the tables and plots"
        for group in groups
        for run in group.runs
        if run.metrics.empty
    ]
    plots = plot_success(metrics, x, colours, layout.labels, plots_dir, threshold)
    plots.extend(plot_changes(changes, layout.labels, plots_dir))
    loss_plot = _plot_critic_loss(train, x, colours, layout.labels, plots_dir)
    if loss_plot is None:
        skipped.append("critic_loss.png: no critic_loss rows in the runs' train.csv")
    else:
        plots.append(loss_plot)
    ratio_plot = _plot_overestimation(train, x, colours, layout.labels, plots_dir)
    if ratio_plot is None:
        skipped.append(
            "critic_overestimation.png: no eval_q_ratio rows in the runs' train.csv "
            "(runs from before the critic probe, or rewards that earn nothing positive)"
        )
    else:
        plots.append(ratio_plot)
    plots.extend(_plot_schedulers(groups, plots_dir, skipped))

    return ReportResult(
        out_dir=out_dir,
        threshold=threshold,
        tables=tables,
        plots=plots,
        update_counts=counts,
        per_seed=per_seed,
        totals=totals,
        groups=[g.path for g in groups],
        skipped=skipped,
        warnings=warnings,
        changes=changes,
        censored=censored,
    )


__all__ = [
    "METRICS_COLUMNS",
    "TRAIN_COLUMNS",
    "ReportResult",
    "RunData",
    "check_report_inputs",
    "check_threshold",
    "column_label",
    "load_run",
    "report",
    "run_dirs",
]
