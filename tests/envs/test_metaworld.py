"""The Meta-World adapter: task names and sets, layout, seeding, episode length, scripted experts."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from seal.envs.metaworld import MetaWorldAdapter
from seal.errors import SealError, UnknownNameError

MT10 = (
    "reach-v3",
    "push-v3",
    "pick-place-v3",
    "door-open-v3",
    "drawer-open-v3",
    "drawer-close-v3",
    "button-press-topdown-v3",
    "peg-insert-side-v3",
    "window-open-v3",
    "window-close-v3",
)


def test_task_names_and_sets() -> None:
    assert MetaWorldAdapter().tasks == MT10  # no tasks: MT10, the paper's set
    assert MetaWorldAdapter(tasks="mt10").tasks == MT10
    assert MetaWorldAdapter(tasks="mt3").tasks == ("reach-v3", "push-v3", "pick-place-v3")
    assert len(MetaWorldAdapter(tasks="mt50").tasks) == 50
    assert MetaWorldAdapter(tasks=["sweep-v3", "mt3"]).tasks == (
        "sweep-v3",
        "reach-v3",
        "push-v3",
        "pick-place-v3",
    )
    with pytest.raises(
        UnknownNameError, match=r"unknown metaworld task 'reach-v2'; valid: assembly-v3"
    ):
        MetaWorldAdapter(tasks=["reach-v2"])


def test_spaces_and_layout() -> None:
    adapter = MetaWorldAdapter(tasks="mt3")
    assert (adapter.obs_dim, adapter.act_dim, adapter.episode_length) == (39, 4, 500)
    layout = adapter.obs_layout
    # hand xyz + gripper, and their previous-frame copies
    assert layout.robot == (0, 1, 2, 3, 18, 19, 20, 21)
    assert layout.objects == tuple(range(4, 18)) + tuple(range(22, 36))
    assert layout.goal == (36, 37, 38)
    assert len(layout.state) == 36


def test_observation_blocks_hold_what_the_layout_says() -> None:
    env = MetaWorldAdapter(tasks="mt3").make("pick-place-v3", seed=0)
    obs, _ = env.reset()
    raw = env.unwrapped
    np.testing.assert_allclose(obs[0:3], raw.get_endeff_pos())
    np.testing.assert_allclose(obs[4:7], raw._get_pos_objects()[:3])  # the puck
    np.testing.assert_allclose(obs[36:39], raw._target_pos)  # goal observable, not zeros
    assert np.any(obs[36:39] != 0.0)
    np.testing.assert_array_equal(obs[0:18], obs[18:36])  # at reset the previous frame is a copy
    obs2, *_ = env.step(np.array([1.0, 0.0, 0.0, 0.0], dtype=np.float32))
    np.testing.assert_allclose(obs2[18:36], obs[0:18])  # after a step: the frame before it


def test_seeding_is_reproducible_though_upstream_ignores_reset_seeds() -> None:
    adapter = MetaWorldAdapter(tasks=["reach-v3"])
    env = adapter.make("reach-v3", seed=0)
    firsts = [env.reset()[0] for _ in range(4)]
    again = adapter.make("reach-v3", seed=0)
    np.testing.assert_array_equal(np.stack(firsts), np.stack([again.reset()[0] for _ in range(4)]))
    # Goals (last 3 floats) are drawn from the 50 benchmark goals: four resets, several goals.
    assert len({tuple(o[36:39]) for o in firsts}) > 1
    # reset(seed) on a used env restarts the goal sequence.
    env.step(np.zeros(4, dtype=np.float32))
    np.testing.assert_array_equal(env.reset(seed=0)[0], firsts[0])
    other = adapter.make("reach-v3", seed=1).reset()[0]
    assert not np.array_equal(other, firsts[0])


def _goals_seen(adapter: MetaWorldAdapter, seed: int, resets: int = 25) -> set[tuple[float, ...]]:
    env = adapter.make("reach-v3", seed=seed)
    return {tuple(env.reset()[0][36:39]) for _ in range(resets)}


def test_env_seeds_share_the_benchmark_goals_and_goal_seed_changes_them() -> None:
    # 25 draws from the same 50 goals: two env seeds overlap (expected ~8 shared goals), so
    # training and evaluation collectors, seeded apart, see the same goal set.
    benchmark = MetaWorldAdapter(tasks=["reach-v3"])
    train, evaluation = _goals_seen(benchmark, seed=0), _goals_seen(benchmark, seed=12345)
    assert len(train | evaluation) <= 50 and len(train & evaluation) >= 3
    # Another goal_seed is another benchmark draw: continuous goals, no overlap.
    other = _goals_seen(MetaWorldAdapter(tasks=["reach-v3"], goal_seed=1), seed=0)
    assert not other & train


def test_success_is_a_float_and_truncation_follows_episode_length() -> None:
    env = MetaWorldAdapter(tasks=["push-v3"], episode_length=5).make("push-v3", seed=0)
    env.reset()
    steps = [env.step(np.zeros(4, dtype=np.float32)) for _ in range(5)]
    assert [s[3] for s in steps] == [False, False, False, False, True]
    assert all(type(s[4]["success"]) is float and s[4]["success"] == 0.0 for s in steps)
    assert all(type(s[1]) is float and 0.0 <= s[1] <= 10.0 for s in steps)


def test_episode_length_above_upstream_limit_is_a_clear_error() -> None:
    with pytest.raises(
        SealError, match=r"episode_length 501 exceeds upstream's max_path_length; valid: 1..500"
    ):
        MetaWorldAdapter(episode_length=501)


def test_make_is_light() -> None:
    # No TimeLimit / checker / checkpoint layers: one wrapper around the raw upstream env.
    env = MetaWorldAdapter(tasks=["reach-v3"]).make("reach-v3", seed=0)
    assert env.env is env.unwrapped
    assert isinstance(env.observation_space, gym.spaces.Box) and env.observation_space.shape == (
        39,
    )
    # The goal bounds are the task's goal space, not upstream's stale zeros.
    assert np.all(env.observation_space.high[36:39] > env.observation_space.low[36:39])


def test_scripted_expert_solves_reach() -> None:
    result = MetaWorldAdapter(tasks=["reach-v3"]).semantic_check("reach-v3", episodes=3)
    assert result["ok"] and result["scripted_success"] == 1.0 and result["episodes"] == 3


class _GoalHiddenAdapter(MetaWorldAdapter):
    """Broken on purpose: zeroes the goal in the observation, so the expert heads for the origin."""

    def make(self, task: str, seed: int) -> gym.Env:
        return gym.wrappers.TransformObservation(super().make(task, seed), _zero_goal, None)


def _zero_goal(obs: np.ndarray) -> np.ndarray:
    obs = obs.copy()
    obs[36:39] = 0.0
    return obs


def test_scripted_check_fails_when_the_goal_is_wrong() -> None:
    adapter = _GoalHiddenAdapter(tasks=["reach-v3"], episode_length=150)
    result = adapter.semantic_check("reach-v3", episodes=2)
    assert not result["ok"] and result["scripted_success"] == 0.0
