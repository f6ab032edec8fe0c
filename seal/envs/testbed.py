"""The cross-environment transfer testbed: `point` seen and driven through other spaces.

Two small built-in environments whose state and action spaces differ from `point`'s but whose
tasks correspond to its tasks, so that transfer from `point` can be measured in seconds
(docs/transfer_testbed.md states the hypothesis, the arms, the metric and the goal):

- `point_view` (the target): the same point mass, seen through a fixed 6 x 4 linear map of
  [x, y, vx, vy] (`VIEW_MATRIX`, orthonormal columns, so nothing is lost and no float is a raw
  coordinate) and driven by 5-D actions of which two move the point (`ACTION_MAP`, a permutation
  with a sign flip) and three are distractors the env ignores. Its tasks t0..t3 have the goals
  of the `point` tasks that `TESTBED_TABLE` pairs them with.
- `point_diagonal` (the no-correspondence control's source): `point` itself, with goals on the
  diagonals, so that no task of it has a counterpart among `point_view`'s.

A permutation with signs, not a random linear action map, keeps the per-axis clipping of
`point`, so `point_view` is exactly as hard to solve as `point` (same reachable moves per step).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np

from seal.envs.base import EnvAdapter, EnvMap, ObsLayout
from seal.envs.point import ARENA, GOAL_RADIUS, GOALS, MAX_STEP, PointAdapter, PointEnv
from seal.errors import SealError, UnknownNameError

# A fixed random map, written out rather than drawn so that every numpy and LAPACK gives the same
# env: QR of a 6 x 4 standard normal matrix (numpy default_rng(20261123)), rounded to 3 decimals.
VIEW_MATRIX = np.array(
    [
        [-0.141, 0.881, -0.128, 0.210],
        [-0.509, -0.075, -0.187, -0.378],
        [-0.468, -0.066, -0.699, 0.187],
        [-0.033, 0.380, 0.137, -0.763],
        [-0.320, 0.175, 0.500, 0.438],
        [0.632, 0.196, -0.437, 0.064],
    ]
)
"""`point_view` observation = VIEW_MATRIX @ [x, y, vx, vy] (6 floats)."""

REWARDS: dict[str, str] = {
    "dense": "minus the distance to the goal, as point's (default)",
    "success": "1.0 within the goal radius, else 0.0 (the positive control's hard target)",
}
"""`point_view`'s `reward` option: its values and what each pays per step."""

VIEW_ACT_DIM = 5
ACTION_MAP: tuple[tuple[int, float], tuple[int, float]] = ((3, 1.0), (1, -1.0))
"""(index, sign) of the `point_view` action entries that make `point`'s x and y moves; 0, 2, 4 are ignored."""

TESTBED_TABLE: dict[str, str] = {
    "point_view:t0": "north",
    "point_view:t1": "east",
    "point_view:t2": "south",
    "point_view:t3": "west",
}
"""Alignment table (`seal.envs.alignment` format): `point_view` task -> the `point` task with its goal.

The order differs from `point`'s on purpose: corresponding tasks do not share a local index.
"""

ORACLE_MAP = EnvMap(
    source=PointAdapter.name,
    target="point_view",
    # The pseudo-inverse, not the transpose: VIEW_MATRIX has full column rank, so this recovers
    # [x, y, vx, vy] exactly, where the transpose is exact only to its 3-decimal rounding.
    obs=np.linalg.pinv(VIEW_MATRIX),
    tasks={key.split(":", 1)[1]: point_task for key, point_task in TESTBED_TABLE.items()},
    actions=ACTION_MAP,
)
"""`point` -> `point_view` by construction (`[transfer] map = "testbed_oracle"`): the testbed's
positive controls start the target from the pre-trained source through it (docs/transfer_testbed.md)."""

_DIAGONAL = GOAL_RADIUS / math.sqrt(2.0)
DIAGONAL_GOALS: dict[str, tuple[float, float]] = {
    "northeast": (_DIAGONAL, _DIAGONAL),
    "northwest": (-_DIAGONAL, _DIAGONAL),
    "southwest": (-_DIAGONAL, -_DIAGONAL),
    "southeast": (_DIAGONAL, -_DIAGONAL),
}
"""`point_diagonal` goals: radius 1 like `point`'s, 45 degrees from each of them."""


def view_goal(task: str) -> tuple[float, float]:
    """The goal of `point_view` task `task`: that of the `point` task `TESTBED_TABLE` pairs it with."""
    key = f"{PointViewAdapter.name}:{task}"
    if key not in TESTBED_TABLE:
        raise UnknownNameError("point_view task", task, list(PointViewAdapter.all_tasks))
    return GOALS[TESTBED_TABLE[key]]


def point_action(view_action: np.ndarray) -> np.ndarray:
    """The 2-D `point` action that a (..., 5) `point_view` action makes."""
    a = np.asarray(view_action)
    return np.stack([sign * a[..., index] for index, sign in ACTION_MAP], axis=-1)


def view_action(point_move: np.ndarray) -> np.ndarray:
    """A `point_view` action that makes the 2-D `point` action `point_move` (distractors 0)."""
    move = np.asarray(point_move, dtype=np.float32)
    out = np.zeros(move.shape[:-1] + (VIEW_ACT_DIM,), dtype=np.float32)
    for axis, (index, sign) in enumerate(ACTION_MAP):
        out[..., index] = sign * move[..., axis]
    return out


