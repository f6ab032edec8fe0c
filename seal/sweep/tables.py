"""The tables a sweep or search writes: its trials (ranked, for a search) and the aggregated `seal report` tables.

`rank_trials` orders a search's trials (finished before stopped early before failed; by mean
success, then mean return), `_write_trials_table` writes trials.{csv,md} / search.{csv,md}, and
`_aggregate` runs `seal report` over the finished runs into the sweep directory's tables/.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from pathlib import Path

from seal.errors import SealError
from seal.protocols.toml_io import toml_value
from seal.run.rundir import atomic_write_text
from seal.sweep.trials import TrialRecord


def _aggregate(sweep_dir: Path, trials: Sequence[TrialRecord], notes: list[str]) -> Path | None:
    """`seal report` tables of the finished runs under sweep_dir/tables; None (with a note) if impossible."""
    finished = [t.run_dir for t in trials if t.status == "finished"]
    if not finished:
        notes.append("no trial finished, so there is no aggregated table")
        return None
    from seal.reports import report

    try:
        result = report(finished, out=sweep_dir)
    except SealError as exc:
        notes.append(f"aggregated table not made: {exc}")
        return None
    return result.tables.get("update_counts.md")


_TABLE_COLUMNS = (
    "rank",
    "trial",
    "status",
    "mean_success",
    "mean_return",
    "evaluations",
    "seed",
    "start",
    "wall_s",
    "error",
    "run_dir",
)


def _write_trials_table(stem: Path, trials: Sequence[TrialRecord], *, ranked: bool) -> Path:
    """<stem>.csv and <stem>.md: one row per trial (search: ranked, sampled values as columns)."""
    import pandas as pd

    keys = list(dict.fromkeys(k for t in trials for k in t.sample))
    rows = []
    for i, t in enumerate(trials, start=1):
        row = {c: getattr(t, c, None) for c in _TABLE_COLUMNS if c != "rank"}
        row["rank"] = i if ranked else None
        row.update({k: t.sample.get(k) for k in keys})
        rows.append(row)
    columns = [c for c in _TABLE_COLUMNS if ranked or c != "rank"]
    columns = columns[:3] + keys + columns[3:]
    frame = pd.DataFrame(rows, columns=columns)
    frame.to_csv(stem.with_suffix(".csv"), index=False)
    shown = frame.drop(columns=["run_dir"]).copy()
    for key in keys:
        shown[key] = [
            f"{v:.4g}" if isinstance(v, float) else toml_value(v) if v is not None else ""
            for v in shown[key]
        ]
    for column in ("mean_success", "mean_return"):
        shown[column] = [("" if v is None or v != v else f"{v:.3f}") for v in shown[column]]
    shown["error"] = [str(e)[:120] for e in shown["error"]]
    title = "Search trials, best first" if ranked else "Sweep trials"
    note = (
        "Ranked by mean success at the last evaluation, then mean return; trials stopped early by ASHA "
        "rank after finished ones, failed trials last."
        if ranked
        else "mean_success / mean_return: means over every (env, task) at the run's last evaluation."
    )
    atomic_write_text(
        stem.with_suffix(".md"),
        f"# {title}\n\n{shown.to_markdown(index=False, disable_numparse=True)}\n\n{note}\n",
    )
    return stem.with_suffix(".md")


def rank_trials(trials: Iterable[TrialRecord]) -> list[TrialRecord]:
    """Best first: finished before stopped early before failed; within each, by mean success then mean return.

    Short searches often leave every trial at 0 success, so mean return breaks ties; a trial that
    ASHA stopped saw less training, so it never ranks above one that ran to the end.
    """
    order = {"finished": 0, "stopped": 1, "preempted": 2, "pending": 2, "failed": 3}

    def key(t: TrialRecord) -> tuple[float, float, float]:
        success = t.mean_success if t.mean_success is not None else -math.inf
        ret = t.mean_return if t.mean_return is not None else -math.inf
        return (order[t.status], -success, -ret)

    return sorted(trials, key=key)
