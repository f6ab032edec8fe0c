"""Plots: the success curves of Figs. 2-4, the changes with their CIs, the critic-loss curves of
Fig. 7, scheduler timelines.

A success curve is a column's mean over seeds with a 95% bootstrap band (seeds resampled,
`seal.stats.bootstrap_band`), a critic-loss curve its mean ± sample std; seeds are aligned on the
epoch and drawn against gradient steps or epochs (`XAxis`), in Fig. 4's colours for the paper's
columns. `plot_intervals` draws changes as one row per arm: the change, its CI, the zero line and
the minimum detectable effect around it (`plot_changes` for a report's changes table). Runs with
a scheduler.csv get their pool-membership (and SMT budget) timelines from seal.schedulers.plots.
Figures are drawn with matplotlib's Agg canvas, never a display.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import MaxNLocator

from seal.reports.groups import BASELINE_COLUMN, _column_rank, _Group
from seal.stats import bootstrap_band

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


def column_colours(columns: Sequence[str]) -> dict[str, str]:
    """Each column's colour: Fig. 4's for the paper's columns, the others from a cycle."""
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


def success_curves(metrics: pd.DataFrame, x: XAxis) -> pd.DataFrame:
    """Per (column, env, epoch): x, the mean over seeds of the success averaged over the env's
    tasks, its 95% bootstrap band (`low`, `high`) and the seeds.

    A seed whose run stopped once every task had reached the threshold (`stops_when_reached`)
    holds its last evaluation at the epochs after it, as the transfer bench's AUC does: left out,
    the mean past the first stop would be that of the seeds still failing, and would fall.

    Evaluations in which some task of the env stopped early (`decided_early`,
    `evaluation.decide_early`) are hidden, for every seed of the column: such a task's success is
    over its first episodes (45/45 reads 1.0), exact as a verdict but not as a rate, so the
    curve is drawn through the evaluations that ran every episode (`evaluation.full_every`).
    """
    if "stops_when_reached" not in metrics.columns:
        metrics = metrics.assign(stops_when_reached=False)
    if "decided_early" in metrics.columns:
        hidden = metrics.groupby(["column", "env", "epoch"])["decided_early"].transform("any")
        metrics = metrics[~hidden.astype(bool)]
    per_eval = (
        metrics.groupby(["column", "env", "seed", "epoch"], sort=False)
        .agg(
            success=("success", "mean"),
            grad_steps=("grad_steps", "mean"),
            held=("stops_when_reached", "any"),
        )
        .reset_index()
    )
    frames = []
    for (column, env), frame in per_eval.groupby(["column", "env"], sort=False):
        table = frame.pivot_table(index="seed", columns="epoch", values="success")
        held = frame.groupby("seed")["held"].any().reindex(table.index).to_numpy(dtype=bool)
        table.loc[held] = table.loc[held].ffill(axis=1)
        low, high = bootstrap_band(table.to_numpy())
        frames.append(
            pd.DataFrame(
                {
                    "column": column,
                    "env": env,
                    "epoch": table.columns,
                    "x": frame.groupby("epoch")[x].mean().reindex(table.columns).to_numpy(),
                    "mean": table.mean(axis=0).to_numpy(),
                    "low": low,
                    "high": high,
                    "seeds": table.notna().sum(axis=0).to_numpy(),
                }
            )
        )
    if not frames:  # every evaluation hidden (decided early): no point to draw
        return pd.DataFrame(columns=["column", "env", "epoch", "x", "mean", "low", "high", "seeds"])
    return pd.concat(frames, ignore_index=True)


