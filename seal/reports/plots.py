"""Plots: the success curves of Figs. 2-4, the critic-loss curves of Fig. 7, scheduler timelines.

Each curve is a column's mean ± sample std over seeds, seeds aligned on the epoch and drawn
against gradient steps or epochs (`XAxis`), in Fig. 4's colours for the paper's columns. Runs
with a scheduler.csv get their pool-membership (and SMT budget) timelines from
seal.schedulers.plots. Figures are drawn with matplotlib's Agg canvas, never a display.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from seal.reports.groups import BASELINE_COLUMN, _column_rank, _Group

# Fig. 4's colours: equal ratio green, high MW blue, high FK orange; the baseline is black.
_COLUMN_COLOURS = {
    BASELINE_COLUMN: "black",
    "50/50": "tab:green",
    "High FK": "tab:orange",
    "High MW": "tab:blue",
}
_OTHER_COLOURS = (
    "tab:red",
    "tab:purple",
    "tab:brown",
    "tab:pink",
    "tab:olive",
    "tab:cyan",
    "tab:gray",
)

XAxis = Literal["grad_steps", "epoch"]


def _colours(columns: Sequence[str]) -> dict[str, str]:
    others = iter(_OTHER_COLOURS * (1 + len(columns) // len(_OTHER_COLOURS)))
    return {c: _COLUMN_COLOURS.get(c) or next(others) for c in columns}


def _markers(points: int) -> dict[str, Any]:
    # Short curves (a few evaluations, or a single one) need markers to be visible at all.
    return {"marker": "o", "markersize": 3} if points <= 20 else {}


def _save(fig: Figure, path: Path) -> Path:
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    return path


def _mean_std_over_seeds(frame: pd.DataFrame, x: str, value: str) -> pd.DataFrame:
    """Per (column, env, step): x position, mean and sample std over seeds of `value`."""
    # Seeds are aligned on the epoch (evaluations happen at the same epochs), x is their mean there.
    grouped = frame.groupby(["column", "env", "epoch"], sort=True)
    return grouped.agg(
        x=(x, "mean"), mean=(value, "mean"), std=(value, "std"), seeds=("seed", "nunique")
    ).reset_index()


def _plot_success(
    metrics: pd.DataFrame,
    x: XAxis,
    colours: dict[str, str],
    labels: dict[str, str],
    plots: Path,
    threshold: float,
) -> list[Path]:
    """Figs. 2-4: per environment, success averaged over its tasks, mean ± std over seeds, per column."""
    per_eval = metrics.groupby(["column", "env", "seed", "epoch"], sort=False).agg(
        success=("success", "mean"), grad_steps=("grad_steps", "mean")
    )
    curves = _mean_std_over_seeds(per_eval.reset_index(), x, "success")
    written = []
    for env in dict.fromkeys(metrics["env"]):
        fig = Figure(figsize=(6.4, 4.0))
        ax = fig.add_subplot()
        env_curves = curves[curves["env"] == env]
        for column in sorted(env_curves["column"].unique(), key=_column_rank):
            curve = env_curves[env_curves["column"] == column].sort_values("x")
            std = curve["std"].fillna(0.0)
            seeds = int(curve["seeds"].max())
            ax.plot(
                curve["x"],
                curve["mean"],
                color=colours[column],
                label=f"{column} ({seeds} seed{'s' * (seeds > 1)})",
                **_markers(len(curve)),
            )
            ax.fill_between(
                curve["x"],
                (curve["mean"] - std).clip(0, 1),
                (curve["mean"] + std).clip(0, 1),
                color=colours[column],
                alpha=0.2,
                linewidth=0,
            )
        ax.axhline(
            threshold, color="grey", linestyle=":", linewidth=1, label=f"threshold {threshold:g}"
        )
        ax.set_ylim(-0.02, 1.02)
        ax.set_xlabel("gradient steps" if x == "grad_steps" else "epoch")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_ylabel("success rate (mean over tasks)")
        ax.set_title(f"{labels[env]}: success, mean ± std over seeds")
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize="small")
        written.append(_save(fig, plots / f"success_{_safe(env)}.png"))
    return written


def _plot_critic_loss(
    train: pd.DataFrame, x: XAxis, colours: dict[str, str], labels: dict[str, str], plots: Path
) -> Path | None:
    """Fig. 7: the value-function (critic) loss per environment, mean ± std over seeds, per column."""
    if train.empty or "critic_loss" not in set(train["key"]):
        return None
    loss = train[train["key"] == "critic_loss"].copy()
    loss["env"] = loss["env"].fillna("all")
    loss = (
        loss.groupby(["column", "env", "seed", "epoch"], sort=False)
        .agg(value=("value", "mean"), grad_steps=("grad_steps", "mean"))
        .reset_index()
    )
    curves = _mean_std_over_seeds(loss, x, "value")
    envs = list(dict.fromkeys(loss["env"]))
    fig = Figure(figsize=(6.0 * len(envs), 4.0))
    axes = fig.subplots(1, len(envs), squeeze=False)[0]
    positive = bool((curves["mean"] > 0).all())
    for ax, env in zip(axes, envs, strict=True):
        env_curves = curves[curves["env"] == env]
        for column in sorted(env_curves["column"].unique(), key=_column_rank):
            curve = env_curves[env_curves["column"] == column].sort_values("x")
            std = curve["std"].fillna(0.0)
            lower = (
                (curve["mean"] - std).clip(lower=curve["mean"] * 0.01)
                if positive
                else curve["mean"] - std
            )
            ax.plot(
                curve["x"],
                curve["mean"],
                color=colours[column],
                label=column,
                **_markers(len(curve)),
            )
            ax.fill_between(
                curve["x"],
                lower,
                curve["mean"] + std,
                color=colours[column],
                alpha=0.2,
                linewidth=0,
            )
        if positive:
            ax.set_yscale("log")  # losses span orders of magnitude as Q-values grow
        ax.set_xlabel("gradient steps" if x == "grad_steps" else "epoch")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_ylabel("critic loss")
        ax.set_title(f"{labels.get(env, env)}: value-function loss")
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize="small")
    return _save(fig, plots / "critic_loss.png")


def _plot_schedulers(groups: Sequence[_Group], plots: Path, skipped: list[str]) -> list[Path]:
    """plots/scheduler_membership.png (and scheduler_budget.png for SMT) of runs with a scheduler.csv.

    One run: those names; several: `scheduler_<protocol>_<group>_seed-<n>_<kind>.png`. A timeline
    of one snapshot with every task alike (the default uniform scheduler) is not drawn; one
    that cannot be plotted (empty, or written by an older runner) is reported in `skipped`.
    """
    from seal.schedulers.plots import plot_budget_usage, plot_membership

    runs = [r for g in groups for r in g.runs if (r.path / "scheduler.csv").is_file()]
    out: list[Path] = []
    for run in runs:
        tag = "" if len(runs) == 1 else "_" + _safe(f"{run.protocol}_{run.group}_seed-{run.seed}")
        try:
            timeline = pd.read_csv(run.path / "scheduler.csv")
            if timeline["status"].nunique() <= 1 and timeline["epoch"].nunique() <= 1:
                continue  # one snapshot, every task alike (the default uniform scheduler): nothing to draw
            out.append(plot_membership(timeline, plots / f"scheduler{tag}_membership.png"))
            if "used" in timeline:  # SMT's budget usage (Fig. 6); curricula have no budgets
                out.append(plot_budget_usage(timeline, plots / f"scheduler{tag}_budget.png"))
        except (ValueError, KeyError, pd.errors.EmptyDataError) as exc:
            skipped.append(f"scheduler{tag}_*.png: {run.path / 'scheduler.csv'}: {exc}")
    return out


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.+-]+", "_", name)
