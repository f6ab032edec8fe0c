"""`seal bench --learn mtrl`: each learner of SMT Table 1 learning at laptop scale, with its speed.

Every arm of protocols/mtrl_learn is one learner (SAC-MT-MH, SAC-MT, PCGrad, PaCo, MOORE, CARE,
Soft Modular) on the same two easy MT10 tasks with the same budget, each seed one Ray task that
runs it as `seal run` does (`seal.experiments.launcher`, two at a time on a local Ray of 2 CPUs,
`--reuse` across sessions). Per learner it prints: k of n seeds in which every task reached 90%
at some evaluation, the first crossing of each task per seed (env steps of that task), its FLOPs
an update (counted) and its updates/s against SAC-MT-MH's, timed side by side in this bench run
(the same batch shapes, the arms interleaved, the best of `repeats`), so the ratio does not
depend on the machine. `seal report` over the arms' runs writes the table in SMT Table 1's layout
(tables/success_by_task.md). `--no-run` reads the finished runs under `--out` (the committed
records of results/mtrl_learn) and names the seeds it did not find. It need not order the
learners as the paper does at this scale: it shows that each one learns.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from seal.errors import SealError
from seal.experiments.arms import Arm, arms_in, chosen
from seal.experiments.launcher import bench_context, run_or_reuse
from seal.experiments.records import code_versions, finished_runs, versions_note
from seal.metrics import DEFAULT_THRESHOLD, first_reach

MTRL_LEARN = Path(__file__).resolve().parents[2] / "protocols" / "mtrl_learn"
"""The arms' protocol files."""
REFERENCE = "sac_mt_mh"
"""The arm whose updates/s the others are set against (MTMHSAC)."""


ARMS: tuple[Arm, ...] = arms_in(
    MTRL_LEARN,
    (
        ("sac_mt_mh", "SAC-MT-MH"),
        ("sac_mt", "SAC-MT"),
        ("pcgrad", "PCGrad"),
        ("paco", "PaCo"),
        ("moore", "MOORE"),
        ("care", "CARE"),
        ("soft_modular", "Soft Modular"),
    ),
)


def arms(only: Sequence[str] | None = None) -> list[Arm]:
    """All arms, or the named ones and the reference."""
    return chosen(ARMS, only, "mtrl arm", also=(REFERENCE,))


def crossings(run_dirs: Mapping[int, Path]) -> dict[int, dict[str, int | None]]:
    """Per seed, per task: the task's env steps at its first evaluation >= 90% (None: never)."""
    from seal import load_run

    out: dict[int, dict[str, int | None]] = {}
    for seed, path in sorted(run_dirs.items()):
        reach = first_reach(load_run(path).metrics, DEFAULT_THRESHOLD)
        out[seed] = {r.task: int(r.env_steps) if r.reached else None for r in reach.itertuples()}
    return out


def update_rates(
    names: Sequence[str], overrides: Sequence[str] = (), updates: int = 20, repeats: int = 3
) -> tuple[dict[str, float], dict[str, int]]:
    """(updates per second, FLOPs per update) of each arm's agent on random batches of its
    protocol's shapes, on one CPU thread: timed interleaved, the best of `repeats` per arm;
    FLOPs counted by FlopCounterMode (`seal.bench.flops.counted_update_flops`)."""
    from seal.bench.flops import _agent_batches, counted_update_flops
    from seal.bench.timing import best_interleaved, updates_of
    from seal.device import torch_threads
    from seal.learner import Agent, EnvSpec
    from seal.protocols import load_protocol
    from seal.run.phase_model import build_adapters

    agents, batches, flops = {}, {}, {}
    for name in names:
        config = load_protocol(MTRL_LEARN / f"{name}.toml", list(overrides))
        specs = [
            EnvSpec(n, a.obs_dim, a.act_dim, len(a.tasks))
            for n, a in build_adapters(config).items()
        ]
        agents[name] = Agent(specs, config.agent, seed=0)
        flops[name] = counted_update_flops(specs, config.agent, config.training.batch_per_task)
        batches[name] = _agent_batches(specs, config.training.batch_per_task, seed=0)
        agents[name].update(batches[name])  # the first update also builds lazy state
    runs = {name: updates_of(agents[name], batches[name], updates) for name in names}
    with torch_threads(1):
        best = best_interleaved(runs, repeats, updates)
    return {name: 1.0 / best[name] for name in names}, flops


