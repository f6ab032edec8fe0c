"""`seal bench --learn transfer`: the fast cross-environment transfer testbed (docs/transfer_testbed.md).

Every arm is an ordinary protocol under `protocols/testbed/`, each seed one Ray task that runs
it as `seal run` does (`seal.experiments.launcher`: two at a time on a local Ray of 2 CPUs, or
on a cluster); this module reads their run directories. The figure is

    transfer_updates_saved = 1 - C(high-source) / C(target alone),

where C is the target's consumed transitions (the `updates` column of metrics.csv, which counts
exactly what the replay handed to gradient updates) until each of its tasks first reaches 90%
evaluated success, summed over its tasks. A task that never reaches it counts as the run's total
for that task and is reported as censored. The mean over seeds is of the per-seed figures; seed
s of an arm is set against seed s of its target-alone arm.

Each arm's three paired statistics against its alone arm, seed for seed: `steps` (steps_saved,
1 - mean G(arm) / mean G(alone), per seed (G(alone) - G(arm)) / mean G(alone): `seal.stats.saving`;
G = gradient steps until every target task first reaches 90%),
`robust_steps` (the same with 2 evaluations in a row) and `auc` (AUC(arm) - AUC(alone), the area
under each target task's evaluated success over gradient steps 0..budget, over the budget,
averaged over the tasks; `target_auc`), each with its 95% CI and what the seeds can resolve
(`seal.stats.paired_power`: sd_paired_<stat>, mde_<stat>, seeds_for_mde_0p10_<stat>).
`false_positive_rate` runs the CI method on two halves of the alone arm, where no effect exists.
The tables (counts, steps x batch, changes: one thing a cell) and plots (each arm's statistics
with CI and MDE, the target's success with a bootstrap band) go to `<out>/transfer/`.

This module holds the testbed's goals and wires the bench: `run_transfer_bench` and
`run_fpr_bench`, and their outputs `format_result` and `format_fpr`; the seeds-until-MDE rule
(`--seeds-until-mde T --max-seeds N`) is `seal.experiments.until_mde`'s. The arms are
`seal.experiments.arms`', the statistics `seal.experiments.statistics`', the tables and plots
`seal.experiments.tables`'.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from seal.errors import SealError
from seal.experiments.arms import Arm, arms
from seal.experiments.launcher import bench_context, run_or_reuse
from seal.experiments.records import agent_mismatches, code_versions, finished_run, versions_note
from seal.experiments.statistics import (
    FPR_HALF,
    FPR_SPLITS,
    ROBUST_CONSECUTIVE,
    TargetCost,
    alignment,
    false_positive_rate,
    pretrain_cost,
    source_sensitivity,
    summarise,
    target_auc,
    target_budget,
    target_cost,
)
from seal.experiments.tables import format_table, write_transfer_report

GOAL = 0.25
"""transfer_updates_saved the default shared_update must reach (issue 10)."""
POSITIVE_GOAL = 0.30
"""steps_saved at least one positive control must reach, with a 95% CI above 0 (issue 22)."""
ORACLE_GOAL = 0.80
"""steps_saved oracle_policy must reach, with a 95% CI above 0, at >= 5 seeds (issue 34)."""
MDE_GOAL = 0.15
"""The smaller of an arm's steps and robust_steps MDEs at 5 seeds (from their paired SDs) must
be at most this, a fraction of the paired alone arm's steps (issue 34)."""
MIN_SEEDS_FOR_GOALS = 5


def _finite_number(value: Any) -> bool:
    return isinstance(value, int | float) and math.isfinite(value)


POSITIVE_CONTROLS = ("pretrained_trunk", "positive_sparse_target")
"""Round 4's positive controls, whose goal is POSITIVE_GOAL (SEAL's own mechanism must carry them)."""


def _all_censored(arm: Mapping[str, Any]) -> bool:
    """Whether no target task of the arm reached the threshold in any seed."""
    return bool(arm.get("task_runs")) and arm.get("censored") == arm.get("task_runs")


