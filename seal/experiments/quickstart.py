"""`seal bench --learn quickstart`: README command 1's protocol over seeds 0-9, as the README shows it.

The shipped `protocols/quickstart.toml`, each seed one Ray task that runs it as `seal run` does
and reserves a whole node, so the seeds run one at a time (`seal.experiments.launcher`), then `seal report` on the ten run directories. It writes what the
README includes: `docs/quickstart_table.md` (the report's table over the seeds and the
"k of n seeds" line), the report's success curves with their 95% bootstrap band (the kitchen's
copied to `docs/quickstart_success_fk.png`), and seed 0's own table, which is what command 1
prints. `--set protocol.threads=1` checks the same seeds at one thread. A fixed seed reproduces a
run only on the same CPU and thread count, so the line says where it was measured.
"""

from __future__ import annotations

import os
import shutil
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from seal.errors import SealError, UnknownNameError
from seal.experiments.arms import Arm
from seal.experiments.launcher import bench_context, run_or_reuse
from seal.experiments.records import code_versions, versions_note
from seal.metrics import DEFAULT_THRESHOLD, first_reach
from seal.provenance import cpu_model

REPO = Path(__file__).resolve().parents[2]
ARM = Arm("quickstart", "quickstart", None, directory=REPO / "protocols")
"""README command 1's protocol."""
SEEDS = 10
GOAL = 9
"""Issue 35: both environments' tasks reach 90% in at least 9 of 10 seeds."""
DOCS = REPO / "docs"


def arms(only: Sequence[str] | None = None) -> list[Arm]:
    """The one arm (named for `--arms`' sake)."""
    for name in only or ():
        if name != ARM.name:
            raise UnknownNameError("quickstart arm", name, [ARM.name])
    return [ARM]


def seeds_reached(run_dirs: Mapping[int, Path]) -> dict[int, dict[str, bool]]:
    """Per seed, per "task (env)": whether it reached 90% at some evaluation (the paper's rule)."""
    from seal import load_run

    out = {}
    for seed, path in sorted(run_dirs.items()):
        reach = first_reach(load_run(path).metrics, DEFAULT_THRESHOLD)
        out[seed] = {f"{r.task} ({r.env})": bool(r.reached) for r in reach.itertuples()}
    return out


def where_run(cpus: Mapping[int, str | None], threads: str | None) -> str:
    """Where the seeds ran, from each run's recorded CPU (runs made before provenance recorded it
    are named as such, with this machine's beside them)."""
    by_cpu: dict[str, list[int]] = {}
    for seed, cpu in sorted(cpus.items()):
        by_cpu.setdefault(cpu or "", []).append(seed)
    parts = []
    for cpu, seeds in by_cpu.items():
        named = cpu or f"CPU not recorded (this machine: {cpu_model()}, {os.cpu_count()} CPUs)"
        parts.append(named if len(by_cpu) == 1 else f"{named} for seeds {_span(seeds)}")
    return f"{'; '.join(parts)}; protocol.threads = {threads or 'as shipped'}"


def _span(seeds: Sequence[int]) -> str:
    """0-6 for a run of consecutive seeds, else the list."""
    if seeds == list(range(seeds[0], seeds[-1] + 1)) and len(seeds) > 2:
        return f"{seeds[0]}-{seeds[-1]}"
    return ", ".join(str(s) for s in seeds)


def k_of_n_line(reached: Mapping[int, Mapping[str, bool]], where: str) -> str:
    """'Both tasks reached 90% in k of n seeds (...)' with the seeds that did not."""
    both = [s for s, tasks in reached.items() if tasks and all(tasks.values())]
    missed = {
        s: [t for t, ok in tasks.items() if not ok] for s, tasks in reached.items() if s not in both
    }
    lines = [
        f"Every task reached 90% success in **{len(both)} of {len(reached)} seeds** "
        f"(seeds {min(reached)}-{max(reached)}; {where})."
    ]
    for seed, tasks in missed.items():
        lines.append(f"Seed {seed} did not reach: {', '.join(tasks) or 'no evaluation'}.")
    return " ".join(lines)


