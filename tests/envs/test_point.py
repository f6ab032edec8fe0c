"""The `point` adapter: hand-computed rewards, success radius, truncation, seeding, difficulty."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import gymnasium as gym
import numpy as np
import pytest

from seal.envs import ObsLayout, make_adapter
from seal.envs.point import PointAdapter, PointEnv


def _env_at(adapter: PointAdapter, task: str, pos: tuple[float, float]) -> PointEnv:
    env = adapter.make(task, seed=0)
    env.reset(seed=0)
    env.unwrapped.pos = np.array(pos, dtype=np.float64)
    return env


def test_reward_and_success_at_known_positions(point_adapter: PointAdapter) -> None:
    # east goal (1, 0). From (0.5, 0) the action (1, 0) moves 0.1 to (0.6, 0): distance 0.4.
    env = _env_at(point_adapter, "east", (0.5, 0.0))
    obs, reward, terminated, truncated, info = env.step(np.array([1.0, 0.0]))
    assert reward == pytest.approx(-0.4)
    assert info["success"] == 0.0
    np.testing.assert_allclose(obs, [0.6, 0.0, 0.1, 0.0])  # position, then velocity (displacement)
    assert (terminated, truncated) == (False, False)
    # From (0.85, 0) to (0.95, 0): distance 0.05 <= 0.1, a success.
    env = _env_at(point_adapter, "east", (0.85, 0.0))
    _, reward, _, _, info = env.step(np.array([1.0, 0.0]))
    assert reward == pytest.approx(-0.05)
    assert info["success"] == 1.0
    # Exactly on the radius counts: (0.8, 0) + (0.1, 0) = (0.9, 0), distance 0.1.
    env = _env_at(point_adapter, "east", (0.8, 0.0))
    _, reward, _, _, info = env.step(np.array([1.0, 0.0]))
    assert reward == pytest.approx(-0.1)
    assert info["success"] == 1.0


def test_actions_are_clipped_and_arena_bounded(point_adapter: PointAdapter) -> None:
    # north goal (0, 1). Action (5, -5) clips to (1, -1): (0, 0) -> (0.1, -0.1);
    # distance to (0, 1) = sqrt(0.1^2 + 1.1^2) = sqrt(1.22) = 1.104536...
    env = _env_at(point_adapter, "north", (0.0, 0.0))
    obs, reward, _, _, _ = env.step(np.array([5.0, -5.0]))
    np.testing.assert_allclose(obs[:2], [0.1, -0.1])
    assert reward == pytest.approx(-1.1045361017)
    # The arena ends at 1.5: (1.45, 0) + (0.1, 0) clips to (1.5, 0), velocity 0.05.
    env = _env_at(point_adapter, "north", (1.45, 0.0))
    obs, _, _, _, _ = env.step(np.array([1.0, 0.0]))
    np.testing.assert_allclose(obs, [1.5, 0.0, 0.05, 0.0])
    # Round-off: (0.2 + 0.1) - 0.2 = 0.10000000000000003 must still lie inside the space.
    env = _env_at(point_adapter, "north", (0.2, 0.2))
    obs, _, _, _, _ = env.step(np.array([1.0, 1.0]))
    assert obs[2] > 0.1 and env.observation_space.contains(obs)


def test_episode_truncates_at_its_length() -> None:
    env = PointAdapter(episode_length=3).make("west", seed=1)
    env.reset()
    flags = [env.step(np.zeros(2))[2:4] for _ in range(3)]
    assert flags == [(False, False), (False, False), (False, True)]


def test_goals_lie_on_the_unit_circle_one_per_task(point_adapter: PointAdapter) -> None:
    goals = {
        task: tuple(point_adapter.make(task, 0).unwrapped.goal) for task in point_adapter.tasks
    }
    assert goals == {
        "east": (1.0, 0.0),
        "north": (0.0, 1.0),
        "west": (-1.0, 0.0),
        "south": (0.0, -1.0),
    }


def test_observation_does_not_reveal_the_task(point_adapter: PointAdapter) -> None:
    # Same seed and actions give the same observations whatever the goal: only the one-hot task
    # id can tell a policy which way to go.
    actions = np.random.default_rng(0).uniform(-1, 1, size=(20, 2))
    trajectories = []
    for task in point_adapter.tasks:
        env = point_adapter.make(task, seed=7)
        obs = [env.reset()[0]] + [env.step(a)[0] for a in actions]
        trajectories.append(np.stack(obs))
    for other in trajectories[1:]:
        np.testing.assert_array_equal(trajectories[0], other)
    assert point_adapter.obs_layout == ObsLayout(robot=(0, 1, 2, 3), objects=(), goal=())


def test_seeding(point_adapter: PointAdapter) -> None:
    first = point_adapter.make("east", seed=3).reset()[0]
    again = point_adapter.make("east", seed=3).reset()[0]
    other = point_adapter.make("east", seed=4).reset()[0]
    np.testing.assert_array_equal(first, again)
    assert not np.array_equal(first, other)
    # Starts lie in [-0.1, 0.1]^2 with zero velocity.
    assert np.all(np.abs(first[:2]) <= 0.1) and np.all(first[2:] == 0.0)


def _episode_success(env: gym.Env, policy) -> float:  # noqa: ANN001
    obs, _ = env.reset()
    success = 0.0
    for _ in range(50):
        obs, _, _, _, info = env.step(policy(env, obs))
        success = max(success, info["success"])
    return success


def test_random_actions_rarely_succeed_but_steering_always_does(
    point_adapter: PointAdapter,
) -> None:
    # Random walk: per-axis step std 0.1/sqrt(3) = 0.058, after 50 steps ~0.41, against a goal
    # 1.0 away and a 0.1 radius: measured ~1%; the issue allows at most 20%.
    rng = np.random.default_rng(0)
    random_policy = lambda env, obs: rng.uniform(-1, 1, size=2)  # noqa: E731
    steer = lambda env, obs: np.clip((env.unwrapped.goal - obs[:2]) / 0.1, -1, 1)  # noqa: E731
    random_rate, steer_rate = [], []
    for i, task in enumerate(point_adapter.tasks):
        env = point_adapter.make(task, seed=100 + i)
        random_rate += [_episode_success(env, random_policy) for _ in range(250)]
        steer_rate += [_episode_success(env, steer) for _ in range(5)]
    assert np.mean(random_rate) <= 0.2
    assert np.mean(steer_rate) == 1.0


def test_semantic_check_passes_on_every_task(point_adapter: PointAdapter) -> None:
    for task in point_adapter.tasks:
        result = point_adapter.semantic_check(task)
        assert (
            result["ok"] and result["success_at_reset"] == 0.0 and result["scripted_success"] == 1.0
        )
        # Start within 0.1*sqrt(2) of the origin: distance to the goal in [0.86, 1.15].
        assert -1.15 <= result["reward_at_reset"] <= -0.85
        assert result["reward_at_goal"] >= -0.1


class ThirdPartyPoint(PointAdapter):
    """A 'third-party' adapter defined outside seal: two of the point tasks, 20-step episodes."""

    name = "third_party_point"
    all_tasks = ("east", "west")
    default_episode_length = 20


def test_third_party_adapter_by_import_path() -> None:
    adapter = make_adapter(f"{__name__}:ThirdPartyPoint")
    assert isinstance(adapter, ThirdPartyPoint)
    assert adapter.tasks == ("east", "west") and adapter.episode_length == 20
    assert adapter.describe() == {
        "tasks": ["east", "west"],
        "obs_dim": 4,
        "act_dim": 2,
        "episode_length": 20,
    }


def test_third_party_module_through_the_cli(tmp_path) -> None:  # noqa: ANN001
    # A module seal has never seen, on PYTHONPATH only: `seal envs check module:Class` checks it.
    (tmp_path / "my_envs.py").write_text(
        textwrap.dedent(
            """
            import gymnasium as gym
            import numpy as np
            from seal.envs import EnvAdapter, ObsLayout
            from seal.envs.point import PointEnv

            class Corridor(EnvAdapter):
                name = "corridor"
                all_tasks = ("far-east",)
                default_episode_length = 60

                observation_space = property(lambda self: PointEnv((1, 0), 1, 0).observation_space)
                action_space = property(lambda self: gym.spaces.Box(-1.0, 1.0, (2,), np.float32))
                obs_layout = property(lambda self: ObsLayout((0, 1, 2, 3), (), ()))

                def make(self, task, seed):
                    return PointEnv((1.4, 0.0), self.episode_length, seed)
            """
        )
    )
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    done = subprocess.run(
        [sys.executable, "-m", "seal.cli.main", "envs", "check", "my_envs:Corridor", "--json"],
        capture_output=True,
        text=True,
        env=env,
    )
    assert done.returncode == 0, done.stderr
    assert '"adapter": "corridor"' in done.stdout and '"far-east"' in done.stdout


def test_unknown_task_names_the_valid_ones(point_adapter: PointAdapter) -> None:
    from seal.errors import UnknownNameError

    with pytest.raises(
        UnknownNameError, match=r"unknown point task 'up'; valid: east, north, west, south"
    ):
        PointAdapter(tasks=["up"])
    with pytest.raises(UnknownNameError, match="'up'"):
        point_adapter.make("up", 0)
