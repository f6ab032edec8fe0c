"""Observation and action alignment across environments for pad-and-fine-tune (SEAL Appendix D).

Every environment's observation becomes

    [ state block, zero-padded to `state_width` | one-hot aligned task id | goal, zero-padded ]
      0 .. state_width                           state_width .. +num_ids    .. obs_dim

so the one-hot and the goal start at the same index in every environment, and similar tasks of
different environments share a one-hot id (paper Table 3). Actions are zero-padded to the largest
action size so that one critic serves all environments; `unpad_action` recovers an env's action.

Build one alignment from every environment of a protocol, also for a phase that trains only one
of them, so that widths and ids do not change between pre-training and fine-tuning.

Example: Meta-World MT10 + the ten dense kitchens give state_width 59 (kitchen), 14 ids, goal 3:
Meta-World's 36-float state block fills [0:36] and [36:59] stays zero, the one-hot is [59:73],
and the goal is [73:76].
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import gymnasium as gym
import numpy as np
from numpy.typing import DTypeLike

from seal.envs.base import EnvAdapter
from seal.errors import SealError, UnknownNameError

# SEAL paper Table 3: kitchen task -> the Meta-World task whose one-hot id it shares.
# Every task not listed is its own group, so MT10 + the ten kitchens give 14 ids.
PAPER_TABLE: dict[str, str] = {
    "slide-cabinet": "drawer-close-v3",
    "kettle": "pick-place-v3",
    "left-hinge-door": "door-open-v3",
    "right-hinge-door": "door-open-v3",
    "microwave": "door-open-v3",
    "light-switch": "push-v3",
}


class _EnvPlan:
    """Precomputed gather indices of one environment, so transforms are pure array ops."""

    def __init__(self, adapter: EnvAdapter, ids: np.ndarray) -> None:
        layout = adapter.obs_layout
        self.tasks: tuple[str, ...] = tuple(adapter.tasks)
        self.task_index = {task: i for i, task in enumerate(self.tasks)}
        self.state_idx = np.asarray(layout.state, dtype=np.intp)
        self.goal_idx = np.asarray(layout.goal, dtype=np.intp)
        self.ids = ids  # local task index -> aligned one-hot id
        self.obs_dim = adapter.obs_dim
        self.act_dim = adapter.act_dim


class Alignment:
    """The aligned observation and padded action spaces of a fixed list of adapters.

    Build it with `Alignment.build(adapters, table)`; environments are named by adapter name.
    Tasks are given as local indices into `adapter.tasks` (ints) or as task names.
    """

    def __init__(
        self, plans: dict[str, _EnvPlan], groups: list[str], state_width: int, goal_width: int
    ) -> None:
        self._plans = plans
        self.groups: tuple[str, ...] = tuple(groups)  # aligned id -> group name
        self.state_width = state_width
        self.goal_width = goal_width
        self.num_ids = len(groups)
        self.onehot_start = state_width
        self.goal_start = state_width + self.num_ids
        self.obs_dim = self.goal_start + goal_width
        self.act_dim = max(plan.act_dim for plan in plans.values())

    @classmethod
    def build(
        cls, adapters: Sequence[EnvAdapter], table: Mapping[str, str] | None = None
    ) -> Alignment:
        """Align `adapters` (in this order) with `table` (task -> group; default: paper Table 3).

        Ids are numbered in order of first appearance, walking adapters then their tasks, so the
        same adapters and table always give the same ids. A table key may be a task name or
        "adapter:task" (for task names shared between adapters, the qualified key wins). A key
        of a user table that matches no task is an error; the default table's kitchen rows are
        simply unused when no kitchen is present.
        """
        if not adapters:
            raise SealError("alignment needs at least one adapter")
        names = [a.name for a in adapters]
        if len(set(names)) != len(names):
            raise SealError(
                f"alignment: adapter names {names} repeat; each environment must appear once"
            )
        if table is None:
            table = PAPER_TABLE
        else:
            _check_table_keys(adapters, table)

        groups: list[str] = []
        group_id: dict[str, int] = {}
        plans: dict[str, _EnvPlan] = {}
        for adapter in adapters:
            ids = []
            for task in adapter.tasks:
                group = table.get(f"{adapter.name}:{task}", table.get(task, task))
                if group not in group_id:
                    group_id[group] = len(groups)
                    groups.append(group)
                ids.append(group_id[group])
            plans[adapter.name] = _EnvPlan(adapter, np.asarray(ids, dtype=np.intp))
        state_width = max(len(plan.state_idx) for plan in plans.values())
        goal_width = max(len(plan.goal_idx) for plan in plans.values())
        return cls(plans, groups, state_width, goal_width)

    # ---- ids -------------------------------------------------------------------------------

    @property
    def envs(self) -> tuple[str, ...]:
        """The aligned adapters' names, in build order."""
        return tuple(self._plans)

    def task_id(self, env: str, task: str | int) -> int:
        """The aligned one-hot id of `task` (name or local index) of adapter `env`."""
        plan = self._plan(env)
        return int(plan.ids[self._local_index(plan, env, task)])

    def task_index(self, env: str, task: str | int) -> int:
        """The local index of `task` (name or index) in adapter `env`'s task list, validated."""
        return self._local_index(self._plan(env), env, task)

    def task_ids(self, env: str) -> np.ndarray:
        """Aligned ids of all of `env`'s tasks, indexed by local task index."""
        return self._plan(env).ids.copy()

    # ---- observations ----------------------------------------------------------------------

    def transform_obs(
        self,
        env: str,
        obs: np.ndarray,
        tasks: np.ndarray | Sequence[str] | str | int,
        dtype: DTypeLike = np.float32,
    ) -> np.ndarray:
        """Aligned observations (batch, obs_dim) from `env`'s raw observations (batch, env_obs_dim).

        `tasks` is one task (name or local index) for the whole batch, or one per row.
        A single observation (1-D) gives a single aligned observation.
        """
        plan = self._plan(env)
        obs = np.asarray(obs)
        single = obs.ndim == 1
        batch = obs.reshape(1, -1) if single else obs
        if batch.shape[1] != plan.obs_dim:
            raise SealError(
                f"alignment: {env} observations have {batch.shape[1]} floats, expected {plan.obs_dim}"
            )
        ids = plan.ids[self._local_indices(plan, env, tasks, len(batch))]

        out = np.zeros((len(batch), self.obs_dim), dtype=dtype)
        out[:, : len(plan.state_idx)] = batch[:, plan.state_idx]
        out[np.arange(len(batch)), self.onehot_start + ids] = 1.0
        out[:, self.goal_start : self.goal_start + len(plan.goal_idx)] = batch[:, plan.goal_idx]
        return out[0] if single else out

    @property
    def observation_space(self) -> gym.spaces.Box:
        """The aligned observation space (unbounded floats, as padding mixes environments' bounds)."""
        return gym.spaces.Box(-np.inf, np.inf, shape=(self.obs_dim,), dtype=np.float32)

    # ---- actions ---------------------------------------------------------------------------

    def pad_action(self, env: str, actions: np.ndarray) -> np.ndarray:
        """`env`'s actions (batch, env_act_dim) zero-padded to (batch, act_dim)."""
        plan = self._plan(env)
        actions = np.asarray(actions)
        out = np.zeros(actions.shape[:-1] + (self.act_dim,), dtype=actions.dtype)
        out[..., : plan.act_dim] = actions
        return out

    def unpad_action(self, env: str, actions: np.ndarray) -> np.ndarray:
        """The first `env_act_dim` entries of padded actions (batch, act_dim): `env`'s own action."""
        return np.asarray(actions)[..., : self._plan(env).act_dim]

    @property
    def action_space(self) -> gym.spaces.Box:
        """The padded action space: [-1, 1]^act_dim (padding entries are ignored by every env)."""
        return gym.spaces.Box(-1.0, 1.0, shape=(self.act_dim,), dtype=np.float32)

    # ---- gymnasium -------------------------------------------------------------------------

    def wrap(self, env: gym.Env, env_name: str, task: str | int) -> gym.Env:
        """`env` (one task of adapter `env_name`) with aligned observations and padded actions."""
        return PaddedAction(AlignedObservation(env, self, env_name, task), self, env_name)

    # ---- helpers ---------------------------------------------------------------------------

    def _plan(self, env: str) -> _EnvPlan:
        if env not in self._plans:
            raise UnknownNameError("aligned environment", env, list(self._plans))
        return self._plans[env]

    def _local_index(self, plan: _EnvPlan, env: str, task: str | int) -> int:
        if isinstance(task, str):
            if task not in plan.task_index:
                raise UnknownNameError(f"{env} task", task, list(plan.tasks))
            return plan.task_index[task]
        index = int(task)
        if not 0 <= index < len(plan.tasks):
            raise SealError(
                f"alignment: {env} task index {index} out of range 0..{len(plan.tasks) - 1}"
            )
        return index

    def _local_indices(
        self, plan: _EnvPlan, env: str, tasks: np.ndarray | Sequence[str] | str | int, n: int
    ) -> np.ndarray:
        if isinstance(tasks, (str, int, np.integer)):
            return np.full(n, self._local_index(plan, env, tasks), dtype=np.intp)
        tasks = np.asarray(tasks)
        if tasks.shape != (n,):
            raise SealError(f"alignment: {n} observations but tasks of shape {tasks.shape}")
        if tasks.dtype.kind in "US":  # names: map the few distinct ones, then broadcast
            names, inverse = np.unique(tasks, return_inverse=True)
            lookup = np.array(
                [self._local_index(plan, env, str(name)) for name in names], dtype=np.intp
            )
            return lookup[inverse]
        index = tasks.astype(np.intp)
        if index.min() < 0 or index.max() >= len(plan.tasks):
            raise SealError(f"alignment: {env} task indices must lie in 0..{len(plan.tasks) - 1}")
        return index


