"""Curricula from the Meta-World multi-task strategies report.

Curriculum V1 (staged, Tables B.3 and C.3): explicit phases, each a number of env steps and a task
distribution. The distribution is the composition of the update batch; tasks with a share > 0
collect one episode per epoch, tasks with share 0 do not collect.

Curriculum V2 (progressive, §III-B): phases with task sets and success thresholds. Training moves
to the next phase at the first evaluation, after the phase began, at which the mean success over
the phase's tasks reaches the phase's threshold (or after `max_env_steps`, if set). The phase's
tasks collect every epoch and the update batch is uniform over them. Presets:

- `sequential`: phase k holds the k easiest tasks (one task added per phase).
- `mixed`: seven cumulative phases of rising difficulty. For Meta-World MT10 (the report names the
  seven phases but does not list them) we group the tasks by how hard they proved in SMT's
  Table 1 (per-task success of five MT10 baselines) and in the report's own MT10 runs:

  ====  ============================================  ===========================================
  P1    reach, drawer-close                           every baseline ~100%; a reach and a push
  P2    + window-open, window-close                   SMT's easy set; sliding a handle
  P3    + drawer-open, button-press-topdown           ~100% in SMT Table 1; need a grasp/precise press
  P4    + door-open                                   easy in SMT, 0% in the report's one-hot run
  P5    + peg-insert-side                             0-80% in SMT Table 1
  P6    + push                                        0-44% for baselines, SMT 62%
  P7    + pick-place                                  0% for every baseline, SMT 34%
  ====  ============================================  ===========================================

  For task sets outside this table (e.g. the kitchen or `point`), `order` (easiest first, default
  the protocol's task order) is split into min(7, n) cumulative groups.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from pydantic import with_config

from seal.errors import ConfigError
from seal.schedulers.base import (
    GRAD_STEPS_COLLECTED,
    Plan,
    Progress,
    Scheduler,
    SchedulerConfig,
    TaskKey,
    scale_duration,
)
from seal.typed_config import SCHEMA

# ---- Curriculum V1 presets: the report's tables, task -> percent per phase ------------------------
TABLE_B3_STEPS = (9_000_000, 3_000_000, 3_000_000, 3_000_000, 3_000_000, 12_000_000)
TABLE_B3: dict[str, tuple[float, ...]] = {
    "reach-v3": (50.0, 20.0, 0.0, 13.3, 13.3, 6.7),
    "push-v3": (50.0, 70.0, 100.0, 53.3, 40.0, 33.3),
    "pick-place-v3": (0.0, 10.0, 0.0, 33.3, 46.7, 60.0),
}
TABLE_C3_STEPS = (3_000_000, 3_000_000, 6_000_000, 3_000_000, 6_000_000, 3_000_000)
TABLE_C3: dict[str, tuple[float, ...]] = {
    "reach-v3": (10.0, 6.7, 3.3, 3.3, 3.3, 10.0),
    "push-v3": (10.0, 13.3, 16.7, 33.3, 30.0, 6.7),
    "pick-place-v3": (10.0, 13.3, 16.7, 6.7, 3.3, 0.0),
    "door-open-v3": (10.0, 13.3, 16.7, 10.0, 6.7, 10.0),
    "drawer-open-v3": (10.0, 6.7, 3.3, 3.3, 3.3, 10.0),
    "drawer-close-v3": (10.0, 6.7, 3.3, 3.3, 3.3, 10.0),
    "button-press-topdown-v3": (10.0, 6.7, 3.3, 3.3, 3.3, 10.0),
    "peg-insert-side-v3": (10.0, 13.3, 16.7, 6.7, 10.0, 0.0),
    "window-open-v3": (10.0, 6.7, 3.3, 3.3, 3.3, 10.0),
    # The extracted table ends at window-open-v3 (the page is cut) and its columns sum to less
    # than 100%; window-close-v3 takes each phase's remainder (in the table's 1/15, 1/30 units).
    "window-close-v3": (10.0, 13.3, 16.7, 26.7, 33.3, 33.3),
}

# ---- Curriculum V2 presets: Meta-World difficulty ------------------------------------------------
# Easiest first, from SMT Table 1 and the report's MT10 results (see the module docstring).
METAWORLD_ORDER: tuple[str, ...] = (
    "reach-v3",
    "drawer-close-v3",
    "window-open-v3",
    "window-close-v3",
    "drawer-open-v3",
    "button-press-topdown-v3",
    "door-open-v3",
    "peg-insert-side-v3",
    "push-v3",
    "pick-place-v3",
)
MIXED_TIERS: dict[str, int] = {
    "reach-v3": 1,
    "drawer-close-v3": 1,
    "window-open-v3": 2,
    "window-close-v3": 2,
    "drawer-open-v3": 3,
    "button-press-topdown-v3": 3,
    "door-open-v3": 4,
    "peg-insert-side-v3": 5,
    "push-v3": 6,
    "pick-place-v3": 7,
}
MIXED_PHASES = 7


@with_config(SCHEMA)
@dataclass(frozen=True, kw_only=True)
class CurriculumPhase:
    """One phase of a staged curriculum: how long it lasts and the task distribution."""

    env_steps: int
    """Env steps collected in this phase (all tasks together); a schedule duration."""
    weights: dict[str, float] = field(default_factory=dict)
    """Task ("task" or "env/task") -> share of the update batch, in percent or fractions (normalised); missing = 0."""


@with_config(SCHEMA)
@dataclass(frozen=True, kw_only=True)
class CurriculumV1Config(SchedulerConfig):
    """kind = "curriculum_v1": explicit phases of env steps and task distributions (report Tables B.3, C.3)."""

    kind: ClassVar[str] = "curriculum_v1"
    preset: str = ""
    """"table_b3" (MT3, 33e6 env steps) or "table_c3" (MT10, 24e6 env steps); or give `phases`."""
    phases: tuple[CurriculumPhase, ...] = ()
    """The phases in order ([[scheduler.phases]] tables with env_steps and weights)."""
    stop_at_end: bool = True
    """Stop training when the last phase ends (the report's total time steps are the phases' sum)."""
    grad_steps: int = 0
    """Gradient steps per epoch: 0 = the runner's default, -1 = as many as env steps collected (the report), n > 0 = n."""

    def scale(self, factor: float) -> CurriculumV1Config:
        """A copy with every phase length multiplied by `factor` (floor 1)."""
        phases = tuple(
            dataclasses.replace(p, env_steps=scale_duration(p.env_steps, factor))
            for p in self.resolved_phases()
        )
        return dataclasses.replace(self, preset="", phases=phases)

    def resolved_phases(self) -> tuple[CurriculumPhase, ...]:
        """The preset's phases, or the given ones."""
        if not self.preset:
            return self.phases
        presets = {"table_b3": (TABLE_B3_STEPS, TABLE_B3), "table_c3": (TABLE_C3_STEPS, TABLE_C3)}
        if self.preset not in presets:
            raise ConfigError(
                f"scheduler.preset = {self.preset!r}: unknown curriculum_v1 preset; valid: {', '.join(presets)}"
            )
        if self.phases:
            raise ConfigError(
                "scheduler: give either scheduler.preset or scheduler.phases, not both"
            )
        steps, table = presets[self.preset]
        return tuple(
            CurriculumPhase(env_steps=s, weights={t: w[i] for t, w in table.items()})
            for i, s in enumerate(steps)
        )

    def _build(
        self,
        env_tasks: Mapping[str, Sequence[str]],
        *,
        seed: int,
        adapters: Mapping[str, str] | None,
        episode_lengths: Mapping[str, int] | None,
    ) -> Scheduler:
        return build_curriculum(self, env_tasks)


