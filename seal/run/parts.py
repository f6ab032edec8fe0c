"""What the phase loop's collaborators see of it (`LoopParts`) and what the loop and its callbacks
see of the run that owns them (`PhaseOwner`): protocols, so that the collaborators' modules
(`seal.run.collection`, `evaluation`, `training`, `stopping`, `loop_log`), the callbacks' and the
loop's need import neither the loop nor the runner."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from contextlib import AbstractContextManager
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from seal.envs.alignment import Alignment
    from seal.envs.base import EnvAdapter
    from seal.learner.config import AgentConfig
    from seal.learner.replay import MultiTaskReplay
    from seal.learner.sac import Agent
    from seal.protocols.config import ProtocolConfig
    from seal.run.phase_model import Phase, PhaseModel
    from seal.run.preemption import SignalStop
    from seal.run.rundir import RunDir
    from seal.run.state import PhaseState
    from seal.schedulers.base import Scheduler


class PhaseOwner(Protocol):
    """What a `PhaseLoop` and its callbacks use of the run that owns them (`seal.run.runner.Run`)."""

    @property
    def config(self) -> ProtocolConfig: ...
    @property
    def seed(self) -> int: ...
    @property
    def device(self) -> str: ...
    @property
    def quiet(self) -> bool: ...
    @property
    def rundir(self) -> RunDir: ...
    @property
    def adapters(self) -> Mapping[str, EnvAdapter]: ...
    @property
    def alignment(self) -> Alignment | None: ...
    @property
    def agent_cfg(self) -> AgentConfig: ...
    @property
    def phases(self) -> Sequence[Phase]: ...
    @property
    def results(self) -> Mapping[str, PhaseState]:
        """Phase name -> the final counters of each phase finished so far."""
        ...

    def initial_agent(self, phase: Phase, model: PhaseModel, resuming: bool = False) -> Agent:
        """The phase's agent before its first update (transferred or fine-tuned where the protocol says)."""
        ...


class LoopParts(Protocol):
    """What the loop's collaborators use of the `PhaseLoop` (`seal.run.loop`): its typed parts,
    its counters (`state`, which a restore or a rollback replaces), its clock and its callbacks."""

    cfg: ProtocolConfig
    owner: PhaseOwner
    phase: Phase
    model: PhaseModel
    agent: Agent
    replay: MultiTaskReplay
    scheduler: Scheduler
    state: PhaseState
    stop: SignalStop
    started: float
    """time.monotonic() at the phase's start, less the wall time of its earlier runs."""

    def timed(self, part: str, count: bool = True) -> AbstractContextManager[None]:
        """Count the block's wall seconds to `part` (`seal.run.state.Clock.timed`)."""
        ...

    def notify(self, hook: str, *args: object) -> None:
        """Call every callback's `hook` (a `LoopCallback` method), in order."""
        ...

    def all_reached(self) -> bool:
        """evaluation.stop_when_reached is on and every task has reached the threshold."""
        ...

    def evaluate(self, final: bool = False) -> None:
        """Evaluate the agent now (after reading the updates' logs)."""
        ...

    def close_workers(self) -> None:
        """Close the training and evaluation instances and the worker processes."""
        ...