def arm_mdes(summary: Mapping[str, Mapping[str, Any]]) -> dict[str, float | None]:
    """Each compared arm's MDE at the goal's 5 seeds, the smaller of steps' and robust_steps'.

    From each statistic's paired SD, whatever --seeds was. None where there is no SD, and where
    the arm and its alone arm never reached in any seed: every pair then sits at the run's budget,
    and an SD of 0 measures the budget, not the instrument.
    """
    from seal.stats import mde

    return {
        name: None
        if _all_censored(s) and _all_censored(summary[s["against"]])
        else min(
            (
                mde(s[k], MIN_SEEDS_FOR_GOALS)
                for k in ("sd_paired_steps", "sd_paired_robust_steps")
                if _finite_number(s.get(k))
            ),
            default=None,
        )
        for name, s in summary.items()
        if s.get("steps_saved") is not None
    }


def run_transfer_bench(
    full: bool = False,
    seeds: int = 5,
    out: str | os.PathLike[str] = "reports/bench_transfer",
    parallel: int = 2,
    overrides: Sequence[str] = (),
    log: Callable[[str], None] = lambda _: None,
    only: Sequence[str] | None = None,
    reuse: bool = False,
    address: str | None = None,
    run: bool = True,
) -> dict[str, Any]:
    """Run every arm's seeds on Ray (a local Ray of `parallel` CPUs, or the cluster at
    `address`), read their run directories, and return the result as JSON-able dict.

    `only` runs just the named arms (with the arms they need), e.g. the `--full` arms after the
    minimum set; the headline figures are then None where not run. `reuse` takes finished runs
    under `out` whose resolved config is today's (`finished_run`). Without `run` nothing is run
    or resumed: the result is of the finished runs `reuse` would take, over the seeds 0..k-1
    that have one of every arm (`finished_seeds`), and `missing` names the runs not found.
    """
    from seal.bench.timing import machine_load

    if seeds < 1:
        raise SealError(f"--seeds must be >= 1, got {seeds}")
    if parallel < 1:
        raise SealError(f"--jobs must be >= 1, got {parallel}")
    chosen = arms(full, only)
    load_before = machine_load()
    started = time.monotonic()
    missing: list[str] = []
    if run:
        run_dirs, reused = run_or_reuse(
            _jobs(chosen, range(seeds)), Path(out), overrides, parallel, log, reuse, address=address
        )
    else:
        run_dirs, missing = finished_seeds(chosen, seeds, Path(out), overrides)
        reused = run_dirs
        seeds = len(run_dirs) // len(chosen)
    result = _result(
        chosen,
        seeds,
        run_dirs,
        reused,
        out=out,
        full=full,
        overrides=overrides,
        parallel=parallel,
        address=address,
        wall=time.monotonic() - started,
        load_before=load_before,
    )
    return {**result, "missing": missing}


def finished_seeds(
    chosen: Sequence[Arm], seeds: int, out: Path, overrides: Sequence[str] = ()
) -> tuple[dict[tuple[str, int], Path], list[str]]:
    """`--no-run`: the finished runs (`finished_run`) of every arm for seeds 0..k-1, k the first
    seed lacking one (the paired statistics need every arm of a seed), and the (arm, seed) runs
    of seeds 0..seeds-1 not found; SealError naming them when seed 0 lacks one."""
    found = {(a.name, s): finished_run(a, s, out, overrides) for s in range(seeds) for a in chosen}
    missing = [f"{name}/seed-{s}" for (name, s), path in found.items() if path is None]
    complete = next(
        (s for s in range(seeds) if any(found[(a.name, s)] is None for a in chosen)), seeds
    )
    if complete == 0:
        raise SealError(
            f"--no-run: {out} holds no finished run of every arm for seed 0; not found: "
            + ", ".join(missing)
        )
    runs = {key: path for key, path in found.items() if path is not None and key[1] < complete}
    return runs, missing


def _jobs(chosen: Sequence[Arm], seeds: Iterable[int]) -> list[tuple[Arm, int]]:
    """Every (arm, seed): pre-training first (the positive controls wait on it), then the longest
    arms, so the last run does not run alone while a core idles."""
    return sorted(
        ((arm, seed) for seed in seeds for arm in chosen),
        key=lambda job: (job[0].has_target, job[0].alone is None),
    )