def run_quickstart_bench(
    seeds: int = SEEDS,
    out: str | os.PathLike[str] = "reports/bench_quickstart",
    parallel: int = 2,
    overrides: Sequence[str] = (),
    log: Callable[[str], None] = lambda _: None,
    only: Sequence[str] | None = None,
    reuse: bool = False,
    docs: Path | None = DOCS,
    address: str | None = None,
) -> dict[str, Any]:
    """Run seeds 0..seeds-1 of the quickstart on Ray (a local Ray of `parallel` CPUs, or the
    cluster at `address`), report them, and (with `docs`) write the README's table, curve and
    k-of-n line there. Each run reserves a whole node, so one runs at a time on it: the shipped
    settings (threads, the overlapped collection and evaluation workers) assume a machine the
    run has to itself."""
    from seal.bench.timing import machine_load
    from seal.reports import report

    if seeds < 1:
        raise SealError(f"--seeds must be >= 1, got {seeds}")
    if parallel < 1:
        raise SealError(f"--jobs must be >= 1, got {parallel}")
    arm = arms(only)[0]
    load_before = machine_load()
    started = time.monotonic()
    jobs = [(arm, seed) for seed in range(seeds)]
    run_dirs, reused = run_or_reuse(
        jobs, Path(out), overrides, parallel, log, reuse, address=address, whole_node=True
    )
    wall = time.monotonic() - started
    by_seed = {s: run_dirs[(arm.name, s)] for s in range(seeds)}
    result = report(list(by_seed.values()), out=Path(out) / "quickstart" / "all_seeds")
    seed0 = report([by_seed[0]], out=Path(out) / "quickstart" / "seed-0")
    reached = seeds_reached(by_seed)
    threads = next(
        (o.split("=", 1)[1] for o in overrides if o.startswith("protocol.threads=")), None
    )
    from seal import load_run

    loaded = {s: load_run(p) for s, p in by_seed.items()}
    where = where_run({s: r.provenance.get("cpu") for s, r in loaded.items()}, threads)
    line = k_of_n_line(reached, where)
    table = result.tables["update_counts.md"].read_text()
    seed0_table = seed0.tables["update_counts.md"].read_text()
    versions = code_versions(
        {(arm.name, s): r.provenance.get("git_sha") for s, r in loaded.items()}
    )
    written = []
    if docs is not None:
        suffix = "" if threads is None else f"_threads{threads}"
        page = docs / f"quickstart_table{suffix}.md"
        page.write_text(
            f"<!-- written by `seal bench --learn quickstart"
            f"{'' if threads is None else f' --set protocol.threads={threads}'}`; do not edit -->\n"
            f"{line}\n\n{table.rstrip()}\n\nSeed 0 alone (what README command 1 prints):\n\n"
            f"{seed0_table.rstrip()}\n"
        )
        written.append(str(page))
        curve = next((p for p in result.plots if Path(p).name == "success_fk.png"), None)
        if curve is not None:
            target = docs / f"quickstart_success_fk{suffix}.png"
            shutil.copyfile(curve, target)
            written.append(str(target))
    both = sum(1 for tasks in reached.values() if tasks and all(tasks.values()))
    return {
        "line": line,
        "table": table,
        "seed0_table": seed0_table,
        "reached": {str(s): t for s, t in reached.items()},
        "k": both,
        "n": seeds,
        "goal": {"needed": GOAL, "of": SEEDS, "met": both >= GOAL if seeds >= SEEDS else None},
        "written": written,
        "report_dir": str(result.out_dir),
        "overrides": list(overrides),
        "run_dirs": {f"seed-{s}": str(p) for s, p in by_seed.items()},
        "reused": sorted(f"seed-{s}" for _, s in reused),
        "run_wall_s": {f"seed-{s}": float(r.metrics["wall_s"].max()) for s, r in loaded.items()},
        "code_versions": versions,
        **bench_context(wall, parallel, address, load_before),
    }


def format_result(result: Mapping[str, Any]) -> str:
    """The human-readable output of `run_quickstart_bench`."""
    lines = [result["line"], "", result["table"].rstrip(), ""]
    note = versions_note(result["code_versions"])
    if note:
        lines.append(f"WARNING, {note}")
    goal = result["goal"]
    verdict = {None: "not judged (fewer than 10 seeds)", True: "met", False: "not met"}[goal["met"]]
    lines.append(f"Goal: >= {goal['needed']} of {goal['of']} seeds: {verdict}")
    lines.append(f"Report (tables, plots): {result['report_dir']}")
    lines += [f"Wrote {p}" for p in result["written"]]
    return "\n".join(lines)
