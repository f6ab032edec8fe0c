"""Multi-task replay: one preallocated float32 ring buffer per (environment, task), on the training device.

Each environment's buffers are tensors of shape (num_tasks, capacity_per_task, ...) on the replay's
device, so task t's buffer is the slice [t] and a batch over all tasks is one gather there, with
row indices drawn by the replay's own torch generator on that device: an update reads no host
memory. Collected steps are staged on the host and written in one copy per field when the replay
is next read (`flush`: once per epoch in the phase loop). The caller (a data-ratio scheduler)
decides how many transitions each task contributes to an update
(`seal.schedulers.base.split_counts` rounds proportions into those per-task counts).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import NotRequired, TypedDict

import numpy as np
import torch

from seal.errors import SealError, UnknownNameError
from seal.learner.config import Batch, EnvSpec
from seal.seeding import stream

DEFAULT_CAPACITY = (
    1_000_000  # transitions per environment (Meta-World), split evenly over its tasks
)
_FIELDS = ("obs", "actions", "rewards", "next_obs", "terminations")


def available_memory_bytes() -> int | None:
    """Memory available to new allocations: psutil when installed, else /proc/meminfo, else None."""
    try:
        import psutil  # type: ignore[import-not-found]

        return int(psutil.virtual_memory().available)
    except ImportError:
        pass
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def replay_bytes(
    specs: Sequence[EnvSpec], capacity: int | Mapping[str, int] = DEFAULT_CAPACITY
) -> int:
    """Bytes the float32 buffers of `specs` take at `capacity` transitions per environment."""
    total = 0
    for spec in specs:
        per_task = _capacity_of(spec, capacity) // spec.num_tasks
        total += spec.num_tasks * per_task * (2 * spec.obs_dim + spec.act_dim + 2) * 4
    return total


def _capacity_of(spec: EnvSpec, capacity: int | Mapping[str, int]) -> int:
    value = capacity[spec.name] if isinstance(capacity, Mapping) else capacity
    if not isinstance(value, int | np.integer) or value < spec.num_tasks:
        raise SealError(
            f"replay capacity of {spec.name!r} must be an int >= its number of tasks ({spec.num_tasks}), got {value!r}"
        )
    return int(value)


class ReplayState(TypedDict):
    """`MultiTaskReplay.state_dict()`: tensors and plain values, as checkpoints hold them."""

    capacity_per_task: dict[str, int]
    generators: NotRequired[dict[str, torch.Tensor]]  # each env's row stream (absent: older)
    envs: dict[
        str, dict[str, torch.Tensor]
    ]  # env -> each field's filled rows, size, position, consumed


class MultiTaskReplay:
    """One preallocated float32 ring buffer per (environment, task), with per-task `consumed` counters.

    `capacity` is per environment (an int for all, or a dict by env name) and is split evenly over
    the env's tasks (capacity // num_tasks each). Before allocating, the total size is checked
    against available memory and a SealError with the numbers is raised if it does not fit.
    `consumed[env][t]` counts the transitions of task t that `sample` has handed to updates
    (cumulative, int64); the update-count metric reads it.
    """

    def __init__(
        self,
        specs: Sequence[EnvSpec],
        capacity: int | Mapping[str, int] = DEFAULT_CAPACITY,
        device: str | torch.device = "cpu",
        check_memory: bool = True,
        seed: int = 0,
    ) -> None:
        self.specs = {s.name: s for s in specs}
        self.device = torch.device(device)
        self.generators: dict[str, torch.Generator] = {}
        """Each env's sampled rows (saved in `state_dict`, so a resumed run draws the same rows)."""
        self.reseed(seed)
        needed = replay_bytes(specs, capacity)
        if check_memory:
            available = available_memory_bytes()
            if available is not None and needed > available:
                per_env = ", ".join(
                    f"{s.name}: {_capacity_of(s, capacity):,} transitions = {replay_bytes([s], capacity) / 2**30:.2f} GiB"
                    for s in specs
                )
                raise SealError(
                    f"replay needs {needed / 2**30:.2f} GiB ({per_env}) but only {available / 2**30:.2f} GiB of memory is available; lower the replay capacity or train fewer tasks"
                )
        self.capacity_per_task: dict[str, int] = {}
        self._storage: dict[str, dict[str, torch.Tensor]] = {}
        self._staged: dict[str, list[tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]]] = {}
        self._size_on_device: dict[str, torch.Tensor] = {}
        self._ids_cache: dict[tuple[str, bytes], torch.Tensor] = {}
        self.size: dict[str, np.ndarray] = {}
        self.position: dict[str, np.ndarray] = {}
        self.consumed: dict[str, np.ndarray] = {}
        for spec in specs:
            per_task = _capacity_of(spec, capacity) // spec.num_tasks
            shape = (spec.num_tasks, per_task)
            self.capacity_per_task[spec.name] = per_task
            shapes = {
                "obs": (*shape, spec.obs_dim),
                "actions": (*shape, spec.act_dim),
                "rewards": shape,
                "next_obs": (*shape, spec.obs_dim),
                "terminations": shape,
            }
            self._storage[spec.name] = {f: self._zeros(shapes[f]) for f in _FIELDS}
            self._staged[spec.name] = []
            self._size_on_device[spec.name] = torch.zeros(
                spec.num_tasks, dtype=torch.int64, device=self.device
            )
            self.size[spec.name] = np.zeros(spec.num_tasks, np.int64)
            self.position[spec.name] = np.zeros(spec.num_tasks, np.int64)
            self.consumed[spec.name] = np.zeros(spec.num_tasks, np.int64)

    def _zeros(self, shape: tuple[int, ...]) -> torch.Tensor:
        if self.device.type == "cpu":
            # np.zeros maps pages lazily, so untouched capacity costs no resident memory.
            return torch.from_numpy(np.zeros(shape, np.float32))
        return torch.zeros(shape, dtype=torch.float32, device=self.device)

    @property
    def storage(self) -> dict[str, dict[str, torch.Tensor]]:
        """Each env's buffers by field, shape (num_tasks, capacity_per_task, ...), staged steps written."""
        self.flush()
        return self._storage

    def _spec(self, env: str) -> EnvSpec:
        if env not in self.specs:
            raise UnknownNameError("environment", env, list(self.specs))
        return self.specs[env]

    def add(
        self,
        env: str,
        task_ids: np.ndarray,
        obs: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        next_obs: np.ndarray,
        terminations: np.ndarray,
    ) -> None:
        """Store one step of N instances of `env`; instance i belongs to task task_ids[i] (repeats allowed)."""
        spec = self._spec(env)
        task_ids = np.asarray(task_ids, dtype=np.int64).reshape(-1)
        n = task_ids.shape[0]
        if n == 0:
            return
        if task_ids.min() < 0 or task_ids.max() >= spec.num_tasks:
            raise SealError(
                f"replay.add({env!r}): task ids must be in [0, {spec.num_tasks}), got {sorted(set(task_ids.tolist()))}"
            )
        # Rank of each instance among those of the same task, so repeats get consecutive slots.
        order = np.argsort(task_ids, kind="stable")
        sorted_ids = task_ids[order]
        rank = np.empty(n, np.int64)
        rank[order] = np.arange(n) - np.searchsorted(sorted_ids, sorted_ids, side="left")
        cap = self.capacity_per_task[env]
        slots = (self.position[env][task_ids] + rank) % cap
        store = self._storage[env]
        values = {
            "obs": obs,
            "actions": actions,
            "rewards": rewards,
            "next_obs": next_obs,
            "terminations": terminations,
        }
        self._staged[env].append(
            (
                task_ids,
                slots,
                {
                    f: np.array(values[f], dtype=np.float32).reshape(n, *store[f].shape[2:])
                    for f in _FIELDS
                },
            )
        )
        added = np.bincount(task_ids, minlength=spec.num_tasks)
        self.position[env] = (self.position[env] + added) % cap
        self.size[env] = np.minimum(self.size[env] + added, cap)

    def flush(self) -> None:
        """Write the staged steps into the buffers: one host-to-device copy per env and field.

        A slot written twice since the last flush (a ring that wrapped) keeps its latest step.
        """
        for env, staged in self._staged.items():
            if not staged:
                continue
            task_ids = np.concatenate([t for t, _, _ in staged])
            slots = np.concatenate([s for _, s, _ in staged])
            cap = self.capacity_per_task[env]
            # The last write of each (task, slot): unique over the reversed flat keys.
            flat = (task_ids * cap + slots)[::-1]
            _, first_in_reversed = np.unique(flat, return_index=True)
            keep = len(flat) - 1 - first_in_reversed
            index = (
                torch.from_numpy(task_ids[keep]).to(self.device),
                torch.from_numpy(slots[keep]).to(self.device),
            )
            for field in _FIELDS:
                rows = np.concatenate([v[field] for _, _, v in staged])[keep]
                self._storage[env][field][index] = torch.from_numpy(rows).to(self.device)
            self._size_on_device[env].copy_(torch.from_numpy(self.size[env]))
            staged.clear()

    def _task_ids(self, env: str, counts: np.ndarray) -> torch.Tensor:
        """counts[t] copies of each task id t on the device (cached: a schedule repeats its counts)."""
        key = (env, counts.tobytes())
        ids = self._ids_cache.get(key)
        if ids is None:
            if len(self._ids_cache) > 256:
                self._ids_cache.clear()
            ids = torch.from_numpy(np.repeat(np.arange(len(counts)), counts)).to(self.device)
            self._ids_cache[key] = ids
        return ids

    def reseed(self, seed: int) -> None:
        """Seed every env's row stream from (seed, env name): common random numbers, so an env's
        draws do not depend on which other envs share the replay."""
        self.generators = {
            env: stream(seed, "replay", env, device=self.device) for env in self.specs
        }

    def sample(self, counts: Mapping[str, np.ndarray]) -> dict[str, Batch]:
        """Draw counts[env][t] transitions uniformly with replacement from each task's buffer.

        Returns one Batch per env with a non-zero total, rows grouped by task in task order, and
        adds the counts to `consumed` (each sample feeds one update). Rows are drawn on the
        replay's device by `generator`; nothing is copied from the host but cached task ids.
        """
        self.flush()
        batches: dict[str, Batch] = {}
        for env, env_counts in counts.items():
            spec = self._spec(env)
            env_counts = np.asarray(env_counts, dtype=np.int64)
            if env_counts.shape != (spec.num_tasks,) or (env_counts < 0).any():
                raise SealError(
                    f"replay.sample: counts of {env!r} must be {spec.num_tasks} non-negative ints (one per task), got {env_counts.tolist()}"
                )
            if env_counts.sum() == 0:
                continue
            empty = np.flatnonzero((env_counts > 0) & (self.size[env] == 0))
            if empty.size:
                raise SealError(
                    f"replay.sample: {env!r} task(s) {empty.tolist()} have no transitions yet but were asked for {env_counts[empty].tolist()}"
                )
            task_ids = self._task_ids(env, env_counts)
            # Uniform rows below each task's size: 62 random bits modulo the size (bias < 2**-40).
            draws = torch.randint(
                0, 1 << 62, task_ids.shape, generator=self.generators[env], device=self.device
            )
            rows = draws % self._size_on_device[env][task_ids]
            store = self._storage[env]
            batches[env] = Batch(
                *(store[field][task_ids, rows] for field in _FIELDS), task_ids=task_ids
            )
            self.consumed[env] += env_counts
        return batches

    def state_dict(self) -> ReplayState:
        """Contents (only the filled rows) and counters, as tensors so torch.load(weights_only=True) reads them."""
        state: ReplayState = {
            "capacity_per_task": dict(self.capacity_per_task),
            "generators": {env: g.get_state() for env, g in self.generators.items()},
            "envs": {},
        }
        for env, store in self.storage.items():
            filled = int(self.size[env].max())
            state["envs"][env] = {
                **{field: store[field][:, :filled].to("cpu", copy=True) for field in _FIELDS},
                "size": torch.from_numpy(self.size[env].copy()),
                "position": torch.from_numpy(self.position[env].copy()),
                "consumed": torch.from_numpy(self.consumed[env].copy()),
            }
        return state

    def load_state_dict(self, state: ReplayState) -> None:
        """Restore `state_dict` output into buffers of the same envs and capacities."""
        if dict(state["capacity_per_task"]) != self.capacity_per_task:
            raise SealError(
                f"replay state has capacities per task {dict(state['capacity_per_task'])}, but this replay has {self.capacity_per_task}"
            )
        # A state saved before the per-env streams (one "generator", or none) keeps this
        # replay's freshly seeded streams: that resume draws other rows than the run would have.
        for env, saved_generator in state.get("generators", {}).items():
            self.generators[env].set_state(saved_generator)
        for env, saved in state["envs"].items():
            self._spec(env)
            store = self.storage[env]
            previous = int(self.size[env].max())
            for field in _FIELDS:
                filled = saved[field].shape[1]
                store[field][:, :filled] = saved[field].to(self.device)
                # Clear only rows this replay had filled: zeroing the whole capacity would make
                # every lazily mapped page resident.
                store[field][:, filled:previous] = 0.0
            self.size[env] = saved["size"].numpy().copy()
            self.position[env] = saved["position"].numpy().copy()
            self.consumed[env] = saved["consumed"].numpy().copy()
            self._size_on_device[env].copy_(saved["size"])

    def consumed_counts(self) -> dict[str, np.ndarray]:
        """A copy of the per-task counters of transitions used by updates."""
        return {env: c.copy() for env, c in self.consumed.items()}
