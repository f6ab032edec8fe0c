"""A phase's checkpoints and stops: the epoch checkpoints that are due (every
`checkpoint.interval` epochs and the phase's last), and on SIGTERM or SIGINT
(`seal.run.preemption`) the stop at a safe point with the checkpoint of the last finished epoch,
rolling back an epoch under way (`seal.run.rollback`) when the signal's budget allows no finishing it.

The loop calls `before_epoch` (a signal between epochs stops here; the rollback mark),
`roll_back` when the epoch under way is abandoned, `close_epoch` after it (the checkpoint, or the
stop), and `at_phase_end`. The `Checkpointer` callback (`seal.run.checkpointing`) writes what
`checkpoint` calls for.
"""

from __future__ import annotations

import copy
import random
import time
from typing import TYPE_CHECKING, NoReturn, cast

import numpy as np
import torch

from seal.device import torch_threads
from seal.errors import SealError
from seal.run.preemption import Preempted
from seal.run.rollback import EpochMark, ReplayMark, RolledBackReplay
from seal.run.state import PhaseState
from seal.run.workers import cpu_copy

if TYPE_CHECKING:
    from seal.learner.agent_state import AgentState
    from seal.learner.replay import MultiTaskReplay
    from seal.run.collection import Collection
    from seal.run.evaluation import Evaluation
    from seal.run.parts import LoopParts


