"""`seal bench --learn transfer`: the fast cross-environment transfer testbed (docs/transfer_testbed.md).

Every arm is an ordinary protocol under `protocols/testbed/`, run by `seal run` in its own
process (two at a time on a 2-core machine); this module only launches them and reads their run
directories. The figure is

    transfer_updates_saved = 1 - C(high-source) / C(target alone),

where C is the target's consumed transitions (the `updates` column of metrics.csv, which counts
exactly what the replay handed to gradient updates) until each of its tasks first reaches 90%
evaluated success, summed over its tasks. A task that never reaches it counts as the run's total
for that task and is reported as censored. The mean over seeds is of the per-seed figures; seed
s of an arm is set against seed s of its target-alone arm.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
import tomllib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from seal.errors import SealError, UnknownNameError
from seal.metrics import DEFAULT_THRESHOLD, first_reach, format_count, format_number

TESTBED = Path(__file__).resolve().parents[2] / "protocols" / "testbed"
"""The testbed's protocol files."""
TARGET_ENV = "target"
"""The [envs.<name>] of the target in every testbed protocol."""
GOAL = 0.25
"""transfer_updates_saved the default shared_update must reach (issue 10)."""


@dataclass(frozen=True)
class Arm:
    """One column of the testbed table: a protocol file and the target-alone arm it is set against."""

    name: str
    label: str
    """Column heading of the table."""
    alone: str | None
    """The target-alone arm with the same per-step batch schedule; None for an alone arm itself."""
    full: bool = False
    """Only with --full."""
    directory: Path = TESTBED
    """Where the arm's protocol file lies."""

    @property
    def protocol(self) -> Path:
        """The arm's protocol file."""
        return self.directory / f"{self.name}.toml"


ARMS: tuple[Arm, ...] = (
    Arm("alone", "Single Env", None),
    Arm("high_source", "High Src", "alone"),
    Arm("high_source_per_env", "High Src per_env", "alone"),
    Arm("no_correspondence", "No corr.", "alone"),
    Arm("alone_50_50", "Single Env (50/50 batch)", None, full=True),
    Arm("joint_50_50", "50/50", "alone_50_50", full=True),
    Arm("alone_high_target", "Single Env (High Tgt batch)", None, full=True),
    Arm("high_target", "High Tgt", "alone_high_target", full=True),
)
"""The minimum set, then the --full arms; the default-mode high-source arm gives the headline figure."""


def arms(full: bool = False, only: Sequence[str] | None = None) -> list[Arm]:
    """The arms run by `seal bench --learn transfer` (with `--full`: all of them; `only`: these and their alone arms)."""
    if not only:
        return [a for a in ARMS if full or not a.full]
    by_name = {a.name: a for a in ARMS}
    for name in only:
        if name not in by_name:
            raise UnknownNameError("testbed arm", name, list(by_name))
    wanted = set(only) | {by_name[n].alone for n in only if by_name[n].alone is not None}
    return [a for a in ARMS if a.name in wanted]


# ---------------------------------------------------------------- reading one run


@dataclass(frozen=True)
class TargetCost:
    """What one run's target env consumed until its tasks first reached the threshold."""

    consumed: float
    """Transitions consumed by updates until first >= threshold, summed over tasks (censored tasks: their total)."""
    grad_steps: int
    """Gradient steps until every task had first reached the threshold (censored: the run's total)."""
    censored: int
    """Tasks that never reached the threshold."""
    tasks: int
    per_task: dict[str, float]
    """Transitions per task (the summands of `consumed`)."""
    reached: tuple[str, ...]
    """The tasks that reached the threshold."""


