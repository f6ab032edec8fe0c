"""The transfer testbed's tables and plots, from `seal.experiments.statistics.summarise`'s result.

`transfer_documents` lays the bench's tables out as `seal.reports.tables` documents: `counts` (M
transitions of the target to 90%, task rows and arm columns, then gradient steps x per-step batch)
and `changes` (each arm against its alone arm with a paired Fieller CI, then one note per paired
statistic of `STATISTICS`); one thing a cell. `format_table` renders them as Markdown for the
terminal; `write_transfer_report` writes them (Markdown and LaTeX) and the plots (each arm's paired
statistics with CI and MDE, the target's success with a bootstrap band) to `<out>/transfer/`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from seal.experiments.arms import ARMS, TARGET_ENV, Arm
from seal.experiments.statistics import CHANGE_BOUNDS, TargetCost
from seal.metrics import AT_LEAST, DEFAULT_THRESHOLD, format_count, format_number

TASK_LABEL = "point_view"
"""How the tables name the target's env ("t0 (point_view)")."""


def _values(runs: Sequence[TargetCost], task: str) -> list[float]:
    """Per seed: the target's transitions to 90% of `task` ("Total": all tasks; censored: totals)."""
    return [c.consumed if task == "Total" else c.per_task[task] for c in runs]


def _reached(runs: Sequence[TargetCost], task: str) -> int:
    return sum(1 for c in runs if (c.censored == 0 if task == "Total" else task in c.reached))


def _counts_display(
    costs: Mapping[str, Sequence[TargetCost]], chosen: Sequence[Arm], tasks: Sequence[str]
) -> pd.DataFrame:
    """Task rows (and Total), arm columns: M transitions to 90% as mean ± std [reached/seeds]."""
    records = []
    for task in [*tasks, "Total"]:
        record = {"Task": f"{task} ({TASK_LABEL})"}
        for arm in chosen:
            values = _values(costs[arm.name], task)
            std = float(np.std(values, ddof=1)) / 1e6 if len(values) > 1 else math.nan
            # Censored seeds count their total, so every cell has a mean, a lower bound ("≥") where
            # a seed is censored; [k/n] says how many reached.
            cell = format_count(float(np.mean(values)) / 1e6, std, 1, len(values))
            reached = _reached(costs[arm.name], task)
            bound = f"{AT_LEAST} " if reached < len(values) else ""
            record[arm.label] = bound + cell.rsplit(" [", 1)[0] + f" [{reached}/{len(values)}]"
        records.append(record)
    return pd.DataFrame.from_records(records)


def _steps_display(
    costs: Mapping[str, Sequence[TargetCost]], chosen: Sequence[Arm], tasks: Sequence[str]
) -> pd.DataFrame:
    """Per (task, arm): gradient steps to 90% x mean per-step batch = the transitions (means over seeds)."""
    records = []
    for task in tasks:
        record = {"Task": f"{task} ({TASK_LABEL})"}
        for arm in chosen:
            runs = costs[arm.name]
            steps = float(np.mean([c.per_task_steps[task] for c in runs]))
            per_step = float(
                np.mean([c.per_task[task] / max(c.per_task_steps[task], 1) for c in runs])
            )
            record[arm.label] = f"{format_number(steps)} × {per_step:.1f}"
        records.append(record)
    return pd.DataFrame.from_records(records)


