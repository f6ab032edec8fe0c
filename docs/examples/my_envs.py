"""A complete environment adapter: a gripper on a rail pushes a block to one of two goals.

The worked example of docs/adapters.md, run by tests/docs/test_adapter_example.py (`seal envs
check` and a short `seal run`). Name it by import path, "my_envs:RailAdapter", with this folder
on PYTHONPATH.
"""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium as gym
import numpy as np

from seal.envs import EnvAdapter, ObsLayout

GOALS = {"push-left": -0.5, "push-right": 0.5}  # where each task wants the block
STEP = 0.05  # an action of 1 moves the gripper this far


class RailEnv(gym.Env):
    """obs = [gripper, block, goal]; the gripper pushes the block when it reaches it."""

    def __init__(self, goal: float, episode_length: int, seed: int) -> None:
        self.goal, self.episode_length = goal, episode_length
        self.observation_space = gym.spaces.Box(-1.0, 1.0, (3,), np.float64)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.np_random, _ = gym.utils.seeding.np_random(seed)
        self.action_space.seed(seed)
        self.gripper = self.block = 0.0
        self.t = 0

    def _obs(self) -> np.ndarray:
        return np.array([self.gripper, self.block, self.goal])

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        if seed is not None:  # None continues the generator seeded at make
            self.np_random, _ = gym.utils.seeding.np_random(seed)
        self.gripper = float(self.np_random.uniform(-0.1, 0.1))
        self.block = float(self.np_random.uniform(-0.05, 0.05)) + np.sign(self.goal) * 0.2
        self.t = 0
        return self._obs(), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        move = STEP * float(np.clip(action[0], -1.0, 1.0))
        self.gripper = float(np.clip(self.gripper + move, -1.0, 1.0))
        # The gripper pushes the block ahead of it in the direction of the goal.
        if np.sign(self.goal) * (self.gripper - self.block) > 0:
            self.block = self.gripper
        self.t += 1
        distance = abs(self.block - self.goal)
        reward = -abs(self.gripper - self.block) - distance
        info = {"success": float(distance < 0.05)}  # 0.0 or 1.0 at every step
        return self._obs(), reward, False, self.t >= self.episode_length, info


class RailAdapter(EnvAdapter):
    """Two pushing tasks on a rail; 40-step episodes."""

    name: ClassVar[str] = "rail"
    all_tasks: ClassVar[tuple[str, ...]] = tuple(GOALS)
    default_episode_length: ClassVar[int] = 40

    @property
    def observation_space(self) -> gym.spaces.Box:
        return gym.spaces.Box(-1.0, 1.0, (3,), np.float64)

    @property
    def action_space(self) -> gym.spaces.Box:
        return gym.spaces.Box(-1.0, 1.0, (1,), np.float32)

    @property
    def obs_layout(self) -> ObsLayout:
        # Which entries are robot state, object state and goal (pad-and-fine-tune aligns by it).
        return ObsLayout(robot=(0,), objects=(1,), goal=(2,))

    def make(self, task: str, seed: int) -> gym.Env:
        return RailEnv(GOALS[task], self.episode_length, seed)

    def expert(self, task: str):  # noqa: ANN201 - optional: enables training.demo_episodes
        goal = GOALS[task]
        return lambda obs: np.array([np.sign(goal - obs[0])], dtype=np.float32)