def target_cost(
    metrics: pd.DataFrame, env: str = TARGET_ENV, threshold: float = DEFAULT_THRESHOLD
) -> TargetCost:
    """The target's `TargetCost` from one run's metrics table (metrics.csv, one seed, one phase)."""
    rows = metrics[metrics["env"] == env]
    if rows.empty:
        raise SealError(
            f"metrics table has no rows of env {env!r}; envs: {sorted(set(metrics['env']))}"
        )
    first = first_reach(rows, threshold)
    # A task never reached counts as all it consumed, at the run's last evaluation.
    last = rows.sort_values(["epoch", "grad_steps"], kind="stable").groupby("task").tail(1)
    total_updates = dict(zip(last["task"], last["updates"], strict=True))
    total_steps = int(rows["grad_steps"].max())
    per_task: dict[str, float] = {}
    steps = 0
    for row in first.itertuples(index=False):
        millions = float(row.updates) if row.reached else float(total_updates[row.task])
        per_task[str(row.task)] = millions * 1e6
        steps = max(steps, int(row.grad_steps) if row.reached else total_steps)
    return TargetCost(
        consumed=float(sum(per_task.values())),
        grad_steps=steps,
        censored=int((~first["reached"]).sum()),
        tasks=len(first),
        per_task=per_task,
        reached=tuple(str(t) for t in first.loc[first["reached"], "task"]),
    )


def updates_saved(arm: Sequence[TargetCost], alone: Sequence[TargetCost]) -> list[float]:
    """Per seed: 1 - arm's consumed / alone's consumed (seed i against seed i)."""
    if len(arm) != len(alone):
        raise SealError(f"{len(arm)} seeds of the arm but {len(alone)} of its target-alone arm")
    return [
        1.0 - a.consumed / b.consumed if b.consumed > 0 else math.nan
        for a, b in zip(arm, alone, strict=True)
    ]


# ---------------------------------------------------------------- launching


def seal_run_command(arm: Arm, seed: int, out: Path, overrides: Sequence[str] = ()) -> list[str]:
    """The `seal run` command line of one seed of one arm."""
    cmd = [sys.executable, "-m", "seal.cli.main", "run", str(arm.protocol), "--seeds", str(seed)]
    cmd += ["--out", str(out), "--quiet", "--no-report", "--json"]
    for item in overrides:
        cmd += ["--set", item]
    return cmd


def run_all(
    jobs: list[tuple[Arm, int]],
    out: Path,
    overrides: Sequence[str] = (),
    parallel: int = 2,
    log: Callable[[str], None] = lambda _: None,
) -> dict[tuple[str, int], Path]:
    """Run every (arm, seed) as its own `seal run` process, `parallel` at a time; their run directories."""
    pending = list(jobs)
    running: list[tuple[Arm, int, subprocess.Popen[str], float]] = []
    done: dict[tuple[str, int], Path] = {}
    try:
        while pending or running:
            while pending and len(running) < parallel:
                arm, seed = pending.pop(0)
                cmd = seal_run_command(arm, seed, out, overrides)
                log(f"start {arm.name} seed {seed}: {' '.join(cmd[1:])}")
                proc = subprocess.Popen(
                    cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
                )
                running.append((arm, seed, proc, time.monotonic()))
            time.sleep(0.2)
            for item in list(running):
                arm, seed, proc, started = item
                if proc.poll() is None:
                    continue
                running.remove(item)
                stdout, stderr = proc.communicate()
                if proc.returncode != 0:
                    tail = (stderr or stdout).strip().splitlines()[-1:] or ["(no output)"]
                    raise SealError(
                        f"seal run {arm.protocol} --seeds {seed} failed (exit {proc.returncode}): {tail[0]}"
                    )
                run_dir = Path(json.loads(stdout.strip().splitlines()[-1])["run_dir"])
                done[(arm.name, seed)] = run_dir
                log(f"done {arm.name} seed {seed} in {time.monotonic() - started:.0f} s: {run_dir}")
    finally:
        for _, _, proc, _ in running:
            proc.kill()
    return done


def run_or_reuse(
    jobs: list[tuple[Arm, int]],
    out: Path,
    overrides: Sequence[str],
    parallel: int,
    log: Callable[[str], None],
    reuse: bool,
) -> tuple[dict[tuple[str, int], Path], dict[tuple[str, int], Path]]:
    """(every job's run directory, the reused ones): with `reuse`, finished runs under `out`
    whose resolved config is today's (`finished_run`) are taken; the rest are run (`run_all`)."""
    reused: dict[tuple[str, int], Path] = {}
    if reuse:
        for arm, seed in jobs:
            found = finished_run(arm, seed, out, overrides)
            if found is not None:
                reused[(arm.name, seed)] = found
                log(f"reuse {arm.name} seed {seed}: {found}")
        jobs = [(a, s) for a, s in jobs if (a.name, s) not in reused]
    return {**reused, **run_all(jobs, out, overrides, parallel, log)}, reused


