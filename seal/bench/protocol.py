"""`seal bench --protocol FILE --epochs N`: measure N epochs of a real protocol and project its wall time.

The window is the protocol itself (same envs, networks, batches, collectors, device) run by the
runner for N epochs per phase, with three changes so that N epochs measure what the whole run
repeats: no warm-up (every window epoch trains, as all but the first few epochs of a paper-scale
run do), and one evaluation and one checkpoint at the window's end. The runner times its parts
(`RunResult.timing`), and the projection is

    epochs x (collect + update seconds per epoch)
      + evaluations x seconds per evaluation
      + checkpoints x seconds per checkpoint x (replay rows at the checkpoint / rows in the window's)

per phase, where evaluations and checkpoints are counted from the full protocol's settings. The
checkpoint term scales with the replay it stores (it dominates a checkpoint's size); warm-up
epochs, which skip updates, are projected at the full per-epoch cost, so the projection is a
slight over-estimate for short runs.

The floor (`floor_projection`): at paper scale the environments, not the updates, bound a run.
Each environment's step cost is measured here (`seal.learner.env_backends.step_seconds`: CPU
seconds of a random-action step, the mean over the protocol's tasks), the env steps a seed makes
are counted from the protocol (every task collecting one episode every epoch, and every
evaluation's episodes), and for N cores at a parallel efficiency e:

    env stepping floor = sum over envs of (training + evaluation env steps) x step cost / (N x e)
    serial projection  = floor + updates + checkpoints   (collect, update, evaluate in turn)
    overlapped         = max(floor, updates) + checkpoints (collection and evaluation beside
                         the updates: `training.overlap`, `evaluation.mode = "async"`)

where updates = gradient steps / the update rate (measured in the window, or `--update-rate`).
All three are projections: e is assumed, not measured, and N may not be this machine's.
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from seal.device import usable_cores
from seal.errors import SealError
from seal.protocols import load_protocol
from seal.protocols.config import ProtocolConfig
from seal.run.phase_model import build_adapters, plan_phases
from seal.run.runner import run_seed
from seal.run.state import LOOP_PARTS

PARTS = ("collect", "update", "evaluate", "checkpoint")
PARALLEL_EFFICIENCY = 0.8
"""Share of N cores' time the env stepping is assumed to get (an assumption, not a measurement)."""
STEP_SAMPLES = 100
"""Random-action steps timed per task for its step cost."""


def window_overrides(config: ProtocolConfig, epochs: int) -> list[str]:
    """`--set` overrides turning `config` into an N-epoch timing window (see the module docstring)."""
    overrides = [
        f"protocol.epochs={epochs}",
        "protocol.seeds=1",
        "training.warmup_steps=0",
        "evaluation.every_grad_steps=0",
        f"evaluation.interval={epochs}",
        f"checkpoint.interval={epochs}",
        "logging.tensorboard=false",
    ]
    if config.finetune is not None:
        overrides += [f"finetune.pretrain_epochs={epochs}", f"finetune.finetune_epochs={epochs}"]
    return overrides


def floor_projection(
    *,
    env_steps: Mapping[str, float],
    step_s: Mapping[str, float],
    cores: int,
    update_s: float | None,
    checkpoint_s: float = 0.0,
    efficiency: float = PARALLEL_EFFICIENCY,
) -> dict[str, float | None]:
    """The env-stepping floor and the serial and overlapped projections, in hours (module docstring).

    `env_steps`: env -> env steps of a seed (training and evaluation); `step_s`: env -> seconds
    per step; `update_s`: seconds of all gradient steps (None: unknown, so no projections).
    """
    core_s = sum(float(n) * step_s[e] for e, n in env_steps.items())
    floor_s = core_s / (cores * efficiency)
    serial = overlapped = None
    if update_s is not None:
        serial = (floor_s + update_s + checkpoint_s) / 3600
        overlapped = (max(floor_s, update_s) + checkpoint_s) / 3600
    return {
        "env_core_h": core_s / 3600,
        "floor_h": floor_s / 3600,
        "update_h": None if update_s is None else update_s / 3600,
        "checkpoint_h": checkpoint_s / 3600,
        "serial_h": serial,
        "overlapped_h": overlapped,
    }


