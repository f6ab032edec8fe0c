"""Worker processes beside the training loop: asynchronous evaluation and overlapped collection.

Both are spawned per phase (`PolicyWorker`): each builds its own adapters, agent and env
instances, so nothing of the training process's torch or CUDA state is inherited, answers one
request at a time in order, and dies with the process that started it.

Evaluation off the critical path (`evaluation.mode = "async"`, `EvaluationWorker`). At each evaluation the loop (`seal.run.loop.PhaseLoop`) takes a snapshot of the agent (its
whole `state_dict`, copied to the CPU) and the metrics rows as they stand then (epoch, gradient
steps, env steps, consumed updates, batch: `PendingEvaluation`), hands the snapshot to the
`EvaluationWorker` and goes on training. The worker evaluates it as a synchronous evaluation
would: the same deterministic policy on the same device and thread count, the same evaluation
instances (`phase_model.build_eval_collector`, seeded from (seed, phase)) and the same episode seeds
(the draw is the snapshot's gradient-step count), so its numbers are those of a synchronous
evaluation of the same snapshot. The loop writes the rows, in the order the snapshots were
taken, when the results come back; best.pt is the snapshot's agent.

At most one evaluation is in flight: a second waits for the first. An epoch checkpoint holds the
evaluations still pending (`PendingEvaluation.fields`) and its CSV row counts exclude their rows,
so a run killed during an evaluation re-runs it on resume and loses nothing.

A SIGTERM or SIGINT sent to the whole process group (a terminal's Ctrl-C, Slurm) is ignored by
the workers: the run decides (`seal.run.preemption`) and closes them, abandoning a request
in flight; they die with the run if it is killed.

Collection beside the updates (`training.overlap`, `ActorWorker`): while the loop runs epoch k's
gradient steps, the worker collects epoch k's episodes with the policy the agent had before them
(the policy after epoch k - 1's updates) on the training instances, which it builds from the same
seeds as the loop would (seed, phase, epoch of the last checkpoint). Its stochastic actions draw
from a generator seeded by (seed, phase, epoch), so what it collects does not depend on timing,
and the loop adds the transitions to the replay after the updates, in the order they were made.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import multiprocessing as mp
import os
import time
import traceback
import warnings
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import TYPE_CHECKING, Any, Generic, NotRequired, TypedDict, TypeVar, cast

import numpy as np
import torch

from seal.errors import SealError, SealWarning
from seal.learner.agent_state import AgentState
from seal.learner.env_backends import exit_with_parent
from seal.learner.sac import Agent
from seal.run.phase_model import (
    ACTING_THREADS,
    Phase,
    PhaseModel,
    build_adapters,
    build_alignment,
    build_eval_collector,
    run_agent_config,
)
from seal.run.preemption import ignore_signals
from seal.seeding import derive_seed

if TYPE_CHECKING:
    from seal.learner.collection import Collector, EpisodeStats
    from seal.protocols.config import ProtocolConfig
    from seal.run.rundir import MetricsRow

Results = dict[str, dict[str, dict[str, float]]]
"""`seal.evaluation.evaluate`'s result: {env: {task: {"success", "return"}}}."""


T = TypeVar("T")


def cpu_copy(obj: T) -> T:
    """A copy of a (nested) state dict whose tensors are detached copies on the CPU."""
    if isinstance(obj, torch.Tensor):
        return cast("T", obj.detach().to("cpu", copy=True))
    if isinstance(obj, dict):
        return cast("T", {k: cpu_copy(v) for k, v in obj.items()})
    if isinstance(obj, list | tuple):
        return cast("T", type(obj)(cpu_copy(v) for v in obj))
    return obj


class PendingFields(TypedDict):
    """`PendingEvaluation.fields`: what an epoch checkpoint stores of an evaluation still pending."""

    draw: int
    epoch: int
    grad_steps: int
    rows: list[MetricsRow]
    agent: AgentState
    decide: NotRequired[bool]


@dataclass
class PendingEvaluation:
    """An evaluation handed to the worker whose results have not been written yet."""

    draw: int
    """Its episode set: the gradient steps at the snapshot, as a synchronous evaluation's."""
    epoch: int
    grad_steps: int
    rows: list[MetricsRow]
    """metrics.csv rows as they stood at the snapshot; success and return are filled in later."""
    agent: AgentState
    """The agent's `state_dict` at the snapshot, on the CPU."""
    decide: bool = False
    """Whether a task may stop once its verdict is settled (`evaluation.decide_early`)."""

    def fields(self) -> PendingFields:
        """What an epoch checkpoint stores of it (tensors and plain values only)."""
        return cast("PendingFields", dataclasses.asdict(self))

    @classmethod
    def from_fields(cls, fields: PendingFields) -> PendingEvaluation:
        """The pending evaluation a checkpoint stored (`fields`)."""
        return cls(
            draw=int(fields["draw"]),
            epoch=int(fields["epoch"]),
            grad_steps=int(fields["grad_steps"]),
            rows=[dict(r) for r in fields["rows"]],  # type: ignore[misc]
            agent=cast("AgentState", dict(fields["agent"])),
            # A checkpoint written before the key was kept had no early decisions.
            decide=bool(fields.get("decide", False)),
        )