# ---------------------------------------------------------------- reuse and consistency

COMPARED_TABLES = ("envs", "agent", "replay", "training", "evaluation", "scheduler")
"""The resolved tables a reused run must share with the protocol as it resolves now."""


def _tables(resolved: Mapping[str, Any]) -> dict[str, Any]:
    out = {t: resolved.get(t, {}) for t in COMPARED_TABLES}
    out["epochs"] = resolved["protocol"]["epochs"]
    return out


def resolved_tables(arm: Arm, overrides: Sequence[str] = ()) -> tuple[str, dict[str, Any]]:
    """(protocol name, the tables a run of `arm` saves in its config.toml), as the code resolves them now."""
    from seal.protocols import load_protocol
    from seal.protocols.loader import config_to_dict, dumps_toml

    config = load_protocol(arm.protocol, overrides)
    # Through TOML, as the runner writes config.toml, so that both sides compare alike.
    return config.name, _tables(tomllib.loads(dumps_toml(config_to_dict(config))))


def finished_run(arm: Arm, seed: int, out: Path, overrides: Sequence[str] = ()) -> Path | None:
    """The newest finished run of (arm, seed) under `out` whose saved config equals today's resolution, else None.

    Defaults of the learner can change between two runs (a new default init, say); a run is
    reused only if every resolved key of COMPARED_TABLES is the same, so arms never mix them.
    """
    from seal import load_run

    name, want = resolved_tables(arm, overrides)
    # Group directories start with their creation time, so the newest sorts last.
    for run in sorted(out.glob(f"{name}/*/seed-{seed}"), reverse=True):
        if not (run / "metrics.csv").is_file() or not (run / "config.toml").is_file():
            continue
        if _tables(tomllib.loads((run / "config.toml").read_text())) != want:
            continue
        loaded = load_run(run)
        epochs = loaded.metrics["epoch"]
        # Finished: all its epochs, or ended early (evaluation.stop_when_reached) with an end time.
        if loaded.provenance.get("end_time") or (
            not epochs.empty and int(epochs.max()) >= want["epochs"]
        ):
            return run
    return None


def agent_mismatches(
    agents: Mapping[tuple[str, int], Mapping[str, Any]], chosen: Sequence[Arm]
) -> list[str]:
    """Agent keys, other than shared_update, that differ between runs set against each other."""
    problems = []
    for arm in chosen:
        base = arm.alone or arm.name
        for (name, seed), agent in agents.items():
            if name != arm.name:
                continue
            ref = agents[(base, 0)]
            keys = sorted(
                k
                for k in set(agent) | set(ref)
                if k != "shared_update" and agent.get(k) != ref.get(k)
            )
            problems += [
                f"{name} seed {seed} vs {base} seed 0: agent.{k} = {agent.get(k)!r} vs {ref.get(k)!r}"
                for k in keys
            ]
    return problems


def code_versions(shas: Mapping[tuple[str, int], str | None]) -> dict[str, list[str]]:
    """The code versions (provenance git_sha) the runs were made with, each with its runs; one key when consistent.

    A learner change without a config key (a loss's scale, say) is invisible to
    `finished_run`; runs of different commits should not be set against each other.
    """
    out: dict[str, list[str]] = {}
    for (arm, seed), sha in sorted(shas.items()):
        out.setdefault(sha or "unknown", []).append(f"{arm}/seed-{seed}")
    return out


# ---------------------------------------------------------------- the table


