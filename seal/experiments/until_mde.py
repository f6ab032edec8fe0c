"""`seal bench --learn transfer --seeds-until-mde T --max-seeds N`: seeds until the answer is
precise enough (issue 58 item 4; docs/transfer_testbed.md, "Seeds until the MDE").

`run_transfer_until_mde` runs the testbed's seeds in batches of as many runs as can go at once
(`rule_batch`) and stops when every named statistic's MDE, taken from an upper confidence bound on
its paired SD (`seal.stopping`), is at most T, or at N seeds; `run_fpr_until_mde` (with `--fpr`)
measures the false-positive rate of the arms' CI under that rule on the alone arm's seeds. The
bench itself (`_jobs`, `_result`, the launcher's `run_or_reuse`) is reached through
`seal.experiments.transfer`, so the two paths run and report the same way.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from seal.errors import SealError
from seal.experiments import transfer
from seal.experiments.arms import Arm, arms
from seal.experiments.launcher import bench_context, describe_ray
from seal.experiments.records import code_versions, versions_note
from seal.experiments.statistics import FPR_SPLITS, target_auc, target_budget, target_cost

RULE_ARMS = ("high_source", "pretrained_trunk", "oracle_translator", "no_correspondence")
"""The arms whose statistics the seeds-until-MDE rule names: the SEAL rungs (high_source and the
ladder's two rungs that leave transfer to SEAL) and the no-correspondence control. oracle_policy
(transfer by construction) and the sparse pair are not named."""
RULE_STATISTICS = ("steps", "auc")
"""Per named arm, the paired statistics the rule makes precise: steps_saved and the AUC gain."""
RULE_MIN_SEEDS = transfer.MIN_SEEDS_FOR_GOALS
"""The rule's first look is at no fewer seeds than this (and --max-seeds may not be fewer)."""
RULE_FPR_SEEDS = 40
"""Alone seeds, at the least, the false-positive rate under the rule splits (2 x --max-seeds if more)."""


def rule_batch(
    chosen: Sequence[Arm],
    parallel: int,
    address: str | None = None,
    overrides: Sequence[str] = (),
) -> dict[str, Any]:
    """How many seeds the rule adds at a time: as many as runs can go at once.

    A run reserves `run_cpus` of its protocol (one CPU for every shipped testbed protocol); the
    batch is the sum over the Ray's nodes of floor(node CPUs / the most CPUs any chosen arm's run
    reserves): on a local Ray of `parallel` CPUs, parallel // that (2 at --jobs 2); on the cluster
    at `address`, its alive nodes' CPUs as Ray reports them now. At least 1.
    """
    from seal.experiments.launcher import run_cpus
    from seal.protocols import load_protocol

    if address is None:
        nodes = [parallel]
    else:
        from seal.sweep.ray_session import RaySession, alive_cpu_nodes, check_address, import_ray

        import_ray("seal bench --learn")
        check_address(address)
        with RaySession(address, None, strict=True) as ray:
            nodes = [int(n["Resources"]["CPU"]) for n in alive_cpu_nodes(ray)]
    if not nodes:
        raise SealError(f"the Ray cluster at --address {address} has no alive node with a CPU")
    per_run = max(run_cpus(load_protocol(a.protocol, overrides), max(nodes)) for a in chosen)
    batch = max(1, sum(cpus // per_run for cpus in nodes))
    where = describe_ray(parallel, address)
    return {
        "batch": batch,
        "how": f"sum over nodes of node CPUs // {per_run} CPU(s) a run, nodes {nodes} ({where})",
    }


def rule_differences(
    loaded: Mapping[tuple[str, int], Any], chosen: Sequence[Arm], seeds: int
) -> dict[str, list[float] | None]:
    """Per named statistic (`<arm>/steps`, `<arm>/auc` of each chosen arm of RULE_ARMS), its
    per-seed paired differences over seeds 0..seeds-1 of `loaded` runs: steps_saved (per seed
    (G(alone) - G(arm)) / mean G(alone), `seal.stats.saving`) and the AUC gain (AUC(arm) -
    AUC(alone) over the alone arm's budget, the tasks' mean), as `summarise` computes them. None for both of an arm that, like its alone arm, never
    reached in any seed (as `arm_mdes`: its SD would measure the budget)."""
    from seal.experiments.statistics import steps_saved

    out: dict[str, list[float] | None] = {}
    for arm in chosen:
        if arm.name not in RULE_ARMS or arm.alone is None:
            continue
        pairs = [
            (loaded[(arm.name, s)].metrics, loaded[(arm.alone, s)].metrics) for s in range(seeds)
        ]
        own = [target_cost(m) for m, _ in pairs]
        base = [target_cost(b) for _, b in pairs]
        if all(c.censored == c.tasks for c in own + base):
            out[f"{arm.name}/steps"] = out[f"{arm.name}/auc"] = None
            continue
        out[f"{arm.name}/steps"] = steps_saved(own, base)
        gains = []
        for m, b in pairs:
            budget = target_budget(b)
            mine, theirs = target_auc(m, budget), target_auc(b, budget)
            gains.append(float(np.mean([mine[t] - theirs[t] for t in mine])))
        out[f"{arm.name}/auc"] = gains
    return out


def check_rule(target: float, max_seeds: int) -> None:
    if not (math.isfinite(target) and target > 0):
        raise SealError(f"--seeds-until-mde {target!r}: expected a target MDE > 0")
    if max_seeds < RULE_MIN_SEEDS:
        raise SealError(
            f"--max-seeds {max_seeds}: the rule looks first at {RULE_MIN_SEEDS} seeds; "
            f"expected >= {RULE_MIN_SEEDS}"
        )


def run_transfer_until_mde(
    target: float,
    max_seeds: int,
    full: bool = False,
    out: str | os.PathLike[str] = "reports/bench_transfer",
    parallel: int = 2,
    overrides: Sequence[str] = (),
    log: Callable[[str], None] = lambda _: None,
    only: Sequence[str] | None = None,
    reuse: bool = False,
    address: str | None = None,
    batch: int | None = None,
) -> dict[str, Any]:
    """`seal bench --learn transfer --seeds-until-mde TARGET --max-seeds N`: seeds in batches
    until every named statistic is precise enough, then `run_transfer_bench`'s result on them.

    The rule (docs/transfer_testbed.md, "Seeds until the MDE"): look first at max(RULE_MIN_SEEDS,
    batch) seeds, then add `batch` seeds (`rule_batch`: as many as runs can go at once) at a
    time; at each look, per named statistic (`rule_differences`) the MDE at the seeds run from
    the one-sided 80% upper limit on the paired SD (`seal.stopping.seeds_until_mde_step`); stop when
    each counted one is <= `target` ("target reached") or at `max_seeds` ("max seeds"). The
    result's `seeds_until_mde` records the rule, every look and why it stopped.
    """
    from seal import load_run
    from seal.bench.timing import machine_load
    from seal.stopping import SD_BOUND_CONFIDENCE, seeds_until_mde_schedule, seeds_until_mde_step

    check_rule(target, max_seeds)
    if parallel < 1:
        raise SealError(f"--jobs must be >= 1, got {parallel}")
    chosen = arms(full, only)
    named = [a.name for a in chosen if a.name in RULE_ARMS]
    if not named:
        raise SealError(
            f"--seeds-until-mde names the statistics of {', '.join(RULE_ARMS)}; "
            "--arms chose none of them"
        )
    how = rule_batch(chosen, parallel, address, overrides) if batch is None else None
    batch = how["batch"] if how is not None else batch
    first = max(RULE_MIN_SEEDS, batch)
    schedule = seeds_until_mde_schedule(first, batch, max_seeds)
    load_before = machine_load()
    started = time.monotonic()
    run_dirs: dict[tuple[str, int], Path] = {}
    reused: dict[tuple[str, int], Path] = {}
    loaded: dict[tuple[str, int], Any] = {}
    looks: list[dict[str, Any]] = []
    done = 0
    for seeds in schedule:
        log(f"seeds-until-mde: running seeds {done}-{seeds - 1}")
        dirs, again = transfer.run_or_reuse(
            transfer._jobs(chosen, range(done, seeds)),
            Path(out),
            overrides,
            parallel,
            log,
            reuse,
            address=address,
        )
        run_dirs.update(dirs)
        reused.update(again)
        loaded.update({k: load_run(p) for k, p in dirs.items() if k not in loaded})
        done = seeds
        look = seeds_until_mde_step(
            rule_differences(loaded, chosen, seeds), seeds, target, max_seeds
        )
        looks.append(look)
        shown = ", ".join(
            f"{name} {'no MDE' if p is None else format(p['mde_upper'], '.3f')}"
            for name, p in look["statistics"].items()
        )
        log(f"seeds-until-mde at {seeds} seeds, MDE from the SD's upper limit: {shown}")
        if look["stop"]:
            break
    result = transfer._result(
        chosen,
        done,
        run_dirs,
        reused,
        out=out,
        full=full,
        overrides=overrides,
        parallel=parallel,
        address=address,
        wall=time.monotonic() - started,
        load_before=load_before,
        loaded=loaded,
    )
    result["seeds_until_mde"] = {
        "rule": {
            "target": target,
            "statistics": [f"{a}/{s}" for a in named for s in RULE_STATISTICS],
            "sd_bound": "one-sided upper limit, SD * sqrt((n - 1) / chi2.ppf(1 - c, n - 1))",
            "sd_bound_confidence": SD_BOUND_CONFIDENCE,
            "mde": "seal.stats.mde(SD upper limit, n): alpha 0.05 two-sided, power 0.8",
            "max_seeds": max_seeds,
            "first": first,
            "batch": batch,
            "batch_how": how["how"] if how is not None else "given",
            "schedule": schedule,
        },
        "seeds_used": done,
        "looks": looks,
        "stopped_because": looks[-1]["reason"],
        "above_target": looks[-1]["above_target"],
    }
    return result


def format_result(result: Mapping[str, Any]) -> str:
    """The bench's output (`seal.experiments.transfer.format_result`), then the rule's lines."""
    return transfer.format_result(result) + "\n" + format_until_mde(result["seeds_until_mde"])


def format_until_mde(rule: Mapping[str, Any]) -> str:
    """The lines `format_result` adds for the seeds-until-MDE rule."""
    spec, last = rule["rule"], rule["looks"][-1]
    shown = ", ".join(
        f"{name} {'no MDE (never reached)' if p is None else format(p['mde_upper'], '.3f')}"
        for name, p in last["statistics"].items()
    )
    lines = [
        f"seeds until MDE <= {spec['target']}: stopped at {rule['seeds_used']} seeds, "
        f"{rule['stopped_because']} (max {spec['max_seeds']}; looks at {spec['schedule']}, "
        f"{spec['batch']} seeds a batch: {spec['batch_how']})",
        f"  MDE from the paired SD's one-sided {spec['sd_bound_confidence']:.0%} upper limit: {shown}",
    ]
    if rule["above_target"]:
        lines.append(f"  still above {spec['target']}: {', '.join(rule['above_target'])}")
    return "\n".join(lines)


def run_fpr_until_mde(
    target: float,
    max_seeds: int,
    out: str | os.PathLike[str] = "reports/bench_transfer",
    parallel: int = 2,
    log: Callable[[str], None] = lambda _: None,
    reuse: bool = False,
    splits: int = FPR_SPLITS,
    address: str | None = None,
    batch: int | None = None,
) -> dict[str, Any]:
    """`seal bench --learn transfer --fpr --seeds-until-mde TARGET --max-seeds N`: the arms' CI's
    false-positive rate under the seeds-until-MDE rule, on max(RULE_FPR_SEEDS, 2 N) alone seeds.

    Runs (or, with `reuse`, takes; it logs how many it found) the alone arm's seeds, then
    `seal.stopping.sequential_false_positive_rate` on their G (gradient steps to 90%): per split two
    disjoint random halves of N seeds, paired in order, looked at as the rule adds batches
    (`rule_batch`, as the bench would on this Ray), stopped by the rule on steps_saved, and
    counted when the arms' CI (`ARM_CI`) at the stop excludes 0. Beside it, the same CI at a
    fixed N pairs on random splits (`split_false_positive_rate`), no rule.
    """
    from seal import load_run
    from seal.bench.timing import machine_load
    from seal.experiments.records import finished_run
    from seal.experiments.statistics import ARM_CI, SAVED_BOUNDS
    from seal.stats import split_false_positive_rate
    from seal.stopping import SD_BOUND_CONFIDENCE, sequential_false_positive_rate

    check_rule(target, max_seeds)
    (alone,) = arms(only=["alone"])
    seeds = max(RULE_FPR_SEEDS, 2 * max_seeds)
    found = sum(finished_run(alone, s, Path(out)) is not None for s in range(seeds)) if reuse else 0
    if reuse:
        log(
            f"{found} of the {seeds} alone seeds the rule's false-positive rate needs are finished "
            f"under {out}; running the other {seeds - found}"
        )
    how = rule_batch([alone], parallel, address) if batch is None else None
    batch = how["batch"] if how is not None else batch
    first = max(RULE_MIN_SEEDS, batch)
    load_before = machine_load()
    started = time.monotonic()
    jobs = [(alone, seed) for seed in range(seeds)]
    run_dirs, reused = transfer.run_or_reuse(
        jobs, Path(out), (), parallel, log, reuse, address=address
    )
    wall = time.monotonic() - started
    runs = [load_run(run_dirs[(alone.name, s)]) for s in range(seeds)]
    costs = [target_cost(r.metrics) for r in runs]
    steps = [c.grad_steps for c in costs]

    def ci(values: Sequence[float]) -> tuple[float, float]:
        return ARM_CI(values, SAVED_BOUNDS)

    rate = sequential_false_positive_rate(
        steps,
        target=target,
        max_seeds=max_seeds,
        batch=batch,
        first=first,
        splits=splits,
        ci=ci,
    )
    return {
        "arm": alone.name,
        "seeds": seeds,
        "found_finished": found,
        "grad_steps_to_90_per_seed": steps,
        "censored_per_seed": [c.censored for c in costs],
        "rule": {
            "target": target,
            "statistic": "steps_saved of two halves of the alone arm, paired in order",
            "sd_bound_confidence": SD_BOUND_CONFIDENCE,
            "max_seeds": max_seeds,
            "first": first,
            "batch": batch,
            "batch_how": how["how"] if how is not None else "given",
        },
        "ci_method": "Student's t CI of the mean saving, cut at 1 (the arms' ci95)",
        "false_positive_rate_under_rule": rate,
        "false_positive_rate_fixed_max_seeds": split_false_positive_rate(
            steps, half=max_seeds, splits=splits, ci=ci
        ),
        "run_dirs": {
            f"{alone.name}/seed-{s}": str(run_dirs[(alone.name, s)]) for s in range(seeds)
        },
        "reused": sorted(f"{a}/seed-{s}" for a, s in reused),
        "code_versions": code_versions(
            {(alone.name, s): r.provenance.get("git_sha") for s, r in enumerate(runs)}
        ),
        **bench_context(wall, parallel, address, load_before),
    }


def format_fpr_until_mde(result: Mapping[str, Any]) -> str:
    """The human-readable output of `run_fpr_until_mde`."""
    rule, rate = result["rule"], result["false_positive_rate_under_rule"]
    fixed = result["false_positive_rate_fixed_max_seeds"]

    def share(r: Mapping[str, Any]) -> str:
        low, high = r["rate_ci95"]
        return (
            f"{r['excluding_0']}/{r['splits']} = {r['rate']:.3f} (95% CI [{low:.3f}, {high:.3f}])"
        )

    lines = [
        f"False-positive rate under seeds-until-MDE <= {rule['target']} (max {rule['max_seeds']} "
        f"seeds, looks at {rate['schedule']}): {result['arm']} seeds 0-{result['seeds'] - 1} "
        f"({result['found_finished']} found finished, {len(result['reused'])} reused)",
        f"  {rate['splits']} random splits into two halves of {rule['max_seeds']}, the rule on "
        f"steps_saved, t CI at the stop excluding 0: {share(rate)}",
        f"  stopped: {rate['stopped']['target reached']} target reached, "
        f"{rate['stopped']['max seeds']} max seeds; seeds used, mean {rate['seeds_used_mean']:.1f}",
        f"  without the rule, t CI at {rule['max_seeds']} pairs: {share(fixed)}",
    ]
    note = versions_note(result["code_versions"])
    if note:
        lines.append(f"WARNING, {note}")
    lines.append(
        f"{result['seeds']} seeds on {result['ray']}, {result['wall_s']:.0f} s wall; load before "
        f"{result['load_before']['loadavg_1m']} (1 min), after {result['load_after']['loadavg_1m']}"
    )
    return "\n".join(lines)
