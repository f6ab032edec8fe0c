"""Data-ratio schedules (SEAL §4.3): what fraction of each update batch comes from each environment.

`constant` keeps fixed fractions (e.g. 50/50); `stepped` starts at e.g. 90/10 and moves 10
points toward the other environment every 1,000 epochs until 50/50. The presets `high_fk` and
`high_mw` are the stepped schedules that start with 90% from the kitchen and from Meta-World.
Within an environment the batch is split uniformly over its tasks.

By default every task collects every epoch and the ratio sets only the update batch ("the data
the agent uses to optimise", §4.3). With `collect = "ratio"` an environment also collects only in
a share of the epochs proportional to its fraction (the environment with the largest fraction
collects every epoch).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import with_config

from seal.errors import ConfigError
from seal.schedulers.base import Plan, Progress, Scheduler, SchedulerConfig, TaskKey
from seal.typed_config import SCHEMA

CollectMode = Literal["all", "ratio"]

KITCHEN_ADAPTER = "franka_kitchen_dense"
METAWORLD_ADAPTER = "metaworld"

# preset -> (adapter whose data starts at 90%, the other adapter)
RATIO_PRESETS: dict[str, tuple[str, str]] = {
    "high_fk": (KITCHEN_ADAPTER, METAWORLD_ADAPTER),
    "high_mw": (METAWORLD_ADAPTER, KITCHEN_ADAPTER),
}

MAX_ABSENT_TASKS = 1_000
"""Largest `scheduler.absent` task count: a joint run trains all its tasks in one agent (Meta-World's largest set, MT50, has 50), and each absent task adds an entry to every epoch's batch split and batch_per_task x share to this run's per-update batch (10^12 asked 7.28 TiB)."""


@with_config(SCHEMA)
@dataclass(frozen=True, kw_only=True)
class UniformConfig(SchedulerConfig):
    """kind = "uniform": every task collects every epoch; the batch is uniform over all tasks (the default)."""

    kind: ClassVar[str] = "uniform"

    def _build(
        self,
        env_tasks: Mapping[str, Sequence[str]],
        *,
        seed: int,
        adapters: Mapping[str, str] | None,
        episode_lengths: Mapping[str, int] | None,
    ) -> Scheduler:
        return build_ratio_scheduler(self, env_tasks, adapters)


@with_config(SCHEMA)
@dataclass(frozen=True, kw_only=True)
class ConstantRatioConfig(SchedulerConfig):
    """kind = "constant": a fixed fraction of every update batch per environment (e.g. 50/50)."""

    kind: ClassVar[str] = "constant"
    ratios: dict[str, float] = field(default_factory=dict)
    """Env name -> fraction of the update batch (fractions sum to 1); empty = equal shares."""
    collect: CollectMode = "all"
    """"all": every task collects every epoch (issue 4 default); "ratio": envs collect in proportion to their fraction."""
    absent: dict[str, int] = field(default_factory=dict)
    """Envs of a joint run that this run stands in for but does not have, with their task counts: their share of the batch is not drawn, so each task here gets the per-step batch it gets in that joint run (a target-alone arm)."""

    def _build(
        self,
        env_tasks: Mapping[str, Sequence[str]],
        *,
        seed: int,
        adapters: Mapping[str, str] | None,
        episode_lengths: Mapping[str, int] | None,
    ) -> Scheduler:
        return build_ratio_scheduler(self, env_tasks, adapters)


@with_config(SCHEMA)
@dataclass(frozen=True, kw_only=True)
class SteppedRatioConfig(SchedulerConfig):
    """kind = "stepped": start at `start`, move `step` toward `end` every `interval` epochs (§4.3)."""

    kind: ClassVar[str] = "stepped"
    DURATIONS: ClassVar[tuple[str, ...]] = ("interval",)
    preset: str = ""
    """"high_fk" (90% kitchen at the start) or "high_mw" (90% Meta-World); sets `start` from the env adapters."""
    start: dict[str, float] = field(default_factory=dict)
    """Env name -> fraction of the update batch at epoch 0 (sum 1); e.g. {fk = 0.9, mw = 0.1}."""
    end: dict[str, float] = field(default_factory=dict)
    """Env name -> final fraction (sum 1); empty = equal shares (50/50 for two envs)."""
    step: float = 0.1
    """Fraction moved toward `end` at each step (§4.3: 10 points)."""
    interval: int = 1000
    """Epochs between steps (§4.3: 1,000); a schedule duration, scaled by --scale."""
    start_fraction: float = 0.9
    """With a preset: the starting fraction of the preset's high environment (§4.3: 0.9)."""
    collect: CollectMode = "all"
    """"all": every task collects every epoch (issue 4 default); "ratio": envs collect in proportion to their fraction."""
    absent: dict[str, int] = field(default_factory=dict)
    """Envs of a joint run that this run stands in for but does not have, with their task counts: their share of the batch is not drawn, so each task here gets the per-step batch it gets in that joint run (a target-alone arm)."""

    def _build(
        self,
        env_tasks: Mapping[str, Sequence[str]],
        *,
        seed: int,
        adapters: Mapping[str, str] | None,
        episode_lengths: Mapping[str, int] | None,
    ) -> Scheduler:
        return build_ratio_scheduler(self, env_tasks, adapters)


def _check_fractions(
    values: Mapping[str, float], envs: Sequence[str], key: str
) -> dict[str, float]:
    """Validate an env -> fraction table against the protocol's envs; empty means equal shares."""
    if not values:
        return {e: 1.0 / len(envs) for e in envs}
    unknown = sorted(set(values) - set(envs))
    missing = sorted(set(envs) - set(values))
    if unknown or missing:
        raise ConfigError(
            f"{key}: env names {sorted(values)} must be exactly the protocol's envs {list(envs)} (unknown: {unknown}, missing: {missing})"
        )
    for env, v in values.items():
        if not 0.0 <= float(v) <= 1.0:
            raise ConfigError(f"{key}.{env} = {v!r}: a fraction must be in [0, 1]")
    total = sum(float(v) for v in values.values())
    if abs(total - 1.0) > 1e-6:
        raise ConfigError(f"{key} = {dict(values)}: fractions must sum to 1, they sum to {total:g}")
    return {e: float(values[e]) for e in envs}


def _check_absent(absent: Mapping[str, int], envs: Sequence[str]) -> dict[str, int]:
    """Validate `scheduler.absent` (env name -> task count) against the protocol's envs."""
    for env, tasks in absent.items():
        if env in envs:
            raise ConfigError(
                f"scheduler.absent.{env}: {env!r} is one of the protocol's envs {list(envs)}; absent envs must not be"
            )
        if not isinstance(tasks, int) or isinstance(tasks, bool) or tasks < 1:
            raise ConfigError(f"scheduler.absent.{env} = {tasks!r}: expected a task count >= 1")
        if tasks > MAX_ABSENT_TASKS:
            raise ConfigError(
                f"scheduler.absent.{env} = {tasks!r}: expected a task count of at most "
                f"{MAX_ABSENT_TASKS:,} (the joint run's tasks of env {env!r}; each one enlarges every update's batch)"
            )
    return dict(absent)


def _check_present_share(
    fractions: Mapping[str, float], envs: Sequence[str], absent: Mapping[str, int], key: str
) -> None:
    """With `absent` envs the fractions may leave this run's own envs nothing: refused, since
    no update could then draw a single transition."""
    if absent and not any(fractions[e] > 0 for e in envs):
        raise ConfigError(
            f"{key} = {dict(fractions)}: no env of this run ({', '.join(envs)}) has a share > 0, "
            f"only the absent {', '.join(absent)}, so no update would draw a batch; "
            f"give at least one of {', '.join(envs)} a fraction > 0"
        )


def resolve_preset(config: SteppedRatioConfig, adapters: Mapping[str, str]) -> dict[str, float]:
    """The `start` fractions of a preset, finding the kitchen and Meta-World envs by adapter name."""
    if config.preset not in RATIO_PRESETS:
        raise ConfigError(
            f"scheduler.preset = {config.preset!r}: unknown; valid: {', '.join(RATIO_PRESETS)} (or give scheduler.start)"
        )
    high, low = RATIO_PRESETS[config.preset]
    by_adapter = {a: e for e, a in adapters.items()}
    if set(adapters.values()) != {high, low} or len(adapters) != 2:
        raise ConfigError(
            f"scheduler.preset = {config.preset!r} needs exactly two envs with adapters {high!r} and {low!r}; "
            f"the protocol has {dict(adapters)} (give scheduler.start instead)"
        )
    return {
        by_adapter[high]: config.start_fraction,
        by_adapter[low]: round(1.0 - config.start_fraction, 12),
    }


class RatioScheduler(Scheduler):
    """Per-env batch fractions that follow a function of the epoch, uniform over tasks within an env."""

    kind = "ratio"

    def __init__(
        self,
        env_tasks: Mapping[str, Sequence[str]],
        fractions_at: Callable[[int], dict[str, float]],
        collect: CollectMode = "all",
        label: str = "ratio",
        absent: Mapping[str, int] | None = None,
    ) -> None:
        super().__init__(env_tasks)
        self._fractions_at = fractions_at
        self._absent = dict(absent or {})
        self.collect_mode: CollectMode = collect
        self.label = label
        # Credits for collect = "ratio": starting at 1 makes every env collect in epoch 0, so
        # every env has data before its fraction of the batch is drawn.
        self._credit = {e: 1.0 for e in self.env_tasks}
        self._has_data = {e: False for e in self.env_tasks}
        self._last: dict[str, float] | None = None

    def fractions(self, epoch: int) -> dict[str, float]:
        """The fraction of the update batch from each env at `epoch`."""
        return self._fractions_at(epoch)

    def plan(self, progress: Progress) -> Plan:
        """Batch fractions for this epoch; collection of every task, or in proportion to the fractions."""
        fractions = self.fractions(progress.epoch)
        if self.collect_mode == "all":
            collecting = {e: True for e in self.env_tasks}
        else:
            biggest = max(fractions.values())
            collecting = {}
            for e in self.env_tasks:
                f = fractions[e]
                # An env collects whenever its credit reaches 1, then gains f / biggest per epoch.
                collecting[e] = self._credit[e] >= 1.0 - 1e-9
                if collecting[e]:
                    self._credit[e] -= 1.0
                self._credit[e] += f / biggest if biggest > 0 else 0.0
        for e, c in collecting.items():
            self._has_data[e] = self._has_data[e] or c
        raw = {
            e: np.full(len(ts), fractions[e] / len(ts) if self._has_data[e] and ts else 0.0)
            for e, ts in self.env_tasks.items()
        }
        total = sum(float(w.sum()) for w in raw.values())
        weights = {e: w / total if total > 0 else w for e, w in raw.items()}
        # Absent envs' shares are not drawn: this run's envs get exactly their joint-run batch.
        absent = {e: np.full(n, fractions[e] / n) for e, n in self._absent.items()}
        collect = {
            e: np.full(len(ts), collecting[e], dtype=bool) for e, ts in self.env_tasks.items()
        }
        if fractions != self._last:
            self._last = dict(fractions)
            status: dict[TaskKey, str] = {(e, t): f"{fractions[e]:.4g}" for e, t in self.task_keys}
            self._record(progress.epoch, progress.env_steps, status)
        label = f"{self.label} " + "/".join(f"{fractions[e]:.4g}" for e in self.env_tasks)
        return Plan(collect=collect, batch_weights=weights, phase=label, absent_weights=absent)

    def state_dict(self) -> dict[str, Any]:
        """Collection credits, which envs have data, and the timeline."""
        return {
            **super().state_dict(),
            "credit": dict(self._credit),
            "has_data": dict(self._has_data),
            "last": self._last,
        }

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore what `state_dict` returned."""
        super().load_state_dict(state)
        self._credit = {e: float(v) for e, v in state["credit"].items()}
        self._has_data = {e: bool(v) for e, v in state["has_data"].items()}
        self._last = (
            None if state.get("last") is None else {e: float(v) for e, v in state["last"].items()}
        )


def stepped_fractions(
    start: Mapping[str, float], end: Mapping[str, float], step: float, interval: int, epoch: int
) -> dict[str, float]:
    """Fractions after epoch // interval steps of `step` from `start` toward `end` (each clipped at its end).

    Rounded to 12 decimals so that 0.9 - 3 * 0.1 reads 0.6, then renormalised to sum 1.
    """
    k = epoch // interval
    moved = {}
    for e, s in start.items():
        gap = end[e] - s
        moved[e] = s + float(np.sign(gap)) * min(abs(gap), k * step)
    total = sum(moved.values())
    return {e: round(v / total, 12) for e, v in moved.items()}


def build_ratio_scheduler(
    config: UniformConfig | ConstantRatioConfig | SteppedRatioConfig,
    env_tasks: Mapping[str, Sequence[str]],
    adapters: Mapping[str, str] | None = None,
) -> RatioScheduler:
    """A RatioScheduler for a uniform, constant or stepped config, validated against the protocol's envs."""
    envs = list(env_tasks)
    absent = _check_absent(getattr(config, "absent", {}), envs)
    envs_all = [*envs, *absent]
    if isinstance(config, UniformConfig):
        sizes = {e: len(ts) for e, ts in env_tasks.items()}
        n = sum(sizes.values())
        # Uniform over tasks: each env's share is its number of tasks over all tasks.
        fixed = {e: sizes[e] / n for e in envs}
        return RatioScheduler(env_tasks, lambda epoch: fixed, "all", label="uniform")
    if isinstance(config, ConstantRatioConfig):
        fixed = _check_fractions(config.ratios, envs_all, "scheduler.ratios")
        _check_present_share(fixed, envs, absent, "scheduler.ratios")
        return RatioScheduler(
            env_tasks, lambda epoch: fixed, config.collect, label="constant", absent=absent
        )
    if isinstance(config, SteppedRatioConfig):
        if config.interval < 1:
            raise ConfigError(f"scheduler.interval = {config.interval!r}: must be >= 1 epoch")
        if not 0.0 < config.step <= 1.0:
            raise ConfigError(f"scheduler.step = {config.step!r}: must be in (0, 1]")
        if config.preset:
            if absent:
                raise ConfigError(
                    "scheduler.absent: a preset names both of its envs; give scheduler.start instead"
                )
            if config.start:
                raise ConfigError(
                    "scheduler: give either scheduler.preset or scheduler.start, not both"
                )
            if not 0.0 <= config.start_fraction <= 1.0:
                raise ConfigError(
                    f"scheduler.start_fraction = {config.start_fraction!r}: must be in [0, 1]"
                )
            start_raw = resolve_preset(
                config, adapters if adapters is not None else {e: e for e in envs}
            )
        else:
            if not config.start:
                raise ConfigError(
                    f"scheduler.start: a stepped schedule needs start fractions per env {envs} or a preset ({', '.join(RATIO_PRESETS)})"
                )
            if config.start_fraction != SteppedRatioConfig().start_fraction:
                raise ConfigError(
                    f"scheduler.start_fraction = {config.start_fraction!r}: applies only to a "
                    "preset, not to scheduler.start; remove it and give the fractions in scheduler.start"
                )
            start_raw = config.start
        start = _check_fractions(start_raw, envs_all, "scheduler.start")
        end = _check_fractions(config.end, envs_all, "scheduler.end")
        # Each env moves monotonically from start to end, so this run's envs have a share > 0 at
        # every epoch exactly when they have one at the start and at the end.
        _check_present_share(start, envs, absent, "scheduler.start")
        _check_present_share(end, envs, absent, "scheduler.end")
        label = config.preset or "stepped"
        return RatioScheduler(
            env_tasks,
            lambda epoch: stepped_fractions(start, end, config.step, config.interval, epoch),
            config.collect,
            label=label,
            absent=absent,
        )
    raise ValueError(f"not a ratio config: {type(config).__name__}")
