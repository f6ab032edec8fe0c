"""A phase's counters (`PhaseState`, saved in every checkpoint), the parts of its loop's wall
(`LOOP_PARTS`) and the clock that counts them (`Clock`), and the policy an evaluation ran
(`Evaluated`). The loop (`seal.run.loop`) and its collaborators share them."""

from __future__ import annotations

import contextlib
import dataclasses
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, cast

if TYPE_CHECKING:
    from seal.learner.sac import Agent
    from seal.run.checkpoint_fields import PhaseStateFields

LOOP_PARTS = ("collect", "update", "evaluate", "checkpoint", "log")
"""The parts of a phase loop's wall that `Clock.timed` counts; the rest of it is "other".

evaluate: the loop's wall spent on evaluation (best.pt included). Synchronous, the evaluation
itself; asynchronous, only the loop's waiting on it (the snapshot, waiting for the previous
result, recording it), the worker's CPU seconds counted apart ("evaluate_worker_cpu"). log: the
CSV rows, the loggers' and progress bar's callbacks (TensorBoard, wandb, Tune), their flushes.
"""


@dataclass
class PhaseState:
    """Counters of one phase (saved in every checkpoint)."""

    epoch: int = 0
    grad_steps: int = 0
    env_steps: dict[str, list[int]] = field(default_factory=dict)
    best_mean_success: float = -1.0
    wall_s: float = 0.0
    anchor_epoch: int = 0
    """Epoch of the last checkpoint: the collectors' seeds derive from it (exact resume)."""
    last_success: dict[str, dict[str, float]] = field(default_factory=dict)
    reached: dict[str, dict[str, float]] = field(default_factory=dict)
    """env -> task -> updates (millions) at the first evaluation at or above the threshold."""
    timeline_rows: int = 0
    """Scheduler timeline records already written to scheduler.csv."""
    log_sums: dict[str, float] = field(default_factory=dict)
    """Sums of the agent's log values over the updates since the last train.csv row."""
    log_updates: int = 0
    """Updates since the last train.csv row (a checkpoint between two rows keeps both)."""
    seconds: dict[str, float] = field(default_factory=dict)
    """Wall seconds of each part of the loop (`LOOP_PARTS`; `Clock.timed`), "demos" (before
    the loop) and "evaluate_worker_cpu" (evaluation.mode = "async": the worker's CPU seconds)."""
    calls: dict[str, int] = field(default_factory=dict)
    """How many times each part ran (update: gradient steps; evaluate: evaluations)."""
    demos: dict[str, dict[str, float]] = field(default_factory=dict)
    """env -> demonstration figures (episodes, env steps, expert success rate) put in the replay at the phase's start."""
    collected_lengths: dict[str, int] = field(default_factory=dict)
    """training.overlap: env -> the longest episode of the last collection, which the next epoch's updates train on."""
    evaluated_at: int = -1
    """Gradient steps at the last evaluation (an evaluation every K steps that falls on the last
    update of the run is not repeated at its end)."""
    evaluations: int = 0
    """Evaluations started in the phase (`evaluation.full_every` counts them)."""

    def fields(self) -> PhaseStateFields:
        """The counters as a checkpoint holds them (`dataclasses.asdict`)."""
        return cast("PhaseStateFields", dataclasses.asdict(self))

    def add_time(self, part: str, seconds: float, calls: int = 0) -> None:
        """Count `seconds` of wall time and `calls` runs to `part`."""
        self.seconds[part] = self.seconds.get(part, 0.0) + seconds
        if calls:
            self.calls[part] = self.calls.get(part, 0) + calls


class Clock:
    """Counts wall seconds by part into the phase's counters (`state_of()`: the loop's state now,
    which a restore or a rollback replaces)."""

    def __init__(self, state_of: Callable[[], PhaseState]) -> None:
        self.state_of = state_of
        self._open: list[tuple[str, float]] = []
        """The open parts, innermost last, each with the time its count resumed."""

    @contextlib.contextmanager
    def timed(self, part: str, count: bool = True) -> Iterator[None]:
        """Count the block's wall seconds to `part` in `state.seconds` (`count`: and one run in
        `state.calls`).

        A part timed within another counts to itself alone (the rows an evaluation writes are
        "log", not "evaluate"), so the parts never overlap and the loop's other = its wall -
        their sum (`LOOP_PARTS`).
        """
        clock, now = self._open, time.perf_counter()
        if clock:
            outer, since = clock[-1]
            self.state_of().add_time(outer, now - since)
        clock.append((part, now))
        try:
            yield
        finally:
            _, since = clock.pop()
            now = time.perf_counter()
            self.state_of().add_time(part, now - since, calls=int(count))
            if clock:
                clock[-1] = (clock[-1][0], now)


class Evaluated:
    """The policy the latest evaluation ran: its epoch, gradient steps and agent.

    Synchronous evaluation ran the live agent; asynchronous evaluation a snapshot, which
    `agent` loads into an agent of its own only when asked (best.pt, the alignment logger).
    """

    def __init__(self, epoch: int, grad_steps: int, agent: Agent | Callable[[], Agent]) -> None:
        self.epoch, self.grad_steps = epoch, grad_steps
        self._agent = agent

    @property
    def agent(self) -> Agent:
        """The agent evaluated (weights as they were at the evaluation)."""
        if callable(self._agent) and not hasattr(self._agent, "state_dict"):
            self._agent = self._agent()
        return self._agent  # type: ignore[return-value]
