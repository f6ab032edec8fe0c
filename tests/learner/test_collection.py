"""Collector: episode bookkeeping, termination vs truncation, batched inference, backends agree."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from seal.envs.base import EnvAdapter, ObsLayout
from seal.errors import SealError, UnknownNameError
from seal.learner import env_backends
from seal.learner.collection import Collector
from seal.learner.env_backends import instance_seed
from tests.waiting import wait_until

# Per task: the step at which info["success"] is 1 (only that step), and the step that terminates.
SUCCESS_AT = {"a": 2, "b": None, "c": 4, "stop": None}
TERMINATE_AT = {"stop": 3}


class ToyEnv(gym.Env):
    """1-D point: x += action, reward = new x, obs = [x, t, seeded noise drawn every reset/step]."""

    def __init__(self, task: str, episode_length: int, seed: int) -> None:
        self.task, self.episode_length = task, episode_length
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (3,), np.float64)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.x, self.t = 0.0, 0
        super().reset(seed=seed)

    def _obs(self) -> np.ndarray:
        return np.array([self.x, self.t, self.np_random.normal()])

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self.x, self.t = 0.0, 0
        return self._obs(), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        self.t += 1
        self.x += float(action[0])
        terminated = TERMINATE_AT.get(self.task) == self.t
        truncated = self.t >= self.episode_length
        return (
            self._obs(),
            self.x,
            terminated,
            truncated,
            {"success": float(SUCCESS_AT[self.task] == self.t)},
        )


class ToyAdapter(EnvAdapter):
    """Stand-in adapter: three tasks, 4-step episodes."""

    name = "toy"
    all_tasks = ("a", "b", "c")
    default_episode_length = 4

    @property
    def observation_space(self) -> gym.spaces.Box:
        return gym.spaces.Box(-np.inf, np.inf, (3,), np.float64)

    @property
    def action_space(self) -> gym.spaces.Box:
        return gym.spaces.Box(-1.0, 1.0, (1,), np.float32)

    @property
    def obs_layout(self) -> ObsLayout:
        return ObsLayout((0,), (), (1,))

    def make(self, task: str, seed: int) -> gym.Env:
        return ToyEnv(task, self.episode_length, seed)


class Toy2Adapter(ToyAdapter):
    """A second environment with 6-step episodes; task "stop" terminates at step 3."""

    name = "toy2"
    all_tasks = ("a", "stop")
    default_episode_length = 6


def half_policy(calls: list[tuple[str, int]]):
    def policy(env: str, obs: np.ndarray, task_ids: np.ndarray) -> np.ndarray:
        calls.append((env, len(task_ids)))
        return np.full((len(obs), 1), 0.5, dtype=np.float32)

    return policy


def adapters() -> dict[str, EnvAdapter]:
    return {"toy": ToyAdapter(), "toy2": Toy2Adapter()}


def test_returns_success_lengths_and_step_counters_are_hand_computed() -> None:
    calls: list[tuple[str, int]] = []
    with Collector(adapters(), seed=0, backend="sync") as col:
        stats = col.collect_episodes(half_policy(calls))
        # x after each step is 0.5, 1.0, 1.5, 2.0 (toy, 4 steps): return 5.0 for every task.
        np.testing.assert_allclose(stats.returns["toy"], [5.0, 5.0, 5.0])
        # toy2 "a": 0.5+1+...+3.0 = 10.5 over 6 steps; "stop" terminates at 3: 0.5+1+1.5 = 3.0.
        np.testing.assert_allclose(stats.returns["toy2"], [10.5, 3.0])
        np.testing.assert_array_equal(stats.lengths["toy2"], [6, 3])
        # Success only at step 2 ("a") or 4 ("c") still counts for the episode; "b" never succeeds.
        np.testing.assert_array_equal(stats.successes["toy"], [True, False, True])
        assert stats.env_steps == 4 * 3 + 6 + 3
        assert stats.per_task()[("toy2", "stop")] == {"return": 3.0, "success": 0.0, "length": 3.0}
        col.collect_episodes(half_policy(calls))
        np.testing.assert_array_equal(col.env_steps["toy"], [8, 8, 8])
        np.testing.assert_array_equal(col.env_steps["toy2"], [12, 6])
        assert col.total_env_steps == 2 * 21
    # One policy call per environment per step, batched over its running instances:
    # toy 4 steps x 3 tasks; toy2 3 steps with both tasks, then 3 with "a" only.
    first = calls[: len(calls) // 2]
    assert sorted(n for e, n in first if e == "toy") == [3, 3, 3, 3]
    assert [n for e, n in first if e == "toy2"] == [2, 2, 2, 1, 1, 1]


def test_sink_stores_termination_not_truncation() -> None:
    rows: list[tuple] = []

    def sink(env, task_ids, obs, actions, rewards, next_obs, terminations) -> None:
        rows.append(
            (
                env,
                task_ids.copy(),
                obs.copy(),
                actions.copy(),
                rewards.copy(),
                next_obs.copy(),
                terminations.copy(),
            )
        )

    with Collector({"toy2": Toy2Adapter()}, seed=3, backend="sync") as col:
        col.collect_episodes(half_policy([]), sink=sink)
    assert len(rows) == 6
    # Step 3: "stop" (task id 1) terminated -> True; "a" keeps running -> False.
    np.testing.assert_array_equal(rows[2][1], [0, 1])
    np.testing.assert_array_equal(rows[2][6], [False, True])
    # Step 6: "a" is truncated at the episode length -> stored as not terminated (bootstrap).
    np.testing.assert_array_equal(rows[5][1], [0])
    np.testing.assert_array_equal(rows[5][6], [False])
    # next_obs of one step is the obs of the next; x after step 6 is 3.0 and t is 6.
    np.testing.assert_array_equal(rows[3][5][0], rows[4][2][0])
    np.testing.assert_allclose(rows[5][5][0][:2], [3.0, 6.0])


def transitions(
    backend: str, seed: int, envs: dict[str, EnvAdapter], episodes: int = 2
) -> list[np.ndarray]:
    out: list[np.ndarray] = []

    def sink(env, task_ids, obs, actions, rewards, next_obs, terminations) -> None:
        out.extend([task_ids, obs, actions, rewards, next_obs, terminations])

    with Collector(envs, seed=seed, backend=backend, num_workers=2) as col:
        for _ in range(episodes):  # the second episode continues each env's RNG stream
            col.collect_episodes(None, random_actions=True, sink=sink)
    return out


@pytest.mark.parametrize("backend", ["subproc-batched", "inline-batched", "gym-async"])
def test_backends_give_identical_transitions(backend: str) -> None:
    envs: dict[str, EnvAdapter] = {"toy": ToyAdapter(), "toy2": Toy2Adapter(tasks=["a"])}
    reference = transitions("sync", 7, envs)
    other = transitions(backend, 7, envs)
    assert len(reference) == len(other) == 6 * (4 + 6) * 2
    for ref, got in zip(reference, other, strict=True):
        np.testing.assert_array_equal(ref, got)
    different = transitions("sync", 8, envs)
    assert not np.array_equal(reference[1], different[1])  # another seed: other noise in obs


@pytest.mark.parametrize("backend", ["subproc-batched", "inline-batched"])
def test_batched_backends_handle_early_termination_like_sync(backend: str) -> None:
    ref = transitions("sync", 1, {"toy2": Toy2Adapter()}, episodes=1)
    got = transitions(backend, 1, {"toy2": Toy2Adapter()}, episodes=1)
    for a, b in zip(ref, got, strict=True):
        np.testing.assert_array_equal(a, b)


def test_batched_backends_deal_instances_round_robin_over_all_environments() -> None:
    """Shares are dealt over all instances, so two envs of one task each (the quickstart) step in
    two processes, not one, and unequal environments spread evenly; transitions do not change."""
    single = {"toy": ToyAdapter(tasks=["a"]), "toy2": Toy2Adapter(tasks=["a"])}
    with Collector(single, seed=3, backend="inline-batched", num_workers=2) as col:
        backend = col._backend
        assert isinstance(backend, env_backends._SubprocBatchedBackend)
        assert [proc is None for proc in backend.procs] == [True, False]  # main + one worker
        assert {e: o.tolist() for e, o in backend._owner.items()} == {"toy": [0], "toy2": [1]}
    uneven = adapters()  # 3 + 2 instances: instance k of the 5 lives in share k % 2
    with Collector(uneven, seed=3, backend="subproc-batched", num_workers=2) as col:
        backend = col._backend
        assert isinstance(backend, env_backends._SubprocBatchedBackend)
        assert {e: o.tolist() for e, o in backend._owner.items()} == {
            "toy": [0, 1, 0],
            "toy2": [1, 0],
        }
        assert {e: i.tolist() for e, i in backend._local.items()} == {
            "toy": [0, 0, 1],
            "toy2": [0, 0],
        }
    for envs in (single, uneven):
        for ref, got in zip(
            transitions("sync", 3, envs), transitions("inline-batched", 3, envs), strict=True
        ):
            np.testing.assert_array_equal(ref, got)


def test_instance_seeds_differ_by_task_and_do_not_depend_on_the_subset() -> None:
    assert instance_seed(0, "toy", "a") != instance_seed(0, "toy", "b")
    assert instance_seed(0, "toy", "a") != instance_seed(0, "toy2", "a")
    full = transitions("sync", 5, {"toy": ToyAdapter()}, episodes=1)
    only_c = transitions("sync", 5, {"toy": ToyAdapter(tasks=["c"])}, episodes=1)
    # full[1] is the first step's obs for tasks (a, b, c); the subset's is task c alone.
    np.testing.assert_array_equal(full[1][2], only_c[1][0])


def test_active_mask_steps_only_active_tasks() -> None:
    with Collector(adapters(), seed=0, backend="sync") as col:
        stats = col.collect_episodes(
            half_policy([]), active={"toy": [False, True, False], "toy2": [False, False]}
        )
        np.testing.assert_array_equal(col.env_steps["toy"], [0, 4, 0])
        np.testing.assert_array_equal(col.env_steps["toy2"], [0, 0])
        assert list(stats.per_task()) == [("toy", "b")]
        with pytest.raises(SealError, match="expected \\(3,\\)"):
            col.collect_episodes(half_policy([]), active={"toy": [True]})
        with pytest.raises(UnknownNameError, match="nope"):
            col.collect_episodes(half_policy([]), active={"nope": [True]})


def test_evaluate_reports_success_rate_per_task() -> None:
    with Collector({"toy": ToyAdapter()}, seed=100, backend="sync") as col:
        result = col.evaluate(half_policy([]), episodes=3)
    assert result["toy"]["a"]["success_rate"] == 1.0
    assert result["toy"]["b"]["success_rate"] == 0.0
    assert result["toy"]["c"]["mean_return"] == 5.0


def noise_policy(starts: list[tuple[str, int, float]]):
    """Acts on the seeded noise of each observation; records (env, task id, noise) at t = 0."""

    def policy(env: str, obs: np.ndarray, task_ids: np.ndarray) -> np.ndarray:
        for o, tid in zip(obs, task_ids, strict=True):
            if o[1] == 0:
                starts.append((env, int(tid), float(o[2])))
        return np.clip(obs[:, 2:3], -1.0, 1.0).astype(np.float32)

    return policy


@pytest.mark.parametrize(
    ("backend", "replicas", "workers"),
    [("sync", 1, 1), ("sync", 2, 1), ("inline-batched", 3, 2), ("subproc-batched", 5, 2)],
)
def test_evaluate_with_replicas_runs_exactly_the_episodes_with_seeds_of_their_own(
    backend: str, replicas: int, workers: int
) -> None:
    episodes = 5  # 2 replicas: rounds of 2, 2, 1; 3 replicas: 3, 2
    results, starts = [], []
    for _ in range(2):
        seen: list[tuple[str, int, float]] = []
        with Collector(
            {"toy": ToyAdapter()},
            seed=7,
            backend=backend,
            num_workers=workers,
            replicas=replicas,
        ) as col:
            results.append(col.evaluate(noise_policy(seen), episodes=episodes, draw=3))
            # Exactly `episodes` episodes of every task (4 steps each), none more.
            np.testing.assert_array_equal(col.env_steps["toy"], [episodes * 4] * 3)
        starts.append(seen)
    assert results[0] == results[1]  # same seed: bitwise identical numbers
    assert starts[0] == starts[1]
    for tid in range(3):
        firsts = {noise for _, t, noise in starts[0] if t == tid}
        assert len(firsts) == episodes  # every episode of a task started from its own seed
    with Collector({"toy": ToyAdapter()}, seed=7, backend="sync") as col:
        # ... and the numbers do not depend on the backend or the replica count
        assert col.evaluate(noise_policy([]), episodes=episodes, draw=3) == results[0]
        assert col.evaluate(noise_policy([]), episodes=episodes, draw=4) != results[0]


def test_evaluate_with_replicas_keeps_the_active_mask() -> None:
    with Collector(adapters(), seed=1, backend="sync", replicas=2) as col:
        result = col.evaluate(
            half_policy([]), episodes=3, active={"toy": [False, True, True], "toy2": [0, 0]}
        )
        assert set(result) == {"toy"} and set(result["toy"]) == {"b", "c"}
        assert result["toy"]["c"] == {"success_rate": 1.0, "mean_return": 5.0, "episodes": 3.0}
        np.testing.assert_array_equal(col.env_steps["toy"], [0, 12, 12])
        np.testing.assert_array_equal(col.env_steps["toy2"], [0, 0])
        # collect_episodes still runs one episode per task (on replica 0)
        stats = col.collect_episodes(half_policy([]))
        assert stats.env_steps == 3 * 4 + 6 + 3


def test_evaluation_replicas_bound_the_instances() -> None:
    from seal.learner.collection import evaluation_replicas

    assert evaluation_replicas(10, tasks=2, workers=2) == 4  # quickstart: rounds of 4, 4, 2
    assert evaluation_replicas(10, tasks=10, workers=2) == 1  # MT10 on 2 cores: 10 are enough
    assert evaluation_replicas(50, tasks=10, workers=16) * 10 <= 64  # MT10 on 16 cores
    assert evaluation_replicas(2, tasks=1, workers=16) == 2  # never more than the episodes
    assert evaluation_replicas(1, tasks=100, workers=1) == 1


def test_user_errors_name_the_bad_value() -> None:
    with pytest.raises(UnknownNameError, match="'threads'.*sync"):
        Collector(adapters(), seed=0, backend="threads")
    with pytest.raises(UnknownNameError, match="'z'"):
        Collector(adapters(), seed=0, tasks={"toy": ["z"]})
    with (
        Collector(adapters(), seed=0, backend="sync") as col,
        pytest.raises(SealError, match="needs a policy"),
    ):
        col.collect_episodes(None)


class BrokenAdapter(ToyAdapter):
    """An env whose step raises: the worker's traceback must reach the caller."""

    name = "broken"

    def make(self, task: str, seed: int) -> gym.Env:
        env = ToyEnv(task, self.episode_length, seed)

        def step(action: np.ndarray) -> tuple:
            raise ValueError("physics exploded in " + task)

        env.step = step  # type: ignore[method-assign]
        return env