Answer = TypeVar("Answer")


class PolicyWorker(Generic[Answer]):
    """A spawned process that answers one phase's requests, one after another (module docstring);
    `result` returns its answers (`Answer`: the subclass's)."""

    role = ""

    def __init__(self, config: ProtocolConfig, phase: Phase, seed: int, device: str) -> None:
        ctx = mp.get_context("spawn")
        self._conn, child = ctx.Pipe()
        # Not a daemon: its env instances may run worker processes of their own.
        self._process = ctx.Process(
            target=_worker_main,
            args=(child, self.role, config, phase, seed, device, os.getpid()),
            name=f"seal-{self.role}-{phase.name}",
        )
        self._process.start()
        child.close()
        self._ready = False
        self.in_flight = 0
        self.last_cpu_s = 0.0
        """CPU seconds the worker (and its env processes) spent on the last answer `result` returned."""

    def _submit(self, request: EvaluationRequest | CollectionRequest) -> None:
        buffer = io.BytesIO()
        torch.save(dict(request), buffer)  # tensors and plain values: read back weights_only
        self._conn.send(("request", buffer.getvalue()))
        self.in_flight += 1

    def done(self) -> bool:
        """Whether the oldest request's answer is waiting (never blocks)."""
        while self.in_flight and self._conn.poll(0):
            if self._ready:
                return True
            self._receive()  # the start-up message
        return False

    def result(self) -> Answer:
        """The oldest request's answer, waiting for it."""
        if not self.in_flight:
            raise RuntimeError("no request in flight")
        while True:
            kind, answer = self._receive()
            if kind == "ok":
                self.in_flight -= 1
                answer, self.last_cpu_s = answer
                return cast("Answer", answer)

    def _receive(self) -> tuple[str, Any]:  # Any: whatever the pipe unpickles
        try:
            kind, answer = self._conn.recv()
        except (EOFError, OSError):
            raise SealError(
                f"the {self.role} worker (pid {self._process.pid}) ended unexpectedly (exit code {self._process.exitcode})"
            ) from None
        if kind == "error":
            raise SealError(f"the {self.role} worker failed:\n{answer}")
        if kind == "ready":
            self._ready = True
        return kind, answer

    def close(self, timeout_s: float = 10.0) -> None:
        """Stop the worker, killing it after `timeout_s` (a request in flight is abandoned)."""
        with contextlib.suppress(OSError, ValueError):
            self._conn.send(("close", b""))
        self._process.join(timeout=timeout_s)
        if self._process.is_alive():
            self._process.kill()
            self._process.join()
        self._conn.close()


class EvaluationRequest(TypedDict):
    """What the evaluation worker is sent: the episode set and the snapshot to evaluate."""

    draw: int
    agent: AgentState
    decide: bool


class EvaluationWorker(PolicyWorker[Results]):
    """Evaluates agent snapshots (`evaluation.mode = "async"`)."""

    role = "evaluation"

    def submit(self, draw: int, agent_state: AgentState, decide: bool = False) -> None:
        """Evaluate `agent_state` with the episodes of `draw` (`decide`: stopping each task once
        its verdict is settled); `result` returns `Results`, in order."""
        self._submit({"draw": draw, "agent": agent_state, "decide": decide})