class Stopping:
    """When the phase's checkpoints are written, and how it stops on a signal (module docstring)."""

    def __init__(
        self, loop: LoopParts, collection: Collection, evaluation: Evaluation, resumed: bool
    ) -> None:
        self.loop, self.collection, self.evaluation = loop, collection, evaluation
        self.saved_epoch: int | None = loop.state.epoch if resumed else None
        """The epoch of this phase's newest epoch checkpoint on disk (None: none yet)."""
        self.mark: EpochMark | None = None
        """What a rollback of the epoch under way restores (kept while a signal is handled)."""
        self.rolled_back: RolledBackReplay | None = None

    @property
    def checkpoint_replay(self) -> MultiTaskReplay:
        """What an epoch checkpoint saves of the replay: the replay, or after a rollback its
        state at the epoch's start (a `RolledBackReplay`, which has the one method a save calls)."""
        return cast("MultiTaskReplay", self.rolled_back or self.loop.replay)

    def before_epoch(self) -> None:
        """A signal that came between epochs stops the loop after the last one; else the mark
        of the coming epoch's start, while signals are handled."""
        stop = self.loop.stop
        if stop.requested:
            self.stop(f"{stop.name} after epoch {self.loop.state.epoch}")
        self.mark = self.take_mark() if stop.active else None

    def close_epoch(self, last_epoch: bool) -> None:
        """The epoch's checkpoint, when one is due or a signal came.

        A signal during the epoch's work that let it finish (`seal.run.preemption`) stops the
        loop here, after the epoch's checkpoint.
        """
        loop = self.loop
        stop, state = loop.stop, loop.state
        if stop.requested:
            budget = loop.cfg.checkpoint.signal_budget_s
            how = (
                f"{stop.name} during epoch {state.epoch}: finished it "
                f"{stop.time_since_signal():.1f} s after the signal "
                f"(checkpoint.signal_budget_s = {budget:g})"
                if stop.during_epoch
                else f"{stop.name} after epoch {state.epoch}"
            )
            if not last_epoch:
                self.stop(how)
            stop.note = f"{how}; it was the phase's last; {self.save_for_stop()}"
        elif state.epoch % loop.cfg.checkpoint.interval == 0 or last_epoch:
            self.checkpoint(reseed=not last_epoch)

    def at_phase_end(self) -> None:
        """A signal after the phase's last epoch: note what was saved (the run stops)."""
        stop = self.loop.stop
        if stop.requested and not stop.note:
            how = f"{stop.name} after epoch {self.loop.state.epoch}, the phase's last"
            stop.note = f"{how}; {self.save_for_stop()}"

    def checkpoint(self, reseed: bool, wall_s: float | None = None) -> None:
        """An epoch checkpoint: `on_checkpoint` (loggers flush), then `write_checkpoint` (the Checkpointer).

        `wall_s`: the run's wall time to record (default: now); a rollback records its epoch start's.
        """
        loop = self.loop
        state = loop.state
        state.wall_s = time.monotonic() - loop.started if wall_s is None else wall_s
        state.anchor_epoch = state.epoch
        # A signal now lets the write finish; a second one kills at once.
        with loop.timed("checkpoint"), loop.stop.saving():
            with loop.timed("log", count=False):
                loop.notify("on_checkpoint")
            loop.notify("write_checkpoint")
        self.saved_epoch = state.epoch
        if reseed:
            # Re-seed env streams at every checkpoint so a resumed run repeats this run exactly:
            # the instances are rebuilt from the new anchor epoch when next used (by the actor,
            # training.overlap, from the anchor it is sent). The rebuild keeps the backend "auto"
            # resolved to (no second probe of step costs); results never depend on the backend.
            with loop.timed("collect", count=False):
                self.collection.close_collector()

    # ------------------------------------------------------------ stopping on a signal
    def take_mark(self) -> EpochMark:
        """What a rollback of the coming epoch restores (the counters, agent, scheduler, RNG
        states, CSV rows and the replay's counters and overwritable slots)."""
        loop = self.loop
        state = loop.state.fields()  # dataclasses.asdict: a deep copy
        state["wall_s"] = time.monotonic() - loop.started
        steps = {loop.model.agent_env[e]: a.episode_length for e, a in loop.model.adapters.items()}
        return EpochMark(
            state=state,
            agent=_copy_on_one_thread(loop.agent.state_dict()),
            scheduler=copy.deepcopy(loop.scheduler.state_dict()),
            pending=list(self.evaluation.pending),
            rows=loop.owner.rundir.row_counts(),
            torch_rng=torch.get_rng_state(),
            py_rng=random.getstate(),
            replay=ReplayMark.take(loop.replay, steps),
        )

    def roll_back(self) -> NoReturn:
        """Abandon the epoch under way: its workers' requests, its rows; restore its start and save it."""
        loop, mark = self.loop, self.mark
        assert mark is not None  # the handler rolls back only while the loop keeps marks
        loop.close_workers()
        for env, adapter in loop.model.adapters.items():
            added = np.subtract(loop.state.env_steps[env], mark.state["env_steps"][env])
            if int(added.max(initial=0)) > adapter.episode_length:
                raise SealError(
                    f"{loop.owner.rundir.path}: cannot roll back epoch {mark.state['epoch'] + 1}: "
                    f"{env} added {int(added.max())} transitions to one task, more than its episode"
                )
        loop.agent.load_state_dict(mark.agent)
        loop.scheduler.load_state_dict(mark.scheduler)
        loop.state, self.evaluation.pending = PhaseState(**mark.state), list(mark.pending)
        torch.set_rng_state(mark.torch_rng)
        random.setstate(mark.py_rng)
        loop.owner.rundir.truncate_to(mark.rows)
        self.rolled_back = RolledBackReplay(loop.replay, mark.replay)
        self.stop(
            f"{loop.stop.name} during epoch {mark.state['epoch'] + 1}: rolled back to its start "
            f"({loop.stop.rollback_reason})",
            wall_s=mark.state["wall_s"],
        )

    def stop(self, how: str, wall_s: float | None = None) -> NoReturn:
        """Save the last finished epoch unless it is on disk, then raise `Preempted`."""
        stop = self.loop.stop
        assert stop.signum is not None
        stop.note = f"{how}; {self.save_for_stop(wall_s)}"
        raise Preempted(stop.signum, stop.note, resumable=self.loop.cfg.checkpoint.save_replay)

    def save_for_stop(self, wall_s: float | None = None) -> str:
        """The checkpoint of the last finished epoch, written unless it is on disk; what it is."""
        loop = self.loop
        state, rundir, phase = loop.state, loop.owner.rundir, loop.phase
        where = f"epoch {state.epoch}"
        if len(loop.owner.phases) > 1:
            where += f" of phase {phase.name}"
        if state.epoch == 0:
            latest = rundir.latest_checkpoint()
            if latest is None:
                return "no epoch had finished: nothing saved, the run starts over when resumed"
            return (
                f"no epoch of phase {phase.name} had finished: nothing new saved; "
                f"the newest checkpoint is {latest}"
            )
        if self.saved_epoch == state.epoch:
            text = f"{where}'s checkpoint {rundir.latest_checkpoint()} is on disk"
        else:
            since = time.perf_counter()
            self.checkpoint(reseed=False, wall_s=wall_s)
            seconds = time.perf_counter() - since
            path = rundir.latest_checkpoint()
            assert path is not None
            text = f"saved {where} to {path} ({_size(path.stat().st_size)} in {seconds:.1f} s)"
        if not loop.cfg.checkpoint.save_replay:
            text += (
                "; it holds no replay (checkpoint.save_replay = false), so --resume cannot "
                "continue the run exactly and refuses it; its agent serves seal eval and [transfer]"
            )
        return text


def _copy_on_one_thread(state: AgentState) -> AgentState:
    """`cpu_copy(state)` on one torch thread: the copy is memory-bound, and a second thread on a
    busy machine only makes it wait (docs/faults.md has the figures)."""
    with torch_threads(1):
        return cpu_copy(state)


def _size(nbytes: int) -> str:
    """A file size for a message: "0.82 GB", "3.1 MB"."""
    return f"{nbytes / 1e9:.2f} GB" if nbytes >= 1e8 else f"{nbytes / 1e6:.1f} MB"
