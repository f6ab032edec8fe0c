"""One phase's epoch loop, by responsibility.

`PhaseLoop._epoch` reads the epoch in order: plan, collect, train, evaluate, log, checkpoint,
stop?. Each step is a collaborator's, in a module of its own:

- `seal.run.collection.Collection`: the training env instances, the actor process beside the
  updates (training.overlap), demonstrations and SMT's scoring episodes;
- `seal.run.training.Training`: the gradient steps and their log values;
- `seal.run.evaluation.Evaluation`: synchronous and asynchronous evaluations and their rows;
- `seal.run.loop_log.LoopLog`: train.csv's training curves, scheduler.csv, `on_epoch_end`;
- `seal.run.stopping.Stopping`: due checkpoints, and a signal's stop, save and rollback.

The phase's parts (agent, replay, scheduler, counters) are built by
`seal.run.phase_parts.build_phase_parts`; the counters and the clock are `seal.run.state`'s.
The loop calls its `LoopCallback`s: the progress bar, the TensorBoard and wandb loggers
(`seal.run.loggers`), a sweep's Ray Tune reporting and the `Checkpointer`
(`seal.run.checkpointing`), which writes the checkpoints the loop calls for. The `Run` that owns
it (`seal.run.runner`) keeps the run directory and registers the callbacks; the loop and its
callbacks see it as a `PhaseOwner` (`seal.run.parts`), so they need not import the runner.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Mapping, Sequence
from contextlib import AbstractContextManager
from typing import TYPE_CHECKING

import numpy as np

from seal.run.collection import Collection
from seal.run.evaluation import Evaluation
from seal.run.loop_log import LoopLog
from seal.run.phase_parts import build_phase_parts
from seal.run.preemption import RollBack, SignalStop
from seal.run.state import Clock, PhaseState
from seal.run.stopping import Stopping
from seal.run.training import Training

if TYPE_CHECKING:
    from tqdm import tqdm

    from seal.learner.replay import MultiTaskReplay
    from seal.run.checkpoint_fields import EpochCheckpoint
    from seal.run.parts import PhaseOwner
    from seal.run.phase_model import Phase, PhaseModel
    from seal.run.rundir import MetricsRow, TrainRow
    from seal.run.state import Evaluated
    from seal.run.workers import PendingEvaluation
    from seal.schedulers.base import Plan


class LoopCallback:
    """Hooks a `PhaseLoop` calls, in the order the callbacks were given; subclasses override what they need.

    The runner registers the progress bar, the loggers (`seal.run.loggers`), its caller's
    callbacks (e.g. a sweep's Ray Tune reporter) and the `Checkpointer`
    (`seal.run.checkpointing`), which implements the two `write_*` hooks.
    """

    def on_phase_start(self, loop: PhaseLoop) -> None:
        """Before the phase's first (or, resumed, next) epoch; metrics.csv holds what came before."""

    def write_best(self, loop: PhaseLoop) -> None:
        """After an evaluation whose mean success beats the phase's best, before any `on_evaluation`."""

    def on_evaluation(self, loop: PhaseLoop) -> None:
        """After each evaluation (its rows are in metrics.csv, `loop.state.last_success` holds them)."""

    def on_train_log(self, loop: PhaseLoop, rows: Sequence[TrainRow]) -> None:
        """After train.csv rows (TRAIN_COLUMNS: the mean logged values of an interval) are written."""

    def on_checkpoint(self, loop: PhaseLoop) -> None:
        """An epoch checkpoint is due; called before it is written (loggers flush, so a resume purges exactly)."""

    def write_checkpoint(self, loop: PhaseLoop) -> None:
        """Write the due epoch checkpoint; called after every callback's `on_checkpoint`."""

    def on_epoch_end(self, loop: PhaseLoop) -> None:
        """After each epoch's collection, updates, evaluation and checkpoint."""

    def on_phase_end(self, loop: PhaseLoop) -> None:
        """When the phase ends, normally or not."""


class ProgressBar(LoopCallback):
    """tqdm over the phase's epochs, with env steps/s, updates/s and the last success per env."""

    def __init__(self) -> None:
        self.bar: tqdm | None = None
        self.tick = (0.0, 0, 0)

    def on_phase_start(self, loop: PhaseLoop) -> None:
        self.bar = _progress_bar(loop.phase, loop.state.epoch)
        self.tick = (time.monotonic(), loop.env_steps(), loop.state.grad_steps)

    def on_epoch_end(self, loop: PhaseLoop) -> None:
        now, env_now, grad_now = time.monotonic(), loop.env_steps(), loop.state.grad_steps
        then, env_then, grad_then = self.tick
        dt = max(now - then, 1e-9)
        postfix = _postfix(env_now - env_then, grad_now - grad_then, dt, loop.state.last_success)
        if self.bar is not None:
            self.bar.set_postfix_str(postfix, refresh=False)
            self.bar.update(1)
        self.tick = (now, env_now, grad_now)

    def on_phase_end(self, loop: PhaseLoop) -> None:
        if self.bar is not None:
            self.bar.close()


class PhaseLoop:
    """One phase's epochs (`_epoch`), its typed parts (agent, replay, scheduler), its counters
    (`state`, saved in every checkpoint) and its collaborators (the module docstring)."""

    def __init__(
        self,
        run: PhaseOwner,
        phase: Phase,
        payload: EpochCheckpoint | None,
        callbacks: Sequence[LoopCallback] = (),
        stop: SignalStop | None = None,
        model: PhaseModel | None = None,
    ) -> None:
        from seal.run.phase_model import PhaseModel

        self.cfg, self.owner, self.phase, self.callbacks = run.config, run, phase, tuple(callbacks)
        self.stop = stop if stop is not None else SignalStop()
        """The run's SIGTERM and SIGINT handling (`seal.run.preemption`)."""
        self.model = model or PhaseModel(run.config, phase, run.adapters, run.alignment)
        parts = build_phase_parts(run, phase, self.model, payload)
        self.agent, self.drift_start, self.replay, self.scheduler, self.state = parts
        self.clock = Clock(lambda: self.state)
        self.collection, self.training, self.log = Collection(self), Training(self), LoopLog(self)
        self.evaluation = Evaluation(self, payload)
        if payload is None and any(self.cfg.demo_episodes(e) for e in self.model.env_tasks):
            with self.timed("demos"):
                self.state.demos = self.collection.demonstrations()
            if self.cfg.training.overlap:
                self.collection.close_collector()  # the actor has training instances of its own
        self.collection.ready()
        self.evaluation.ready()
        self.started = time.monotonic() - self.state.wall_s
        self.stopping = Stopping(self, self.collection, self.evaluation, payload is not None)

    def run(self) -> PhaseState:
        """Run the phase's remaining epochs; its counters.

        A signal (`seal.run.preemption`) stops the loop at a safe point with the checkpoint
        of the last finished epoch and raises `Preempted`; after the phase's last epoch it only
        notes what was saved (`SignalStop.note`) and returns, and the run stops.
        """
        self.notify("on_phase_start")
        try:
            self.evaluation.start_worker()
            self.collection.start_actor()
            while self.state.epoch < self.phase.epochs and not self.all_reached():
                if self._epoch():
                    break
            # The loop's wall (`LOOP_PARTS` and other); closing its workers is start-up's.
            self.state.wall_s = time.monotonic() - self.started
            self.stopping.at_phase_end()
        finally:
            self.close_workers()
            self.notify("on_phase_end")
        return self.state

    def _epoch(self) -> bool:
        """One epoch, in order: plan, collect, train, evaluate, log, checkpoint, stop?; whether
        it was the phase's last. A signal between epochs stops before it (`Stopping`); one
        during it finishes it or rolls it back to its start (`seal.run.preemption`)."""
        self.stopping.before_epoch()
        try:
            with self.stop.epoch():
                plan = self._plan()
                # training.overlap: the actor collects beside the updates
                self.collection.start(plan)
                self._train(plan, self.collection.lengths())
                self.collection.finish()
                last_epoch = self._end_epoch()  # count it, log its curves, evaluate
        except RollBack:
            self.stopping.roll_back()
        self.log.timeline()
        self._close_epoch(last_epoch)  # the checkpoint, or the stop a signal asked for
        self.log.epoch_end()
        return last_epoch

    def _plan(self) -> Plan:
        """The scheduler's plan for the epoch (after the evaluations it reads are in)."""
        from seal.schedulers import Progress

        if self.evaluation.reads_eval:
            self.evaluation.finish(wait=True)
        state, tasks = self.state, self.model.env_tasks
        steps = {(e, t): state.env_steps[e][i] for e, ts in tasks.items() for i, t in enumerate(ts)}
        progress = Progress(
            epoch=state.epoch,
            env_steps=sum(steps.values()),
            grad_steps=state.grad_steps,
            task_env_steps=steps,
        )
        plan = self.scheduler.plan(progress)
        if plan.reset_agent:
            self.agent.reset_parameters()
        return plan

    def _train(self, plan: Plan, lengths: Mapping[str, int]) -> None:
        """The epoch's gradient steps (`Training.train`)."""
        self.training.train(plan, lengths)

    def _end_epoch(self) -> bool:
        """Count the epoch, log its training curves and evaluate when due (with SMT's scores);
        whether the phase ends with it."""
        state, ev = self.state, self.cfg.evaluation
        self.evaluation.finish(wait=False)
        state.epoch += 1
        last_epoch = state.epoch >= self.phase.epochs or self.scheduler.done
        self.log.training_curves(last_epoch)
        # Evaluation (Appendix B): every `interval` epochs, or every K gradient steps (in training).
        due = not ev.every_grad_steps and state.epoch % ev.interval == 0
        if due or (
            last_epoch and not (ev.every_grad_steps and state.evaluated_at == state.grad_steps)
        ):
            self.evaluate(final=last_epoch)
        request = self.scheduler.wants_scores()
        if request is not None:
            with self.timed("collect", count=False):  # SMT's scoring episodes
                self.scheduler.observe_scores(self.collection.scores(request, state.epoch))
        if last_epoch or self.all_reached():
            self.evaluation.finish(wait=True)  # the phase's results are complete at its end
        last_epoch = last_epoch or self.all_reached()
        self.stop.epoch_done()  # finished: a signal from here on stops after it, never rolls it back
        return last_epoch

    def _close_epoch(self, last_epoch: bool) -> None:
        """The epoch's checkpoint when one is due, or the stop a signal asked for (`Stopping`)."""
        self.stopping.close_epoch(last_epoch)

    def _checkpoint(self, reseed: bool, wall_s: float | None = None) -> None:
        """An epoch checkpoint now (`Stopping.checkpoint`)."""
        self.stopping.checkpoint(reseed, wall_s)

    # ------------------------------------------------------------ what the collaborators share
    def evaluate(self, final: bool = False) -> None:
        """An evaluation now, after the updates' log values are read (a diverged run stops first)."""
        self.training.read_logs()
        self.evaluation.evaluate(final, self.training.batch_now)

    def timed(self, part: str, count: bool = True) -> AbstractContextManager[None]:
        """Count the block's wall seconds to `part` (`seal.run.state.Clock.timed`)."""
        return self.clock.timed(part, count)

    def notify(self, hook: str, *args: object) -> None:
        """Call every callback's `hook`, in the order they were given."""
        for callback in self.callbacks:
            getattr(callback, hook)(self, *args)

    def close_workers(self) -> None:
        """Close the training and evaluation instances and the worker processes (idempotent);
        after a signal a worker's request in flight is abandoned at once."""
        self.collection.close_collector()
        self.evaluation.close_collector()
        wait_s = 0.5 if self.stop.requested else 10.0
        self.evaluation.close_worker(wait_s)
        self.collection.close_actor(wait_s)

    def env_steps(self) -> int:
        """All env steps of the phase so far (demonstrations excluded)."""
        return sum(map(sum, self.state.env_steps.values()))

    def all_reached(self) -> bool:
        """evaluation.stop_when_reached is on and every task has reached the threshold."""
        reached = self.state.reached
        return self.cfg.evaluation.stop_when_reached and all(
            t in reached.get(e, {}) for e, ts in self.model.env_tasks.items() for t in ts
        )

    # ------------------------------------------------------------ what the callbacks read
    @property
    def evaluated(self) -> Evaluated | None:
        """The policy of the latest evaluation whose results are in (`write_best`, `on_evaluation`)."""
        return self.evaluation.evaluated

    @property
    def pending(self) -> list[PendingEvaluation]:
        """Evaluations handed to the worker whose rows are not written yet, oldest first."""
        return self.evaluation.pending

    @property
    def last_rows(self) -> list[MetricsRow]:
        """metrics.csv rows of the latest evaluation, one per (env, task)."""
        return self.evaluation.last_rows

    @property
    def last_critic_rows(self) -> list[TrainRow]:
        """The latest evaluation's critic-probe train rows (`seal.run.eval_rows.critic_rows`)."""
        return self.evaluation.last_critic_rows

    @property
    def checkpoint_replay(self) -> MultiTaskReplay:
        """What an epoch checkpoint saves of the replay (`Stopping.checkpoint_replay`)."""
        return self.stopping.checkpoint_replay

    @property
    def saved_epoch(self) -> int | None:
        """The epoch of this phase's newest epoch checkpoint on disk (None: none yet)."""
        return self.stopping.saved_epoch


def _progress_bar(phase: Phase, initial: int) -> tqdm:
    from tqdm import tqdm

    return tqdm(
        total=phase.epochs,
        initial=initial,
        desc=f"{phase.name}",
        unit="epoch",
        dynamic_ncols=True,
        file=sys.stderr,
    )


def _postfix(
    env_steps: int, grad_steps: int, dt: float, success: Mapping[str, Mapping[str, float]]
) -> str:
    parts = [f"env {env_steps / dt:,.0f}/s", f"upd {grad_steps / dt:,.0f}/s"]
    for env, per_task in success.items():
        if per_task:
            parts.append(f"{env} {np.mean(list(per_task.values())):.2f}")
    return " ".join(parts)