def measure_step_costs(
    config: ProtocolConfig, steps: int = STEP_SAMPLES, log: Callable[[str], None] = lambda _: None
) -> dict[str, float]:
    """env -> mean CPU seconds of one env step over the protocol's tasks (each task weighs the same,
    as each collects the same episodes)."""
    from seal.learner.env_backends import step_seconds

    costs: dict[str, float] = {}
    for env, adapter in build_adapters(config).items():
        per_task = [step_seconds(adapter, task, steps) for task in adapter.tasks]
        costs[env] = sum(per_task) / len(per_task)
        log(f"{env}: {costs[env] * 1e3:.3f} ms a step ({len(per_task)} tasks x {steps} steps)")
    return costs


def _cpu_count() -> int:
    """This machine's cores (those this process may run on)."""
    return usable_cores()


def bench_protocol(
    path: str | Path,
    epochs: int,
    overrides: Sequence[str] = (),
    out: str | Path | None = None,
    log: Callable[[str], None] = lambda _: None,
    cores: int | None = None,
    update_rate: float | None = None,
    floor_only: bool = False,
) -> dict[str, Any]:
    """Run the N-epoch window of the protocol at `path` and project the whole protocol's wall time.

    Returns {"protocol", "epochs", "phases": {phase: per-epoch and per-event seconds, counts and
    projected seconds}, "projected_s", "projected_h", "window_s", "floor"}. `out` keeps the
    window's run directory (default: a temporary one, deleted afterwards). "floor" holds the
    env-stepping floor and the serial and overlapped projections for `cores` cores (default:
    this machine's) at `update_rate` updates/s (default: the window's); `floor_only` skips the
    window (no update rate unless `update_rate` is given).
    """
    if epochs < 1 and not floor_only:
        raise SealError(f"--epochs {epochs}: expected an integer >= 1")
    if cores is not None and cores < 1:
        raise SealError(f"--cores {cores}: expected an integer >= 1")
    if update_rate is not None and not update_rate > 0:
        raise SealError(f"--update-rate {update_rate}: expected updates per second > 0")
    full = load_protocol(path, overrides)
    step_s = measure_step_costs(full, log=log)
    if floor_only:
        return {
            "protocol": str(path),
            "epochs": 0,
            "floor": _floor(full, step_s, None, cores or _cpu_count(), update_rate),
        }
    window = load_protocol(path, [*overrides, *window_overrides(full, epochs)])
    with tempfile.TemporaryDirectory(prefix="seal-bench-protocol-") as tmp:
        group = Path(out) if out is not None else Path(tmp)
        log(f"{full.name}: {epochs} epochs per phase into {group}")
        result = run_seed(window, full.seeds[0], group / full.name, quiet=True)
    phases: dict[str, dict[str, Any]] = {}
    total = 0.0
    for phase in plan_phases(full):
        timing = result.timing[phase.name]
        seconds, calls = timing["seconds"], timing["calls"]
        measured_epochs = max(int(timing["epochs"]), 1)
        grad_per_epoch = timing["grad_steps"] / measured_epochs
        per_epoch = {p: seconds.get(p, 0.0) / measured_epochs for p in ("collect", "update")}
        per_eval = seconds.get("evaluate", 0.0) / max(calls.get("evaluate", 0), 1)
        per_ckpt = seconds.get("checkpoint", 0.0) / max(calls.get("checkpoint", 0), 1)
        evaluations = _evaluations(full, phase.epochs, grad_per_epoch)
        checkpoints = math.ceil(phase.epochs / full.checkpoint.interval)
        # A checkpoint's size is mostly the replay it holds: rows grow with epochs up to capacity.
        rows_window = epochs * _env_steps_per_epoch(full, phase.envs)
        capacity = full.replay.capacity_per_env * len(phase.envs)
        rows_full_mean = min(capacity, phase.epochs * _env_steps_per_epoch(full, phase.envs) / 2)
        ckpt_scale = max(1.0, rows_full_mean / max(rows_window, 1))
        projected = (
            phase.epochs * (per_epoch["collect"] + per_epoch["update"])
            + evaluations * per_eval
            + checkpoints * per_ckpt * ckpt_scale
        )
        total += projected
        phases[phase.name] = {
            "collect_s_per_epoch": per_epoch["collect"],
            "update_s_per_epoch": per_epoch["update"],
            "grad_steps_per_epoch": grad_per_epoch,
            "updates_per_s": grad_per_epoch / per_epoch["update"] if per_epoch["update"] else None,
            "evaluate_s_each": per_eval,
            "checkpoint_s_each": per_ckpt,
            "epochs": phase.epochs,
            "evaluations": evaluations,
            "checkpoints": checkpoints,
            "projected_s": projected,
            "share": {
                "collect": phase.epochs * per_epoch["collect"] / projected if projected else 0.0,
                "update": phase.epochs * per_epoch["update"] / projected if projected else 0.0,
                "evaluate": evaluations * per_eval / projected if projected else 0.0,
            },
        }
    window_s = sum(
        t["seconds"].get(p, 0.0) for t in result.timing.values() for p in (*LOOP_PARTS, "demos")
    )
    return {
        "protocol": str(path),
        "epochs": epochs,
        "device": window.agent.device if window.agent is not None else "auto",
        "phases": phases,
        "window_s": window_s,
        "projected_s": total,
        "projected_h": total / 3600,
        "floor": _floor(full, step_s, phases, cores or _cpu_count(), update_rate),
        "threads": result.threads,
    }