def summarise(costs: Mapping[str, Sequence[TargetCost]], chosen: Sequence[Arm]) -> dict[str, Any]:
    """Per arm: consumed transitions, censored tasks, gradient steps and transfer_updates_saved per seed and mean."""
    out: dict[str, Any] = {}
    for arm in chosen:
        runs = costs[arm.name]
        entry: dict[str, Any] = {
            "label": arm.label,
            "protocol": str(arm.protocol.relative_to(TESTBED.parents[1])),
            "consumed_per_seed": [c.consumed for c in runs],
            "consumed_mean": float(np.mean([c.consumed for c in runs])),
            "grad_steps_to_90_per_seed": [c.grad_steps for c in runs],
            "grad_steps_to_90_mean": float(np.mean([c.grad_steps for c in runs])),
            "censored_per_seed": [c.censored for c in runs],
            "censored": int(sum(c.censored for c in runs)),
            "task_runs": int(sum(c.tasks for c in runs)),
        }
        if arm.alone is not None:
            saved = updates_saved(runs, costs[arm.alone])
            entry["against"] = arm.alone
            entry["transfer_updates_saved_per_seed"] = saved
            entry["transfer_updates_saved"] = float(np.mean(saved))
            base = float(np.mean([c.consumed for c in costs[arm.alone]]))
            # Beside it, the ratio of the seed means (less sensitive to one slow alone seed).
            entry["saved_of_means"] = 1.0 - entry["consumed_mean"] / base if base > 0 else math.nan
        out[arm.name] = entry
    return out