def _result(
    chosen: Sequence[Arm],
    seeds: int,
    run_dirs: Mapping[tuple[str, int], Path],
    reused: Mapping[tuple[str, int], Path],
    *,
    out: str | os.PathLike[str],
    full: bool,
    overrides: Sequence[str],
    parallel: int,
    address: str | None,
    wall: float,
    load_before: Mapping[str, Any],
    loaded: Mapping[tuple[str, int], Any] | None = None,
) -> dict[str, Any]:
    """`run_transfer_bench`'s result from the run directories of seeds 0..seeds-1 of `chosen`
    (`loaded`: those already read, by key)."""
    from seal import load_run

    known = dict(loaded or {})
    loaded = {key: known[key] if key in known else load_run(path) for key, path in run_dirs.items()}
    targets = [a for a in chosen if a.has_target]

    def costs_of(consecutive: int) -> dict[str, list[TargetCost]]:
        return {
            arm.name: [
                target_cost(loaded[(arm.name, s)].metrics, consecutive=consecutive)
                for s in range(seeds)
            ]
            for arm in targets
        }

    costs = costs_of(1)
    pretrain = {}
    for arm in chosen:
        if not arm.has_target:
            runs = [pretrain_cost(loaded[(arm.name, s)].metrics) for s in range(seeds)]
            pretrain[arm.name] = {
                "grad_steps_per_seed": [r["grad_steps"] for r in runs],
                "grad_steps_mean": float(np.mean([r["grad_steps"] for r in runs])),
                "consumed_per_seed": [r["consumed"] for r in runs],
                "consumed_mean": float(np.mean([r["consumed"] for r in runs])),
                "reached_all": int(sum(r["reached_all"] for r in runs)),
            }
    mismatches = agent_mismatches({k: r.config.get("agent", {}) for k, r in loaded.items()}, chosen)
    versions = code_versions({k: r.provenance.get("git_sha") for k, r in loaded.items()})
    # Each arm's target AUC over its alone arm's budget, so that a pair shares one window.
    auc = {
        arm.name: [
            target_auc(
                loaded[(arm.name, s)].metrics,
                target_budget(loaded[(arm.alone or arm.name, s)].metrics),
            )
            for s in range(seeds)
        ]
        for arm in targets
    }
    summary = summarise(
        costs,
        chosen,
        robust=costs_of(ROBUST_CONSECUTIVE),
        cka=alignment(run_dirs, chosen, seeds),
        pretrain=pretrain,
        auc=auc,
    )
    report_dir = Path(out) / "transfer"
    written = write_transfer_report(
        report_dir, costs, chosen, summary, {k: r.metrics for k, r in loaded.items()}
    )

    def figure(name: str, key: str = "transfer_updates_saved") -> Any:
        return summary[name][key] if name in summary else None

    positives = {
        name: {key: s[key] for key in ("steps_saved", "ci95")}
        for name, s in summary.items()
        if name in POSITIVE_CONTROLS
    }
    # Issue 22: a positive control saves >= 30% of the target's steps with a CI above 0, and the
    # no-correspondence control's CI includes 0 or lies below it.
    positive_met = any(
        p["steps_saved"] >= POSITIVE_GOAL and p["ci95"][0] > 0 for p in positives.values()
    )
    control_ci = figure("no_correspondence", "ci95")
    # Issue 34: transfer by construction must be seen (oracle_policy >= 80% with a CI above 0 at
    # >= 5 seeds), and the instrument must resolve 15% of the alone arm's steps at 5 seeds.
    oracle = summary.get("oracle_policy")
    oracle_goal = None
    if oracle is not None and oracle.get("steps_saved") is not None:
        oracle_goal = {
            "steps_saved_ge": ORACLE_GOAL,
            "seeds_ge": MIN_SEEDS_FOR_GOALS,
            "steps_saved": oracle["steps_saved"],
            "ci95": oracle["ci95"],
            "met": bool(
                seeds >= MIN_SEEDS_FOR_GOALS
                and oracle["steps_saved"] >= ORACLE_GOAL
                and oracle["ci95"][0] > 0
            ),
        }
    mdes = arm_mdes(summary)
    return {
        "transfer_updates_saved": figure("high_source"),
        "goal": {
            "transfer_updates_saved_ge": GOAL,
            "met": None if figure("high_source") is None else bool(figure("high_source") >= GOAL),
            "per_env": figure("high_source_per_env"),
            "no_correspondence": figure("no_correspondence"),
            "positive_steps_saved_ge": POSITIVE_GOAL,
            "positive": positives,
            "positive_met": positive_met if positives else None,
            "no_correspondence_ci95": control_ci,
            "no_correspondence_ci_not_above_0": None if control_ci is None else control_ci[0] <= 0,
            "oracle_policy": oracle_goal,
            "mde": {
                "mde_le": MDE_GOAL,
                "at_seeds": MIN_SEEDS_FOR_GOALS,
                "per_arm": mdes,
                "met": {n: None if v is None else bool(v <= MDE_GOAL) for n, v in mdes.items()},
            },
        },
        "arms": summary,
        "pretrain": pretrain,
        "target_curve_distance": source_sensitivity(
            {k: r.metrics for k, r in loaded.items()}, chosen, seeds
        ),
        "table": format_table(costs, chosen, summary),
        "report_dir": str(report_dir),
        "tables": written["tables"],
        "plots": written["plots"],
        "seeds": seeds,
        "full": full,
        "overrides": list(overrides),
        "run_dirs": {f"{a}/seed-{s}": str(p) for (a, s), p in run_dirs.items()},
        "commands": {f"{a}/seed-{s}": r.provenance.get("command") for (a, s), r in loaded.items()},
        "reused": sorted(f"{a}/seed-{s}" for a, s in reused),
        "agent_mismatches": mismatches,
        "code_versions": versions,
        **bench_context(wall, parallel, address, load_before),
    }


