"""`seal bench --learn table1`: paper Table 1 at laptop scale (protocols/table1_small, docs/table1_small.md).

Meta-World drawer-close-v3 (no demonstrations) and the kitchen's slide-cabinet (30 of its
expert's episodes) under the paper's four columns (Single Env, 50/50, High FK, High MW), each
ratio column with its batch-matched alone arms. Every
arm is an ordinary protocol, each seed one Ray task that runs it as `seal run` does
(`seal.experiments.launcher`, two at a time on a local Ray of 2 CPUs); the table is `seal report`'s on their run directories, so its cells, changes,
CIs, [reached/seeds] and plots (changes with their MDE, success with a bootstrap band) are the
ones a user gets from `seal report` on the same runs. Beside it, `auc_changes`: the paired area
under each task's success curve, which no censored seed drops.
"""

from __future__ import annotations

import math
import os
import statistics
import textwrap
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from seal.errors import SealError
from seal.experiments.arms import Arm, arms_in, chosen
from seal.experiments.launcher import bench_context, run_or_reuse
from seal.experiments.records import code_versions, versions_note

if TYPE_CHECKING:
    import pandas as pd

TABLE1 = Path(__file__).resolve().parents[2] / "protocols" / "table1_small"
"""The arms' protocol files."""
BUDGET_S = 90 * 60
"""Wall time the default set (5 seeds of every arm) must fit on 2 CPU cores (issues 23, 34)."""
MIN_SEEDS = 5
TABLES = ("update_counts.md", "update_changes.md")
"""The report's tables the bench prints, in order."""


ARMS: tuple[Arm, ...] = arms_in(
    TABLE1,
    (
        ("single_mw", "Single Env (MW)"),
        ("single_fk", "Single Env (FK)"),
        ("joint_50_50", "50/50"),
        ("high_fk", "High FK"),
        ("high_mw", "High MW"),
        ("high_fk_mw_alone", "Single Env (High FK batch), MW"),
        ("high_fk_fk_alone", "Single Env (High FK batch), FK"),
        ("high_mw_mw_alone", "Single Env (High MW batch), MW"),
        ("high_mw_fk_alone", "Single Env (High MW batch), FK"),
    ),
)
"""Every arm. 50/50 has no alone arm of its own: with one task per env, 50/50 gives each task
128 per step, Single Env's batch, so Single Env is its batch-matched alone arm too."""

REFERENCES: dict[str, tuple[str, ...]] = {
    "joint_50_50": ("single_mw", "single_fk"),
    "high_fk": ("single_mw", "single_fk", "high_fk_mw_alone", "high_fk_fk_alone"),
    "high_mw": ("single_mw", "single_fk", "high_mw_mw_alone", "high_mw_fk_alone"),
}
"""The arms each joint arm's cells are set against."""


def arms(only: Sequence[str] | None = None) -> list[Arm]:
    """All arms, or the named ones with the arms they are set against."""
    also = [ref for name in only or () for ref in REFERENCES.get(name, ())]
    return chosen(ARMS, only, "table1 arm", also)


def _cells(counts: pd.DataFrame) -> list[dict[str, Any]]:
    """The report's update-count rows (one per column, env and task) as JSON records; NaN as None."""
    records = counts.astype(object).where(counts.notna(), None).to_dict(orient="records")
    return [
        {str(k): (v.item() if hasattr(v, "item") else v) for k, v in r.items()} for r in records
    ]


AUC_NOTE = (
    "AUC: per task, the area under its evaluated success over gradient steps 0 to the table's "
    "budget (the last evaluated step of any run), / the budget; a run that stopped once every task "
    "reached 90% holds its last evaluation. Diff: AUC(arm) - AUC(reference), paired by seed; 95% "
    "t CI; MDE at power 0.8 and the seeds an MDE <= 0.10 needs, from the paired SD; matched = the "
    "joint arm's batch-matched alone arm."
)
"""The AUC table's note: the statistic that does not censor (a task never reached still has an area)."""