def plot_success(
    metrics: pd.DataFrame,
    x: XAxis,
    colours: dict[str, str],
    labels: dict[str, str],
    plots: Path,
    threshold: float,
) -> list[Path]:
    """Figs. 2-4: per environment, success averaged over its tasks, mean over seeds with a 95%
    bootstrap band, per column; `plots/success_<env>.png`."""
    curves = success_curves(metrics, x)
    written = []
    for env in dict.fromkeys(metrics["env"]):
        fig = Figure(figsize=(6.4, 4.0))
        ax = fig.add_subplot()
        env_curves = curves[curves["env"] == env]
        for column in sorted(env_curves["column"].unique(), key=_column_rank):
            curve = env_curves[env_curves["column"] == column].sort_values("x")
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
                curve["low"],
                curve["high"],
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
        ax.set_title(f"{labels.get(env, env)}: success, mean over seeds, 95% bootstrap band")
        notes = []
        if metrics.get("stops_when_reached", pd.Series(False)).any():
            notes.append(
                "runs stop once every task has reached the threshold; a stopped run holds its last value"
            )
        if metrics[metrics["env"] == env].get("decided_early", pd.Series(False)).any():
            notes.append(
                "evaluations decided early (evaluation.decide_early) hidden: points are full evaluations"
            )
        for i, note in enumerate(notes):
            ax.text(
                0.0,
                -0.2 - 0.06 * i,
                note,
                transform=ax.transAxes,
                fontsize="x-small",
                color="grey",
            )
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize="small")
        written.append(_save(fig, plots / f"success_{_safe(env)}.png"))
    return written


@dataclass(frozen=True)
class Interval:
    """One row of an interval plot: a change, its CI and the minimum detectable effect."""

    label: str
    value: float
    low: float
    high: float
    mde: float = math.nan
    """The smallest effect the row's seeds can detect (seal.stats.mde); NaN: none drawn."""
    resolved: bool = False
    """Drawn in colour: the CI excludes 0 with enough seeds (seal.stats.MIN_SEEDS_RESOLVED)."""


def plot_intervals(
    panels: Sequence[tuple[str, Sequence[Interval]]],
    path: Path,
    xlabel: str,
    title: str,
    limits: tuple[float, float] | None = None,
) -> Path:
    """One panel per (title, rows), one row per arm: the change (a dot, in colour when resolved),
    its CI (a bar), the zero line, and the band -MDE..+MDE around 0 within which the row's seeds
    would miss a true effect more often than 1 time in 5. With `limits` the axis spans them: a
    CI or band beyond is cut at the edge and the cut marked with an arrowhead, so that one row's
    CI of +-10,000% does not squeeze the others to a point."""
    low_edge, high_edge = limits if limits is not None else (-math.inf, math.inf)

    def clip(x: float) -> float:
        return min(max(x, low_edge), high_edge)

    heights = [0.45 * max(len(rows), 1) + 0.9 for _, rows in panels]
    fig = Figure(figsize=(7.0, sum(heights) + 0.9), layout="constrained")
    axes = fig.subplots(len(panels), 1, squeeze=False, height_ratios=heights)[:, 0]
    for ax, (name, rows) in zip(axes, panels, strict=True):
        ys = np.arange(len(rows))[::-1]
        for y, row in zip(ys, rows, strict=True):
            if math.isfinite(row.mde):
                left, right = clip(-row.mde), clip(row.mde)
                ax.barh(y, right - left, left=left, height=0.6, color="0.85", zorder=0)
            if not math.isfinite(row.value):
                ax.text(0, y, " n/a", va="center", fontsize="small", color="grey")
                continue
            colour = "tab:blue" if row.resolved else "black"
            value = clip(row.value)
            if math.isfinite(row.low) and math.isfinite(row.high):
                low, high = clip(row.low), clip(row.high)
                ax.errorbar(
                    value,
                    y,
                    xerr=[[value - low], [high - value]],
                    fmt="o",
                    color=colour,
                    capsize=3,
                    zorder=2,
                )
                for end, cut, marker in ((row.low, low, "<"), (row.high, high, ">")):
                    if end != cut:
                        ax.plot(cut, y, marker, color=colour, markersize=7, zorder=3)
            else:  # the seeds bound no interval (a reference not resolved from 0, one seed)
                ax.plot(value, y, "o", color=colour, zorder=2)
                ax.annotate(
                    "no CI",
                    (value, y),
                    xytext=(6, 0),
                    textcoords="offset points",
                    va="center",
                    fontsize="x-small",
                    color="grey",
                )
        ax.axvline(0.0, color="black", linewidth=1, zorder=1)
        ax.set_yticks(ys, [r.label for r in rows], fontsize="small")
        ax.set_ylim(-0.7, len(rows) - 0.3)
        if limits is not None:
            pad = 0.03 * (high_edge - low_edge)
            ax.set_xlim(low_edge - pad, high_edge + pad)
        ax.set_title(name, fontsize="medium")
        ax.grid(axis="x", alpha=0.3)
    axes[-1].set_xlabel(xlabel)
    handles = [
        Line2D([], [], color="black", marker="o", label="change, 95% CI"),
        Line2D([], [], color="tab:blue", marker="o", label="resolved"),
        Patch(color="0.85", label="±MDE (power 0.8, two-sided 0.05)"),
    ]
    if limits is not None:
        handles.append(Line2D([], [], color="black", marker=">", linestyle="", label="cut at axis"))
    fig.legend(handles=handles, loc="outside lower center", ncols=len(handles), fontsize="x-small")
    fig.suptitle(title)
    return _save(fig, path)


