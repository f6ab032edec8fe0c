"""One phase of a run: its counters and its loop.

The phase plan and how its agent meets the envs are `seal.protocols.phase_model`'s. `PhaseLoop` runs a phase's epochs in steps (plan, collect, train, evaluate, end of epoch,
checkpoint) over typed parts (agent, replay, scheduler, collector) and calls its
`LoopCallback`s: the progress bar, the TensorBoard and wandb loggers (`seal.protocols.loggers`),
a sweep's Ray Tune reporting and the `Checkpointer` (`seal.protocols.checkpointing`), which writes
the checkpoints the loop calls for. The `Run` that owns it (`seal.protocols.runner`) keeps the run
directory and registers the callbacks; the loop and its callbacks see it as a `PhaseOwner`, so
this module and the callbacks' need not import the runner.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import random
import sys
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, NoReturn, Protocol, cast

import numpy as np
import torch

from seal.device import torch_threads
from seal.envs.base import EnvAdapter
from seal.errors import SealError, TrainingDivergedError
from seal.evaluation import evaluate, mean_success, reaches
from seal.learner.sac import Agent
from seal.protocols.config import ProtocolConfig
from seal.protocols.evaluation_cost import decides_early, decision_rows, runs_all_episodes
from seal.protocols.phase_model import (
    ACTING_THREADS,
    Phase,
    PhaseModel,
    build_eval_collector,
)
from seal.protocols.preemption import Preempted, RollBack, SignalStop
from seal.protocols.rollback import EpochMark, ReplayMark, RolledBackReplay
from seal.protocols.workers import (
    ActorWorker,
    EvaluationWorker,
    PendingEvaluation,
    Results,
    cpu_copy,
)
from seal.seeding import derive_seed

if TYPE_CHECKING:
    from tqdm import tqdm

    from seal.envs.alignment import Alignment
    from seal.learner.collection import Collector, EpisodeStats
    from seal.learner.config import AgentConfig
    from seal.learner.drift import DriftStart
    from seal.learner.replay import MultiTaskReplay
    from seal.learner.sac import AgentState
    from seal.protocols.checkpoint_fields import EpochCheckpoint, PhaseStateFields
    from seal.protocols.rundir import MetricsRow, RunDir, TrainRow
    from seal.schedulers.base import Plan, Scheduler, ScoreRequest


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


# ---------------------------------------------------------------- one phase

LOOP_PARTS = ("collect", "update", "evaluate", "checkpoint", "log")
"""The parts of a phase loop's wall that `PhaseLoop.timed` counts; the rest of it is "other".

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
    """Wall seconds of each part of the loop (`LOOP_PARTS`; `PhaseLoop.timed`), "demos" (before
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


class LoopCallback:
    """Hooks a `PhaseLoop` calls, in the order the callbacks were given; subclasses override what they need.

    The runner registers the progress bar, the loggers (`seal.protocols.loggers`), its caller's
    callbacks (e.g. a sweep's Ray Tune reporter) and the `Checkpointer`
    (`seal.protocols.checkpointing`), which implements the two `write_*` hooks.
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


class PhaseOwner(Protocol):
    """What a `PhaseLoop` and its callbacks use of the run that owns them (`seal.protocols.runner.Run`)."""

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


class PhaseLoop:
    """One phase's epochs: plan, collect, update, evaluate, checkpoint, then the callbacks.

    Holds the phase's parts (agent, replay, scheduler, collector) and its counters (`state`,
    saved in every checkpoint); `run` (the `Run`) owns the run directory. The loop decides when a
    checkpoint is due (a new best evaluation; every `checkpoint.interval` epochs and the phase's
    last) and its callbacks write it (`LoopCallback.write_best`, `write_checkpoint`).
    """

    def __init__(
        self,
        run: PhaseOwner,
        phase: Phase,
        payload: EpochCheckpoint | None,
        callbacks: Sequence[LoopCallback] = (),
        stop: SignalStop | None = None,
    ) -> None:
        from seal.schedulers.ratio import UniformConfig

        cfg = self.cfg = run.config
        self.owner, self.phase = run, phase
        self.stop = stop if stop is not None else SignalStop()
        """The run's SIGTERM and SIGINT handling (`seal.protocols.preemption`)."""
        self._clock: list[tuple[str, float]] = []
        """`timed`'s open parts, innermost last, each with the time its count resumed."""
        model = self.model = PhaseModel(cfg, phase, run.adapters, run.alignment)
        self.agent: Agent = run.initial_agent(phase, model, resuming=payload is not None)
        self.drift_start: DriftStart | None = None
        """logging.drift: W0, each env's pieces at the phase's start, after any mapped start
        (`seal.learner.drift`); a resumed phase takes its checkpoint's, as the start is not redone."""
        if cfg.logging.drift:
            self.drift_start = self._drift_start(payload)
        self.replay: MultiTaskReplay = cfg.replay.build(
            model.replay_specs,
            device=run.device,
            seed=derive_seed(run.seed, "replay", phase.index),
        )
        self.scheduler: Scheduler = (cfg.scheduler or UniformConfig()).build(
            model.env_tasks,
            seed=derive_seed(run.seed, "scheduler", phase.index),
            adapters={e: cfg.envs[e].adapter for e in phase.envs},
            episode_lengths={e: run.adapters[e].episode_length for e in phase.envs},
            source=cfg.path,
        )
        self.state = PhaseState(env_steps={e: [0] * len(t) for e, t in model.env_tasks.items()})
        if payload is not None:
            self._restore(payload)
        self._collector: Collector | None = None
        self._backend: str | None = None
        self.actor: ActorWorker | None = None
        """training.overlap: the worker process that collects beside the updates (`run` starts it)."""
        self._actor_passes: list[tuple[bool, dict[str, np.ndarray]]] = []
        self.eval_collector: Collector | None = None
        """Evaluation's own env instances, several per task (built at the first evaluation)."""
        self.evaluator: EvaluationWorker | None = None
        """evaluation.mode = "async": the worker process that evaluates snapshots (`run` starts it)."""
        self.pending: list[PendingEvaluation] = (
            []
            if payload is None
            else [
                PendingEvaluation.from_fields(f)
                for f in payload["runner"].get("pending_evaluations", [])
            ]
        )
        """Evaluations handed to the worker whose rows are not written yet, oldest first."""
        self.evaluated: Evaluated | None = None
        """The policy of the latest evaluation whose results are in (`write_best`, `on_evaluation`)."""
        self._snapshot_agent: Agent | None = None
        from seal.schedulers.base import Scheduler as SchedulerBase

        # A scheduler that reads evaluations sees each one before its next plan, as it would
        # synchronously (asynchronous evaluation then waits for results before planning).
        self._reads_eval = type(self.scheduler).observe_eval is not SchedulerBase.observe_eval
        self.decide_early = decides_early(cfg, phase.name, self._reads_eval, quiet=run.quiet)
        """evaluation.decide_early applies to this phase (`seal.protocols.evaluation_cost`)."""
        if payload is None and any(cfg.demo_episodes(e) for e in model.env_tasks):
            with self.timed("demos"):
                self.state.demos = self._demonstrations()
            if cfg.training.overlap:
                self._close_collector()  # the actor has training instances of its own
        self.id_maps = {
            model.agent_env[e]: torch.as_tensor(model.aligned_ids(e), dtype=torch.long)
            for e in phase.envs
        }
        self.total_tasks = sum(len(t) for t in model.env_tasks.values())
        self.train_policy = model.policy(self.agent, deterministic=False)
        self.eval_policy = model.policy(self.agent, deterministic=True)
        self.started = time.monotonic() - self.state.wall_s
        self.batch_now: dict[str, np.ndarray] = {}
        """The per-task batch of the latest update (metrics.csv's `batch`)."""
        self.last_rows: list[MetricsRow] = []
        self.last_critic_rows: list[TrainRow] = []
        """The latest evaluation's critic-probe train rows (`critic_rows`)."""
        """metrics.csv rows of the latest evaluation, one per (env, task)."""
        self.pending_logs: dict[tuple[str, ...], torch.Tensor] = {}
        """Sums on the device of the agent's log values (by name tuple) since `_read_logs`."""
        self.pending_since = self.agent.num_updates
        self.callbacks = tuple(callbacks)
        self.saved_epoch: int | None = None if payload is None else self.state.epoch
        """The epoch of this phase's newest epoch checkpoint on disk (None: none yet)."""
        self._mark: EpochMark | None = None
        self._rolled_back: RolledBackReplay | None = None

    @property
    def collector(self) -> Collector:
        """The phase's training instances, built when first used after each checkpoint."""
        if self._collector is None:
            self._collector = self._new_collector(self.state.anchor_epoch, self._backend)
        return self._collector

    @property
    def checkpoint_replay(self) -> MultiTaskReplay:
        """What an epoch checkpoint saves of the replay: the replay, or after a rollback its
        state at the epoch's start (a `RolledBackReplay`, which has the one method a save calls)."""
        return cast("MultiTaskReplay", self._rolled_back or self.replay)

    def _close_collector(self) -> None:
        if self._collector is not None:
            self._backend = self._collector.backend_name
            self._collector.close()
            self._collector = None

    def _new_collector(self, anchor: int, backend: str | None = None) -> Collector:
        """The phase's env instances, seeded from (seed, phase, epoch of the last checkpoint).

        Evaluation runs on instances of its own (`_eval_collector`), built once per phase.
        """
        seed = derive_seed(self.owner.seed, "envs", self.phase.index, anchor)
        return self.cfg.training.build_collector(self.model.adapters, seed, backend=backend)

    def _eval_collector(self) -> Collector:
        """Evaluation's instances (`build_eval_collector`), built at the first evaluation."""
        if self.eval_collector is None:
            self.eval_collector = build_eval_collector(self.cfg, self.model, self.owner.seed)
        return self.eval_collector

    def _drift_start(self, payload: EpochCheckpoint | None) -> DriftStart:
        """W0 of the fresh phase's agent (before any restore), or the checkpoint's, on the agent's device."""
        from seal.learner.drift import start_weights

        if payload is None:
            return start_weights(self.agent, self.model.agent_env)
        saved = payload["runner"].get("drift_start")
        if saved is None:
            raise SealError(
                f"{self.owner.rundir.path}: logging.drift is on, but the checkpoint holds no drift start (W0) to measure from; it was written without logging.drift"
            )
        device = self.agent.device
        return {env: {p: t.to(device) for p, t in pieces.items()} for env, pieces in saved.items()}

    def _restore(self, payload: EpochCheckpoint) -> None:
        """Agent, replay, scheduler, counters and RNG streams from a checkpoint's payload."""
        self.agent.load_state_dict(payload["agent"])
        replay = payload.get("replay")
        if replay is None:
            raise SealError(
                f"{self.owner.rundir.path}: the checkpoint holds no replay (checkpoint.save_replay = false), so the run cannot resume exactly"
            )
        self.replay.load_state_dict(replay)
        self.scheduler.load_state_dict(payload["scheduler"])
        self.state = PhaseState(**payload["runner"]["state"])
        torch.set_rng_state(payload["runner"]["torch_rng"])
        random.setstate(_tuple_state(payload["runner"]["py_rng"]))

    def env_steps(self) -> int:
        """All env steps of the phase so far (demonstrations excluded)."""
        return sum(map(sum, self.state.env_steps.values()))

    def all_reached(self) -> bool:
        """evaluation.stop_when_reached is on and every task has reached the threshold."""
        reached = self.state.reached
        return self.cfg.evaluation.stop_when_reached and all(
            t in reached.get(e, {}) for e, ts in self.model.env_tasks.items() for t in ts
        )

    @contextlib.contextmanager
    def timed(self, part: str, count: bool = True) -> Iterator[None]:
        """Count the block's wall seconds to `part` in `state.seconds` (`count`: and one run in
        `state.calls`).

        A part timed within another counts to itself alone (the rows an evaluation writes are
        "log", not "evaluate"), so the parts never overlap and the loop's other = its wall -
        their sum (`LOOP_PARTS`).
        """
        clock, now = self._clock, time.perf_counter()
        if clock:
            outer, since = clock[-1]
            self.state.add_time(outer, now - since)
        clock.append((part, now))
        try:
            yield
        finally:
            _, since = clock.pop()
            now = time.perf_counter()
            self.state.add_time(part, now - since, calls=int(count))
            if clock:
                clock[-1] = (clock[-1][0], now)

    def run(self) -> PhaseState:
        """Run the phase's remaining epochs; its counters.

        A signal (`seal.protocols.preemption`) stops the loop at a safe point with the checkpoint
        of the last finished epoch and raises `Preempted`; after the phase's last epoch it only
        notes what was saved (`SignalStop.note`) and returns, and the run stops.
        """
        for callback in self.callbacks:
            callback.on_phase_start(self)
        try:
            if self.cfg.evaluation.mode == "async" or self.pending:
                with self.timed("evaluate", count=False):
                    self.evaluator = EvaluationWorker(
                        self.cfg, self.phase, self.owner.seed, self.owner.device
                    )
                    # A resumed run re-runs the evaluations its checkpoint left pending.
                    for pending in self.pending:
                        self.evaluator.submit(pending.draw, pending.agent, pending.decide)
            if self.cfg.training.overlap:
                with self.timed("collect", count=False):
                    self.actor = ActorWorker(
                        self.cfg, self.phase, self.owner.seed, self.owner.device
                    )
            while self.state.epoch < self.phase.epochs and not self.all_reached():
                if self.stop.requested:  # came between epochs: stop after the last one
                    self._stop(f"{self.stop.name} after epoch {self.state.epoch}")
                self._mark = self._take_mark() if self.stop.active else None
                try:
                    with self.stop.epoch():
                        last_epoch = self._epoch()
                except RollBack:
                    self._roll_back()
                self._close_epoch(last_epoch)
                with self.timed("log", count=False):
                    for callback in self.callbacks:
                        callback.on_epoch_end(self)
                if last_epoch:
                    break
            # The loop's wall (`LOOP_PARTS` and other); closing its workers is start-up's.
            self.state.wall_s = time.monotonic() - self.started
            if self.stop.requested and not self.stop.note:
                how = f"{self.stop.name} after epoch {self.state.epoch}, the phase's last"
                self.stop.note = f"{how}; {self._save_for_stop()}"
        finally:
            self._close_workers()
            for callback in self.callbacks:
                callback.on_phase_end(self)
        return self.state

    def _epoch(self) -> bool:
        """One epoch's work, up to its checkpoint: plan, collect, train, then `_end_epoch`;
        whether the phase ends with it."""
        plan = self._plan()
        if plan.reset_agent:
            self.agent.reset_parameters()
        if self.actor is None:
            self._train(plan, self._collect(plan))
        else:
            # Actor-learner: this epoch's episodes are collected with the policy as it
            # is now while the updates train on the replay up to the last epoch's.
            self._start_collection(plan)
            self._train(plan, self.state.collected_lengths)
            self.state.collected_lengths = self._finish_collection()
        return self._end_epoch()

    def _close_workers(self) -> None:
        """Close the training and evaluation instances and the worker processes (idempotent);
        after a signal a worker's request in flight is abandoned at once."""
        self._close_collector()
        if self.eval_collector is not None:
            self.eval_collector.close()
            self.eval_collector = None
        wait_s = 0.5 if self.stop.requested else 10.0
        for worker in (self.evaluator, self.actor):
            if worker is not None:
                worker.close(timeout_s=wait_s)
        self.evaluator = self.actor = None

    # ------------------------------------------------------------ stopping on a signal
    def _take_mark(self) -> EpochMark:
        """What a rollback of the coming epoch restores (the counters, agent, scheduler, RNG
        states, CSV rows and the replay's counters and overwritable slots)."""
        state = self.state.fields()  # dataclasses.asdict: a deep copy
        state["wall_s"] = time.monotonic() - self.started
        steps = {self.model.agent_env[e]: a.episode_length for e, a in self.model.adapters.items()}
        return EpochMark(
            state=state,
            agent=_copy_on_one_thread(self.agent.state_dict()),
            scheduler=copy.deepcopy(self.scheduler.state_dict()),
            pending=list(self.pending),
            rows=self.owner.rundir.row_counts(),
            torch_rng=torch.get_rng_state(),
            py_rng=random.getstate(),
            replay=ReplayMark.take(self.replay, steps),
        )

    def _roll_back(self) -> NoReturn:
        """Abandon the epoch under way: its workers' requests, its rows; restore its start and save it."""
        mark = self._mark
        assert mark is not None  # the handler rolls back only while the loop keeps marks
        self._close_workers()
        for env, adapter in self.model.adapters.items():
            added = np.subtract(self.state.env_steps[env], mark.state["env_steps"][env])
            if int(added.max(initial=0)) > adapter.episode_length:
                raise SealError(
                    f"{self.owner.rundir.path}: cannot roll back epoch {mark.state['epoch'] + 1}: "
                    f"{env} added {int(added.max())} transitions to one task, more than its episode"
                )
        self.agent.load_state_dict(mark.agent)
        self.scheduler.load_state_dict(mark.scheduler)
        self.state, self.pending = PhaseState(**mark.state), list(mark.pending)
        torch.set_rng_state(mark.torch_rng)
        random.setstate(mark.py_rng)
        self.owner.rundir.truncate_to(mark.rows)
        self._rolled_back = RolledBackReplay(self.replay, mark.replay)
        self._stop(
            f"{self.stop.name} during epoch {mark.state['epoch'] + 1}: rolled back to its start "
            f"({self.stop.rollback_reason})",
            wall_s=mark.state["wall_s"],
        )

    def _stop(self, how: str, wall_s: float | None = None) -> NoReturn:
        """Save the last finished epoch unless it is on disk, then raise `Preempted`."""
        assert self.stop.signum is not None
        self.stop.note = f"{how}; {self._save_for_stop(wall_s)}"
        raise Preempted(self.stop.signum, self.stop.note, resumable=self.cfg.checkpoint.save_replay)

    def _save_for_stop(self, wall_s: float | None = None) -> str:
        """The checkpoint of the last finished epoch, written unless it is on disk; what it is."""
        state, rundir = self.state, self.owner.rundir
        where = f"epoch {state.epoch}"
        if len(self.owner.phases) > 1:
            where += f" of phase {self.phase.name}"
        if state.epoch == 0:
            latest = rundir.latest_checkpoint()
            if latest is None:
                return "no epoch had finished: nothing saved, the run starts over when resumed"
            return (
                f"no epoch of phase {self.phase.name} had finished: nothing new saved; "
                f"the newest checkpoint is {latest}"
            )
        if self.saved_epoch == state.epoch:
            text = f"{where}'s checkpoint {rundir.latest_checkpoint()} is on disk"
        else:
            since = time.perf_counter()
            self._checkpoint(reseed=False, wall_s=wall_s)
            seconds = time.perf_counter() - since
            path = rundir.latest_checkpoint()
            assert path is not None
            text = f"saved {where} to {path} ({_size(path.stat().st_size)} in {seconds:.1f} s)"
        if not self.cfg.checkpoint.save_replay:
            text += (
                "; it holds no replay (checkpoint.save_replay = false), so --resume cannot "
                "continue the run exactly and refuses it; its agent serves seal eval and [transfer]"
            )
        return text

    def _plan(self) -> Plan:
        from seal.schedulers import Progress

        if self._reads_eval:
            self._finish_evaluations(wait=True)
        state = self.state
        task_steps = {
            (e, t): state.env_steps[e][i]
            for e, ts in self.model.env_tasks.items()
            for i, t in enumerate(ts)
        }
        return self.scheduler.plan(
            Progress(
                epoch=state.epoch,
                env_steps=sum(task_steps.values()),
                grad_steps=state.grad_steps,
                task_env_steps=task_steps,
            )
        )

    def _collect(self, plan: Plan) -> dict[str, int]:
        """One episode per planned task: warm-up envs act uniformly at random, the others with the policy.

        Returns env -> the longest episode it collected (envs that collected nothing are absent).
        """
        lengths: dict[str, int] = {}
        with self.timed("collect"):
            for random_actions, active in self._passes(plan):
                with torch_threads(ACTING_THREADS):
                    stats = self.collector.collect_episodes(
                        self.train_policy,  # random_actions: actions ignore it; its task encoder still reads the steps
                        active=active,
                        random_actions=random_actions,
                        sink=_ReplaySink(self.replay, self.model),
                    )
                self._observe_episodes(active, stats, lengths)
        return lengths

    def _passes(self, plan: Plan) -> list[tuple[bool, dict[str, np.ndarray]]]:
        """The epoch's collection calls: (random actions, env -> which tasks collect), warm-up first."""
        state, envs = self.state, self.phase.envs
        warm = {e: sum(state.env_steps[e]) < self.cfg.training.warmup_steps for e in envs}
        passes = []
        for random_actions in (True, False):
            active = {
                e: np.asarray(plan.collect[e], dtype=bool) & (warm[e] == random_actions)
                for e in envs
            }
            if any(m.any() for m in active.values()):
                passes.append((random_actions, active))
        return passes

    def _observe_episodes(
        self, active: Mapping[str, np.ndarray], stats: EpisodeStats, lengths: dict[str, int]
    ) -> None:
        """Count a collection call's env steps, tell the scheduler, and note each env's longest episode."""
        state, model = self.state, self.model
        for e in self.phase.envs:
            idx = np.flatnonzero(active[e])
            if not idx.size:
                continue
            for i in idx:
                state.env_steps[e][i] += int(stats.lengths[e][i])
            lengths[e] = int(stats.lengths[e][idx].max())
            self.scheduler.observe_episodes(
                e,
                [model.env_tasks[e][i] for i in idx],
                [float(stats.returns[e][i]) for i in idx],
                [float(stats.successes[e][i]) for i in idx],
                [int(stats.lengths[e][i]) for i in idx],
            )

    def _start_collection(self, plan: Plan) -> None:
        """training.overlap: hand the epoch's collection to the actor, with the policy as it is now."""
        assert self.actor is not None
        passes = self._passes(plan)
        self._actor_passes = passes
        acting = any(not random_actions for random_actions, _ in passes)
        self.actor.submit(
            [(r, {e: m.tolist() for e, m in active.items()}) for r, active in passes],
            anchor=self.state.anchor_epoch,
            act_seed=derive_seed(self.owner.seed, "act", self.phase.index, self.state.epoch),
            agent_state=cpu_copy(self.agent.state_dict()) if acting else None,
        )

    def _finish_collection(self) -> dict[str, int]:
        """training.overlap: wait for the actor's episodes, add them to the replay in order and
        count them; env -> the longest episode collected (the next epoch's updates train on them)."""
        assert self.actor is not None
        sink = _ReplaySink(self.replay, self.model)
        lengths: dict[str, int] = {}
        with self.timed("collect"):
            for (_, active), (steps, stats) in zip(
                self._actor_passes, self.actor.result(), strict=True
            ):
                for step in steps:
                    sink(*step)
                self._observe_episodes(active, stats, lengths)
        return lengths

    def _train(self, plan: Plan, lengths: Mapping[str, int]) -> None:
        """The epoch's gradient steps, once every env has finished its warm-up (evaluating every K steps)."""
        state, model, cfg = self.state, self.model, self.cfg
        self.batch_now = {e: np.zeros(len(model.env_tasks[e]), np.int64) for e in self.phase.envs}
        warm = any(sum(state.env_steps[e]) < cfg.training.warmup_steps for e in self.phase.envs)
        if warm or not lengths:
            return
        counts = plan.batch_counts(cfg.training.batch_per_task * self.total_tasks)
        sample_counts = {
            model.agent_env[e]: np.asarray(c, dtype=np.int64)
            for e, c in counts.items()
            if int(np.sum(c)) > 0
        }
        self.batch_now = {e: np.asarray(c, dtype=np.int64) for e, c in counts.items()}
        every = cfg.evaluation.every_grad_steps
        with self.timed("update", count=False):
            self.agent.refresh_beliefs(self.replay)  # smt_gru with encoder_refresh_interval
        with self.timed("update", count=False):  # a mid-epoch evaluation counts to itself
            steps = self._grad_steps(plan, lengths)
            last_epoch = state.epoch + 1 >= self.phase.epochs
            for step in range(steps):
                batches = self.replay.sample(sample_counts)
                if model.alignment is not None:
                    batches = {
                        k: b._replace(task_ids=self.id_maps[k].to(b.task_ids.device)[b.task_ids])
                        for k, b in batches.items()
                    }
                names, values = self.agent.update_on_device(batches)
                sums = self.pending_logs.get(names)
                self.pending_logs[names] = values if sums is None else sums + values
                encoder_logs = self.agent.update_encoder(self.replay)
                if encoder_logs is not None:  # smt_gru, every agent.encoder_interval updates
                    names, values = encoder_logs
                    sums = self.pending_logs.get(names)
                    self.pending_logs[names] = values if sums is None else sums + values
                state.grad_steps += 1
                state.log_updates += 1
                state.calls["update"] = state.calls.get("update", 0) + 1
                if self.agent.last_ratio_lever is not None:
                    lever = self.agent.last_ratio_lever
                    state.log_sums["charts/ratio_lever"] = (
                        state.log_sums.get("charts/ratio_lever", 0.0) + lever
                    )
                if every and state.grad_steps % every == 0:
                    # mid-epoch: the update-count grid is K x batch; on the phase's last update
                    # it is the phase's last evaluation (`_end_epoch` does not repeat it)
                    self._evaluate(final=last_epoch and step == steps - 1)
            self._read_logs()

    def _read_logs(self) -> None:
        """Fetch the updates' log sums from the device (one sync) into `state.log_sums`.

        Runs at the end of every epoch's updates and before every evaluation, so a diverged run
        stops before it evaluates or writes a checkpoint; the sync's wait counts as update time.
        """
        pending, self.pending_logs = self.pending_logs, {}
        first, self.pending_since = self.pending_since, self.agent.num_updates
        if not pending:
            return
        with self.timed("update", count=False):
            for names, sums in pending.items():
                try:
                    values = self.agent.read_logs(names, sums, first_update=first)
                except TrainingDivergedError as exc:
                    rundir = self.owner.rundir
                    raise SealError(
                        f"{rundir.path}: training diverged in phase {self.phase.name!r} by gradient step {self.state.grad_steps} ({exc}); last good checkpoint: {rundir.latest_checkpoint() or 'none yet'}"
                    ) from None
                for k, v in values.items():
                    self.state.log_sums[k] = self.state.log_sums.get(k, 0.0) + v

    def _demonstrations(self) -> dict[str, dict[str, float]]:
        """Put `demo_episodes` episodes per task of each env's scripted expert in the replay (`ProtocolConfig.demo_episodes`)."""
        model = self.model
        episodes = {e: self.cfg.demo_episodes(e) for e in model.env_tasks}
        experts = {
            e: [model.adapters[e].expert(t) for t in tasks]
            for e, tasks in model.env_tasks.items()
            if episodes[e]
        }

        class Experts:
            """The scripted experts; under smt_gru the agent's task encoder reads their steps
            (the replay stores its beliefs), and each expert gets its raw observation."""

            memory = model.policy(self.agent, deterministic=False).memory

            def __call__(self, env: str, obs: np.ndarray, task_ids: np.ndarray) -> np.ndarray:
                width = model.adapters[env].obs_dim
                return np.stack(
                    [experts[env][i](o[:width]) for o, i in zip(obs, task_ids, strict=True)]
                )

        act = Experts()

        steps = {e: 0 for e in experts}
        successes = {e: 0.0 for e in experts}
        sink = _ReplaySink(self.replay, model)
        for i in range(max(episodes.values())):
            # Only the envs with demonstrations left step: an env without any keeps its reset
            # sequence, so its warm-up matches a run of the same seed that has no demonstrations.
            active = {e: np.full(len(ts), i < episodes[e]) for e, ts in model.env_tasks.items()}
            stats = self.collector.collect_episodes(act, active=active, sink=sink)
            for e in experts:
                if i < episodes[e]:
                    steps[e] += int(stats.lengths[e].sum())
                    successes[e] += float(stats.successes[e].sum())
        figures = {
            e: {
                "episodes": episodes[e] * len(experts[e]),
                "env_steps": steps[e],
                "expert_success": successes[e] / (episodes[e] * len(experts[e])),
            }
            for e in experts
        }
        if not self.owner.quiet:
            for e, f in figures.items():
                print(
                    f"[seal] {e}: {f['episodes']} demonstration episodes, {f['env_steps']} env steps "
                    f"in the replay (expert success {f['expert_success']:.2f})",
                    file=sys.stderr,
                )
        return figures

    def _grad_steps(self, plan: Plan, collected_lengths: Mapping[str, int]) -> int:
        from seal.schedulers import GRAD_STEPS_COLLECTED

        if plan.grad_steps is not None:
            if plan.grad_steps == GRAD_STEPS_COLLECTED:
                return int(sum(collected_lengths.values()))
            return int(plan.grad_steps)
        n = self.cfg.training.grad_steps_per_epoch
        # -1: the longest episode collected this epoch (see TrainingConfig.grad_steps_per_epoch).
        return int(max(collected_lengths.values())) if n == -1 else int(n)

    def _train_rows(
        self, epoch: int, grad_steps: int, values: Mapping[str, float]
    ) -> list[TrainRow]:
        """train.csv rows of the mean logged values (`train_rows_for` names them)."""
        return [
            {
                "seed": self.owner.seed,
                "phase": self.phase.name,
                "epoch": epoch,
                "grad_steps": grad_steps,
                "env": env,
                "key": name,
                "value": float(v),
            }
            for key, value in values.items()
            for env, name, v in train_rows_for(key, value, self.model)
        ]

    def _evaluate(self, final: bool = False) -> None:
        """Appendix B's evaluation: metrics.csv rows, first crossings, best.pt, then the callbacks.

        Synchronous (`evaluation.mode = "sync"`): here and now, training stopped. Asynchronous:
        a snapshot goes to the worker (`seal.protocols.workers`) and its results are recorded
        when they come back (`_finish_evaluations`); the loop waits only for the previous one.
        `final`: the phase's last epoch's evaluation, which runs in full (`evaluation.full_every`).
        """
        self._read_logs()
        state, agent, ev = self.state, self.agent, self.cfg.evaluation
        state.evaluated_at = state.grad_steps
        state.evaluations += 1
        decide = self.decide_early and not runs_all_episodes(
            state.evaluations, ev.full_every, final
        )
        if self.evaluator is None:
            with self.timed("evaluate"), torch_threads(ACTING_THREADS):
                results = evaluate(
                    self.eval_policy,
                    self.model.adapters,
                    episodes=ev.episodes,
                    seed=0,
                    collector=self._eval_collector(),
                    draw=state.grad_steps,  # one evaluation per grad-step count: its own episode seeds
                    probe=self.eval_policy.critic_probe(self.cfg.agent.gamma),
                    threshold=ev.threshold if decide else None,
                    end_on_success=ev.end_on_success,
                )
                self.evaluated = Evaluated(state.epoch, state.grad_steps, agent)
                self._record_evaluation(self._eval_rows(), results)
            self._on_evaluation()
            return
        self._finish_evaluations(wait=True)  # one in flight at most, so rows stay in order
        with self.timed("evaluate"):
            if not self.all_reached():  # a synchronous run would have stopped at that result
                pending = PendingEvaluation(
                    draw=state.grad_steps,
                    epoch=state.epoch,
                    grad_steps=state.grad_steps,
                    rows=self._eval_rows(),
                    agent=cpu_copy(agent.state_dict()),
                    decide=decide,
                )
                self.pending.append(pending)
                self.evaluator.submit(pending.draw, pending.agent, pending.decide)

    def _on_evaluation(self) -> None:
        """The callbacks' `on_evaluation` (the loggers: "log" time)."""
        with self.timed("log"), self.stop.protected():
            for callback in self.callbacks:
                callback.on_evaluation(self)

    def _finish_evaluations(self, wait: bool) -> None:
        """Record the asynchronous evaluations whose results are in (all of them with `wait`), oldest first."""
        evaluator = self.evaluator
        while self.pending and evaluator is not None and (wait or evaluator.done()):
            with self.timed("evaluate", count=False):  # the loop waiting on evaluation
                results = evaluator.result()
                self.state.add_time("evaluate_worker_cpu", evaluator.last_cpu_s)
                pending = self.pending.pop(0)
                self.evaluated = Evaluated(
                    pending.epoch, pending.grad_steps, lambda p=pending: self._load_snapshot(p)
                )
                self._record_evaluation(pending.rows, results)
            self._on_evaluation()

    def _load_snapshot(self, pending: PendingEvaluation) -> Agent:
        """An agent (one per phase, reused) holding an asynchronous evaluation's snapshot."""
        if self._snapshot_agent is None:
            config = dataclasses.replace(self.owner.agent_cfg, compile=False)
            self._snapshot_agent = Agent(self.model.specs, config, 0)
        self._snapshot_agent.load_state_dict(pending.agent)
        return self._snapshot_agent

    def _record_evaluation(self, rows: list[MetricsRow], results: Results) -> None:
        """Write an evaluation's rows and pass it on: first crossings, scheduler, best.pt."""
        state, model, phase = self.state, self.model, self.phase
        rows = self._fill_rows(rows, results)
        self.last_critic_rows = critic_rows(rows, results)
        with self.timed("log"), self.stop.protected():
            self.owner.rundir.log_eval(rows)
            self.owner.rundir.log_train([*self.last_critic_rows, *decision_rows(rows, results)])
        self.last_rows = rows
        state.last_success = {
            e: {t: results[e][t]["success"] for t in model.env_tasks[e]} for e in phase.envs
        }
        assert self.evaluated is not None
        self.scheduler.observe_eval(
            self.evaluated.epoch, {(r["env"], r["task"]): r["success"] for r in rows}
        )
        mean = mean_success(results)
        # A decided-early rate is over a task's first episodes (45/45 reads 1.0): best.pt is
        # chosen among the evaluations in which every task ran all its episodes.
        partial = any(r.get("decided_early") for per in results.values() for r in per.values())
        if mean > state.best_mean_success and not partial:
            state.best_mean_success = mean
            with self.stop.protected():
                for callback in self.callbacks:
                    callback.write_best(self)  # best.pt (the Checkpointer): evaluation time

    def _eval_rows(self) -> list[MetricsRow]:
        """metrics.csv rows of an evaluation of the agent as it is now, success and return to come."""
        state, model, batch = self.state, self.model, self.batch_now
        rows: list[MetricsRow] = []
        for env in self.phase.envs:
            consumed = np.asarray(self.replay.consumed[model.agent_env[env]], dtype=np.int64)
            for i, task in enumerate(model.env_tasks[env]):
                rows.append(
                    {
                        "seed": self.owner.seed,
                        "phase": self.phase.name,
                        "epoch": state.epoch,
                        "env": env,
                        "task": task,
                        "success": 0.0,
                        "return": 0.0,
                        "grad_steps": state.grad_steps,
                        "env_steps": state.env_steps[env][i],
                        "updates": float(consumed[i]) / 1e6,
                        "batch": int(batch[env][i]) if env in batch else 0,
                        "wall_s": 0.0,
                    }
                )
        return rows

    def _fill_rows(self, rows: list[MetricsRow], results: Results) -> list[MetricsRow]:
        """`rows` with an evaluation's results and the wall time now; records first crossings in `state.reached`."""
        state = self.state
        wall = round(time.monotonic() - self.started, 3)
        filled: list[MetricsRow] = []
        for row in rows:
            env, task = row["env"], row["task"]
            r = results[env][task]
            filled.append({**row, "success": r["success"], "return": r["return"], "wall_s": wall})
            first = task not in state.reached.get(env, {})
            if first and reaches(r["success"], self.cfg.evaluation.threshold):
                state.reached.setdefault(env, {})[task] = row["updates"]
        return filled

    def _scores(self, request: ScoreRequest, epoch: int) -> dict[tuple[str, str], float]:
        """SMT Eq. 5 scores: mean over episodes of sum_t gamma^t r_t - log pi(a_t|s_t) (stochastic policy).

        The entropy term needs `agent.log_prob(env, obs, actions, task_ids)`; an agent without it
        is scored by discounted return alone (said in the scheduler's docs).
        """
        from seal.learner.collection import Collector

        model, agent = self.model, self.agent
        keys = list(request.tasks)
        tasks = {e: [t for (e2, t) in keys if e2 == e] for e in model.env_tasks}
        tasks = {e: ts for e, ts in tasks.items() if ts}
        totals = {k: 0.0 for k in keys}
        policy = model.policy(agent, deterministic=False)
        log_prob = getattr(agent, "log_prob", None)
        with (
            torch_threads(ACTING_THREADS),
            Collector(
                {e: model.adapters[e] for e in tasks},
                seed=derive_seed(self.owner.seed, "score", model.phase.index, epoch),
                tasks=tasks,
                backend="sync",
            ) as col,
        ):
            for _ in range(request.episodes):
                t_of: dict[str, np.ndarray] = {}

                def sink(
                    env: str,
                    task_ids: np.ndarray,
                    obs: np.ndarray,
                    actions: np.ndarray,
                    rewards: np.ndarray,
                    next_obs: np.ndarray,
                    terminations: np.ndarray,
                    _t: dict[str, np.ndarray] = t_of,
                ) -> None:
                    names = model.adapters[env].tasks
                    steps = _t.setdefault(env, np.zeros(len(names), dtype=np.int64))
                    term = rewards * request.discount ** steps[task_ids]
                    if log_prob is not None:
                        name, agent_obs, ids = policy.agent_inputs(env, obs, task_ids)
                        term = term - np.asarray(
                            log_prob(name, agent_obs, actions, ids), dtype=np.float64
                        )
                    for j, tid in enumerate(task_ids):
                        totals[(env, names[tid])] += float(term[j]) / request.episodes
                    steps[task_ids] += 1

                col.collect_episodes(policy, sink=sink)
        return totals

    def _end_epoch(self) -> bool:
        """Training curves, evaluation and scheduler scores; whether the phase ends (then
        `_close_epoch` writes the timeline and the checkpoint)."""
        run, state, cfg, scheduler = self.owner, self.state, self.cfg, self.scheduler
        self._finish_evaluations(wait=False)
        state.epoch += 1
        epoch = state.epoch
        last_epoch = epoch >= self.phase.epochs or scheduler.done
        # Training curves: the mean of every logged value over the interval's updates.
        if state.log_updates and (epoch % cfg.logging.train_interval == 0 or last_epoch):
            means = {k: v / state.log_updates for k, v in state.log_sums.items()}
            rows = self._train_rows(epoch, state.grad_steps, means)
            with self.timed("log"), self.stop.protected():
                run.rundir.log_train(rows)
                for callback in self.callbacks:
                    callback.on_train_log(self, rows)
            state.log_sums, state.log_updates = {}, 0
        # Evaluation (Appendix B): every `interval` epochs, or every K gradient steps (in _train).
        every = cfg.evaluation.every_grad_steps
        due = not every and epoch % cfg.evaluation.interval == 0
        if due or (last_epoch and not (every and state.evaluated_at == state.grad_steps)):
            self._evaluate(final=last_epoch)
        request = scheduler.wants_scores()
        if request is not None:
            with self.timed("collect", count=False):  # SMT's scoring episodes
                scheduler.observe_scores(self._scores(request, epoch))
        if last_epoch or self.all_reached():
            self._finish_evaluations(wait=True)  # the phase's results are complete at its end
        last_epoch = last_epoch or self.all_reached()
        self.stop.epoch_done()  # finished: a signal from here on stops after it, never rolls it back
        return last_epoch

    def _close_epoch(self, last_epoch: bool) -> None:
        """The epoch's scheduler timeline and its checkpoint, when one is due or a signal came.

        A signal during the epoch's work that let it finish (`seal.protocols.preemption`)
        stops the loop here, after the epoch's checkpoint.
        """
        run, state, scheduler = self.owner, self.state, self.scheduler
        timeline = scheduler.timeline()
        if len(timeline) > state.timeline_rows:
            with self.timed("log", count=False):
                run.rundir.log_scheduler(
                    [{"phase": self.phase.name, **r} for r in timeline[state.timeline_rows :]]
                )
            state.timeline_rows = len(timeline)
        if self.stop.requested:
            budget = self.cfg.checkpoint.signal_budget_s
            how = (
                f"{self.stop.name} during epoch {state.epoch}: finished it "
                f"{self.stop.time_since_signal():.1f} s after the signal "
                f"(checkpoint.signal_budget_s = {budget:g})"
                if self.stop.during_epoch
                else f"{self.stop.name} after epoch {state.epoch}"
            )
            if not last_epoch:
                self._stop(how)
            self.stop.note = f"{how}; it was the phase's last; {self._save_for_stop()}"
        elif state.epoch % self.cfg.checkpoint.interval == 0 or last_epoch:
            self._checkpoint(reseed=not last_epoch)

    def _checkpoint(self, reseed: bool, wall_s: float | None = None) -> None:
        """An epoch checkpoint: `on_checkpoint` (loggers flush), then `write_checkpoint` (the Checkpointer).

        `wall_s`: the run's wall time to record (default: now); a rollback records its epoch start's.
        """
        state = self.state
        state.wall_s = time.monotonic() - self.started if wall_s is None else wall_s
        state.anchor_epoch = state.epoch
        # A signal now lets the write finish; a second one kills at once.
        with self.timed("checkpoint"), self.stop.saving():
            with self.timed("log", count=False):
                for callback in self.callbacks:
                    callback.on_checkpoint(self)
            for callback in self.callbacks:
                callback.write_checkpoint(self)
        self.saved_epoch = state.epoch
        if reseed:
            # Re-seed env streams at every checkpoint so a resumed run repeats this run exactly:
            # the instances are rebuilt from the new anchor epoch when next used (by the actor,
            # training.overlap, from the anchor it is sent). The rebuild keeps the backend "auto"
            # resolved to (no second probe of step costs); results never depend on the backend.
            with self.timed("collect", count=False):
                self._close_collector()


def _copy_on_one_thread(state: AgentState) -> AgentState:
    """`cpu_copy(state)` on one torch thread: the copy is memory-bound, and a second thread on a
    busy machine only makes it wait (docs/faults.md has the figures)."""
    with torch_threads(1):
        return cpu_copy(state)


def _size(nbytes: int) -> str:
    """A file size for a message: "0.82 GB", "3.1 MB"."""
    return f"{nbytes / 1e9:.2f} GB" if nbytes >= 1e8 else f"{nbytes / 1e6:.1f} MB"


def _tuple_state(state: Any) -> Any:
    """random.getstate() after a round trip through torch.save (lists back to tuples)."""
    if isinstance(state, list):
        return tuple(_tuple_state(s) for s in state)
    return state


# The agent's log keys ("losses/<env>/critic", "charts/<env>/alpha/<id>") -> train.csv keys.
_TRAIN_KEYS = {
    "losses/critic": "critic_loss",
    "losses/actor": "actor_loss",
    "losses/qf1": "qf1_loss",
    "losses/qf2": "qf2_loss",
    "losses/alpha": "alpha_loss",
    "charts/mean_q": "mean_q",
    "charts/entropy": "entropy",
}


def critic_rows(rows: Sequence[MetricsRow], results: Results) -> list[TrainRow]:
    """train.csv rows of an evaluation's critic probe (`seal.learner.critic_probe`), per task:
    `eval_q/<task>` (the critic's mean Q at the episodes' first states), `eval_earned/<task>` (what
    they earned, bootstrapped past the time limit) and `eval_q_ratio/<task>` (their ratio, left out
    where the episodes earned nothing positive)."""
    from seal.learner.critic_probe import overestimation

    out: list[TrainRow] = []
    for row in rows:
        r = results[row["env"]][row["task"]]
        if "q_start" not in r:
            continue
        ratio = overestimation(r["q_start"], r["earned"])
        values = {"eval_q": r["q_start"], "eval_earned": r["earned"], "eval_q_ratio": ratio}
        out += [
            {
                "seed": row["seed"],
                "phase": row["phase"],
                "epoch": row["epoch"],
                "grad_steps": row["grad_steps"],
                "env": row["env"],
                "key": f"{key}/{row['task']}",
                "value": float(value),
            }
            for key, value in values.items()
            if np.isfinite(value)
        ]
    return out


def train_rows_for(key: str, value: float, model: PhaseModel) -> list[tuple[str, str, float]]:
    """(env, train.csv key, value) rows for one of the agent's log values.

    "losses/<agent env>/critic" becomes (env, "critic_loss"); "charts/<agent env>/alpha/<id>"
    becomes one "alpha/<task>" row for every task of env whose head id is <id> (under
    pad-and-fine-tune several kitchen tasks share an aligned id, so they share a temperature).
    """
    parts = key.split("/")
    if len(parts) < 3 or parts[1] not in model.env_of_agent:
        return [("", key, value)]
    env = model.env_of_agent[parts[1]]
    if len(parts) == 4 and parts[2] == "alpha" and parts[3].isdigit():
        ids = model.aligned_ids(env)
        return [
            (env, f"alpha/{task}", value)
            for task, i in zip(model.env_tasks[env], ids, strict=True)
            if int(i) == int(parts[3])
        ]
    short = f"{parts[0]}/{'/'.join(parts[2:])}"
    return [(env, _TRAIN_KEYS.get(short, "/".join(parts[2:])), value)]


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


class _ReplaySink:
    """Feeds collector transitions to the replay, aligning observations for pad-and-fine-tune."""

    def __init__(self, replay: MultiTaskReplay, model: PhaseModel) -> None:
        self.replay = replay
        self.model = model

    def __call__(
        self,
        env: str,
        task_ids: np.ndarray,
        obs: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        next_obs: np.ndarray,
        terminations: np.ndarray,
    ) -> None:
        model = self.model
        if model.alignment is not None:
            name = model.adapters[env].name
            obs = model.alignment.transform_obs(name, obs, task_ids)
            next_obs = model.alignment.transform_obs(name, next_obs, task_ids)
        self.replay.add(
            model.agent_env[env], task_ids, obs, actions, rewards, next_obs, terminations
        )
