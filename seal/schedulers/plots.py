"""Plots of a scheduler's timeline: SMT's budget usage per task (SMT Fig. 6) and pool/phase membership.

Both take the records of `Scheduler.timeline()` (or the rows of the CSV the runner writes from
them) and write a PNG with matplotlib's Agg backend.
"""

from __future__ import annotations

import zlib
from collections.abc import Iterable, Mapping
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402 - the backend must be chosen first
import pandas as pd  # noqa: E402

STATUS_COLOURS: dict[str, str] = {
    "main": "#bbbbbb",
    "training": "#1f77b4",
    "solved": "#2ca02c",
    "unsolvable": "#d62728",
    "off": "#eeeeee",
}


def _frame(records: Iterable[Mapping[str, object]] | pd.DataFrame) -> pd.DataFrame:
    df = records.copy() if isinstance(records, pd.DataFrame) else pd.DataFrame(list(records))
    if df.empty:
        raise ValueError("the timeline has no records to plot")
    df["label"] = df["env"].astype(str) + "/" + df["task"].astype(str)
    return df


def plot_budget_usage(
    records: Iterable[Mapping[str, object]] | pd.DataFrame,
    path: str | Path,
    total_budget: float | None = None,
) -> Path:
    """SMT Fig. 6: each task's share S_i / B of the total budget against the env steps spent.

    Between snapshots a task's usage grows linearly (it collects one episode per epoch while in
    a collecting pool), so the lines joining the snapshots are exact. `total_budget` defaults to
    the env steps spent at the last snapshot (B1 + B2 at the end of a run).
    """
    df = _frame(records)
    if "used" not in df:
        raise ValueError("budget usage needs SMT timeline records (a 'used' column)")
    total = float(total_budget or df["env_steps"].max() or 1)
    fig, ax = plt.subplots(figsize=(7, 4))
    styles = ("-", "--", ":", "-.")  # tasks with equal usage would otherwise hide each other
    for i, (label, rows) in enumerate(df.groupby("label", sort=False)):
        ax.plot(
            rows["env_steps"], rows["used"] / total, linestyle=styles[i % len(styles)], label=label
        )
    ax.set_xlabel("env steps spent (B)")
    ax.set_ylabel("budget usage S_i / B")
    ax.set_title("Budget usage per task")
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_membership(
    records: Iterable[Mapping[str, object]] | pd.DataFrame, path: str | Path, x: str = "env_steps"
) -> Path:
    """A bar per task coloured by its pool (SMT) or phase membership (curricula) over `x`."""
    df = _frame(records)
    labels = list(dict.fromkeys(df["label"]))
    end = float(df[x].max()) or 1.0
    fig, ax = plt.subplots(figsize=(8, 0.35 * len(labels) + 1.2))
    seen: set[str] = set()
    colour_cycle = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for row_index, label in enumerate(labels):
        rows = df[df["label"] == label].sort_values(x, kind="stable")
        starts = rows[x].tolist()
        statuses = rows["status"].astype(str).tolist()
        for i, (start, status) in enumerate(zip(starts, statuses, strict=True)):
            stop = starts[i + 1] if i + 1 < len(starts) else end
            base = status.split(":")[-1]
            colour = (
                STATUS_COLOURS.get(base)
                or colour_cycle[zlib.crc32(base.encode()) % len(colour_cycle)]
            )
            ax.barh(
                row_index,
                max(stop - start, end * 1e-3),
                left=start,
                color=colour,
                label=None if base in seen else base,
            )
            seen.add(base)
    ax.set_yticks(range(len(labels)), labels, fontsize=7)
    ax.invert_yaxis()
    ax.set_xlabel(x.replace("_", " "))
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