def auc_changes(runs: Mapping[tuple[str, int], pd.DataFrame]) -> list[dict[str, Any]]:
    """Per (task, joint arm, reference arm): the paired AUC difference over the seeds both ran.

    `runs` maps (arm, seed) to that run's metrics. The updates-to-90% changes lose every pair in
    which one side never reached the task (a censored seed); the AUC keeps them, which is why the
    bench reports it beside them. Gradient steps, not consumed updates, are the x axis: against a
    batch-matched arm the two are proportional, against Single Env it is "the same number of
    network updates".
    """
    from seal.experiments.statistics import ARM_CI, AUC_GAIN_BOUNDS, target_auc
    from seal.stats import paired_power

    budget = max(int(m["grad_steps"].max()) for m in runs.values())
    areas: dict[tuple[str, int, str, str], float] = {}
    for (arm, seed), metrics in runs.items():
        for env in dict.fromkeys(metrics["env"]):
            for task, area in target_auc(metrics, budget, env=env).items():
                areas[(arm, seed, env, task)] = area
    rows = []
    for arm, references in REFERENCES.items():
        for reference in references:
            keys = sorted({(e, t) for (a, _, e, t) in areas if a == reference})
            for env, task in keys:
                seeds = sorted(
                    s
                    for (a, s, e, t) in areas
                    if a == arm and (e, t) == (env, task) and (reference, s, env, task) in areas
                )
                if not seeds:
                    continue
                own = [areas[(arm, s, env, task)] for s in seeds]
                base = [areas[(reference, s, env, task)] for s in seeds]
                diff = [a - b for a, b in zip(own, base, strict=True)]
                rows.append(
                    {
                        "env": env,
                        "task": task,
                        "arm": arm,
                        "vs": reference,
                        "seeds": seeds,
                        "auc_arm": statistics.fmean(own),
                        "auc_vs": statistics.fmean(base),
                        "auc_diff_per_seed": diff,
                        "auc_diff": statistics.fmean(diff),
                        "auc_diff_ci95": list(
                            ARM_CI(diff, AUC_GAIN_BOUNDS)
                        ),  # a difference of AUCs in [0, 1]
                        **paired_power(diff, "auc"),
                    }
                )
    return rows