def test_worker_errors_reach_the_caller() -> None:
    with (
        Collector(
            {"broken": BrokenAdapter()}, seed=0, backend="subproc-batched", num_workers=2
        ) as col,
        pytest.raises(RuntimeError, match="physics exploded in a"),
    ):
        col.collect_episodes(None, random_actions=True)


def test_gym_async_refuses_partial_masks() -> None:
    with (
        Collector({"toy": ToyAdapter()}, seed=0, backend="gym-async") as col,
        pytest.raises(SealError, match="all instances of environment 'toy'"),
    ):
        col.collect_episodes(None, random_actions=True, active={"toy": [True, False, True]})


def test_auto_chooses_from_what_splitting_a_step_saves(monkeypatch: pytest.MonkeyPatch) -> None:
    # The measurement is injected, so the choice does not depend on this machine's speed. The
    # toy envs have 3 + 2 tasks, dealt over 2 shares as toy [0, 1, 0], toy2 [1, 0]; each env's
    # probe prices all its instances. 100 us each: shares 300 + 200 us, the split saves 200 us.
    assert env_backends.AUTO_PARALLEL_MIN_SAVING_S == 1e-3
    monkeypatch.setattr(env_backends, "_probe_step_seconds", lambda instance, steps=10: 1e-4)
    with Collector(adapters(), seed=0, backend="auto", num_workers=2) as col:
        assert col.backend_name == "sync"
        assert col.step_cost_s == pytest.approx(5 * 1e-4)
    # 1 ms each: shares 3 + 2 ms, the split saves 2 ms -> the main process steps one share.
    monkeypatch.setattr(env_backends, "_probe_step_seconds", lambda instance, steps=10: 1e-3)
    with Collector(adapters(), seed=0, backend="auto", num_workers=2) as col:
        assert col.backend_name == "inline-batched"
        assert col.step_cost_s == pytest.approx(5 * 1e-3)
    # The quickstart's shape: one costly env (4 ms) and one cheap (0.5 ms), one task each. The
    # whole step costs 4.5 ms, but the split saves only the cheap 0.5 ms: one process.
    pair = {"toy": ToyAdapter(tasks=["a"]), "toy2": Toy2Adapter(tasks=["a"])}
    costs = {"toy": 4e-3, "toy2": 5e-4}
    monkeypatch.setattr(
        env_backends, "_probe_step_seconds", lambda instance, steps=10: costs[instance.env]
    )
    with Collector(pair, seed=0, backend="auto", num_workers=2) as col:
        assert col.backend_name == "sync"
        assert col.step_cost_s == pytest.approx(4.5e-3)
    # One worker: never parallel, and nothing is probed.
    with Collector(adapters(), seed=0, backend="auto", num_workers=1) as col:
        assert col.backend_name == "sync" and col.step_cost_s is None
    assert env_backends.choose_backend(0.999e-3) == "sync"
    assert env_backends.choose_backend(1e-3) == "inline-batched"


