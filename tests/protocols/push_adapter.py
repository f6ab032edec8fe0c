"""`push`: a test env that SAC learns in a few hundred updates, with success rates in between.

Each step shows a fresh random 2-D observation; the reward is the action's component along the
task's direction, and a step succeeds when that component beats a bar that the observation
raises or lowers. An untrained deterministic policy succeeds in some episodes and not in others,
so evaluations go both ways and tasks cross 90% within a few epochs: what the early-decision
tests (tests/protocols/test_decide_early.py) need of a protocol run.
"""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium as gym
import numpy as np

from seal.envs.base import EnvAdapter, ObsLayout

DIRECTIONS = {"east": (1.0, 0.0), "north": (0.0, 1.0)}


class PushEnv(gym.Env):
    """reward = a . d; success when a . d > 0.3 + 0.5 obs[0] (obs uniform in [-1, 1]^2 each step)."""

    def __init__(self, direction: tuple[float, float], episode_length: int, seed: int) -> None:
        self.direction = np.asarray(direction)
        self.episode_length = episode_length
        self.observation_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float64)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.t = 0
        super().reset(seed=seed)
        self.obs = self.np_random.uniform(-1.0, 1.0, 2)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self.t = 0
        self.obs = self.np_random.uniform(-1.0, 1.0, 2)
        return self.obs.copy(), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        push = float(np.clip(action, -1.0, 1.0) @ self.direction)
        success = float(push > 0.3 + 0.5 * self.obs[0])
        self.t += 1
        self.obs = self.np_random.uniform(-1.0, 1.0, 2)
        return self.obs.copy(), push, False, self.t >= self.episode_length, {"success": success}


class PushAdapter(EnvAdapter):
    """Two tasks, "east" and "north"; 3-step episodes."""

    name: ClassVar[str] = "push"
    all_tasks: ClassVar[tuple[str, ...]] = tuple(DIRECTIONS)
    default_episode_length: ClassVar[int] = 3

    @property
    def observation_space(self) -> gym.spaces.Box:
        return gym.spaces.Box(-1.0, 1.0, (2,), np.float64)

    @property
    def action_space(self) -> gym.spaces.Box:
        return gym.spaces.Box(-1.0, 1.0, (2,), np.float32)

    @property
    def obs_layout(self) -> ObsLayout:
        return ObsLayout(robot=(0, 1), objects=(), goal=())

    def make(self, task: str, seed: int) -> gym.Env:
        return PushEnv(DIRECTIONS[task], self.episode_length, seed)