def format_table(
    costs: Mapping[str, Sequence[TargetCost]], chosen: Sequence[Arm], summary: Mapping[str, Any]
) -> str:
    """Table 1's layout for the target: task rows, arm columns, M transitions to 90% as mean ± std (change) [k/n]."""
    tasks = list(next(iter(costs.values()))[0].per_task)
    header = ["Task (point_view)", *(a.label for a in chosen)]
    rows: list[list[str]] = []
    for task in [*tasks, "Total"]:
        row = [task]
        for arm in chosen:
            runs = costs[arm.name]
            if task == "Total":
                values = [c.consumed for c in runs]
                reached = sum(1 for c in runs if c.censored == 0)
            else:
                values = [c.per_task[task] for c in runs]
                reached = sum(1 for c in runs if task in c.reached)
            mean = float(np.mean(values)) / 1e6
            std = float(np.std(values, ddof=1)) / 1e6 if len(values) > 1 else math.nan
            pct = None
            if arm.alone is not None:
                base = costs[arm.alone]
                base_values = (
                    [c.consumed for c in base]
                    if task == "Total"
                    else [c.per_task[task] for c in base]
                )
                base_mean = float(np.mean(base_values)) / 1e6
                pct = 100.0 * (mean - base_mean) / base_mean if base_mean > 0 else None
            # Censored seeds count their total, so every cell has a mean; [k/n] says how many reached.
            cell = format_count(mean, std, max(reached, 1), len(runs), pct, arm.alone is not None)
            row.append(cell.rsplit(" [", 1)[0] + f" [{reached}/{len(runs)}]")
        rows.append(row)
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    lines = [
        "  ".join(h.ljust(w) for h, w in zip(header, widths, strict=True)),
        "  ".join("-" * w for w in widths),
        *("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) for r in rows),
    ]
    lines.append(
        "M transitions of the target consumed by updates until first >= 90% success; mean ± std over seeds "
        "(change vs. its Single Env column) [seeds that reached / seeds]; a task never reached counts its run's total."
    )
    lines.append("")
    for arm in chosen:
        s = summary[arm.name]
        text = (
            f"{arm.label:<28} steps to 90% {format_number(s['grad_steps_to_90_mean'])} "
            f"{s['grad_steps_to_90_per_seed']}; censored {s['censored']}/{s['task_runs']}"
        )
        if "transfer_updates_saved" in s:
            per_seed = ", ".join(f"{v:+.3f}" for v in s["transfer_updates_saved_per_seed"])
            text += (
                f"; transfer_updates_saved {s['transfer_updates_saved']:+.3f} ({per_seed}); "
                f"of seed means {s['saved_of_means']:+.3f}"
            )
        lines.append(text)
    return "\n".join(lines)


# ---------------------------------------------------------------- the command


def run_transfer_bench(
    full: bool = False,
    seeds: int = 3,
    out: str | os.PathLike[str] = "reports/bench_transfer",
    parallel: int = 2,
    overrides: Sequence[str] = (),
    log: Callable[[str], None] = lambda _: None,
    only: Sequence[str] | None = None,
    reuse: bool = False,
) -> dict[str, Any]:
    """Run every arm's seeds with `seal run`, read their run directories, and return the result as JSON-able dict.

    `only` runs just the named arms (with the alone arms they are set against), e.g. the
    `--full` arms after the minimum set; the headline figures are then None where not run.
    `reuse` takes finished runs under `out` whose resolved config is today's (`finished_run`).
    """
    from seal import load_run
    from seal.bench.timing import machine_load

    if seeds < 1:
        raise SealError(f"--seeds must be >= 1, got {seeds}")
    if parallel < 1:
        raise SealError(f"--jobs must be >= 1, got {parallel}")
    chosen = arms(full, only)
    load_before = machine_load()
    started = time.monotonic()
    # Longest arms first, so the last process does not run alone while a core idles.
    order = sorted(chosen, key=lambda a: a.alone is None)
    jobs = [(arm, seed) for arm in order for seed in range(seeds)]
    run_dirs, reused = run_or_reuse(jobs, Path(out), overrides, parallel, log, reuse)
    wall = time.monotonic() - started
    loaded = {key: load_run(path) for key, path in run_dirs.items()}
    costs = {
        arm.name: [target_cost(loaded[(arm.name, s)].metrics) for s in range(seeds)]
        for arm in chosen
    }
    mismatches = agent_mismatches({k: r.config.get("agent", {}) for k, r in loaded.items()}, chosen)
    versions = code_versions({k: r.provenance.get("git_sha") for k, r in loaded.items()})
    summary = summarise(costs, chosen)

    def saved(name: str) -> float | None:
        return summary[name]["transfer_updates_saved"] if name in summary else None

    headline = saved("high_source")
    return {
        "transfer_updates_saved": headline,
        "goal": {
            "transfer_updates_saved_ge": GOAL,
            "met": None if headline is None else bool(headline >= GOAL),
            "per_env": saved("high_source_per_env"),
            "no_correspondence": saved("no_correspondence"),
        },
        "arms": summary,
        "table": format_table(costs, chosen, summary),
        "seeds": seeds,
        "full": full,
        "overrides": list(overrides),
        "run_dirs": {f"{a}/seed-{s}": str(p) for (a, s), p in run_dirs.items()},
        "reused": sorted(f"{a}/seed-{s}" for a, s in reused),
        "agent_mismatches": mismatches,
        "code_versions": versions,
        "wall_s": wall,
        "parallel": parallel,
        "load_before": load_before,
        "load_after": machine_load(),
    }


def format_result(result: Mapping[str, Any]) -> str:
    """The human-readable output of `run_transfer_bench`."""
    goal = result["goal"]
    load = result["load_before"]

    def shown(value: float | None) -> str:
        return "not run" if value is None else f"{value:+.3f}"

    verdict = {None: "not run", True: "met", False: "not met"}[goal["met"]]
    lines = [
        result["table"],
        "",
        f"transfer_updates_saved (high-source, default shared_update) = {shown(result['transfer_updates_saved'])} "
        f"(goal >= {goal['transfer_updates_saved_ge']}: {verdict}); "
        f"per_env {shown(goal['per_env'])}, no correspondence {shown(goal['no_correspondence'])}",
    ]
    lines += [f"WARNING, arms not comparable: {m}" for m in result["agent_mismatches"]]
    versions = result["code_versions"]
    if len(versions) > 1:
        listed = "; ".join(f"{sha}: {', '.join(runs)}" for sha, runs in versions.items())
        lines.append(f"WARNING, runs made with {len(versions)} code versions: {listed}")
    reused = f" ({len(result['reused'])} runs reused)" if result["reused"] else ""
    lines.append(
        f"{result['seeds']} seeds, {result['parallel']} runs at a time, {result['wall_s']:.0f} s wall{reused}; "
        f"load before {load['loadavg_1m']} (1 min) on {load['cpus']} CPUs, after {result['load_after']['loadavg_1m']}"
    )
    return "\n".join(lines)