def paired_states(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """`n` states of the one world both testbed envs see, as (point obs (n, 4), point_view obs (n, 6)).

    Positions are uniform over the arena and velocities uniform within `MAX_STEP` per axis, drawn
    from numpy's default_rng(`seed`) alone; row i of the second array is VIEW_MATRIX @ row i of
    the first, so the rows pair one state seen by each env (`point_diagonal` sees `point`'s obs).
    """
    if n < 1:
        raise SealError(f"paired_states: n must be >= 1, got {n}")
    rng = np.random.default_rng(seed)
    positions = rng.uniform(-ARENA, ARENA, size=(n, 2))
    velocities = rng.uniform(-MAX_STEP, MAX_STEP, size=(n, 2))
    point_obs = np.concatenate([positions, velocities], axis=1)
    return point_obs, point_obs @ VIEW_MATRIX.T


def _view_observation_space() -> gym.spaces.Box:
    inner = PointAdapter().observation_space
    # |W x| <= |W| |x| per row: the box that holds every mapped observation.
    bound = np.abs(VIEW_MATRIX) @ inner.high
    return gym.spaces.Box(-bound, bound, dtype=np.float64)


def _view_action_space() -> gym.spaces.Box:
    return gym.spaces.Box(-1.0, 1.0, shape=(VIEW_ACT_DIM,), dtype=np.float32)


class PointViewEnv(gym.Env):
    """A `PointEnv` (`inner`) seen through `VIEW_MATRIX` and driven through `ACTION_MAP`."""

    def __init__(
        self, goal: tuple[float, float], episode_length: int, seed: int, reward: str = "dense"
    ) -> None:
        self.inner = PointEnv(goal, episode_length, seed)
        self.reward = reward
        self.observation_space = _view_observation_space()
        self.action_space = _view_action_space()
        self.action_space.seed(seed)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset the inner point env and map its observation."""
        super().reset(seed=seed)  # gymnasium's contract; the inner env draws the start state
        if seed is not None:
            self.action_space.seed(seed)
        obs, info = self.inner.reset(seed=seed, options=options)
        return VIEW_MATRIX @ obs, info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Step the inner env with the two moving entries; success is the inner env's, the reward per `reward`."""
        obs, reward, terminated, truncated, info = self.inner.step(point_action(action))
        if self.reward == "success":
            reward = info["success"]
        return VIEW_MATRIX @ obs, reward, terminated, truncated, info


class PointViewAdapter(EnvAdapter):
    """The testbed's target: `point`'s four reaching tasks behind a 6-D observation map and 5-D actions."""

    name: ClassVar[str] = "point_view"
    all_tasks: ClassVar[tuple[str, ...]] = ("t0", "t1", "t2", "t3")
    default_episode_length: ClassVar[int] = PointAdapter.default_episode_length

    def __init__(
        self,
        tasks: Sequence[str] | str | None = None,
        episode_length: int | None = None,
        **options: Any,
    ) -> None:
        """`options`: `reward` ("dense" or "success", see `REWARDS`)."""
        unknown = sorted(set(options) - {"reward"})
        reward = options.get("reward", "dense")
        if unknown or not isinstance(reward, str) or reward not in REWARDS:
            raise SealError(
                f"adapter {self.name!r}: option(s) {options} not valid; valid: reward = "
                + " or ".join(f'"{k}" ({v})' for k, v in REWARDS.items())
            )
        super().__init__(tasks=tasks, episode_length=episode_length)
        self.reward = reward

    @property
    def observation_space(self) -> gym.spaces.Box:
        return _view_observation_space()

    @property
    def action_space(self) -> gym.spaces.Box:
        return _view_action_space()

    @property
    def obs_layout(self) -> ObsLayout:
        # Every float mixes position and velocity: all "robot", no objects, no goal in the obs.
        return ObsLayout(robot=tuple(range(VIEW_MATRIX.shape[0])), objects=(), goal=())

    def make(self, task: str, seed: int) -> gym.Env:
        """A PointViewEnv whose goal is the paired `point` task's, its start positions drawn from `seed`."""
        return PointViewEnv(view_goal(task), self.episode_length, seed, self.reward)

    def semantic_check(self, task: str, seed: int = 0) -> dict[str, Any]:
        """Not solved at reset; solved by steering the inner point at the goal through `view_action`."""
        env = self.make(task, seed)
        env.reset(seed=seed)
        _, reward_at_start, _, _, info = env.step(np.zeros(VIEW_ACT_DIM, dtype=np.float32))
        success_at_start, success_reached, reward_at_end = info["success"], 0.0, reward_at_start
        inner = env.unwrapped.inner
        for _ in range(self.episode_length - 1):
            move = np.clip((inner.goal - inner.pos) / MAX_STEP, -1.0, 1.0)
            _, reward_at_end, _, _, info = env.step(view_action(move))
            if info["success"] == 1.0:
                success_reached = 1.0
                break
        ok = success_at_start == 0.0 and success_reached == 1.0 and reward_at_start < reward_at_end
        return {
            "ok": bool(ok),
            "success_at_reset": success_at_start,
            "scripted_success": success_reached,
            "reward_at_reset": reward_at_start,
            "reward_at_goal": reward_at_end,
        }


class PointDiagonalAdapter(PointAdapter):
    """`point` with goals on the diagonals: the no-correspondence control's source for `point_view`."""

    name: ClassVar[str] = "point_diagonal"
    all_tasks: ClassVar[tuple[str, ...]] = tuple(DIAGONAL_GOALS)

    def make(self, task: str, seed: int) -> gym.Env:
        """A PointEnv whose goal is the diagonal task's."""
        if task not in DIAGONAL_GOALS:
            raise UnknownNameError("point_diagonal task", task, list(DIAGONAL_GOALS))
        return PointEnv(DIAGONAL_GOALS[task], self.episode_length, seed)
