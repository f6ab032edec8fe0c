"""Changes with their uncertainty: each column against Single Env and its batch-matched alone arm.

A cell's change is mean(column) / mean(reference) - 1 over the seeds that reached 90%; its 95% CI
is `seal.stats.change_ci` over those seeds, paired by seed when both columns reached it in the
same seeds (a seed's two runs then share the seed's environment draws), else unpaired. An
environment's total changes over the tasks both columns reached, with
`seal.stats.stratified_change_ci` (seeds resampled within each task). A change is resolved when
its CI excludes 0 and both columns reached it in at least `seal.stats.MIN_SEEDS_RESOLVED` seeds;
only a resolved decrease is bold.

The references of a column C are Single Env and, when the report has it, the batch-matched alone
arm "Single Env (C batch)" (`seal.reports.groups.matched_label`): the same per-task batch as C
without the other environment, so the change against it is what the other environment's data did.

`change_rows` lays every change out as one row per (task, column, reference), with the seeds
behind it and, where it is paired by seed, the minimum detectable effect of its seeds
(`seal.stats.mde` of the per-seed relative changes): the changes table and the interval plot.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from seal.metrics import percent_change
from seal.reports.groups import BASELINE_COLUMN, matched_label
from seal.stats import MIN_SEEDS_RESOLVED, change_ci, mde, resolved, stratified_change_ci

# Column prefixes of the two references in the counts and totals tables.
_REFERENCES = ("", "matched_")


def _seed_values(per_seed: pd.DataFrame) -> dict[tuple[str, str], pd.DataFrame]:
    """(column, env) -> seeds x tasks table of millions of updates (NaN where a seed never reached)."""
    values = per_seed.assign(value=per_seed["updates"].where(per_seed["reached"]))
    return {
        (str(column), str(env)): frame.pivot_table(
            index="seed", columns="task", values="value", aggfunc="first", dropna=False
        )
        for (column, env), frame in values.groupby(["column", "env"], sort=False)
    }


def _reference(
    column: str, env: str, prefix: str, tables: Mapping[tuple[str, str], pd.DataFrame]
) -> str:
    """The reference column of `column` for `prefix` ("" Single Env, "matched_"), or "" if none."""
    if column == BASELINE_COLUMN:
        return ""
    if prefix == "":
        return BASELINE_COLUMN if (BASELINE_COLUMN, env) in tables else ""
    if column.startswith(f"{BASELINE_COLUMN} ("):
        return ""  # a matched arm is set against Single Env only
    matched = matched_label(column)
    return matched if (matched, env) in tables else ""


def _pair(arm: pd.DataFrame, base: pd.DataFrame) -> bool:
    # Pairing by seed only when both columns ran exactly the same seeds.
    return set(arm.index) == set(base.index)


def _task_values(table: pd.DataFrame, task: str, seeds: list[int]) -> list[float]:
    column = table[task] if task in table.columns else pd.Series(dtype=float)
    return [float(column.get(seed, math.nan)) for seed in seeds]


def _reached(table: pd.DataFrame, task: str) -> set[int]:
    """The seeds of a seeds x tasks table that reached `task` (a finite count)."""
    values = _task_values(table, task, sorted(table.index))
    return {seed for seed, v in zip(sorted(table.index), values, strict=True) if math.isfinite(v)}


def _pairing(arm: pd.DataFrame, base: pd.DataFrame, tasks: list[str]) -> tuple[bool, bool]:
    """(paired, enough seeds) of a change over `tasks`.

    A change is shown over each column's seeds that reached the task, so its CI pairs by seed only
    when both columns reached every task in exactly the same seeds: pairs dropped for a seed that
    one column never reached would make it the CI of another change. Enough: every task reached
    in >= MIN_SEEDS_RESOLVED seeds on both sides.
    """
    reached = [(_reached(arm, t), _reached(base, t)) for t in tasks]
    paired = _pair(arm, base) and all(a == b for a, b in reached)
    enough = all(min(len(a), len(b)) >= MIN_SEEDS_RESOLVED for a, b in reached)
    return paired, enough


def _cell_change(
    arm: pd.DataFrame, base: pd.DataFrame, task: str
) -> tuple[float, float, bool, bool]:
    """(ci_low %, ci_high %, paired, enough seeds) of one task's change (`_pairing`)."""
    paired, enough = _pairing(arm, base, [task])
    a = _task_values(arm, task, sorted(arm.index))
    b = _task_values(base, task, sorted(base.index))
    low, high = change_ci(a, b, paired=paired)
    return 100 * low, 100 * high, paired, enough