Pass = tuple[bool, dict[str, list[bool]]]
"""One `Collector.collect_episodes` call: (random actions, env -> which tasks collect)."""
Transition = tuple[str, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
"""One step of one env's running instances, as a `TransitionSink` receives it."""
Collected = tuple[list[Transition], "EpisodeStats"]
"""One pass's transitions, in the order they were made, and its episode statistics."""


class CollectionRequest(TypedDict):
    """What the actor is sent: the passes to collect, the instances' and the noise's seeds, the policy."""

    passes: list[Pass]
    anchor: int
    act_seed: int
    agent: AgentState | None


class ActorWorker(PolicyWorker[list[Collected]]):
    """Collects epochs' episodes beside the updates (`training.overlap`)."""

    role = "collection"

    def submit(
        self,
        passes: list[Pass],
        anchor: int,
        act_seed: int,
        agent_state: AgentState | None,
    ) -> None:
        """Collect `passes` on the instances seeded from checkpoint epoch `anchor`, acting with
        `agent_state` (None: every pass acts at random) and noise from `act_seed`; `result` returns
        one (transitions, `EpisodeStats`) per pass."""
        self._submit(
            {"passes": passes, "anchor": anchor, "act_seed": act_seed, "agent": agent_state}
        )


def _cpu_seconds() -> float:
    """CPU seconds of this process and of its live child processes (a collector's env workers;
    read from /proc, so on Linux only)."""
    total = time.process_time()
    tick = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
    for child in mp.active_children():
        with contextlib.suppress(OSError, ValueError, IndexError):
            with open(f"/proc/{child.pid}/stat") as f:
                fields = f.read().rpartition(")")[2].split()
            total += (int(fields[11]) + int(fields[12])) / tick  # utime, stime
    return total


def _worker_main(
    conn: Connection,
    role: str,
    config: ProtocolConfig,
    phase: Phase,
    seed: int,
    device: str,
    parent: int,
) -> None:
    """The worker: build the phase's side of `role`, then answer ("request", payload) messages."""
    exit_with_parent(parent)
    ignore_signals()  # a SIGTERM or Ctrl-C reaches the run, which closes its workers

    try:
        torch.set_num_threads(ACTING_THREADS)
        # The run's own process has already said what its adapters warn of, once.
        warnings.simplefilter("ignore", SealWarning)
        adapters = build_adapters(config)
        alignment = build_alignment(config, adapters) if config.kind == "finetune" else None
        model = PhaseModel(config, phase, adapters, alignment)
        # Acting never runs compiled code, so the worker's agent skips compiling its updates.
        agent_config = dataclasses.replace(run_agent_config(config, device), compile=False)
        agent = Agent(model.specs, agent_config, 0)
        handler = (_Evaluation if role == "evaluation" else _Collection)(config, model, agent, seed)
    except BaseException:  # noqa: BLE001 - reported to the loop, which raises it
        conn.send(("error", traceback.format_exc()))
        return
    conn.send(("ready", None))
    try:
        while True:
            try:
                kind, payload = conn.recv()
            except EOFError:
                return
            if kind == "close":
                return
            try:
                request = torch.load(io.BytesIO(payload), weights_only=True)
                since = _cpu_seconds()
                answer = handler(request)
                conn.send(("ok", (answer, _cpu_seconds() - since)))
            except BaseException:  # noqa: BLE001
                conn.send(("error", traceback.format_exc()))
    finally:
        handler.close()


class _Evaluation:
    """The evaluation worker's side: the phase's evaluation instances and a deterministic policy."""

    def __init__(self, config: ProtocolConfig, model: PhaseModel, agent: Agent, seed: int) -> None:
        self.config, self.model, self.agent = config, model, agent
        self.policy = model.policy(agent, deterministic=True)
        self.collector = build_eval_collector(config, model, seed)

    def __call__(self, request: EvaluationRequest) -> Results:
        from seal.evaluation import evaluate

        self.agent.load_state_dict(request["agent"])
        ev = self.config.evaluation
        return evaluate(
            self.policy,
            self.model.adapters,
            episodes=ev.episodes,
            seed=0,
            collector=self.collector,
            draw=int(request["draw"]),
            probe=self.policy.critic_probe(self.config.agent.gamma),
            threshold=ev.threshold if request["decide"] else None,
            end_on_success=ev.end_on_success,
        )

    def close(self) -> None:
        self.collector.close()


class _Collection:
    """The actor's side: the phase's training instances (rebuilt at each new checkpoint epoch)
    and the stochastic policy."""

    def __init__(self, config: ProtocolConfig, model: PhaseModel, agent: Agent, seed: int) -> None:
        self.config, self.model, self.agent, self.seed = config, model, agent, seed
        self.policy = model.policy(agent, deterministic=False)
        self.collector: Collector | None = None
        self.anchor = -1
        self.backend: str | None = None

    def __call__(self, request: CollectionRequest) -> list[Collected]:
        anchor = int(request["anchor"])
        if self.collector is None or anchor != self.anchor:
            # As the loop re-seeds its own instances after every checkpoint (exact resume).
            self.close()
            env_seed = derive_seed(self.seed, "envs", self.model.phase.index, anchor)
            self.collector = self.config.training.build_collector(
                self.model.adapters, env_seed, backend=self.backend
            )
            self.anchor, self.backend = anchor, self.collector.backend_name
        state = request["agent"]
        if state is not None:
            # The snapshot's own acting stream would repeat every epoch: draw from the epoch's.
            self.agent.load_state_dict(state)
            self.agent.reseed_acting(int(request["act_seed"]))
        out = []
        for random_actions, active in request["passes"]:
            steps: list[Transition] = []
            stats = self.collector.collect_episodes(
                self.policy,  # random_actions: actions ignore it; its task encoder still reads the steps
                active={e: np.asarray(m, dtype=bool) for e, m in active.items()},
                random_actions=random_actions,
                sink=lambda *step, _s=steps: _s.append(step),
            )
            out.append((steps, stats))
        return out

    def close(self) -> None:
        if self.collector is not None:
            self.collector.close()
            self.collector = None