@with_config(SCHEMA)
@dataclass(frozen=True, kw_only=True)
class ProgressivePhase:
    """One phase of a progressive curriculum: its tasks and the success that opens the next phase."""

    tasks: tuple[str, ...]
    """Tasks ("task" or "env/task") trained in this phase; the batch is uniform over them."""
    threshold: float = 0.8
    """Mean evaluation success over this phase's tasks at which training moves to the next phase."""
    max_env_steps: int = 0
    """Move on after this many env steps in the phase even below the threshold; 0 = no limit."""


@with_config(SCHEMA)
@dataclass(frozen=True, kw_only=True)
class CurriculumV2Config(SchedulerConfig):
    """kind = "curriculum_v2": progressive phases gated by success thresholds (report §III-B)."""

    kind: ClassVar[str] = "curriculum_v2"
    DURATIONS: ClassVar[tuple[str, ...]] = ()
    preset: str = ""
    """"sequential" (add the tasks one at a time, easiest first) or "mixed" (seven phases); or give `phases`."""
    phases: tuple[ProgressivePhase, ...] = ()
    """The phases in order ([[scheduler.phases]] tables with tasks, threshold, max_env_steps)."""
    order: tuple[str, ...] = ()
    """For presets: the tasks easiest first; empty = built-in Meta-World order, else the protocol's task order."""
    threshold: float = 0.8
    """For presets: the success threshold of every phase."""
    max_phase_env_steps: int = 0
    """For presets: env steps after which a phase ends even below its threshold; 0 = no limit; a schedule duration."""
    grad_steps: int = 0
    """Gradient steps per epoch: 0 = the runner's default, -1 = as many as env steps collected (the report), n > 0 = n."""

    def scale(self, factor: float) -> CurriculumV2Config:
        """A copy with phase step limits multiplied by `factor` (floor 1; 0 = no limit stays 0)."""
        phases = tuple(
            dataclasses.replace(p, max_env_steps=scale_duration(p.max_env_steps, factor))
            for p in self.phases
        )
        return dataclasses.replace(
            self,
            phases=phases,
            max_phase_env_steps=scale_duration(self.max_phase_env_steps, factor),
        )

    def _build(
        self,
        env_tasks: Mapping[str, Sequence[str]],
        *,
        seed: int,
        adapters: Mapping[str, str] | None,
        episode_lengths: Mapping[str, int] | None,
    ) -> Scheduler:
        return build_curriculum(self, env_tasks)


