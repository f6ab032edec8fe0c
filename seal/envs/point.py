"""`point`: a 2-D point mass that must reach one of four goals, one per task. Pure numpy, fast.

It is the quick fixture for tests and the worked example of plugging an environment into SEAL:
an adapter is a subclass of `seal.envs.EnvAdapter` that names its tasks, spaces, episode length
and observation layout, and builds one seeded gymnasium env per task.

The observation ([x, y, vx, vy]) does not reveal the goal, so one policy can solve all tasks
only if it is told the task (the one-hot id): this makes the env a test of task conditioning.
"""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium as gym
import numpy as np

from seal.envs.base import EnvAdapter, ObsLayout
from seal.errors import UnknownNameError

GOAL_RADIUS = 1.0  # goals lie on a circle of this radius around the origin
SUCCESS_RADIUS = 0.1  # success: within this distance of the goal
MAX_STEP = 0.1  # an action of norm 1 per axis moves the point this far per step
START_NOISE = 0.1  # start uniformly in [-START_NOISE, START_NOISE]^2
ARENA = 1.5  # positions are clipped to [-ARENA, ARENA]^2
GOALS: dict[str, tuple[float, float]] = {
    "east": (GOAL_RADIUS, 0.0),
    "north": (0.0, GOAL_RADIUS),
    "west": (-GOAL_RADIUS, 0.0),
    "south": (0.0, -GOAL_RADIUS),
}


def _observation_space() -> gym.spaces.Box:
    # [x, y, vx, vy]; the velocity is the last displacement, at most MAX_STEP per axis
    # (plus slack: (0.2 + 0.1) - 0.2 = 0.10000000000000003 in floats).
    vmax = MAX_STEP * (1 + 1e-6)
    bound = np.array([ARENA, ARENA, vmax, vmax])
    return gym.spaces.Box(-bound, bound, dtype=np.float64)


def _action_space() -> gym.spaces.Box:
    return gym.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)


class PointEnv(gym.Env):
    """Point mass at `pos`; an action moves it by `MAX_STEP * clip(action, -1, 1)`.

    Reward is minus the distance to the goal after the move; `info["success"]` is 1.0 within
    `SUCCESS_RADIUS`. Episodes never terminate; they truncate after `episode_length` steps.
    """

    def __init__(self, goal: tuple[float, float], episode_length: int, seed: int) -> None:
        self.goal = np.asarray(goal, dtype=np.float64)
        self.episode_length = episode_length
        self.observation_space = _observation_space()
        self.action_space = _action_space()
        self._seed(seed)
        self.pos = np.zeros(2)
        self.t = 0

    def _seed(self, seed: int) -> None:
        self.np_random, _ = gym.utils.seeding.np_random(seed)
        self.action_space.seed(seed)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start near the origin; `seed` restarts the generator, None continues the one seeded at make."""
        if seed is not None:
            self._seed(seed)
        self.pos = self.np_random.uniform(-START_NOISE, START_NOISE, size=2)
        self.t = 0
        return np.concatenate([self.pos, np.zeros(2)]), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Move, then score: reward = -distance to goal, success = distance <= SUCCESS_RADIUS."""
        old = self.pos
        self.pos = np.clip(old + MAX_STEP * np.clip(action, -1.0, 1.0), -ARENA, ARENA)
        self.t += 1
        distance = float(np.hypot(*(self.pos - self.goal)))
        obs = np.concatenate([self.pos, self.pos - old])
        info = {"success": float(distance <= SUCCESS_RADIUS), "distance": distance}
        return obs, -distance, False, self.t >= self.episode_length, info


class PointAdapter(EnvAdapter):
    """Four reaching tasks ("east", "north", "west", "south") on a circle of radius 1; 50-step episodes."""

    name: ClassVar[str] = "point"
    all_tasks: ClassVar[tuple[str, ...]] = tuple(GOALS)
    default_episode_length: ClassVar[int] = 50

    @property
    def observation_space(self) -> gym.spaces.Box:
        return _observation_space()

    @property
    def action_space(self) -> gym.spaces.Box:
        return _action_space()

    @property
    def obs_layout(self) -> ObsLayout:
        # Position and velocity are the "robot"; there are no objects, and no goal in the obs.
        return ObsLayout(robot=(0, 1, 2, 3), objects=(), goal=())

    def make(self, task: str, seed: int) -> gym.Env:
        """A PointEnv whose goal is the task's and whose start positions are drawn from `seed`."""
        return PointEnv(GOALS[self._known(task)], self.episode_length, seed)

    def semantic_check(self, task: str, seed: int = 0) -> dict[str, Any]:
        """Reward and success mean what they say: not solved at reset, solved by heading to the goal.

        One step of the zero action after reset must not succeed; steering straight at the goal
        must succeed within the episode with a reward that rises to at least -SUCCESS_RADIUS.
        """
        env = self.make(task, seed)
        env.reset(seed=seed)
        _, reward_at_start, _, _, info = env.step(np.zeros(2, dtype=np.float32))
        success_at_start = info["success"]
        success_reached, reward_at_end = 0.0, reward_at_start
        for _ in range(self.episode_length - 1):
            direction = env.unwrapped.goal - env.unwrapped.pos
            action = np.clip(direction / MAX_STEP, -1.0, 1.0)  # full speed, no overshoot
            _, reward_at_end, _, _, info = env.step(action)
            if info["success"] == 1.0:
                success_reached = 1.0
                break
        ok = (
            success_at_start == 0.0
            and success_reached == 1.0
            and reward_at_start < reward_at_end
            and reward_at_end >= -SUCCESS_RADIUS
        )
        return {
            "ok": bool(ok),
            "success_at_reset": success_at_start,
            "scripted_success": success_reached,
            "reward_at_reset": reward_at_start,
            "reward_at_goal": reward_at_end,
        }

    def _known(self, task: str) -> str:
        if task not in GOALS:
            raise UnknownNameError("point task", task, list(GOALS))
        return task