def run_mtrl_bench(
    seeds: int = 3,
    out: str | os.PathLike[str] = "reports/bench_mtrl",
    parallel: int = 2,
    overrides: Sequence[str] = (),
    log: Callable[[str], None] = lambda _: None,
    only: Sequence[str] | None = None,
    reuse: bool = False,
    run: bool = True,
    address: str | None = None,
) -> dict[str, Any]:
    """Run (or reuse) every arm's seeds 0..seeds-1 on Ray (a local Ray of `parallel` CPUs, or
    the cluster at `address`), time the updates, report the runs.

    Without `run`, nothing is run or resumed: the figures are those of the finished runs under
    `out` that `reuse` would take, each learner's k of n over the seeds found, and `missing`
    names the rest; a learner with none is left out, the reference's speed still timed."""
    from seal import load_run
    from seal.bench.timing import machine_load
    from seal.reports import report

    if seeds < 1:
        raise SealError(f"--seeds must be >= 1, got {seeds}")
    chosen = arms(only)
    load_before = machine_load()
    started = time.monotonic()
    jobs = [(arm, seed) for seed in range(seeds) for arm in chosen]
    if run:
        run_dirs, reused = run_or_reuse(
            jobs, Path(out), overrides, parallel, log, reuse, address=address
        )
    else:
        run_dirs = reused = finished_runs(jobs, Path(out), overrides)
        if not run_dirs:
            raise SealError(
                f"--no-run: {out} holds no finished run of these arms (seeds 0-{seeds - 1}); "
                "run them first (--reuse continues any that a session cut short)"
            )
    wall = time.monotonic() - started
    log("timing the updates side by side")
    rates, flops = update_rates([a.name for a in chosen], overrides)
    learners = {}
    for arm in chosen:
        by_seed = {s: run_dirs[(arm.name, s)] for s in range(seeds) if (arm.name, s) in run_dirs}
        if not by_seed:
            continue
        crossed = crossings(by_seed)
        every = [
            s
            for s, tasks in crossed.items()
            if tasks and all(v is not None for v in tasks.values())
        ]
        learners[arm.name] = {
            "label": arm.label,
            "every_task_90": len(every),
            "seeds": len(by_seed),
            "first_crossing_env_steps": {str(s): t for s, t in crossed.items()},
            "updates_per_s": rates[arm.name],
            "speed_vs_reference": rates[arm.name] / rates[REFERENCE],
            "flops_per_update": flops[arm.name],
            "run_dirs": {str(s): str(p) for s, p in by_seed.items()},
        }
    result = report([p for p in run_dirs.values()], out=Path(out) / "mtrl" / "all")
    loaded = {key: load_run(p) for key, p in run_dirs.items()}
    return {
        "missing": [f"{a.name}/seed-{s}" for a, s in jobs if (a.name, s) not in run_dirs],
        "learners": learners,
        "reference": REFERENCE,
        "by_task_table": result.tables["success_by_task.md"].read_text(),
        "report_dir": str(result.out_dir),
        "reused": sorted(f"{a}/seed-{s}" for a, s in reused),
        "code_versions": code_versions(
            {key: r.provenance.get("git_sha") for key, r in loaded.items()}
        ),
        "overrides": list(overrides),
        **bench_context(wall, parallel, address, load_before),
    }


def format_result(result: Mapping[str, Any]) -> str:
    """The human-readable output of `run_mtrl_bench`."""
    ref = next(a.label for a in ARMS if a.name == result["reference"])
    lines = [
        f"{'learner':<14} {'every task >= 90%':<18} {'first crossing per seed (env steps a task)':<60} "
        f"updates/s (x {ref}), GFLOP an update"
    ]
    for learner in result["learners"].values():
        per_seed = "; ".join(
            f"s{s} "
            + ", ".join(
                f"{t.split('-v')[0]} {'-' if v is None else f'{v:,}'}" for t, v in tasks.items()
            )
            for s, tasks in learner["first_crossing_env_steps"].items()
        )
        lines.append(
            f"{learner['label']:<14} {learner['every_task_90']} of {learner['seeds']:<13} "
            f"{per_seed:<60} {learner['updates_per_s']:.1f} (x {learner['speed_vs_reference']:.2f}), "
            f"{learner['flops_per_update'] / 1e9:.2f}"
        )
    lines += ["", "- = never reached 90% within the run."]
    if result.get("missing"):
        lines.append(f"not run (--no-run found no finished run): {', '.join(result['missing'])}")
    lines += ["", result["by_task_table"].rstrip(), ""]
    note = versions_note(result["code_versions"])
    if note:
        lines.append(f"WARNING, {note}")
    lines.append(f"Report (tables, plots): {result['report_dir']}")
    return "\n".join(lines)
