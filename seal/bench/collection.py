"""``collect_mt10_speedup`` / ``collect_fk_speedup``: env steps/s of `Collector` / a plain loop.

Every collection backend runs all tasks of an adapter (MT10, the 10 kitchens) with a fixed action
sequence, next to a plain single-process loop over envs built by the same adapter (same wrappers)
with the same actions; every backend must end on the plain loop's observations. The speedup is
that of the backend `auto` picks.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from seal.envs.base import EnvAdapter


class _PlainLoop:
    """The reference: one process, one env after another, envs built by the same adapter (same wrappers)."""

    def __init__(self, adapter: EnvAdapter, env_name: str, seed: int) -> None:
        from seal.learner.env_backends import instance_seed

        self.seeds = [instance_seed(seed, env_name, task) for task in adapter.tasks]
        self.envs = [
            adapter.make(task, s) for task, s in zip(adapter.tasks, self.seeds, strict=True)
        ]
        self.first = True

    def run(self, actions: np.ndarray) -> list[np.ndarray]:
        """Episodes of `actions` (episodes, steps, tasks, act_dim); the last observation of each task."""
        last: list[np.ndarray] = [np.empty(0)] * len(self.envs)
        for ep in range(actions.shape[0]):
            for i, env in enumerate(self.envs):
                last[i], _ = env.reset(seed=self.seeds[i] if self.first else None)
            self.first = False
            for t in range(actions.shape[1]):
                for i, env in enumerate(self.envs):
                    last[i], _, terminated, truncated, _ = env.step(actions[ep, t, i])
        return last

    def close(self) -> None:
        for env in self.envs:
            env.close()


class _CollectorLoop:
    """Our Collector replaying a fixed action sequence through its batched policy call."""

    def __init__(
        self, adapter: EnvAdapter, env_name: str, seed: int, backend: str, num_workers: int | None
    ) -> None:
        from seal.learner.collection import Collector

        start = time.perf_counter()
        self.collector = Collector(
            {env_name: adapter}, seed=seed, backend=backend, num_workers=num_workers
        )
        self.startup_s = time.perf_counter() - start
        self.num_tasks = len(adapter.tasks)

    def run(self, actions: np.ndarray) -> list[np.ndarray]:
        """Like `_PlainLoop.run`."""
        last: list[np.ndarray] = [np.empty(0)] * self.num_tasks
        step = [0, 0]  # episode, t

        def policy(env: str, obs: np.ndarray, task_ids: np.ndarray) -> np.ndarray:
            a = actions[step[0], step[1], task_ids]
            step[1] += 1
            return a

        def sink(
            env: str,
            task_ids: np.ndarray,
            obs: np.ndarray,
            act: np.ndarray,
            rew: np.ndarray,
            next_obs: np.ndarray,
            term: np.ndarray,
        ) -> None:
            for k, i in enumerate(task_ids):
                last[int(i)] = next_obs[k]

        for ep in range(actions.shape[0]):
            step[:] = [ep, 0]
            self.collector.collect_episodes(policy, sink=sink)
        return last

    def close(self) -> None:
        self.collector.close()


def bench_collection(
    adapter_name: str,
    episodes: int = 2,
    episode_length: int | None = None,
    backends: Sequence[str] = ("sync", "subproc-batched", "inline-batched", "gym-async"),
    num_workers: int | None = None,
    seed: int = 0,
    repeats: int = 1,
) -> dict[str, Any]:
    """Env steps/s of each collection backend and of the plain loop over all tasks of an adapter.

    Each repeat runs `episodes` episodes on the plain loop and then on every backend, all built
    once (start-up is reported, not timed); the best repeat of each counts, so a burst of load
    from other processes hits one side's single run rather than the ratio. Speedup = backend
    steps/s / plain steps/s; `speedup` is that of the backend `auto` picks. Raises
    AssertionError if a backend ends any repeat on other observations than the plain loop.
    """
    from seal.envs import make_adapter
    from seal.learner.env_backends import auto_backend

    adapter = make_adapter(
        adapter_name, episode_length=episode_length
    )  # all tasks: MT10, the 10 kitchens
    n, length = len(adapter.tasks), adapter.episode_length
    space = adapter.action_space
    actions = (
        np.random.default_rng(seed)
        .uniform(space.low, space.high, (episodes, length, n, *space.shape))
        .astype(space.dtype)
    )
    steps = episodes * length * n
    loops: dict[str, Any] = {"plain": _PlainLoop(adapter, adapter_name, seed)}
    try:
        for backend in backends:
            loops[backend] = _CollectorLoop(adapter, adapter_name, seed, backend, num_workers)
        best = {name: math.inf for name in loops}
        for _ in range(repeats):
            finals = {}
            for name, loop in loops.items():
                start = time.perf_counter()
                finals[name] = loop.run(actions)
                best[name] = min(best[name], time.perf_counter() - start)
            for name in backends:
                for task, a, b in zip(adapter.tasks, finals["plain"], finals[name], strict=True):
                    if not np.array_equal(a, b):
                        raise AssertionError(
                            f"collection backend {name!r} ended task {task!r} on other observations than the plain loop"
                        )
    finally:
        for loop in loops.values():
            loop.close()
    result: dict[str, Any] = {
        "tasks": n,
        "episodes": episodes,
        "episode_length": length,
        "env_steps": steps,
        "repeats": repeats,
        "plain_steps_per_s": steps / best["plain"],
        "backends": {},
    }
    for name in backends:
        result["backends"][name] = {
            "steps_per_s": steps / best[name],
            "speedup": best["plain"] / best[name],
            "startup_s": loops[name].startup_s,
            "same_final_obs": True,
        }
    result["auto_backend"] = auto_backend({adapter_name: adapter}, seed, num_workers)
    chosen = result["backends"].get(result["auto_backend"])
    result["speedup"] = chosen["speedup"] if chosen else None
    return result
