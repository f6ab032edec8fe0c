"""Vectorised experience collection: every (environment, task) instance steps together.

A `Collector` owns one gymnasium env per (environment, task) instance, built by the adapter with a
seed derived from (collector seed, environment name, task name). Each call to `collect_episodes`
runs one full episode on every active instance; at every step it makes one policy call per
environment over all of that environment's running instances (batched inference), steps them
all, and hands the transitions to a sink such as `MultiTaskReplay.add`.

Backends (`seal.learner.env_backends`; same seed -> identical transitions on every backend;
`tests/learner/test_collection.py`):

- ``sync``: one process steps every env in turn.
- ``subproc-batched``: `num_workers` processes, each stepping a round-robin share of all
  instances (of every environment) per message (one pipe round trip per worker per step).
- ``inline-batched``: like ``subproc-batched``, but the main process steps one share itself
  (`num_workers - 1` worker processes), so on 2 cores two processes are busy instead of three.
- ``gym-async``: the reference design, gymnasium's `AsyncVectorEnv` (one process per env
  instance) per environment; it can only step all instances of an environment together.
- ``auto``: ``inline-batched`` with one share per CPU when there are >= 2 CPUs and splitting a
  step of all instances over the shares saves >= 1 ms of CPU (each env's step cost probed on a
  throwaway env at start), else ``sync``. `seal bench` (collect_mt10_speedup / collect_fk_speedup) measures every
  backend against a plain loop: on this 2-core machine inline-batched was the fastest (MT10 and
  kitchens), the one-process-per-env reference the slowest of the parallel designs.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

from seal.envs.base import EnvAdapter
from seal.errors import SealError, UnknownNameError
from seal.learner.critic_probe import CriticProbe
from seal.learner.env_backends import (
    BACKENDS,
    Seeds,
    Selection,
    _auto_backend,
    _Backend,
    _cpu_count,
    _GymAsyncBackend,
    _Instance,
    _SubprocBatchedBackend,
    _SyncBackend,
    instance_seed,
)
from seal.learner.evaluation_waves import Decide, Played, evaluate_in_waves

if TYPE_CHECKING:
    from seal.learner.task_encoder import BeliefMemory

# evaluation_replicas: at most this many evaluation instances in all (memory: a Meta-World env
# holds ~25 MB, a kitchen env ~100 MB), and about this many per worker process/share.
EVAL_MAX_INSTANCES = 64
EVAL_INSTANCES_PER_WORKER = 4


class Policy(Protocol):
    """Maps one environment's running instances to actions: (env, obs [n, obs_dim], task_ids [n]) -> [n, act_dim]."""

    def __call__(self, env: str, obs: np.ndarray, task_ids: np.ndarray) -> np.ndarray: ...


class TransitionSink(Protocol):
    """Receives one step of one environment's running instances, e.g. `MultiTaskReplay.add`."""

    def __call__(
        self,
        env: str,
        task_ids: np.ndarray,
        obs: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        next_obs: np.ndarray,
        terminations: np.ndarray,
    ) -> object: ...


