"""A second point-mass adapter with other obs and action sizes, for pad-and-fine-tune tests.

`point_wide` wraps the `point` env: its observation has one extra constant feature (5 floats)
and its action one extra ignored entry (3 floats), so aligning it with `point` needs padding of
both the state block and the action, as Meta-World <-> kitchen does.
"""

from __future__ import annotations

from typing import ClassVar

import gymnasium as gym
import numpy as np

from seal.envs.base import ObsLayout
from seal.envs.point import GOALS, PointAdapter, PointEnv


class _Wide(gym.Wrapper):
    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        low, high = env.observation_space.low, env.observation_space.high
        self.observation_space = gym.spaces.Box(
            np.append(low, 0.0), np.append(high, 1.0), dtype=np.float64
        )
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(3,), dtype=np.float32)

    def reset(self, **kwargs):  # noqa: ANN003, ANN201
        obs, info = self.env.reset(**kwargs)
        return np.append(obs, 1.0), info

    def step(self, action):  # noqa: ANN001, ANN201
        obs, reward, terminated, truncated, info = self.env.step(np.asarray(action)[:2])
        return np.append(obs, 1.0), reward, terminated, truncated, info


class PointWideAdapter(PointAdapter):
    """The point tasks with a 5-float observation and a 3-float action (last entry ignored)."""

    name: ClassVar[str] = "point_wide"

    @property
    def observation_space(self) -> gym.spaces.Box:
        return _Wide(PointEnv(GOALS["east"], self.episode_length, 0)).observation_space

    @property
    def action_space(self) -> gym.spaces.Box:
        return gym.spaces.Box(-1.0, 1.0, shape=(3,), dtype=np.float32)

    @property
    def obs_layout(self) -> ObsLayout:
        return ObsLayout(robot=(0, 1, 2, 3, 4), objects=(), goal=())

    def make(self, task: str, seed: int) -> gym.Env:
        return _Wide(super().make(task, seed))