def resolve_task(name: str, env_tasks: Mapping[str, Sequence[str]], key: str) -> TaskKey:
    """The (env, task) a curriculum names: "env/task", or a task name found in exactly one env."""
    if "/" in name:
        env, _, task = name.partition("/")
        if env in env_tasks and task in env_tasks[env]:
            return (env, task)
    else:
        hits = [(e, name) for e, ts in env_tasks.items() if name in ts]
        if len(hits) == 1:
            return hits[0]
        if len(hits) > 1:
            raise ConfigError(
                f"{key}: task {name!r} is in several envs {[e for e, _ in hits]}; write it as env/task"
            )
    valid = [f"{e}/{t}" for e, ts in env_tasks.items() for t in ts]
    raise ConfigError(f"{key}: unknown task {name!r}; the protocol's tasks are {', '.join(valid)}")


def resolve_tasks_once(
    names: Sequence[str], env_tasks: Mapping[str, Sequence[str]], key: str
) -> list[TaskKey]:
    """`resolve_task` of each name, refusing two names of one task ("east" and "pt/east")."""
    seen: dict[TaskKey, str] = {}
    for name in names:
        task = resolve_task(name, env_tasks, key)
        if task in seen:
            raise ConfigError(
                f"{key}: {seen[task]!r} and {name!r} both name task {task[0]}/{task[1]}; "
                "name each task once"
            )
        seen[task] = name
    return list(seen)


def _grad_steps(value: int) -> int | None:
    return None if value == 0 else (GRAD_STEPS_COLLECTED if value < 0 else value)