def evaluation_replicas(episodes: int, tasks: int, workers: int | None = None) -> int:
    """Env instances per task for evaluating `episodes` episodes of `tasks` tasks at once."""
    workers = _cpu_count() if workers is None else max(1, int(workers))
    tasks = max(1, int(tasks))
    # Replicas: enough for ~4 instances per worker (parallel steps, bigger policy batches), never
    # more than `episodes` nor 64 instances in all; then as few rounds as that allows, evened out.
    most = min(episodes, max(1, EVAL_MAX_INSTANCES // tasks))
    wanted = min(most, max(1, -(-EVAL_INSTANCES_PER_WORKER * workers // tasks)))
    rounds = -(-episodes // wanted)
    return max(1, -(-episodes // rounds))


@dataclass
class EpisodeStats:
    """Per-instance results of one `collect_episodes` call; arrays are indexed like `tasks[env]`.

    Inactive instances have `active == False`, return 0, success False and length 0.
    """

    tasks: dict[str, tuple[str, ...]]
    active: dict[str, np.ndarray]
    returns: dict[str, np.ndarray]
    successes: dict[str, np.ndarray]
    lengths: dict[str, np.ndarray]

    @property
    def env_steps(self) -> int:
        """Env steps taken in these episodes, over all instances."""
        return int(sum(int(v.sum()) for v in self.lengths.values()))

    def per_task(self) -> dict[tuple[str, str], dict[str, float]]:
        """{(env, task): {"return", "success", "length"}} for the active instances."""
        out: dict[tuple[str, str], dict[str, float]] = {}
        for env, tasks in self.tasks.items():
            for i, task in enumerate(tasks):
                if self.active[env][i]:
                    out[(env, task)] = {
                        "return": float(self.returns[env][i]),
                        "success": float(self.successes[env][i]),
                        "length": float(self.lengths[env][i]),
                    }
        return out


# ---------------------------------------------------------------- collector
class Collector:
    """Steps every (environment, task) instance together with batched policy inference.

    `adapters` maps environment names to adapters; `tasks` optionally restricts an environment to
    a subset of its adapter's tasks (task ids stay the adapter's indices, i.e. one-hot positions).
    A separate Collector with another seed serves evaluation (its own env instances and seeds).
    `env_steps[env]` counts env steps per task (indexed like `self.tasks[env]`).

    `replicas` > 1 builds that many instances of every task (see `evaluation_replicas`), so
    `evaluate` runs that many episodes of each task at once; `collect_episodes` uses replica 0,
    and replica 0's seeds are those of a one-replica Collector.
    """

    def __init__(
        self,
        adapters: Mapping[str, EnvAdapter],
        seed: int,
        tasks: Mapping[str, Sequence[str]] | None = None,
        backend: str = "auto",
        num_workers: int | None = None,
        start_method: str | None = None,
        replicas: int = 1,
    ) -> None:
        if backend not in BACKENDS:
            raise UnknownNameError("collection backend", backend, BACKENDS)
        if not adapters:
            raise SealError("Collector needs at least one environment adapter")
        self.adapters = dict(adapters)
        self.seed = int(seed)
        self.tasks: dict[str, tuple[str, ...]] = {}
        for env, adapter in self.adapters.items():
            chosen = tuple(adapter.tasks if tasks is None or env not in tasks else tasks[env])
            for task in chosen:
                if task not in adapter.tasks:
                    raise UnknownNameError(f"{env} task", task, adapter.tasks)
            self.tasks[env] = chosen
        if tasks is not None:
            for env in tasks:
                if env not in self.adapters:
                    raise UnknownNameError(
                        "environment in collector tasks", env, list(self.adapters)
                    )
        self.task_ids = {
            env: np.array([self.adapters[env].tasks.index(t) for t in ts], dtype=np.int64)
            for env, ts in self.tasks.items()
        }
        self.env_steps = {env: np.zeros(len(ts), dtype=np.int64) for env, ts in self.tasks.items()}
        if int(replicas) < 1:
            raise SealError(f"Collector replicas must be >= 1, got {replicas}")
        self.replicas = int(replicas)
        # Instance r * len(tasks) + i is replica r of task i: replica 0's indices are the tasks'.
        self._instance_ids = {
            env: np.tile(ids, self.replicas) for env, ids in self.task_ids.items()
        }
        self._draws = 0
        groups = {
            env: [
                _Instance(env, task, instance_seed(self.seed, env, task, r), self.adapters[env])
                for r in range(self.replicas)
                for task in ts
            ]
            for env, ts in self.tasks.items()
        }
        self._action_rng = {
            env: np.random.default_rng(
                np.random.SeedSequence(self.seed, spawn_key=(zlib.crc32(env.encode()), 1))
            )
            for env in self.tasks
        }
        workers = _cpu_count() if num_workers is None else int(num_workers)
        if workers < 1:
            raise SealError(f"Collector num_workers must be >= 1, got {num_workers}")
        self.step_cost_s: float | None = None
        """auto only: probed CPU seconds of one step of every instance, in one process."""
        if backend == "auto":
            backend, self.step_cost_s = _auto_backend(groups, workers)
        # fork: workers start in ~0.1 s and need nothing pickled; they never touch torch, so
        # forking a process that has started torch threads is safe here.
        method = start_method or ("fork" if "fork" in mp.get_all_start_methods() else "spawn")
        self.backend_name = backend
        if backend == "sync":
            self._backend: _Backend = _SyncBackend(groups)
        elif backend == "subproc-batched":
            self._backend = _SubprocBatchedBackend(groups, workers, method)
        elif backend == "inline-batched":
            self._backend = _SubprocBatchedBackend(groups, workers, method, inline=True)
        else:
            self._backend = _GymAsyncBackend(groups, method)

    # ------------------------------------------------------------ episodes
    def collect_episodes(
        self,
        policy: Policy | None,
        active: Mapping[str, Sequence[bool] | np.ndarray] | None = None,
        random_actions: bool = False,
        sink: TransitionSink | None = None,
    ) -> EpisodeStats:
        """Run one full episode on every active instance; return per-instance return, success, length.

        `random_actions` samples uniformly from each action space (warm-up) instead of calling
        `policy`. Each step's transitions go to `sink(env, task_ids, obs, actions, rewards,
        next_obs, terminations)`, where terminations hold `terminated` only: a truncated episode
        is bootstrapped from its last observation, a terminated one is not.
        """
        if policy is None and not random_actions:
            raise SealError("collect_episodes needs a policy unless random_actions=True")
        if self._backend is None:
            raise SealError("this Collector is closed")
        mask = self._active_mask(active)
        running: Selection = {env: np.flatnonzero(m) for env, m in mask.items() if m.any()}
        returns, successes, lengths = self._run(running, None, policy, random_actions, sink)
        n = {env: len(ts) for env, ts in self.tasks.items()}
        returns = {env: v[: n[env]] for env, v in returns.items()}
        successes = {env: v[: n[env]] for env, v in successes.items()}
        lengths = {env: v[: n[env]] for env, v in lengths.items()}
        return EpisodeStats(dict(self.tasks), mask, returns, successes, lengths)

    def _run(
        self,
        running: Selection,
        seeds: Seeds | None,
        policy: Policy | None,
        random_actions: bool,
        sink: TransitionSink | None,
        probe: CriticProbe | None = None,
        end_on_success: bool = False,
    ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, np.ndarray]]:
        """One episode on each selected instance: per-instance (returns, successes, lengths).
        A `probe` sees every episode's first state and action and every step; `end_on_success`
        ends an episode after its first successful step (not a termination: a probe bootstraps it)."""
        size = {env: len(ids) for env, ids in self._instance_ids.items()}
        returns = {env: np.zeros(k) for env, k in size.items()}
        successes = {env: np.zeros(k, dtype=bool) for env, k in size.items()}
        lengths = {env: np.zeros(k, dtype=np.int64) for env, k in size.items()}
        # A policy with a task encoder (`seal.learner.task_encoder.BeliefMemory`) sees, and the
        # probe and the sink get, observations with the belief and the episode step appended.
        memory: BeliefMemory | None = getattr(policy, "memory", None)
        obs = self._backend.reset(running, seeds)
        if memory is not None:
            for env, run in running.items():
                memory.start(env, run)
        seen = self._seen(memory, running, obs)
        actions = self._actions(policy, random_actions, running, seen)
        if probe is not None:
            probe.start(size)
            for env, run in running.items():
                probe.first(env, run, self._instance_ids[env][run], seen[env], actions[env])
        self._backend.step_async(running, actions)
        t = 0
        while running:
            results = self._backend.step_wait()
            t += 1
            if memory is not None:
                for env, (next_obs, rewards, *_) in results.items():
                    memory.advance(env, running[env], actions[env], rewards, next_obs)
            # Decide who keeps running and send their next actions before the bookkeeping of
            # this step, so worker processes step while the sink (replay) copies data.
            step_running, step_obs, step_actions = running, obs, actions
            running, obs = {}, {}
            dones: dict[str, np.ndarray] = {}
            for env, (next_obs, _, terminated, truncated, success) in results.items():
                # An env that forgets to truncate at its episode length is cut there anyway.
                done = terminated | truncated | (t >= self.adapters[env].episode_length)
                if end_on_success:
                    done = done | (success > 0.5)
                dones[env] = done
                if not done.all():
                    running[env] = step_running[env][~done]
                    obs[env] = next_obs[~done]
            if running:
                actions = self._actions(
                    policy, random_actions, running, self._seen(memory, running, obs)
                )
                self._backend.step_async(running, actions)
            for env, (next_obs, rewards, terminated, _, success) in results.items():
                run = step_running[env]
                before = step_obs[env]
                if memory is not None:  # [obs | belief | step] before and after the step
                    extra_before, extra_after = memory.last(env)
                    before = np.concatenate((np.asarray(before, np.float32), extra_before), axis=1)
                    next_obs = np.concatenate(
                        (np.asarray(next_obs, np.float32), extra_after), axis=1
                    )
                returns[env][run] += rewards
                if probe is not None:
                    probe.step(env, run, rewards, next_obs, terminated)
                successes[env][run] |= success > 0.5
                lengths[env][run] += 1
                if self.replicas == 1:
                    self.env_steps[env][run] += 1
                else:  # replicas of one task may step together
                    np.add.at(self.env_steps[env], run % len(self.tasks[env]), 1)
                if sink is not None:
                    sink(
                        env,
                        self._instance_ids[env][run],
                        before,
                        step_actions[env],
                        rewards,
                        next_obs,
                        terminated,
                    )
        return returns, successes, lengths

    @staticmethod
    def _seen(
        memory: BeliefMemory | None, running: Selection, obs: dict[str, np.ndarray]
    ) -> dict[str, np.ndarray]:
        """What the policy sees of the running instances: raw obs, or [obs | belief | step]."""
        if memory is None:
            return obs
        return {env: memory.augment(env, run, obs[env]) for env, run in running.items()}

    def _actions(
        self,
        policy: Policy | None,
        random_actions: bool,
        running: Selection,
        obs: dict[str, np.ndarray],
    ) -> dict[str, np.ndarray]:
        """One batched policy call (or uniform sample) per environment over its running instances."""
        out: dict[str, np.ndarray] = {}
        for env, run in running.items():
            space = self.adapters[env].action_space
            if random_actions:
                out[env] = (
                    self._action_rng[env]
                    .uniform(space.low, space.high, size=(len(run), *space.shape))
                    .astype(space.dtype)
                )
            else:
                assert policy is not None
                out[env] = np.asarray(
                    policy(env, obs[env], self._instance_ids[env][run]), dtype=space.dtype
                )
        return out

    def evaluate(
        self,
        policy: Policy,
        episodes: int,
        active: Mapping[str, Sequence[bool] | np.ndarray] | None = None,
        draw: int | None = None,
        probe: CriticProbe | None = None,
        decide: Decide | None = None,
        end_on_success: bool = False,
    ) -> dict[str, dict[str, dict[str, float]]]:
        """Mean success rate and return over `episodes` episodes per task: {env: {task: {...}}}.

        With a `probe` (`seal.learner.critic_probe`), also the means of its `q_start` and `earned`.

        Pass a deterministic policy and use a Collector seeded apart from the training one.
        Episode e of a task resets with `evaluation_waves.episode_seed(seed, env, task, draw, e)`,
        so the results do not depend on the backend or on `replicas`; `draw` (default: this
        Collector's count of `evaluate` calls) picks a fresh set of episodes. The `replicas`
        instances of each task run episodes `replicas` at a time, in waves
        (`seal.learner.evaluation_waves`); with `decide` (`seal.evaluation.EarlyDecision`) a task
        whose verdict is settled stops after its wave, and `end_on_success` ends every episode at
        its first success.
        """
        if episodes < 1:
            raise SealError(f"evaluate: episodes must be >= 1, got {episodes}")
        if policy is None:
            raise SealError("evaluate needs a policy")
        if self._backend is None:
            raise SealError("this Collector is closed")
        draw = self._draws if draw is None else int(draw)
        self._draws += 1

        def play(running: Selection, seeds: Seeds) -> Played:
            returns, successes, _ = self._run(
                running, seeds, policy, False, None, probe, end_on_success
            )
            played: Played = {}
            for env, run in running.items():
                played[env] = {"return": returns[env][run], "success": successes[env][run]}
                if probe is not None:
                    ids = self._instance_ids[env][run]
                    played[env]["q_start"], played[env]["earned"] = probe.finish(env, run, ids)
            return played

        return evaluate_in_waves(
            play,
            self.tasks,
            self._active_mask(active),
            seed=self.seed,
            draw=draw,
            episodes=episodes,
            replicas=self.replicas,
            # gym-async can only reset whole environments: spare episodes, results dropped.
            whole=isinstance(self._backend, _GymAsyncBackend),
            decide=decide,
        )

    def _active_mask(
        self, active: Mapping[str, Sequence[bool] | np.ndarray] | None
    ) -> dict[str, np.ndarray]:
        mask = {env: np.ones(len(ts), dtype=bool) for env, ts in self.tasks.items()}
        if active is None:
            return mask
        for env, m in active.items():
            if env not in self.tasks:
                raise UnknownNameError("environment in active mask", env, list(self.tasks))
            arr = np.asarray(m, dtype=bool)
            if arr.shape != mask[env].shape:
                raise SealError(
                    f"active mask for {env!r} has shape {arr.shape}; expected ({len(self.tasks[env])},) for tasks {list(self.tasks[env])}"
                )
            mask[env] = arr
        return mask

    @property
    def total_env_steps(self) -> int:
        """Env steps over every instance since this Collector was built."""
        return int(sum(int(v.sum()) for v in self.env_steps.values()))

    def close(self) -> None:
        """Close every env and stop worker processes."""
        backend = getattr(self, "_backend", None)
        if backend is not None:
            backend.close()
            self._backend = None  # type: ignore[assignment]

    def __enter__(self) -> Collector:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        with contextlib.suppress(Exception):  # interpreter shutdown may have torn down modules
            self.close()