HOLDER = """
import signal
from seal.envs.registry import make_adapter
from seal.learner.collection import Collector

col = Collector({"pt": make_adapter("point")}, seed=0, backend="subproc-batched", num_workers=2)
print(" ".join(str(p.pid) for p in col._backend.procs if p is not None), flush=True)
while True:  # until the test kills it, however long the test takes to get there
    signal.pause()
"""


def test_a_killed_collector_leaves_no_worker_behind() -> None:
    """kill -9 of the process that holds a Collector: its env workers die with it (PDEATHSIG),
    where they would otherwise wait on their pipes for ever (the daemonic workers' cleanup runs
    only at a normal exit, never at a kill)."""
    import os
    import signal
    import subprocess
    import sys

    holder = subprocess.Popen([sys.executable, "-c", HOLDER], stdout=subprocess.PIPE, text=True)
    try:
        pids = [int(p) for p in holder.stdout.readline().split()]  # type: ignore[union-attr]
        assert pids, "no worker process started"
        for pid in pids:
            os.kill(pid, 0)  # alive
        holder.send_signal(signal.SIGKILL)
        holder.wait()
        # Waits for the event, not for a duration: a worker that outlives its parent is a hang.
        alive = list(pids)

        def all_ended() -> bool:
            alive[:] = [p for p in alive if _running(p)]  # a pid seen dead is not asked again
            return not alive

        wait_until(all_ended, "every worker ended", poll_s=0.1)
    finally:
        holder.kill()


def _running(pid: int) -> bool:
    """Whether `pid` is a live process (a zombie, dead and not yet reaped by init, is not)."""
    import os

    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False
    except OSError:
        return os.path.exists(f"/proc/{pid}")
