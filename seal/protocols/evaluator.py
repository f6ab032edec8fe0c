"""Evaluation off the critical path (`evaluation.mode = "async"`): a worker process evaluates.

At each evaluation the loop (`seal.protocols.phase.PhaseLoop`) takes a snapshot of the agent (its
whole `state_dict`, copied to the CPU) and the metrics rows as they stand then (epoch, gradient
steps, env steps, consumed updates, batch: `PendingEvaluation`), hands the snapshot to the
`EvaluationWorker` and goes on training. The worker evaluates it as a synchronous evaluation
would: the same deterministic policy on the same device and thread count, the same evaluation
instances (`phase.build_eval_collector`, seeded from (seed, phase)) and the same episode seeds
(the draw is the snapshot's gradient-step count), so its numbers are those of a synchronous
evaluation of the same snapshot. The loop writes the rows, in the order the snapshots were
taken, when the results come back; best.pt is the snapshot's agent.

At most one evaluation is in flight: a second waits for the first. An epoch checkpoint holds the
evaluations still pending (`PendingEvaluation.fields`) and its CSV row counts exclude their rows,
so a run killed during an evaluation re-runs it on resume and loses nothing.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import multiprocessing as mp
import os
import signal
import traceback
from collections.abc import Mapping
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import TYPE_CHECKING, Any

import torch

from seal.errors import SealError

if TYPE_CHECKING:
    from seal.protocols.config import ProtocolConfig
    from seal.protocols.phase import Phase
    from seal.protocols.rundir import MetricsRow

Results = dict[str, dict[str, dict[str, float]]]
"""`seal.evaluation.evaluate`'s result: {env: {task: {"success", "return"}}}."""


def cpu_copy(obj: Any) -> Any:
    """A copy of a (nested) state dict whose tensors are detached copies on the CPU."""
    if isinstance(obj, torch.Tensor):
        return obj.detach().to("cpu", copy=True)
    if isinstance(obj, dict):
        return {k: cpu_copy(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return type(obj)(cpu_copy(v) for v in obj)
    return obj


@dataclass
class PendingEvaluation:
    """An evaluation handed to the worker whose results have not been written yet."""

    draw: int
    """Its episode set: the gradient steps at the snapshot, as a synchronous evaluation's."""
    epoch: int
    grad_steps: int
    rows: list[MetricsRow]
    """metrics.csv rows as they stood at the snapshot; success and return are filled in later."""
    agent: dict[str, Any]
    """The agent's `state_dict` at the snapshot, on the CPU."""

    def fields(self) -> dict[str, Any]:
        """What an epoch checkpoint stores of it (tensors and plain values only)."""
        return dataclasses.asdict(self)

    @classmethod
    def from_fields(cls, fields: Mapping[str, Any]) -> PendingEvaluation:
        """The pending evaluation a checkpoint stored (`fields`)."""
        return cls(
            draw=int(fields["draw"]),
            epoch=int(fields["epoch"]),
            grad_steps=int(fields["grad_steps"]),
            rows=[dict(r) for r in fields["rows"]],  # type: ignore[misc]
            agent=dict(fields["agent"]),
        )


class EvaluationWorker:
    """A process that evaluates agent snapshots of one phase, one after another (module docstring).

    Started with the phase (spawned: it builds its own adapters, agent and evaluation instances,
    so nothing of the training process's torch or CUDA state is inherited); it dies with the
    process that started it.
    """

    def __init__(self, config: ProtocolConfig, phase: Phase, seed: int, device: str) -> None:
        ctx = mp.get_context("spawn")
        self._conn, child = ctx.Pipe()
        # Not a daemon: its evaluation instances may run worker processes of their own.
        self._process = ctx.Process(
            target=_worker_main,
            args=(child, config, phase, seed, device, os.getpid()),
            name=f"seal-evaluation-{phase.name}",
        )
        self._process.start()
        child.close()
        self._ready = False
        self.in_flight = 0

    def submit(self, draw: int, agent_state: Mapping[str, Any]) -> None:
        """Evaluate `agent_state` with the episodes of `draw`; `result` returns it, in order."""
        buffer = io.BytesIO()
        torch.save(agent_state, buffer)
        self._conn.send(("evaluate", draw, buffer.getvalue()))
        self.in_flight += 1

    def done(self) -> bool:
        """Whether the oldest submitted evaluation's result is waiting (never blocks)."""
        while self.in_flight and self._conn.poll(0):
            if self._ready:
                return True
            self._receive()  # the start-up message
        return False

    def result(self) -> Results:
        """The oldest submitted evaluation's result, waiting for it."""
        if not self.in_flight:
            raise RuntimeError("no evaluation in flight")
        while True:
            kind, answer = self._receive()
            if kind == "ok":
                self.in_flight -= 1
                return answer

    def _receive(self) -> tuple[str, Any]:
        try:
            kind, answer = self._conn.recv()
        except (EOFError, OSError):
            raise SealError(
                f"the evaluation worker (pid {self._process.pid}) ended unexpectedly (exit code {self._process.exitcode})"
            ) from None
        if kind == "error":
            raise SealError(f"the evaluation worker failed:\n{answer}")
        if kind == "ready":
            self._ready = True
        return kind, answer

    def close(self) -> None:
        """Stop the worker (an evaluation in flight is abandoned)."""
        with contextlib.suppress(OSError, ValueError):
            self._conn.send(("close", None, b""))
        self._process.join(timeout=10)
        if self._process.is_alive():
            self._process.kill()
            self._process.join()
        self._conn.close()


def _exit_with_parent(parent: int) -> None:
    """Have the kernel kill this process when its parent dies (Linux), so a kill -9 leaves no orphan."""
    with contextlib.suppress(OSError, AttributeError):
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    if os.getppid() != parent:  # the parent died before prctl took effect
        os._exit(1)


def _worker_main(
    conn: Connection, config: ProtocolConfig, phase: Phase, seed: int, device: str, parent: int
) -> None:
    """The worker: build the phase's evaluation side, then answer ("evaluate", draw, state) messages."""
    _exit_with_parent(parent)
    from seal.evaluation import evaluate
    from seal.protocols.phase import ACTING_THREADS, PhaseModel, build_eval_collector
    from seal.protocols.runner import build_adapters, build_alignment, run_agent_config

    try:
        torch.set_num_threads(ACTING_THREADS)
        adapters = build_adapters(config)
        alignment = build_alignment(config, adapters) if config.kind == "finetune" else None
        model = PhaseModel(config, phase, adapters, alignment)
        # Acting never runs compiled code, so the worker's agent skips compiling its updates.
        agent_config = dataclasses.replace(run_agent_config(config, device), compile=False)
        agent = agent_config.build(model.specs, 0)
        policy = model.policy(agent, deterministic=True)
        collector = build_eval_collector(config, model, seed)
    except BaseException:  # noqa: BLE001 - reported to the loop, which raises it
        conn.send(("error", traceback.format_exc()))
        return
    conn.send(("ready", None))
    try:
        while True:
            try:
                kind, draw, blob = conn.recv()
            except EOFError:
                return
            if kind == "close":
                return
            try:
                agent.load_state_dict(torch.load(io.BytesIO(blob), weights_only=True))
                results = evaluate(
                    policy,
                    model.adapters,
                    episodes=config.evaluation.episodes,
                    seed=0,
                    collector=collector,
                    draw=draw,
                )
                conn.send(("ok", results))
            except BaseException:  # noqa: BLE001
                conn.send(("error", traceback.format_exc()))
    finally:
        collector.close()