def _change_rows(
    costs: Mapping[str, Sequence[TargetCost]], chosen: Sequence[Arm], tasks: Sequence[str]
) -> pd.DataFrame:
    """Per (task or Total, arm with an alone arm): the change of the mean transitions to 90%
    against the alone arm, with its paired 95% Fieller CI over seeds cut at -100%
    (`CHANGE_BOUNDS`: transitions are >= 0), as `seal.reports.changes.change_rows` lays changes
    out (censored seeds count their totals)."""
    from seal.reports.changes import CHANGE_ROW_COLUMNS
    from seal.stats import MIN_SEEDS_RESOLVED, change_ci, clip_ci, resolved

    labels = {a.name: a.label for a in ARMS}
    records = []
    for task in [*tasks, "Total"]:
        for arm in chosen:
            if arm.alone is None:
                continue
            mine, base = _values(costs[arm.name], task), _values(costs[arm.alone], task)
            low, high = clip_ci(change_ci(mine, base, paired=True), CHANGE_BOUNDS)
            base_mean = float(np.mean(base))
            n = len(mine)
            records.append(
                {
                    "env": TARGET_ENV,
                    "task": task,
                    "column": arm.label,
                    "reference": labels[arm.alone],
                    "vs": labels[arm.alone],
                    "pct_change": 100 * (float(np.mean(mine)) / base_mean - 1)
                    if base_mean > 0
                    else math.nan,
                    "pct_ci_low": 100 * low,
                    "pct_ci_high": 100 * high,
                    "n_column": n,
                    "n_reference": len(base),
                    "paired": True,
                    "resolved": n >= MIN_SEEDS_RESOLVED and resolved((low, high)),
                    "shared_tasks": len(tasks) if task == "Total" else 0,
                    "sd_paired_pct": math.nan,
                    "mde_pct": math.nan,
                }
            )
    return pd.DataFrame.from_records(records, columns=list(CHANGE_ROW_COLUMNS))


STATISTICS: tuple[tuple[str, str, str, str], ...] = (
    ("steps", "steps_saved", "ci95", "steps_saved = 1 - mean G(arm) / mean G(alone)"),
    ("robust_steps", "robust_steps_saved", "robust_ci95", "the same, 2 evaluations in a row"),
    ("auc", "auc_gain", "auc_gain_ci95", "AUC(arm) - AUC(alone) of the target's success"),
)
"""The paired statistics: (name in the sd_/mde_ keys, its key, its CI's key, what it is)."""


def _statistic_note(label: str, name: str, key: str, ci_key: str, s: Mapping[str, Any]) -> str:
    """ "steps +0.115* [-0.27, +0.45] (+0.20, ...), sd_paired_steps 0.440, mde_steps 0.546,
    seeds_for_mde_0p10_steps 154": a statistic's mean (* resolved), CI, per-seed values and power."""
    from seal.stats import resolved

    low, high = s[ci_key]
    per_seed = ", ".join(f"{v:+.3f}" for v in s[f"{key}_per_seed"])
    seeds = s[f"seeds_for_mde_0p10_{name}"]
    text = (
        f"{name} {s[key]:+.3f}{'*' if resolved((low, high)) else ''} [{low:+.3f}, {high:+.3f}] "
        f"({per_seed}), sd_paired_{name} {s[f'sd_paired_{name}']:.3f}, "
        f"mde_{name} {s[f'mde_{name}']:.3f}, seeds_for_mde_0p10_{name} "
        f"{'n/a' if seeds is None else seeds}"
    )
    if name == "auc":
        iqm_low, iqm_high = s["auc_gain_iqm_ci95"]
        text += (
            f"; IQM over (seed, task) {s['auc_gain_iqm']:+.3f} [{iqm_low:+.3f}, {iqm_high:+.3f}]"
        )
    return f"{label}: {text}"