class CurriculumV1Scheduler(Scheduler):
    """Staged curriculum: each phase lasts a number of env steps and fixes the batch composition."""

    kind = "curriculum_v1"

    def __init__(
        self,
        env_tasks: Mapping[str, Sequence[str]],
        phases: Sequence[tuple[int, dict[TaskKey, float]]],
        stop_at_end: bool,
        grad_steps: int | None,
    ) -> None:
        super().__init__(env_tasks)
        self.phases = [(int(n), dict(w)) for n, w in phases]
        self.ends = np.cumsum([n for n, _ in self.phases]).tolist()
        self.stop_at_end = stop_at_end
        self.grad_steps = grad_steps
        self.env_steps = 0
        self.phase_index = -1

    def current_phase(self) -> int:
        """The phase the collected env steps are in (the last one after the end)."""
        for i, end in enumerate(self.ends):
            if self.env_steps < end:
                return i
        return len(self.phases) - 1

    def plan(self, progress: Progress) -> Plan:
        """Collect the phase's tasks with share > 0; the batch follows the phase's distribution."""
        index = self.current_phase()
        weights = self.phases[index][1]
        active = {k for k, w in weights.items() if w > 0}
        if index != self.phase_index:
            self.phase_index = index
            status = {k: f"P{index}" if k in active else "off" for k in self.task_keys}
            self._record(
                progress.epoch,
                self.env_steps,
                status,
                weight={k: weights.get(k, 0.0) for k in self.task_keys},
            )
        return Plan(
            collect=self._masks(active),
            batch_weights=self._weights(weights),
            grad_steps=self.grad_steps,
            phase=f"P{index}",
        )

    def observe_episodes(
        self,
        env: str,
        task_names: Sequence[str],
        returns: Sequence[float],
        successes: Sequence[float],
        env_steps: Sequence[int],
    ) -> None:
        """Count env steps toward the phase lengths."""
        self.env_steps += int(sum(env_steps))

    @property
    def done(self) -> bool:
        """True after the last phase's env steps (when stop_at_end)."""
        return self.stop_at_end and self.env_steps >= self.ends[-1]

    def state_dict(self) -> dict[str, Any]:
        """Env steps so far, the current phase and the timeline."""
        return {
            **super().state_dict(),
            "env_steps": self.env_steps,
            "phase_index": self.phase_index,
        }

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore what `state_dict` returned."""
        super().load_state_dict(state)
        self.env_steps = int(state["env_steps"])
        self.phase_index = int(state["phase_index"])


class CurriculumV2Scheduler(Scheduler):
    """Progressive curriculum: a phase ends when its tasks' mean evaluation success reaches its threshold."""

    kind = "curriculum_v2"

    def __init__(
        self,
        env_tasks: Mapping[str, Sequence[str]],
        phases: Sequence[tuple[tuple[TaskKey, ...], float, int]],
        grad_steps: int | None,
    ) -> None:
        super().__init__(env_tasks)
        self.phases = [(tuple(ts), float(th), int(mx)) for ts, th, mx in phases]
        self.grad_steps = grad_steps
        self.phase_index = 0
        self.phase_start_epoch = 0
        self.phase_env_steps = 0
        self.advance = False
        self.last_success: float | None = None
        self._recorded = -1

    def plan(self, progress: Progress) -> Plan:
        """Move on if the last evaluation (or the step limit) allows; collect the phase's tasks."""
        last = len(self.phases) - 1
        max_steps = self.phases[self.phase_index][2]
        if self.phase_index < last and (
            self.advance or (max_steps > 0 and self.phase_env_steps >= max_steps)
        ):
            self.phase_index += 1
            self.phase_start_epoch = progress.epoch
            self.phase_env_steps = 0
            self.advance = False
        tasks = self.phases[self.phase_index][0]
        if self._recorded != self.phase_index:
            self._recorded = self.phase_index
            status = {
                k: f"P{self.phase_index + 1}" if k in tasks else "off" for k in self.task_keys
            }
            self._record(
                progress.epoch,
                progress.env_steps,
                status,
                gate_success={k: self.last_success for k in self.task_keys},
            )
        return Plan(
            collect=self._masks(tasks),
            batch_weights=self._weights({k: 1.0 for k in tasks}),
            grad_steps=self.grad_steps,
            phase=f"P{self.phase_index + 1}",
        )

    def observe_episodes(
        self,
        env: str,
        task_names: Sequence[str],
        returns: Sequence[float],
        successes: Sequence[float],
        env_steps: Sequence[int],
    ) -> None:
        """Count env steps toward the phase's step limit."""
        self.phase_env_steps += int(sum(env_steps))

    def observe_eval(self, epoch: int, success: Mapping[TaskKey, float]) -> None:
        """Open the next phase if this evaluation, made after the phase began, reaches the threshold."""
        tasks, threshold, _ = self.phases[self.phase_index]
        if epoch <= self.phase_start_epoch or any(k not in success for k in tasks):
            return  # the policy evaluated has not trained in this phase yet (or tasks are missing)
        mean = float(np.mean([success[k] for k in tasks]))
        if mean >= threshold:
            self.advance = True
            self.last_success = mean

    def state_dict(self) -> dict[str, Any]:
        """The phase, when it began, its env steps, a pending move, and the timeline."""
        return {
            **super().state_dict(),
            "phase_index": self.phase_index,
            "phase_start_epoch": self.phase_start_epoch,
            "phase_env_steps": self.phase_env_steps,
            "advance": self.advance,
            "last_success": self.last_success,
            "recorded": self._recorded,
        }

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore what `state_dict` returned."""
        super().load_state_dict(state)
        self.phase_index = int(state["phase_index"])
        self.phase_start_epoch = int(state["phase_start_epoch"])
        self.phase_env_steps = int(state["phase_env_steps"])
        self.advance = bool(state["advance"])
        self.last_success = state["last_success"]
        self._recorded = int(state["recorded"])


def difficulty_order(
    config: CurriculumV2Config, env_tasks: Mapping[str, Sequence[str]]
) -> list[TaskKey]:
    """The protocol's tasks easiest first: `order`, else the built-in Meta-World order, else as listed."""
    keys = [(e, t) for e, ts in env_tasks.items() for t in ts]
    if config.order:
        order = [resolve_task(n, env_tasks, "scheduler.order") for n in config.order]
        missing = [f"{e}/{t}" for e, t in keys if (e, t) not in order]
        twice = sorted({f"{e}/{t}" for e, t in order if order.count((e, t)) > 1})
        if missing or twice:
            found = [f"missing: {missing}"] * bool(missing) + [f"listed twice: {twice}"] * bool(
                twice
            )
            raise ConfigError(
                f"scheduler.order must list every task of the protocol once; {'; '.join(found)}"
            )
        return order
    if all(t in METAWORLD_ORDER for _, t in keys):
        return sorted(keys, key=lambda k: METAWORLD_ORDER.index(k[1]))
    return keys