def _floor(
    config: ProtocolConfig,
    step_s: Mapping[str, float],
    measured: Mapping[str, Mapping[str, Any]] | None,
    cores: int,
    update_rate: float | None,
) -> dict[str, Any]:
    """The "floor" entry of `bench_protocol`: per phase and for the whole seed. Evaluation env
    steps are the full evaluations' times the share that evaluation.decide_early and
    end_on_success leave (`seal.bench.evaluation_cost`: a model, measured expert success steps)."""
    shares: dict[str, dict[str, float]] = {}
    success: dict[str, float] = {}
    if config.evaluation.decide_early or config.evaluation.end_on_success:
        from seal.bench.evaluation_cost import evaluation_shares, success_steps

        success = success_steps(config, build_adapters(config))
        shares = evaluation_shares(config, success)
    per_phase: dict[str, dict[str, Any]] = {}
    for phase in plan_phases(config):
        window = None if measured is None else measured[phase.name]
        grad_per_epoch = (
            window["grad_steps_per_epoch"]
            if window is not None
            else _grad_steps_per_epoch(config, phase.envs)
        )
        rate = update_rate if update_rate is not None else (window or {}).get("updates_per_s")
        grad_steps = phase.epochs * grad_per_epoch
        evaluations = _evaluations(config, phase.epochs, grad_per_epoch)
        train = {e: phase.epochs * _env_steps_per_epoch(config, [e]) for e in phase.envs}
        evals = {
            e: evaluations
            * config.evaluation.episodes
            * _env_steps_per_epoch(config, [e])
            * shares.get(e, {"share": 1.0})["share"]
            for e in phase.envs
        }
        checkpoint_s = 0.0
        if window is not None:
            checkpoint_s = window["checkpoint_s_each"] * window["checkpoints"]
        figures = floor_projection(
            env_steps={e: train[e] + evals[e] for e in phase.envs},
            step_s=step_s,
            cores=cores,
            update_s=grad_steps / rate if rate else None,
            checkpoint_s=checkpoint_s,
        )
        per_phase[phase.name] = {
            "train_env_steps": sum(train.values()),
            "eval_env_steps": sum(evals.values()),
            "grad_steps": grad_steps,
            "updates_per_s": rate,
            **figures,
        }
    totals = {
        k: None
        if any(p[k] is None for p in per_phase.values())
        else sum(p[k] for p in per_phase.values())
        for k in ("env_core_h", "floor_h", "update_h", "checkpoint_h", "serial_h", "overlapped_h")
    }
    return {
        "label": "projections",
        "cores": cores,
        "parallel_efficiency": PARALLEL_EFFICIENCY,
        "update_rate": "given" if update_rate is not None else "measured",
        "step_ms": {e: s * 1e3 for e, s in step_s.items()},
        "evaluation_share": shares,
        "expert_success_step": success,
        "phases": per_phase,
        **totals,
    }