# ---------------------------------------------------------------- the false-positive rate

FPR_SEEDS = 10
"""Seeds of the alone arm the false-positive rate splits (two halves of FPR_HALF)."""


def run_fpr_bench(
    seeds: int = FPR_SEEDS,
    out: str | os.PathLike[str] = "reports/bench_transfer",
    parallel: int = 2,
    log: Callable[[str], None] = lambda _: None,
    reuse: bool = False,
    splits: int = FPR_SPLITS,
    address: str | None = None,
) -> dict[str, Any]:
    """`seal bench --learn transfer --fpr`: run (or, with `reuse`, take) the alone arm's seeds
    0..seeds-1 under `out`, then `false_positive_rate` on them; a JSON-able dict."""
    from seal import load_run
    from seal.bench.timing import machine_load

    if seeds < 2 * FPR_HALF:
        raise SealError(f"--seeds {seeds}: the false-positive rate needs >= {2 * FPR_HALF}")
    (alone,) = arms(only=["alone"])
    load_before = machine_load()
    started = time.monotonic()
    jobs = [(alone, seed) for seed in range(seeds)]
    run_dirs, reused = run_or_reuse(jobs, Path(out), (), parallel, log, reuse, address=address)
    wall = time.monotonic() - started
    paths = [run_dirs[(alone.name, s)] for s in range(seeds)]
    shas = {(alone.name, s): load_run(p).provenance.get("git_sha") for s, p in enumerate(paths)}
    return {
        "arm": alone.name,
        "seeds": seeds,
        **false_positive_rate(paths, splits=splits),
        "run_dirs": {f"{alone.name}/seed-{s}": str(p) for s, p in enumerate(paths)},
        "reused": sorted(f"{a}/seed-{s}" for a, s in reused),
        "code_versions": code_versions(shas),
        **bench_context(wall, parallel, address, load_before),
    }


def format_fpr(result: Mapping[str, Any]) -> str:
    """The human-readable output of `run_fpr_bench`."""
    rate, other = result["false_positive_rate"], result["false_positive_rate_bootstrap"]

    def share(r: Mapping[str, Any]) -> str:
        low, high = r["rate_ci95"]
        return (
            f"{r['excluding_0']}/{r['splits']} = {r['rate']:.3f} (95% CI [{low:.3f}, {high:.3f}])"
        )

    verdict = "met" if result["goal"]["met"] else "not met: change the CI method and say so"
    lines = [
        f"False-positive rate: {result['arm']} seeds 0-{result['seeds'] - 1}, G = target steps to "
        f"90% {result['grad_steps_to_90_per_seed']} (censored tasks per seed "
        f"{result['censored_per_seed']})",
        f"{rate['splits']} random {rate['half']}/{rate['half']} splits, halves paired at random, "
        "CI of the saving 1 - mean G(a) / mean G(b) excluding 0:",
        f"  {result['ci_method']}: {share(rate)}; goal <= {result['goal']['rate_le']}: {verdict}",
        f"  percentile bootstrap (the arms' CI until measured here), for comparison: {share(other)}",
    ]
    if "false_positive_rate_report" in result:
        lines.append(
            "  seal report's CI of mean(G(a)) / mean(G(b)) - 1 (Fieller's, paired by seed): "
            f"{share(result['false_positive_rate_report'])}"
        )
    note = versions_note(result["code_versions"])
    if note:
        lines.append(f"WARNING, {note}")
    reused = f" ({len(result['reused'])} runs reused)" if result["reused"] else ""
    lines.append(
        f"{result['seeds']} seeds on {result['ray']}, {result['wall_s']:.0f} s "
        f"wall{reused}; load before {result['load_before']['loadavg_1m']} (1 min), after "
        f"{result['load_after']['loadavg_1m']}"
    )
    return "\n".join(lines)