def preset_phases(
    config: CurriculumV2Config, env_tasks: Mapping[str, Sequence[str]]
) -> list[tuple[tuple[TaskKey, ...], float, int]]:
    """The phases of the `sequential` or `mixed` preset (cumulative task sets)."""
    order = difficulty_order(config, env_tasks)
    if config.preset == "sequential":
        groups = [[k] for k in order]
    elif config.preset == "mixed":
        if not config.order and all(t in MIXED_TIERS for _, t in order):
            tiers = sorted({MIXED_TIERS[t] for _, t in order})
            groups = [[k for k in order if MIXED_TIERS[k[1]] == tier] for tier in tiers]
        else:
            groups = [
                list(g)
                for g in np.array_split(np.arange(len(order)), min(MIXED_PHASES, len(order)))
            ]
            groups = [[order[i] for i in g] for g in groups]
    else:
        raise ConfigError(
            f"scheduler.preset = {config.preset!r}: unknown curriculum_v2 preset; valid: sequential, mixed"
        )
    phases, so_far = [], []
    for group in groups:
        so_far = so_far + group
        phases.append((tuple(so_far), config.threshold, config.max_phase_env_steps))
    return phases


def build_curriculum(
    config: CurriculumV1Config | CurriculumV2Config, env_tasks: Mapping[str, Sequence[str]]
) -> Scheduler:
    """A curriculum scheduler with its task names resolved and values validated."""
    if config.grad_steps < -1:
        raise ConfigError(
            f"scheduler.grad_steps = {config.grad_steps!r}: must be -1, 0 or a positive number"
        )
    if isinstance(config, CurriculumV1Config):
        phases = []
        given = config.resolved_phases()
        if not given:
            raise ConfigError(
                "scheduler.phases: a curriculum_v1 needs at least one phase (or a preset: table_b3, table_c3)"
            )
        for i, phase in enumerate(given):
            where = f"scheduler.phases[{i}]"
            if phase.env_steps < 1:
                raise ConfigError(f"{where}.env_steps = {phase.env_steps!r}: must be >= 1")
            for name, w in phase.weights.items():
                if float(w) < 0:
                    raise ConfigError(f"{where}.weights.{name} = {w!r}: must be >= 0")
            keys = resolve_tasks_once(list(phase.weights), env_tasks, f"{where}.weights")
            weights = {k: float(w) for k, w in zip(keys, phase.weights.values(), strict=True)}
            if sum(weights.values()) <= 0:
                raise ConfigError(f"{where}.weights: at least one task needs a share > 0")
            phases.append((phase.env_steps, weights))
        return CurriculumV1Scheduler(
            env_tasks, phases, config.stop_at_end, _grad_steps(config.grad_steps)
        )
    if isinstance(config, CurriculumV2Config):
        if config.preset and config.phases:
            raise ConfigError(
                "scheduler: give either scheduler.preset or scheduler.phases, not both"
            )
        if not 0.0 <= config.threshold <= 1.0:
            raise ConfigError(f"scheduler.threshold = {config.threshold!r}: must be in [0, 1]")
        if config.max_phase_env_steps < 0:
            raise ConfigError(
                f"scheduler.max_phase_env_steps = {config.max_phase_env_steps!r}: must be >= 0 (0 = no limit)"
            )
        if config.phases:
            # The preset keys do nothing beside explicit phases: refused, not ignored.
            defaults = CurriculumV2Config()
            for key, per_phase in (
                ("order", "list each phase's tasks in scheduler.phases[i].tasks"),
                ("threshold", "set scheduler.phases[i].threshold"),
                ("max_phase_env_steps", "set scheduler.phases[i].max_env_steps"),
            ):
                value = getattr(config, key)
                if value != getattr(defaults, key):
                    shown = list(value) if isinstance(value, tuple) else value
                    raise ConfigError(
                        f"scheduler.{key} = {shown!r}: applies only to a preset, not to "
                        f"scheduler.phases; remove it and {per_phase}"
                    )
        if config.preset:
            resolved = preset_phases(config, env_tasks)
        else:
            if not config.phases:
                raise ConfigError(
                    "scheduler.phases: a curriculum_v2 needs phases or a preset (sequential, mixed)"
                )
            resolved = []
            for i, phase in enumerate(config.phases):
                where = f"scheduler.phases[{i}]"
                if not phase.tasks:
                    raise ConfigError(f"{where}.tasks: a phase needs at least one task")
                if not 0.0 <= phase.threshold <= 1.0:
                    raise ConfigError(f"{where}.threshold = {phase.threshold!r}: must be in [0, 1]")
                if phase.max_env_steps < 0:
                    raise ConfigError(
                        f"{where}.max_env_steps = {phase.max_env_steps!r}: must be >= 0 (0 = no limit)"
                    )
                tasks = tuple(resolve_tasks_once(phase.tasks, env_tasks, f"{where}.tasks"))
                resolved.append((tasks, phase.threshold, phase.max_env_steps))
        return CurriculumV2Scheduler(env_tasks, resolved, _grad_steps(config.grad_steps))
    raise ValueError(f"not a curriculum config: {type(config).__name__}")
