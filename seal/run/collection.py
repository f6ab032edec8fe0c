"""A phase's collection: its training env instances, the actor process beside the updates
(`training.overlap`), the scripted experts' demonstrations and SMT's scoring episodes.

The loop (`seal.run.loop`) calls `start(plan)` then, after the updates, `finish()`; the updates
train on `lengths()`. Synchronously, `start` collects the epoch's episodes at once; with
training.overlap it hands them to the actor (`seal.run.workers.ActorWorker`), which collects with
the policy as it is before the updates, and `finish` adds them to the replay in order.
"""

from __future__ import annotations

import sys
from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from seal.device import torch_threads
from seal.run.phase_model import ACTING_THREADS
from seal.run.workers import ActorWorker, cpu_copy
from seal.seeding import derive_seed

if TYPE_CHECKING:
    from seal.evaluation import AgentPolicy
    from seal.learner.collection import Collector, EpisodeStats
    from seal.learner.replay import MultiTaskReplay
    from seal.run.parts import LoopParts
    from seal.run.phase_model import PhaseModel
    from seal.schedulers.base import Plan, ScoreRequest


class Collection:
    """The phase's training instances (rebuilt after every checkpoint), its actor and what they collect."""

    def __init__(self, loop: LoopParts) -> None:
        self.loop = loop
        self._collector: Collector | None = None
        self._backend: str | None = None
        self.actor: ActorWorker | None = None
        """training.overlap: the worker process that collects beside the updates (`start_actor`)."""
        self._actor_passes: list[tuple[bool, dict[str, np.ndarray]]] = []
        self._lengths: dict[str, int] = {}
        self.train_policy: AgentPolicy | None = None
        """The stochastic policy the episodes act with (`ready` makes it, after any demonstrations)."""

    def ready(self) -> None:
        """Make the training policy (at the end of the loop's set-up, as the loop always has)."""
        self.train_policy = self.loop.model.policy(self.loop.agent, deterministic=False)

    # ------------------------------------------------------------ env instances
    @property
    def collector(self) -> Collector:
        """The phase's training instances, built when first used after each checkpoint."""
        if self._collector is None:
            self._collector = self._new_collector(self.loop.state.anchor_epoch, self._backend)
        return self._collector

    def close_collector(self) -> None:
        """Close the training instances; the next use rebuilds them from the anchor epoch."""
        if self._collector is not None:
            self._backend = self._collector.backend_name
            self._collector.close()
            self._collector = None

    def _new_collector(self, anchor: int, backend: str | None = None) -> Collector:
        """The phase's env instances, seeded from (seed, phase, epoch of the last checkpoint).

        Evaluation runs on instances of its own (`seal.run.evaluation`), built once per phase.
        """
        loop = self.loop
        seed = derive_seed(loop.owner.seed, "envs", loop.phase.index, anchor)
        return loop.cfg.training.build_collector(loop.model.adapters, seed, backend=backend)

    def start_actor(self) -> None:
        """training.overlap: start the actor process (collect time)."""
        loop = self.loop
        if loop.cfg.training.overlap:
            with loop.timed("collect", count=False):
                self.actor = ActorWorker(loop.cfg, loop.phase, loop.owner.seed, loop.owner.device)

    def close_actor(self, timeout_s: float) -> None:
        if self.actor is not None:
            self.actor.close(timeout_s=timeout_s)
        self.actor = None

    # ------------------------------------------------------------ the epoch's collection
    def start(self, plan: Plan) -> None:
        """The epoch's episodes: collected now, or (training.overlap) handed to the actor with
        the policy as it is now, while the updates train on the replay up to the last epoch's."""
        if self.actor is None:
            self._lengths = self._collect(plan)
        else:
            self._start_actor_collection(plan)

    def lengths(self) -> Mapping[str, int]:
        """env -> the longest episode the epoch's updates train on: this epoch's, or
        (training.overlap) the last epoch's."""
        return self._lengths if self.actor is None else self.loop.state.collected_lengths

    def finish(self) -> None:
        """training.overlap: wait for the actor's episodes and add them to the replay."""
        if self.actor is not None:
            self.loop.state.collected_lengths = self._finish_actor_collection()

    def _collect(self, plan: Plan) -> dict[str, int]:
        """One episode per planned task: warm-up envs act uniformly at random, the others with the policy.

        Returns env -> the longest episode it collected (envs that collected nothing are absent).
        """
        loop = self.loop
        lengths: dict[str, int] = {}
        with loop.timed("collect"):
            for random_actions, active in self._passes(plan):
                with torch_threads(ACTING_THREADS):
                    assert self.train_policy is not None
                    stats = self.collector.collect_episodes(
                        self.train_policy,  # random_actions: actions ignore it; its task encoder still reads the steps
                        active=active,
                        random_actions=random_actions,
                        sink=ReplaySink(loop.replay, loop.model),
                    )
                self._observe_episodes(active, stats, lengths)
        return lengths

    def _passes(self, plan: Plan) -> list[tuple[bool, dict[str, np.ndarray]]]:
        """The epoch's collection calls: (random actions, env -> which tasks collect), warm-up first."""
        state, envs = self.loop.state, self.loop.phase.envs
        warm = {e: sum(state.env_steps[e]) < self.loop.cfg.training.warmup_steps for e in envs}
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
        state, model = self.loop.state, self.loop.model
        for e in self.loop.phase.envs:
            idx = np.flatnonzero(active[e])
            if not idx.size:
                continue
            for i in idx:
                state.env_steps[e][i] += int(stats.lengths[e][i])
            lengths[e] = int(stats.lengths[e][idx].max())
            self.loop.scheduler.observe_episodes(
                e,
                [model.env_tasks[e][i] for i in idx],
                [float(stats.returns[e][i]) for i in idx],
                [float(stats.successes[e][i]) for i in idx],
                [int(stats.lengths[e][i]) for i in idx],
            )

    def _start_actor_collection(self, plan: Plan) -> None:
        """training.overlap: hand the epoch's collection to the actor, with the policy as it is now."""
        assert self.actor is not None
        loop = self.loop
        passes = self._passes(plan)
        self._actor_passes = passes
        acting = any(not random_actions for random_actions, _ in passes)
        self.actor.submit(
            [(r, {e: m.tolist() for e, m in active.items()}) for r, active in passes],
            anchor=loop.state.anchor_epoch,
            act_seed=derive_seed(loop.owner.seed, "act", loop.phase.index, loop.state.epoch),
            agent_state=cpu_copy(loop.agent.state_dict()) if acting else None,
        )

    def _finish_actor_collection(self) -> dict[str, int]:
        """training.overlap: wait for the actor's episodes, add them to the replay in order and
        count them; env -> the longest episode collected (the next epoch's updates train on them)."""
        assert self.actor is not None
        sink = ReplaySink(self.loop.replay, self.loop.model)
        lengths: dict[str, int] = {}
        with self.loop.timed("collect"):
            for (_, active), (steps, stats) in zip(
                self._actor_passes, self.actor.result(), strict=True
            ):
                for step in steps:
                    sink(*step)
                self._observe_episodes(active, stats, lengths)
        return lengths

    # ------------------------------------------------------------ other episodes
    def demonstrations(self) -> dict[str, dict[str, float]]:
        """Put `demo_episodes` episodes per task of each env's scripted expert in the replay (`ProtocolConfig.demo_episodes`)."""
        model, loop = self.loop.model, self.loop
        episodes = {e: loop.cfg.demo_episodes(e) for e in model.env_tasks}
        experts = {
            e: [model.adapters[e].expert(t) for t in tasks]
            for e, tasks in model.env_tasks.items()
            if episodes[e]
        }

        class Experts:
            """The scripted experts; under smt_gru the agent's task encoder reads their steps
            (the replay stores its beliefs), and each expert gets its raw observation."""

            memory = model.policy(loop.agent, deterministic=False).memory

            def __call__(self, env: str, obs: np.ndarray, task_ids: np.ndarray) -> np.ndarray:
                width = model.adapters[env].obs_dim
                return np.stack(
                    [experts[env][i](o[:width]) for o, i in zip(obs, task_ids, strict=True)]
                )

        act = Experts()

        steps = {e: 0 for e in experts}
        successes = {e: 0.0 for e in experts}
        sink = ReplaySink(loop.replay, model)
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
        if not loop.owner.quiet:
            for e, f in figures.items():
                print(
                    f"[seal] {e}: {f['episodes']} demonstration episodes, {f['env_steps']} env steps "
                    f"in the replay (expert success {f['expert_success']:.2f})",
                    file=sys.stderr,
                )
        return figures

    def scores(self, request: ScoreRequest, epoch: int) -> dict[tuple[str, str], float]:
        """SMT Eq. 5 scores: mean over episodes of sum_t gamma^t r_t - log pi(a_t|s_t) (stochastic policy).

        The entropy term needs `agent.log_prob(env, obs, actions, task_ids)`; an agent without it
        is scored by discounted return alone (said in the scheduler's docs).
        """
        from seal.learner.collection import Collector

        model, agent = self.loop.model, self.loop.agent
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
                seed=derive_seed(self.loop.owner.seed, "score", model.phase.index, epoch),
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


class ReplaySink:
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