def format_result(result: Mapping[str, Any]) -> str:
    """The human-readable output of `run_transfer_bench`."""
    goal = result["goal"]
    load = result["load_before"]

    def shown(value: float | None) -> str:
        return "not run" if value is None else f"{value:+.3f}"

    verdict = {None: "not run", True: "met", False: "not met"}[goal["met"]]
    lines = [
        *([f"every arm with --set {' '.join(result['overrides'])}"] if result["overrides"] else []),
        result["table"],
        "",
        f"transfer_updates_saved (high-source, default shared_update) = {shown(result['transfer_updates_saved'])} "
        f"(goal >= {goal['transfer_updates_saved_ge']}: {verdict}); "
        f"per_env {shown(goal['per_env'])}, no correspondence {shown(goal['no_correspondence'])}",
    ]
    if goal["positive"]:
        verdict = {True: "met", False: "not met"}[goal["positive_met"]]
        shown_positive = "; ".join(
            f"{name} {p['steps_saved']:+.3f} [{p['ci95'][0]:+.2f}, {p['ci95'][1]:+.2f}]"
            for name, p in goal["positive"].items()
        )
        lines.append(
            f"positive controls, steps_saved with 95% CI: {shown_positive} "
            f"(goal >= {goal['positive_steps_saved_ge']} with the CI above 0: {verdict})"
        )
    if goal["no_correspondence_ci95"] is not None:
        low, high = goal["no_correspondence_ci95"]
        lines.append(
            f"no-correspondence control steps_saved 95% CI [{low:+.2f}, {high:+.2f}] "
            f"(goal: includes 0 or lies below it: {'met' if goal['no_correspondence_ci_not_above_0'] else 'not met'})"
        )
    oracle = goal.get("oracle_policy")
    if oracle is not None:
        low, high = oracle["ci95"]
        lines.append(
            f"oracle_policy steps_saved {oracle['steps_saved']:+.3f} [{low:+.2f}, {high:+.2f}] "
            f"(goal >= {oracle['steps_saved_ge']} with the CI above 0 at >= {oracle['seeds_ge']} "
            f"seeds: {'met' if oracle['met'] else 'not met'})"
        )
    mdes = goal.get("mde", {}).get("per_arm", {})
    if mdes:
        shown_mde = ", ".join(f"{n} {v:.2f}" for n, v in mdes.items() if v is not None)
        met = [n for n, ok in goal["mde"]["met"].items() if ok]
        lines.append(
            f"MDE at {goal['mde']['at_seeds']} seeds, min(steps, robust_steps): {shown_mde} "
            f"(goal <= {goal['mde']['mde_le']}: met by {', '.join(met) or 'no arm'})"
        )
    distance = result["target_curve_distance"]
    if distance is not None:
        moved = ", ".join(f"{k} {v:.3f}" for k, v in distance.items() if k != "between_seeds")
        lines.append(
            f"target success curve vs high_source's, same seed, mean |difference|: {moved}; "
            f"between seeds of high_source {distance['between_seeds']:.3f}"
        )
    if result.get("missing"):
        lines.append(
            f"--no-run: seeds 0-{result['seeds'] - 1} have a finished run of every arm; not "
            f"found: {', '.join(result['missing'])}"
        )
    if result["seeds"] < 3:
        lines.append(f"{result['seeds']} seeds: fewer than 3, so no change is resolved.")
    lines += [f"WARNING, arms not comparable: {m}" for m in result["agent_mismatches"]]
    note = versions_note(result["code_versions"])
    if note:
        lines.append(f"WARNING, {note}")
    lines.append(f"Tables and plots: {result['report_dir']}")
    reused = f" ({len(result['reused'])} runs reused)" if result["reused"] else ""
    lines.append(
        f"{result['seeds']} seeds on {result['ray']}, {result['wall_s']:.0f} s wall{reused}; "
        f"load before {load['loadavg_1m']} (1 min) on {load['cpus']} CPUs, after {result['load_after']['loadavg_1m']}"
    )
    return "\n".join(lines)