def _statistics_notes(chosen: Sequence[Arm], summary: Mapping[str, Any]) -> list[str]:
    """What the paired statistics are, then one note per (arm, statistic) with its keys."""
    notes = [
        "Paired statistics, arm seed s against its alone arm's seed s: "
        + "; ".join(f"{name}: {what}" for name, _, _, what in STATISTICS)
        + ". G = gradient steps until every target task first evaluates >= 90% (censored: the "
        "run's total); AUC = per task the area under the evaluated success over gradient steps "
        "0..the alone arm's budget (success 0 at step 0 unless evaluated there), over the budget, "
        "mean over the tasks.",
        "[lo, hi] = 95% Student's t CI of the mean over seeds, cut at the statistic's range "
        "(steps <= 1, auc in [-1, 1]; the percentile bootstrap called "
        "17% of no-effect 5/5 splits resolved: --fpr); * = it excludes 0. sd_paired_<stat> = SD of the per-seed "
        "values; mde_<stat> = (t(0.975, n-1) + t(0.80, n-1)) sd / sqrt(n), the effect found with "
        "power 0.8 at these n seeds; seeds_for_mde_0p10_<stat> = the seeds an MDE <= 0.10 needs "
        "at that SD (seal.stats). IQM = rliable's interquartile mean, stratified bootstrap CI.",
    ]
    for arm in chosen:
        s = summary[arm.name]
        if arm.alone is None or s["steps_saved"] is None:
            continue
        label = f"{arm.label} vs {summary[arm.alone]['label']}"
        for name, key, ci_key, _ in STATISTICS:
            if key in s:
                notes.append(_statistic_note(label, name, key, ci_key, s))
    return notes


def _arm_notes(chosen: Sequence[Arm], summary: Mapping[str, Any]) -> list[str]:
    """One note per arm: steps to 90% per seed, censored tasks, transfer_updates_saved, CKA, pre-training."""
    notes = []
    for arm in chosen:
        s = summary[arm.name]
        text = (
            f"{arm.label}: steps to 90% {format_number(s['grad_steps_to_90_mean'])} "
            f"{s['grad_steps_to_90_per_seed']}; censored {s['censored']}/{s['task_runs']}"
        )
        if s["steps_saved"] is not None:
            low, high = s["transfer_updates_saved_ci95"]
            text += (
                f"; transfer_updates_saved {s['transfer_updates_saved']:+.3f} "
                f"[{low:+.2f}, {high:+.2f}]; P(fewer steps) {s['probability_of_improvement']:.2f}"
            )
        if s["alignment_cka"] is not None:
            cka = s["alignment_cka"]
            text += f"; CKA translator {cka['translator']:.2f}, trunk {cka['trunk']:.2f}"
        if "pretrain" in s:
            pre = s["pretrain"]
            text += (
                f"; source pre-training {format_number(pre['grad_steps_mean'])} steps, "
                f"{format_number(pre['consumed_mean'] / 1e6)} M transitions, "
                f"all tasks reached in {pre['reached_all']}/{len(pre['grad_steps_per_seed'])} seeds"
            )
        notes.append(text)
    return notes


def transfer_documents(
    costs: Mapping[str, Sequence[TargetCost]], chosen: Sequence[Arm], summary: Mapping[str, Any]
) -> dict[str, tuple[str, list[Any], list[str]]]:
    """The bench's tables as `seal.reports.tables` documents, stem -> (title, sections, notes):
    `counts` (M transitions to 90%, arms as columns, then gradient steps x per-step batch) and
    `changes` (one row per (task, arm, alone arm), then the paired statistics in the notes)."""
    from seal.reports.tables import change_sections, changes_display

    chosen = [a for a in chosen if a.has_target]
    tasks = list(next(iter(costs.values()))[0].per_task)
    counts = (
        "M transitions of the target consumed by updates until first >= 90% success",
        [
            ("", _counts_display(costs, chosen, tasks), None),
            ("Gradient steps × per-step batch", _steps_display(costs, chosen, tasks), None),
        ],
        [
            "Mean ± sample std over seeds [seeds that reached / seeds]; a task never reached counts "
            "its run's total. Total = the sum over the target's tasks.",
            "Gradient steps to first >= 90% × the task's mean per-step batch over them "
            "(transitions per step), means over seeds: the transitions above are steps × batch, so "
            "a change in them is a change in steps times a change in batch share. Steps count from "
            "the target's first update.",
            *_arm_notes(chosen, summary),
        ],
    )
    rows = _change_rows(costs, chosen, tasks)
    labels = {TARGET_ENV: TASK_LABEL}
    changes = (
        "Changes against each arm's alone arm",
        change_sections(
            changes_display(rows, labels, "markdown"), changes_display(rows, labels, "latex")
        )
        if len(rows)
        else [],
        [
            "Change = mean(arm) / mean(alone) - 1 of the target's transitions to 90% (censored "
            "seeds at their totals), 95% CI = paired Fieller interval (t quantiles) in percent, "
            "cut at -100%; "
            "bold = it excludes 0 with >= 3 seeds; n = seed pairs; tasks = the tasks in a total.",
            *_statistics_notes(chosen, summary),
        ],
    )
    return {"counts": counts, "changes": changes}