def format_auc(rows: Sequence[Mapping[str, Any]]) -> str:
    """The AUC changes as a Markdown table (one row per task, arm and reference) and its note."""
    labels = {a.name: a.label for a in ARMS if a.name in REFERENCES}
    labels.update({a.name: "Single Env" for a in ARMS if a.name.startswith("single_")})
    labels.update({a.name: "matched" for a in ARMS if a.name.endswith("_alone")})

    def number(value: float, sign: str = "") -> str:
        return "-" if not math.isfinite(value) else f"{value:{sign}.3f}"

    lines = [
        "## Area under the success curve (no censoring)",
        "",
        "| task | arm | vs | AUC arm | AUC vs | diff | 95% CI | n | MDE | n for MDE <= 0.10 |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        low, high = r["auc_diff_ci95"]
        needed = r["seeds_for_mde_0p10_auc"]
        lines.append(
            f"| {r['task']} | {labels[r['arm']]} | {labels[r['vs']]} | {number(r['auc_arm'])} | "
            f"{number(r['auc_vs'])} | {number(r['auc_diff'], '+')} | "
            f"[{number(low, '+')}, {number(high, '+')}] | {len(r['seeds'])} | "
            f"{number(r['mde_auc'])} | {needed if needed is not None else '-'} |"
        )
    return "\n".join([*lines, "", *textwrap.wrap(AUC_NOTE, 100)])


def run_table1_bench(
    seeds: int = MIN_SEEDS,
    out: str | os.PathLike[str] = "reports/bench_table1",
    parallel: int = 2,
    overrides: Sequence[str] = (),
    log: Callable[[str], None] = lambda _: None,
    only: Sequence[str] | None = None,
    reuse: bool = False,
    address: str | None = None,
) -> dict[str, Any]:
    """Run every arm's seeds on Ray (a local Ray of `parallel` CPUs, or the cluster at
    `address`), then `seal report` on their run directories; a JSON-able dict.

    `overrides` go to every run (`--set agent.preset=...`, or the tiny sizes of the CI test);
    `reuse` takes finished runs under `out` whose resolved config is today's.
    """
    from seal import load_run
    from seal.bench.timing import machine_load
    from seal.reports import report

    if seeds < 1:
        raise SealError(f"--seeds must be >= 1, got {seeds}")
    if parallel < 1:
        raise SealError(f"--jobs must be >= 1, got {parallel}")
    chosen = arms(only)
    load_before = machine_load()
    started = time.monotonic()
    # Joint arms first (the longest), so the last run does not run alone while a core idles.
    jobs = sorted(
        ((arm, seed) for seed in range(seeds) for arm in chosen),
        key=lambda job: job[0].name not in REFERENCES,
    )
    run_dirs, reused = run_or_reuse(
        jobs, Path(out), overrides, parallel, log, reuse, address=address
    )
    wall = time.monotonic() - started
    ordered = [run_dirs[(a.name, s)] for a in chosen for s in range(seeds)]
    result = report(ordered, out=Path(out) / "table1")
    # The counts (and steps x batch), then one row per (task, arm, reference): the changes.
    table = "\n".join(result.tables[name].read_text() for name in TABLES if name in result.tables)
    loaded = {key: load_run(path) for key, path in run_dirs.items()}
    versions = code_versions({k: r.provenance.get("git_sha") for k, r in loaded.items()})
    auc = auc_changes({key: run.metrics for key, run in loaded.items()})
    fresh = not reused
    return {
        "table": table,
        "cells": _cells(result.update_counts),
        "changes": result.to_json()["changes"],
        "auc": auc,
        "auc_table": format_auc(auc),
        "plots": [str(p) for p in result.plots],
        "report_dir": str(result.out_dir),
        "seeds": seeds,
        "arms": [a.name for a in chosen],
        "overrides": list(overrides),
        "run_dirs": {f"{a}/seed-{s}": str(p) for (a, s), p in run_dirs.items()},
        "reused": sorted(f"{a}/seed-{s}" for a, s in reused),
        "code_versions": versions,
        "warnings": list(result.warnings),
        "budget": {
            "wall_s_le": BUDGET_S,
            "seeds_ge": MIN_SEEDS,
            # Only a run that made every run itself says whether the set fits the budget.
            "met": (wall <= BUDGET_S and seeds >= MIN_SEEDS) if fresh else None,
        },
        **bench_context(wall, parallel, address, load_before),
    }


def format_result(result: Mapping[str, Any]) -> str:
    """The human-readable output of `run_table1_bench`: the report's table, then cost and budget."""
    load = result["load_before"]
    budget = result["budget"]
    verdict = {None: "not judged (runs reused)", True: "met", False: "not met"}[budget["met"]]
    lines = [
        result["table"].rstrip(),
        "",
        result["auc_table"],
        "",
        "50/50's batch-matched alone arm is Single Env: with one task per env, 50/50 draws 128 per "
        "task per step, Single Env's batch.",
        f"Report (tables, plots): {result['report_dir']}",
    ]
    note = versions_note(result["code_versions"])
    if note:
        lines.append(f"WARNING, {note}")
    reused = f" ({len(result['reused'])} runs reused)" if result["reused"] else ""
    lines.append(
        f"{result['seeds']} seeds of {len(result['arms'])} arms, on {result['ray']}, "
        f"{result['wall_s']:.0f} s wall{reused} (budget {budget['wall_s_le']} s with >= "
        f"{budget['seeds_ge']} seeds: {verdict}); load before {load['loadavg_1m']} (1 min) on "
        f"{load['cpus']} CPUs, after {result['load_after']['loadavg_1m']}"
    )
    return "\n".join(lines)