def _evaluations(config: ProtocolConfig, epochs: int, grad_per_epoch: float) -> int:
    """Evaluations of a phase of `epochs` epochs, from the protocol's evaluation settings."""
    every = config.evaluation.every_grad_steps
    if every:
        return math.floor(epochs * grad_per_epoch / every) + 1
    return math.ceil(epochs / config.evaluation.interval)


def _grad_steps_per_epoch(config: ProtocolConfig, envs: Sequence[str]) -> int:
    """Gradient steps of an epoch in which every env collects (`training.grad_steps_per_epoch`)."""
    n = config.training.grad_steps_per_epoch
    return max(config.envs[e].episode_length for e in envs) if n == -1 else n


def _env_steps_per_epoch(config: ProtocolConfig, envs: Sequence[str]) -> int:
    """Env steps one epoch collects when every task collects one episode."""
    return sum(len(config.envs[e].tasks) * config.envs[e].episode_length for e in envs)


def format_protocol_bench(result: dict[str, Any]) -> str:
    """The bench result as a few readable lines."""
    lines = [f"{result['protocol']}: {result['epochs']} epochs per phase measured"]
    if "phases" not in result:
        lines = [f"{result['protocol']}: step costs only (no window)"]
    for name, p in result.get("phases", {}).items():
        ups = p["updates_per_s"]
        lines.append(
            f"  {name}: collect {p['collect_s_per_epoch']:.2f} s + update {p['update_s_per_epoch']:.2f} s per epoch"
            f" ({p['grad_steps_per_epoch']:.0f} gradient steps, {ups:.1f} updates/s)"
            if ups
            else f"  {name}: collect {p['collect_s_per_epoch']:.2f} s per epoch, no updates"
        )
        lines.append(
            f"    evaluation {p['evaluate_s_each']:.1f} s x {p['evaluations']}, checkpoint "
            f"{p['checkpoint_s_each']:.2f} s x {p['checkpoints']}; {p['epochs']} epochs -> "
            f"{p['projected_s'] / 3600:.2f} h (collect {p['share']['collect']:.0%}, update "
            f"{p['share']['update']:.0%}, evaluation {p['share']['evaluate']:.0%})"
        )
    if result.get("threads"):
        lines.append(f"  update threads: {result['threads']}")
    if "projected_h" in result:
        lines.append(f"  projected wall time: {result['projected_h']:.2f} h per seed")
    f = result["floor"]
    steps = ", ".join(f"{e} {ms:.2f} ms" for e, ms in f["step_ms"].items())
    train = sum(p["train_env_steps"] for p in f["phases"].values())
    evals = sum(p["eval_env_steps"] for p in f["phases"].values())
    lines.append(
        f"  projections for {f['cores']} cores at parallel efficiency {f['parallel_efficiency']}: "
        f"env stepping {f['env_core_h']:.1f} core-h ({train / 1e6:.1f} M training + "
        f"{evals / 1e6:.1f} M evaluation env steps; a step: {steps})"
    )
    line = f"    env-stepping floor {f['floor_h']:.2f} h per seed"
    if f["serial_h"] is not None:
        line += (
            f"; serial {f['serial_h']:.2f} h; overlapped {f['overlapped_h']:.2f} h (updates "
            f"{f['update_h']:.2f} h at the {f['update_rate']} rate, checkpoints {f['checkpoint_h']:.2f} h)"
        )
    lines.append(line)
    if f.get("evaluation_share"):
        per_env = ", ".join(
            f"{e} {s['share']:.0%} (expert's first success at step {f['expert_success_step'][e]:.0f})"
            for e, s in f["evaluation_share"].items()
        )
        lines.append(
            f"    evaluation env steps at {per_env} of the full evaluation's, by the clean model "
            "(a task fails every episode before its crossing, succeeds in every one after; a task "
            "hovering near the threshold costs more: seal/bench/evaluation_cost.py)"
        )
    return "\n".join(lines)