def format_table(
    costs: Mapping[str, Sequence[TargetCost]], chosen: Sequence[Arm], summary: Mapping[str, Any]
) -> str:
    """`transfer_documents` as Markdown: the counts (and steps x batch), then the changes and the
    paired statistics; no line longer than 100 characters (`seal.reports.tables.LINE_LIMIT`)."""
    from seal.reports.tables import markdown_document

    return "\n".join(
        markdown_document(title, sections, notes)
        for title, sections, notes in transfer_documents(costs, chosen, summary).values()
    )


def write_transfer_report(
    directory: Path,
    costs: Mapping[str, Sequence[TargetCost]],
    chosen: Sequence[Arm],
    summary: Mapping[str, Any],
    metrics: Mapping[tuple[str, int], pd.DataFrame],
) -> dict[str, list[str]]:
    """`directory`/tables/{counts,changes}.{md,tex} and `directory`/plots/: changes.png (each
    arm's paired statistics with their CIs and MDEs) and success_target.png (the target's mean
    success per arm, 95% bootstrap band over seeds). Returns the paths written."""
    from seal.reports.plots import (
        Interval,
        column_colours,
        plot_intervals,
        plot_success,
    )
    from seal.reports.tables import write_document
    from seal.stats import MIN_SEEDS_RESOLVED, resolved

    tables_dir, plots_dir = directory / "tables", directory / "plots"
    tables_dir.mkdir(parents=True, exist_ok=True)
    plots_dir.mkdir(parents=True, exist_ok=True)
    written: dict[str, list[str]] = {"tables": [], "plots": []}
    for stem, (title, sections, notes) in transfer_documents(costs, chosen, summary).items():
        if sections:
            paths = write_document(tables_dir / stem, title, sections, notes)
            written["tables"] += [str(p) for p in paths.values()]
    targets = [a for a in chosen if a.has_target]
    compared = [
        a for a in targets if a.alone is not None and summary[a.name]["steps_saved"] is not None
    ]
    if compared:
        panels = []
        for name, key, ci_key, what in STATISTICS:
            rows = []
            for arm in compared:
                s = summary[arm.name]
                if key not in s:
                    continue
                ci = (float(s[ci_key][0]), float(s[ci_key][1]))
                enough = len(s[f"{key}_per_seed"]) >= MIN_SEEDS_RESOLVED
                rows.append(
                    Interval(
                        f"{arm.label} vs {summary[arm.alone]['label']}",
                        float(s[key]),
                        *ci,
                        float(s[f"mde_{name}"]),
                        enough and resolved(ci),
                    )
                )
            if rows:
                panels.append((f"{name}: {what}", rows))
        path = plot_intervals(
            panels,
            plots_dir / "changes.png",
            "paired statistic (positive = the arm needs less / learns more than its alone arm)",
            "Target: each arm against its alone arm, mean over seeds, 95% CI, ±MDE",
        )
        written["plots"].append(str(path))
    frames = [
        frame[frame["env"] == TARGET_ENV].assign(column=arm.label, env_label=TASK_LABEL)
        for (name, _), frame in metrics.items()
        for arm in targets
        if arm.name == name
    ]
    if frames:
        labels = [a.label for a in targets]
        success = plot_success(
            pd.concat(frames, ignore_index=True),
            "grad_steps",
            column_colours(labels),
            {TARGET_ENV: f"{TASK_LABEL} (target)"},
            plots_dir,
            DEFAULT_THRESHOLD,
        )
        written["plots"] += [str(p) for p in success]
    return written
