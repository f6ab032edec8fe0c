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
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from seal.errors import SealError
from seal.protocols import load_protocol, run_seed
from seal.protocols.config import ProtocolConfig
from seal.protocols.runner import plan_phases

PARTS = ("collect", "update", "evaluate", "checkpoint")


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


def bench_protocol(
    path: str | Path,
    epochs: int,
    overrides: Sequence[str] = (),
    out: str | Path | None = None,
    log: Callable[[str], None] = lambda _: None,
) -> dict[str, Any]:
    """Run the N-epoch window of the protocol at `path` and project the whole protocol's wall time.

    Returns {"protocol", "epochs", "phases": {phase: per-epoch and per-event seconds, counts and
    projected seconds}, "projected_s", "projected_h", "window_s"}. `out` keeps the window's run
    directory (default: a temporary one, deleted afterwards).
    """
    if epochs < 1:
        raise SealError(f"--epochs {epochs}: expected an integer >= 1")
    full = load_protocol(path, overrides)
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
        every = full.evaluation.every_grad_steps
        evaluations = (
            math.floor(phase.epochs * grad_per_epoch / every) + 1
            if every
            else math.ceil(phase.epochs / full.evaluation.interval)
        )
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
    window_s = sum(sum(t["seconds"].values()) for t in result.timing.values())
    return {
        "protocol": str(path),
        "epochs": epochs,
        "device": window.agent.device if window.agent is not None else "auto",
        "phases": phases,
        "window_s": window_s,
        "projected_s": total,
        "projected_h": total / 3600,
    }


def _env_steps_per_epoch(config: ProtocolConfig, envs: Sequence[str]) -> int:
    """Env steps one epoch collects when every task collects one episode."""
    return sum(len(config.envs[e].tasks) * config.envs[e].episode_length for e in envs)


def format_protocol_bench(result: dict[str, Any]) -> str:
    """The bench result as a few readable lines."""
    lines = [f"{result['protocol']}: {result['epochs']} epochs per phase measured"]
    for name, p in result["phases"].items():
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
    lines.append(f"  projected wall time: {result['projected_h']:.2f} h per seed")
    return "\n".join(lines)
