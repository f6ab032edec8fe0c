"""A phase's evaluations (Appendix B), synchronous or asynchronous, and what they write.

Synchronous (`evaluation.mode = "sync"`): `evaluate` runs here and now, training stopped, on
evaluation's own env instances (`seal.run.phase_model.build_eval_collector`). Asynchronous: a
snapshot goes to the worker (`seal.run.workers.EvaluationWorker`) and its results are recorded
when they come back (`finish`); the loop waits only for the previous one. Either way an
evaluation's results become metrics.csv rows, train.csv rows (`seal.run.eval_rows`), first
crossings, the scheduler's observation and, for a new best, best.pt (`LoopCallback.write_best`),
then the callbacks' `on_evaluation`.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from seal.device import torch_threads
from seal.evaluation import evaluate, mean_success, reaches
from seal.learner.sac import Agent
from seal.protocols.evaluation_cost import decides_early, runs_all_episodes
from seal.run.eval_rows import critic_rows, decision_rows
from seal.run.phase_model import ACTING_THREADS, build_eval_collector
from seal.run.state import Evaluated
from seal.run.workers import EvaluationWorker, PendingEvaluation, Results, cpu_copy

if TYPE_CHECKING:
    from seal.evaluation import AgentPolicy
    from seal.learner.collection import Collector
    from seal.run.checkpoint_fields import EpochCheckpoint
    from seal.run.parts import LoopParts
    from seal.run.rundir import MetricsRow, TrainRow


class Evaluation:
    """The phase's evaluations: their instances and worker, those pending, the latest's rows."""

    def __init__(self, loop: LoopParts, payload: EpochCheckpoint | None) -> None:
        from seal.schedulers.base import Scheduler as SchedulerBase

        self.loop = loop
        self.eval_collector: Collector | None = None
        """Evaluation's own env instances, several per task (built at the first evaluation)."""
        self.evaluator: EvaluationWorker | None = None
        """evaluation.mode = "async": the worker process that evaluates snapshots (`start_worker`)."""
        saved = [] if payload is None else payload["runner"].get("pending_evaluations", [])
        self.pending: list[PendingEvaluation] = [PendingEvaluation.from_fields(f) for f in saved]
        """Evaluations handed to the worker whose rows are not written yet, oldest first."""
        self.evaluated: Evaluated | None = None
        """The policy of the latest evaluation whose results are in (`write_best`, `on_evaluation`)."""
        self._snapshot_agent: Agent | None = None
        # A scheduler that reads evaluations sees each one before its next plan, as it would
        # synchronously (asynchronous evaluation then waits for results before planning).
        self.reads_eval = type(loop.scheduler).observe_eval is not SchedulerBase.observe_eval
        self.decide_early = decides_early(
            loop.cfg, loop.phase.name, self.reads_eval, quiet=loop.owner.quiet
        )
        """evaluation.decide_early applies to this phase (`seal.protocols.evaluation_cost`)."""
        self.last_rows: list[MetricsRow] = []
        """metrics.csv rows of the latest evaluation, one per (env, task)."""
        self.last_critic_rows: list[TrainRow] = []
        """The latest evaluation's critic-probe train rows (`critic_rows`)."""
        self.eval_policy: AgentPolicy | None = None
        """The deterministic policy evaluated (`ready` makes it, after any demonstrations)."""

    def ready(self) -> None:
        """Make the evaluated policy (at the end of the loop's set-up, as the loop always has)."""
        self.eval_policy = self.loop.model.policy(self.loop.agent, deterministic=True)

    def start_worker(self) -> None:
        """evaluation.mode = "async" (or evaluations left pending): start the worker; a resumed
        run re-runs the evaluations its checkpoint left pending."""
        loop = self.loop
        if loop.cfg.evaluation.mode == "async" or self.pending:
            with loop.timed("evaluate", count=False):
                self.evaluator = EvaluationWorker(
                    loop.cfg, loop.phase, loop.owner.seed, loop.owner.device
                )
                for pending in self.pending:
                    self.evaluator.submit(pending.draw, pending.agent, pending.decide)

    def close_collector(self) -> None:
        if self.eval_collector is not None:
            self.eval_collector.close()
            self.eval_collector = None

    def close_worker(self, timeout_s: float) -> None:
        if self.evaluator is not None:
            self.evaluator.close(timeout_s=timeout_s)
        self.evaluator = None

    def _eval_collector(self) -> Collector:
        """Evaluation's instances (`build_eval_collector`), built at the first evaluation."""
        if self.eval_collector is None:
            loop = self.loop
            self.eval_collector = build_eval_collector(loop.cfg, loop.model, loop.owner.seed)
        return self.eval_collector

    def evaluate(self, final: bool, batch: Mapping[str, np.ndarray]) -> None:
        """Appendix B's evaluation: metrics.csv rows, first crossings, best.pt, then the callbacks.

        `final`: the phase's last epoch's evaluation, which runs in full (`evaluation.full_every`);
        `batch`: the per-task batch of the latest update (metrics.csv's `batch`).
        """
        loop = self.loop
        state, agent, ev = loop.state, loop.agent, loop.cfg.evaluation
        state.evaluated_at = state.grad_steps
        state.evaluations += 1
        decide = self.decide_early and not runs_all_episodes(
            state.evaluations, ev.full_every, final
        )
        if self.evaluator is None:
            assert self.eval_policy is not None
            with loop.timed("evaluate"), torch_threads(ACTING_THREADS):
                results = evaluate(
                    self.eval_policy,
                    loop.model.adapters,
                    episodes=ev.episodes,
                    seed=0,
                    collector=self._eval_collector(),
                    draw=state.grad_steps,  # one evaluation per grad-step count: its own episode seeds
                    probe=self.eval_policy.critic_probe(loop.cfg.agent.gamma),
                    threshold=ev.threshold if decide else None,
                    end_on_success=ev.end_on_success,
                )
                self.evaluated = Evaluated(state.epoch, state.grad_steps, agent)
                self._record(self._rows(batch), results)
            self._on_evaluation()
            return
        self.finish(wait=True)  # one in flight at most, so rows stay in order
        with loop.timed("evaluate"):
            if not loop.all_reached():  # a synchronous run would have stopped at that result
                pending = PendingEvaluation(
                    draw=state.grad_steps,
                    epoch=state.epoch,
                    grad_steps=state.grad_steps,
                    rows=self._rows(batch),
                    agent=cpu_copy(agent.state_dict()),
                    decide=decide,
                )
                self.pending.append(pending)
                self.evaluator.submit(pending.draw, pending.agent, pending.decide)

    def finish(self, wait: bool) -> None:
        """Record the asynchronous evaluations whose results are in (all of them with `wait`), oldest first."""
        evaluator, loop = self.evaluator, self.loop
        while self.pending and evaluator is not None and (wait or evaluator.done()):
            with loop.timed("evaluate", count=False):  # the loop waiting on evaluation
                results = evaluator.result()
                loop.state.add_time("evaluate_worker_cpu", evaluator.last_cpu_s)
                pending = self.pending.pop(0)
                self.evaluated = Evaluated(
                    pending.epoch, pending.grad_steps, lambda p=pending: self._load_snapshot(p)
                )
                self._record(pending.rows, results)
            self._on_evaluation()

    def _on_evaluation(self) -> None:
        """The callbacks' `on_evaluation` (the loggers: "log" time)."""
        with self.loop.timed("log"), self.loop.stop.protected():
            self.loop.notify("on_evaluation")

    def _load_snapshot(self, pending: PendingEvaluation) -> Agent:
        """An agent (one per phase, reused) holding an asynchronous evaluation's snapshot."""
        if self._snapshot_agent is None:
            config = dataclasses.replace(self.loop.owner.agent_cfg, compile=False)
            self._snapshot_agent = Agent(self.loop.model.specs, config, 0)
        self._snapshot_agent.load_state_dict(pending.agent)
        return self._snapshot_agent

    def _record(self, rows: list[MetricsRow], results: Results) -> None:
        """Write an evaluation's rows and pass it on: first crossings, scheduler, best.pt."""
        loop = self.loop
        state, model, phase = loop.state, loop.model, loop.phase
        rows = self._fill_rows(rows, results)
        self.last_critic_rows = critic_rows(rows, results)
        with loop.timed("log"), loop.stop.protected():
            loop.owner.rundir.log_eval(rows)
            loop.owner.rundir.log_train([*self.last_critic_rows, *decision_rows(rows, results)])
        self.last_rows = rows
        state.last_success = {
            e: {t: results[e][t]["success"] for t in model.env_tasks[e]} for e in phase.envs
        }
        assert self.evaluated is not None
        loop.scheduler.observe_eval(
            self.evaluated.epoch, {(r["env"], r["task"]): r["success"] for r in rows}
        )
        mean = mean_success(results)
        # A decided-early rate is over a task's first episodes (45/45 reads 1.0): best.pt is
        # chosen among the evaluations in which every task ran all its episodes.
        partial = any(r.get("decided_early") for per in results.values() for r in per.values())
        if mean > state.best_mean_success and not partial:
            state.best_mean_success = mean
            with loop.stop.protected():
                loop.notify("write_best")  # best.pt (the Checkpointer): evaluation time

    def _rows(self, batch: Mapping[str, np.ndarray]) -> list[MetricsRow]:
        """metrics.csv rows of an evaluation of the agent as it is now, success and return to come."""
        loop = self.loop
        state, model = loop.state, loop.model
        rows: list[MetricsRow] = []
        for env in loop.phase.envs:
            consumed = np.asarray(loop.replay.consumed[model.agent_env[env]], dtype=np.int64)
            for i, task in enumerate(model.env_tasks[env]):
                rows.append(
                    {
                        "seed": loop.owner.seed,
                        "phase": loop.phase.name,
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
        state = self.loop.state
        wall = round(time.monotonic() - self.loop.started, 3)
        filled: list[MetricsRow] = []
        for row in rows:
            env, task = row["env"], row["task"]
            r = results[env][task]
            filled.append({**row, "success": r["success"], "return": r["return"], "wall_s": wall})
            first = task not in state.reached.get(env, {})
            if first and reaches(r["success"], self.loop.cfg.evaluation.threshold):
                state.reached.setdefault(env, {})[task] = row["updates"]
        return filled