def _check_table_keys(adapters: Sequence[EnvAdapter], table: Mapping[str, str]) -> None:
    """Every key of a user table must name a task ("task" or "adapter:task") of the adapters."""
    valid = {task for a in adapters for task in a.tasks} | {
        f"{a.name}:{t}" for a in adapters for t in a.tasks
    }
    for key, group in table.items():
        if key not in valid:
            raise UnknownNameError("task in alignment table", key, sorted(valid))
        if not isinstance(group, str) or not group:
            raise SealError(
                f"alignment table: group of {key!r} must be a non-empty string, got {group!r}"
            )


def lone_entries(adapters: Sequence[EnvAdapter], table: Mapping[str, str]) -> list[tuple[str, str]]:
    """The (key, group) entries of a user table that put their task in a group of its own under
    another name: no other task maps there, so the entry does what leaving it out does (a typo
    of a shared group's name, most likely)."""
    members: dict[str, int] = {}
    for adapter in adapters:
        for task in adapter.tasks:
            group = table.get(f"{adapter.name}:{task}", table.get(task, task))
            members[group] = members.get(group, 0) + 1
    return [
        (key, group)
        for key, group in table.items()
        if members.get(group) == 1 and group != key.rpartition(":")[2]
    ]


class AlignedObservation(gym.ObservationWrapper):
    """Observations of one task's env, aligned by an `Alignment`."""

    def __init__(self, env: gym.Env, alignment: Alignment, env_name: str, task: str | int) -> None:
        super().__init__(env)
        self._alignment, self._env_name = alignment, env_name
        self._task_index = alignment.task_index(env_name, task)
        self.observation_space = alignment.observation_space

    def observation(self, observation: np.ndarray) -> np.ndarray:
        """The aligned observation."""
        return self._alignment.transform_obs(self._env_name, observation, self._task_index)


class PaddedAction(gym.ActionWrapper):
    """Takes padded actions (act_dim of the alignment) and passes the env its own entries."""

    def __init__(self, env: gym.Env, alignment: Alignment, env_name: str) -> None:
        super().__init__(env)
        self._alignment, self._env_name = alignment, env_name
        self.action_space = alignment.action_space

    def action(self, action: np.ndarray) -> np.ndarray:
        """The env's own action: the first env_act_dim entries."""
        return self._alignment.unpad_action(self._env_name, action)