def _with_uncertainty(
    per_seed: pd.DataFrame, counts: pd.DataFrame, totals: pd.DataFrame
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """`counts` and `totals` with each change's CI and resolution, against both references.

    Adds to counts, for prefix "" (Single Env) and "matched_" (the batch-matched alone arm):
    `<prefix>reference`, `<prefix>pct_ci_low`/`_high` (percent), `<prefix>paired`,
    `<prefix>resolved`, and `matched_pct_change`; to totals, per prefix: `<prefix>pct_change`
    over the tasks both reached, its CI, `<prefix>shared_tasks`, `<prefix>paired`, `<prefix>resolved`.
    """
    tables = _seed_values(per_seed)
    means = {(r.column, r.env, r.task): r for r in counts.itertuples(index=False)}
    counts = counts.copy()
    for prefix in _REFERENCES:
        rows: list[dict[str, object]] = []
        for row in counts.itertuples(index=False):
            ref = _reference(row.column, row.env, prefix, tables)
            record: dict[str, object] = {
                "reference": ref,
                "pct_ci_low": math.nan,
                "pct_ci_high": math.nan,
                "paired": False,
                "resolved": False,
            }
            if ref:
                low, high, paired, enough = _cell_change(
                    tables[(row.column, row.env)], tables[(ref, row.env)], row.task
                )
                record.update(pct_ci_low=low, pct_ci_high=high, paired=paired)
                record["resolved"] = enough and resolved((low, high))
                if prefix:
                    base = means.get((ref, row.env, row.task))
                    record["pct_change"] = _percent(row, base)
            rows.append(record)
        extra = pd.DataFrame(rows, index=counts.index)
        if prefix and "pct_change" not in extra.columns:
            extra["pct_change"] = math.nan
        for name in extra.columns:
            counts[f"{prefix}{name}"] = extra[name]
    return counts, _totals_with_uncertainty(totals, counts, tables)


def _percent(row: Any, base: Any) -> float:
    """Percent change of one counts row against its reference's row (NaN if either is missing)."""
    if base is None:
        return math.nan
    change = percent_change(row.updates_mean, base.updates_mean, row.reached > 0, base.reached > 0)
    return math.nan if change is None else change


def _totals_with_uncertainty(
    totals: pd.DataFrame, counts: pd.DataFrame, tables: Mapping[tuple[str, str], pd.DataFrame]
) -> pd.DataFrame:
    totals = totals.copy()
    reached = {
        (r.column, r.env, r.task): (r.reached > 0, r.updates_mean)
        for r in counts.itertuples(index=False)
    }
    for prefix in _REFERENCES:
        rows: list[dict[str, object]] = []
        for row in totals.itertuples(index=False):
            ref = _reference(row.column, row.env, prefix, tables)
            record: dict[str, object] = {
                "reference": ref,
                "pct_change": math.nan,
                "pct_ci_low": math.nan,
                "pct_ci_high": math.nan,
                "shared_tasks": 0,
                "paired": False,
                "resolved": False,
            }
            if ref:
                arm, base = tables[(row.column, row.env)], tables[(ref, row.env)]
                # The total's change is over the tasks both columns reached (the others have no count).
                shared = [
                    task
                    for (column, env, task), (hit, _) in reached.items()
                    if column == row.column
                    and env == row.env
                    and hit
                    and reached.get((ref, env, task), (False, 0.0))[0]
                ]
                if shared:
                    paired, enough = _pairing(arm, base, shared)
                    seeds_a, seeds_b = sorted(arm.index), sorted(base.index)
                    arm_values = {t: _task_values(arm, t, seeds_a) for t in shared}
                    base_values = {t: _task_values(base, t, seeds_b) for t in shared}
                    low, high = stratified_change_ci(arm_values, base_values, paired=paired)
                    arm_total = sum(reached[(row.column, row.env, t)][1] for t in shared)
                    base_total = sum(reached[(ref, row.env, t)][1] for t in shared)
                    record.update(
                        pct_change=100 * (arm_total / base_total - 1)
                        if base_total > 0
                        else math.nan,
                        pct_ci_low=100 * low,
                        pct_ci_high=100 * high,
                        shared_tasks=len(shared),
                        paired=paired,
                        resolved=enough and resolved((low, high)),
                    )
            rows.append(record)
        extra = pd.DataFrame(rows, index=totals.index)
        for name in extra.columns:
            totals[f"{prefix}{name}"] = extra[name]
    return totals


def few_seeds(per_seed: pd.DataFrame, counts: pd.DataFrame) -> dict[str, int]:
    """Columns in a comparison whose seeds are fewer than MIN_SEEDS_RESOLVED: column -> seeds."""
    compared = set()
    for prefix in _REFERENCES:
        has_ref = counts[f"{prefix}reference"] != ""
        compared |= set(counts.loc[has_ref, "column"]) | set(
            counts.loc[has_ref, f"{prefix}reference"]
        )
    seeds = per_seed.groupby("column")["seed"].nunique()
    return {str(c): int(n) for c, n in seeds.items() if c in compared and n < MIN_SEEDS_RESOLVED}


def pairing(counts: pd.DataFrame, labels: Mapping[str, str]) -> dict[str, list[str]]:
    """ "paired" / "unpaired" -> the comparisons ("High FK vs Single Env (MW)") of each kind.

    Only cells with a CI count; a comparison is paired when every such cell was.
    """
    out: dict[str, list[str]] = {"paired": [], "unpaired": []}
    for prefix in _REFERENCES:
        with_ci = counts[f"{prefix}pct_ci_low"].notna()
        rows = counts[(counts[f"{prefix}reference"] != "") & with_ci]
        keys = ["column", f"{prefix}reference", "env"]
        for (column, ref, env), paired in (
            rows.groupby(keys, sort=False)[f"{prefix}paired"].all().items()
        ):
            kind = "paired" if paired else "unpaired"
            out[kind].append(f"{column} vs {ref} ({labels.get(env, env)})")
    return out


CHANGE_ROW_COLUMNS = (
    "env",
    "task",
    "column",
    "reference",
    "vs",
    "pct_change",
    "pct_ci_low",
    "pct_ci_high",
    "n_column",
    "n_reference",
    "paired",
    "resolved",
    "shared_tasks",
    "sd_paired_pct",
    "mde_pct",
)
"""update_changes.csv's columns (`change_rows`)."""


def _paired_spread(arm: pd.DataFrame, base: pd.DataFrame, task: str) -> tuple[float, float]:
    """(SD, MDE) in percent of the per-seed relative changes arm / base - 1 of one task's pairs."""
    seeds = sorted(set(arm.index) & set(base.index))
    a = np.array(_task_values(arm, task, seeds))
    b = np.array(_task_values(base, task, seeds))
    keep = np.isfinite(a) & np.isfinite(b) & (b > 0)
    if keep.sum() < 2:
        return math.nan, math.nan
    sd = float(np.std(100 * (a[keep] / b[keep] - 1), ddof=1))
    return sd, mde(sd, int(keep.sum()))


def change_rows(
    per_seed: pd.DataFrame,
    counts: pd.DataFrame,
    totals: pd.DataFrame,
    rows: Sequence[tuple[str, str]],
    columns: Sequence[str],
) -> pd.DataFrame:
    """One row per (task, column, reference) with a reference, tasks in `rows`' order, then the
    totals of each env; CHANGE_ROW_COLUMNS. `vs` is "Single Env" or "matched" (the column's
    batch-matched alone arm); n_column and n_reference are the seeds that reached the task in each
    (a total: the seeds run); a paired row has its seeds' SD and MDE, in percent."""
    tables = _seed_values(per_seed)
    cells = {(r.column, r.env, r.task): r for r in counts.itertuples(index=False)}
    records: list[dict[str, object]] = []

    def record(env: str, task: str, column: str, prefix: str, row: Any, n: tuple[int, int]) -> None:
        records.append(
            {
                "env": env,
                "task": task,
                "column": column,
                "reference": getattr(row, f"{prefix}reference"),
                "vs": "matched" if prefix else BASELINE_COLUMN,
                "pct_change": float(getattr(row, f"{prefix}pct_change")),
                "pct_ci_low": float(getattr(row, f"{prefix}pct_ci_low")),
                "pct_ci_high": float(getattr(row, f"{prefix}pct_ci_high")),
                "n_column": n[0],
                "n_reference": n[1],
                "paired": bool(getattr(row, f"{prefix}paired")),
                "resolved": bool(getattr(row, f"{prefix}resolved")),
                "shared_tasks": int(getattr(row, f"{prefix}shared_tasks", 0) or 0),
                "sd_paired_pct": math.nan,
                "mde_pct": math.nan,
            }
        )

    for env, task in rows:
        for column in columns:
            row = cells.get((column, env, task))
            for prefix in _REFERENCES:
                ref = "" if row is None else getattr(row, f"{prefix}reference")
                if not ref:
                    continue
                base = cells[(ref, env, task)]
                record(env, task, column, prefix, row, (int(row.reached), int(base.reached)))
                if records[-1]["paired"]:
                    spread = _paired_spread(tables[(column, env)], tables[(ref, env)], task)
                    records[-1].update(sd_paired_pct=spread[0], mde_pct=spread[1])
    seeds = per_seed.groupby(["column", "env"])["seed"].nunique()
    total_rows = {(t.column, t.env): t for t in totals.itertuples(index=False)}
    for env in dict.fromkeys(env for env, _ in rows):
        for column in columns:
            total = total_rows.get((column, env))
            for prefix in _REFERENCES:
                ref = "" if total is None else getattr(total, f"{prefix}reference")
                if not ref:
                    continue
                n = (int(seeds.get((column, env), 0)), int(seeds.get((ref, env), 0)))
                record(env, "Total", column, prefix, total, n)
    return pd.DataFrame.from_records(records, columns=list(CHANGE_ROW_COLUMNS))


__all__ = ["change_rows", "few_seeds", "pairing"]
