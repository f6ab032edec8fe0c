"""What a run produced: its headline numbers (`RunResult`, `run_result`, `seal run --json`'s
line: `result_json`) and where its wall time went (`time_shares`, `time_line`)."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

from seal.run.state import LOOP_PARTS, PhaseState

if TYPE_CHECKING:
    from seal.envs.base import EnvAdapter
    from seal.run.phase_model import Phase


class PhaseTiming(TypedDict):
    """Where one phase's wall time went (`RunResult.timing`, `seal bench --protocol`)."""

    seconds: dict[str, float]
    """Part -> wall seconds: `seal.run.state.LOOP_PARTS`, demos, evaluate_worker_cpu."""
    calls: dict[str, int]
    """Part -> how many times it ran (update: gradient steps; evaluate: evaluations)."""
    epochs: int
    grad_steps: int


class TimeShares(TypedDict):
    """Where a run's wall time went (`time_shares`; provenance.json's "time_shares", `RunResult`).

    loop_s is the phases' epoch loops (across resumes); parts_s splits it into `LOOP_PARTS`
    and other_s is the rest (planning, the epoch's bookkeeping, a signal's rollback marks).
    startup_s is this process's wall outside the loops: building the run and each phase (agent,
    replay, demonstrations), then closing the phase's env instances and workers.
    """

    wall_s: float
    startup_s: float
    loop_s: float
    parts_s: dict[str, float]
    other_s: float
    evaluate_worker_cpu_s: float
    """evaluation.mode = "async": the evaluation worker's CPU seconds (parts_s's evaluate is then
    the loop's waiting on it); 0 for synchronous evaluation."""


def time_shares(states: Sequence[PhaseState], startup_s: float) -> TimeShares:
    """The phases' loop time by part (`PhaseState.seconds`), other and `startup_s` beside it."""
    loop_s = sum(s.wall_s for s in states)
    parts = {p: sum(s.seconds.get(p, 0.0) for s in states) for p in LOOP_PARTS}
    return {
        "wall_s": startup_s + loop_s,
        "startup_s": startup_s,
        "loop_s": loop_s,
        "parts_s": parts,
        "other_s": loop_s - sum(parts.values()),
        "evaluate_worker_cpu_s": sum(s.seconds.get("evaluate_worker_cpu", 0.0) for s in states),
    }


def time_line(shares: TimeShares) -> str:
    """`shares` in one line: start-up, then the loop's wall by part with its percentage."""
    loop = shares["loop_s"]

    def part(name: str, seconds: float) -> str:
        return f"{name} {seconds:.1f} s ({100 * seconds / loop if loop else 0.0:.0f}%)"

    parts = dict(shares["parts_s"])
    cpu = shares["evaluate_worker_cpu_s"]
    if cpu:
        parts["evaluate (waiting)"] = parts.pop("evaluate")
    text = (
        f"time: wall {shares['wall_s']:.1f} s = start-up {shares['startup_s']:.1f} s + loop "
        f"{loop:.1f} s: "
        + ", ".join(part(n, s) for n, s in [*parts.items(), ("other", shares["other_s"])])
    )
    if cpu:
        text += f"; evaluation worker CPU {cpu:.1f} s"
    return text


@dataclass(frozen=True)
class RunResult:
    """What one seed's run produced: its directory and the headline numbers (also `seal run --json`)."""

    run_dir: Path
    update_counts: dict[str, dict[str, float | None]]
    """env -> task -> millions of that task's transitions consumed by updates when it first reached the threshold (None, JSON null: never; 0 would be a task reached before any update)."""
    final_success: dict[str, dict[str, float]]
    """env -> task -> success rate at the last evaluation of the phase that trained on env."""
    timing: dict[str, PhaseTiming] = field(default_factory=dict)
    """phase -> {"seconds", "calls"} of its collect/update/evaluate/checkpoint parts, "epochs", "grad_steps" (`seal bench --protocol`)."""
    threads: str = ""
    """The updates' intra-op threads and what chose them (`seal.device.ThreadChoice.describe`)."""
    time_shares: TimeShares | None = None
    """Where the run's wall time went (`time_shares`)."""


def run_result(
    run_dir: Path,
    phases: Sequence[Phase],
    results: Mapping[str, PhaseState],
    adapters: Mapping[str, EnvAdapter],
    threads: str,
    shares: TimeShares,
) -> RunResult:
    """The headline numbers and the per-part timing of the finished phases."""
    counts: dict[str, dict[str, float | None]] = {}
    final: dict[str, dict[str, float]] = {}
    for phase in phases:
        state = results[phase.name]
        for env in phase.envs:
            tasks = adapters[env].tasks
            reached = state.reached.get(env, {})
            counts[env] = {t: float(reached[t]) if t in reached else None for t in tasks}
            final[env] = {t: float(state.last_success.get(env, {}).get(t, 0.0)) for t in tasks}
    timing: dict[str, PhaseTiming] = {
        name: {
            "seconds": dict(state.seconds),
            "calls": dict(state.calls),
            "epochs": state.epoch,
            "grad_steps": state.grad_steps,
        }
        for name, state in results.items()
    }
    return RunResult(run_dir, counts, final, timing, threads, shares)


def result_json(results: Sequence[RunResult]) -> str:
    """The one-line JSON that `seal run --json` ends with."""
    last = results[-1]
    data: dict[str, Any] = {
        "run_dir": str(last.run_dir),
        "update_counts": last.update_counts,
        "final_success": last.final_success,
    }
    if len(results) > 1:
        data["run_dirs"] = [str(r.run_dir) for r in results]
    return json.dumps(
        data,
        allow_nan=False,
        default=lambda o: None if isinstance(o, float) and not math.isfinite(o) else str(o),
    )