CHANGE_AXIS = (-100.0, 300.0)
"""The changes plot's axis (percent): no task takes fewer than 0 updates (-100%), and a change
beyond 4 times the reference's updates (+300%) reads the same for the question asked."""


def plot_changes(changes: pd.DataFrame, labels: Mapping[str, str], plots: Path) -> list[Path]:
    """`plots/changes_<env>.png`: a report's changes (seal.reports.changes.change_rows), one
    panel per task and total, one row per (arm, reference), in percent."""
    written = []
    for env, rows in changes.groupby("env", sort=False):
        panels = [
            (
                f"{task} ({labels.get(str(env), env)})",
                [
                    Interval(
                        f"{r.column} vs {r.vs}",
                        r.pct_change,
                        r.pct_ci_low,
                        r.pct_ci_high,
                        r.mde_pct,
                        bool(r.resolved),
                    )
                    for r in task_rows.itertuples(index=False)
                ],
            )
            for task, task_rows in rows.groupby("task", sort=False)
        ]
        path = plots / f"changes_{_safe(str(env))}.png"
        written.append(
            plot_intervals(
                panels,
                path,
                "change in updates to the threshold (%)",
                f"{labels.get(str(env), env)}: changes against the references",
                limits=CHANGE_AXIS,
            )
        )
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


def _plot_overestimation(
    train: pd.DataFrame, x: XAxis, colours: dict[str, str], labels: dict[str, str], plots: Path
) -> Path | None:
    """plots/critic_overestimation.png: per task, the critic's Q at the evaluation episodes' first
    states over what they earned (train.csv's `eval_q_ratio/<task>`, `seal.learner.critic_probe`),
    mean ± std over seeds, per column; 1 is a critic that says what the policy earns."""
    if train.empty:
        return None
    ratio = train[train["key"].astype(str).str.startswith("eval_q_ratio/")].copy()
    if ratio.empty:
        return None
    task = ratio["key"].str.removeprefix("eval_q_ratio/")
    ratio["env"] = ratio["env"].fillna("all").astype(str) + "\0" + task
    curves = _mean_std_over_seeds(ratio, x, "value")
    panels = list(dict.fromkeys(ratio["env"]))
    across = min(len(panels), 5)
    down = -(-len(panels) // across)
    fig = Figure(figsize=(4.0 * across, 3.2 * down))
    axes = fig.subplots(down, across, squeeze=False).ravel()
    for ax, panel in zip(axes, panels, strict=False):
        env, task_name = panel.split("\0")
        panel_curves = curves[curves["env"] == panel]
        for column in sorted(panel_curves["column"].unique(), key=_column_rank):
            curve = panel_curves[panel_curves["column"] == column].sort_values("x")
            std = curve["std"].fillna(0.0)
            ax.plot(curve["x"], curve["mean"], color=colours[column], label=column)
            ax.fill_between(
                curve["x"],
                curve["mean"] - std,
                curve["mean"] + std,
                color=colours[column],
                alpha=0.2,
                linewidth=0,
            )
        ax.axhline(1.0, color="black", linewidth=0.8, linestyle="--")
        ax.set_xlabel("gradient steps" if x == "grad_steps" else "epoch")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_ylabel("Q at start / earned")
        ax.set_title(f"{labels.get(env, env)}: {task_name}", fontsize="small")
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize="x-small")
    for ax in axes[len(panels) :]:
        ax.set_visible(False)
    return _save(fig, plots / "critic_overestimation.png")


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
