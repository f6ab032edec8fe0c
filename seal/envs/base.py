"""The adapter interface: the one thing an environment implements to plug into SEAL.

An adapter describes an environment family (its tasks, spaces, episode length and observation
layout) and builds one gymnasium env per task. Everything above this layer (learner, protocols,
reports) talks to environments only through this interface, so adding an environment never
requires editing seal: write a subclass and name it by import path, "package.module:Class".
"""

from __future__ import annotations

import abc
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np


@dataclass(frozen=True)
class ObsLayout:
    """Which indices of a flat observation hold robot state, object state and the goal.

    `robot + objects` (in that order) is the "state block" that pad-and-fine-tune alignment
    pads to a common width; `goal` is appended after the aligned one-hot task id.
    """

    robot: tuple[int, ...]
    objects: tuple[int, ...]
    goal: tuple[int, ...]

    @property
    def state(self) -> tuple[int, ...]:
        """Robot then object indices: the block that is padded during alignment."""
        return self.robot + self.objects

    @classmethod
    def from_slices(
        cls, robot: Sequence[slice], objects: Sequence[slice], goal: Sequence[slice]
    ) -> ObsLayout:
        """Build a layout from lists of slices (convenient for observations made of blocks)."""

        def idx(slices: Sequence[slice]) -> tuple[int, ...]:
            return tuple(i for s in slices for i in range(s.start, s.stop))

        return cls(idx(robot), idx(objects), idx(goal))


@dataclass(frozen=True)
class EnvMap:
    """A correspondence between two environments known by construction: a positive control's oracle.

    It says how a source env's observations, tasks and actions are read off a target env's, so
    that a policy and critic learnt on the source can be rewritten to compute the same on the
    target (`seal.learner.transfer.map_env`); `seal.envs.registry.env_map` finds one by name.
    """

    source: str
    """The adapter name (`EnvAdapter.name`) of the env the mapped modules were learnt on."""
    target: str
    """The adapter name of the env whose modules are started from them."""
    obs: np.ndarray
    """(source obs_dim, target obs_dim): the source's observation of a state is `obs @` the target's."""
    tasks: Mapping[str, str]
    """Target task -> the source task it is (same goal, same reward)."""
    actions: tuple[tuple[int, float], ...]
    """Per source action entry k, (index, sign): entry k is sign * the target's entry `index`;
    the target's other entries are ignored by its env."""

    def task_order(self, source_tasks: Sequence[str], target_tasks: Sequence[str]) -> list[int]:
        """For each of `target_tasks`, the index in `source_tasks` of the task it is."""
        from seal.errors import SealError

        missing = [t for t in target_tasks if self.tasks.get(t) not in source_tasks]
        if missing:
            raise SealError(
                f"env map {self.source} -> {self.target}: target task(s) {missing} have no source "
                f"task among {list(source_tasks)}; the map pairs {dict(self.tasks)}"
            )
        return [list(source_tasks).index(self.tasks[t]) for t in target_tasks]


class EnvAdapter(abc.ABC):
    """One environment family with named tasks, built as seeded gymnasium envs.

    Subclasses set `name` and `all_tasks`, and implement the abstract members. Every env made by
    `make` returns flat Box observations of `observation_space.shape`, actions in
    `action_space`, truncates after `episode_length` steps, and puts `info["success"]` (0.0 or
    1.0) in every step's info.
    """

    name: ClassVar[str]
    all_tasks: ClassVar[tuple[str, ...]]
    task_sets: ClassVar[dict[str, tuple[str, ...]]] = {}
    default_episode_length: ClassVar[int]
    shaping_discount: float | None = None
    """The discount of a potential-based shaping term in the adapter's reward (None: it has none);
    the protocol loader requires it to equal `agent.gamma`, or the shaping changes the optimum."""

    def __init__(
        self,
        tasks: Sequence[str] | str | None = None,
        episode_length: int | None = None,
        **options: Any,
    ) -> None:
        from seal.errors import SealError, UnknownNameError

        if options:
            raise SealError(
                f"adapter {self.name!r} takes no option(s) {sorted(options)}; it takes tasks, episode_length"
            )
        self.tasks: tuple[str, ...] = self.resolve_tasks(tasks)
        for task in self.tasks:
            if task not in self.all_tasks:
                raise UnknownNameError(
                    f"{self.name} task", task, list(self.all_tasks) + sorted(self.task_sets)
                )
        if len(set(self.tasks)) != len(self.tasks):
            raise SealError(f"adapter {self.name!r}: task list {list(self.tasks)} repeats a task")
        if episode_length is not None and (
            isinstance(episode_length, bool) or not isinstance(episode_length, int | np.integer)
        ):
            raise SealError(
                f"adapter {self.name!r}: episode_length must be an integer, got {episode_length!r}"
            )
        length = self.default_episode_length if episode_length is None else int(episode_length)
        if length < 1:
            raise SealError(f"adapter {self.name!r}: episode_length must be >= 1, got {length}")
        self.episode_length = length

    @classmethod
    def resolve_tasks(cls, tasks: Sequence[str] | str | None) -> tuple[str, ...]:
        """Expand a task-set name (e.g. "mt10") or list of names into a tuple of task names."""
        if tasks is None:
            return tuple(cls.all_tasks)
        if isinstance(tasks, str):
            return tuple(cls.task_sets[tasks]) if tasks in cls.task_sets else (tasks,)
        out: list[str] = []
        for t in tasks:
            out.extend(cls.task_sets.get(t, (t,)))
        return tuple(out)

    @property
    @abc.abstractmethod
    def observation_space(self) -> gym.spaces.Box:
        """The flat observation space shared by all of this adapter's tasks."""

    @property
    @abc.abstractmethod
    def action_space(self) -> gym.spaces.Box:
        """The action space shared by all of this adapter's tasks."""

    @property
    @abc.abstractmethod
    def obs_layout(self) -> ObsLayout:
        """Robot, object and goal indices of the observation."""

    @abc.abstractmethod
    def make(self, task: str, seed: int) -> gym.Env:
        """A gymnasium env for `task`, fully determined by `seed` (reset(seed=None) continues it)."""

    def semantic_check(self, task: str, seed: int = 0) -> dict[str, Any]:
        """Adapter-specific evidence that reward and success mean what they say, for `seal envs check`.

        Returns {"ok": bool, ...figures}. The default has no such evidence and says so.
        """
        return {"ok": True, "semantic_check": "none defined for this adapter"}

    def expert(self, task: str) -> Callable[[np.ndarray], np.ndarray] | None:
        """A scripted expert for `task`: one observation (as `reset`/`step` return it) -> one action.

        Used to seed the replay with demonstrations (`training.demo_episodes`). None (the
        default) means the adapter ships none for that task.
        """
        return None

    @property
    def obs_dim(self) -> int:
        return int(np.prod(self.observation_space.shape))

    @property
    def act_dim(self) -> int:
        return int(np.prod(self.action_space.shape))

    def describe(self) -> dict[str, Any]:
        """The summary `seal envs --json` prints for this adapter."""
        return {
            "tasks": list(self.tasks),
            "obs_dim": self.obs_dim,
            "act_dim": self.act_dim,
            "episode_length": self.episode_length,
        }
