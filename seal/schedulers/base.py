"""The scheduler interface: what the protocol runner asks, every epoch, about what to train on.

A scheduler decides two things at each scheduling interval (one epoch of the runner):

1. which (environment, task) pairs collect an episode (`Plan.collect`), and
2. in what proportions the update batch draws from each pair (`Plan.batch_weights`).

Data-ratio schedules (issue 4), SMT (hard tasks first) and the curricula are all schedulers; the
runner knows only this module. The runner drives a scheduler like this, once per epoch::

    plan = scheduler.plan(progress)                     # start of the epoch
    if plan.reset_agent:
        agent.reset_parameters()                        # SMT reset: buffers are kept
    for env in envs:                                    # collect where plan.collect[env] is True
        ... one episode per collecting task ...
        scheduler.observe_episodes(env, task_names, returns, successes, env_steps)
    counts = plan.batch_counts(env, total_batch)        # per-task transitions of each update
    ... grad steps (plan.grad_steps, None = the runner's default) ...
    if evaluation epoch:
        scheduler.observe_eval(epoch, {(env, task): success})
    request = scheduler.wants_scores()                  # SMT's Eq. 5 scores, when it wants them
    if request is not None:
        scheduler.observe_scores({key: score for key in request.tasks})
    if scheduler.done:
        stop training (after the usual final evaluation and checkpoint)

`state_dict()` goes into every checkpoint (it is JSON-serialisable) and `load_state_dict()`
restores it on resume; `timeline()` returns the records the runner writes to `scheduler.csv`.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, Self

import numpy as np
from pydantic import with_config

from seal.errors import ConfigError, SealError, UnknownNameError
from seal.typed_config import SCHEMA

TaskKey = tuple[str, str]
"""(environment name, task name): one task instance of one environment."""

GRAD_STEPS_COLLECTED = -1
"""`Plan.grad_steps` value meaning: as many gradient steps as env steps collected this epoch, all
envs and tasks together (Stable-Baselines3's `gradient_steps=-1`, the report's setting). Note
that this differs from `[training].grad_steps_per_epoch = -1` (one episode's worth of steps)."""


TimelineRow = dict[str, int | float | str | None]
"""One record of `Scheduler.timeline()`: epoch, env_steps, env, task, status and extras."""


@dataclass(frozen=True)
class Progress:
    """Where training stands, passed to `Scheduler.plan` at the start of every epoch."""

    epoch: int
    """Epochs completed so far (0 at the first call)."""
    env_steps: int = 0
    """Env steps collected so far, all environments and tasks together (warm-up included)."""
    grad_steps: int = 0
    """Gradient steps taken so far."""
    task_env_steps: Mapping[TaskKey, int] = field(default_factory=dict)
    """Env steps collected so far per (env, task); may be empty if the runner does not track it."""


@dataclass(frozen=True)
class ScoreRequest:
    """SMT asks the runner for Eq. 5 scores of these tasks (see `Scheduler.wants_scores`).

    The score of a task is the mean over `episodes` trajectories, sampled with the *stochastic*
    policy, of sum_t (discount**t * r_t - log pi(a_t | s_t)) (t from 0): discounted return plus
    the policy's entropy along the trajectory (SMT Eq. 5, the constant C dropped).
    """

    tasks: tuple[TaskKey, ...]
    """The (env, task) pairs to score."""
    episodes: int
    """n_eval: trajectories per task (SMT Appendix G.2: 5)."""
    discount: float
    """gamma in Eq. 5."""


@dataclass(frozen=True)
class Plan:
    """What to do this epoch: which tasks collect, and the composition of the update batch.

    `collect[env]` is a bool array over that env's tasks (in the order given to
    `build_scheduler`): True means that task instance collects one episode this epoch. It may be
    all False for an env (or for every env: then the runner collects nothing this epoch).

    `batch_weights[env]` is a float array over that env's tasks: the fraction of every update
    batch drawn from each (env, task). All weights are >= 0 and, over all envs together, sum to
    1. A task gets weight > 0 only if it has data: it collected in an earlier epoch or collects in
    this one. An env whose weights are all 0 takes no part in this epoch's updates.
    """

    collect: dict[str, np.ndarray]
    """Per env, bool mask over its tasks: which task instances collect an episode this epoch."""
    batch_weights: dict[str, np.ndarray]
    """Per env, per-task nonnegative weights; all envs together sum to 1."""
    reset_agent: bool = False
    """Re-initialise actor, critics, targets, temperatures and optimisers before collecting (SMT)."""
    grad_steps: int | None = None
    """Gradient steps after this epoch's collection; None = the runner's default; -1 = GRAD_STEPS_COLLECTED."""
    phase: str = ""
    """A short label for logs (e.g. "ratio 0.8/0.2", "stage1", "P3")."""
    absent_weights: dict[str, np.ndarray] = field(default_factory=dict)
    """Per-task weights, in the joint run, of the envs a run stands in for but lacks
    (`scheduler.absent`): their share is not drawn, and the rounding is the joint run's, so this
    run's tasks get exactly the counts they get there. Empty for every other run."""

    def env_fraction(self, env: str) -> float:
        """The fraction of the update batch drawn from `env`."""
        return float(self.batch_weights[env].sum())

    def batch_counts(
        self, total: int, rng: np.random.Generator | None = None
    ) -> dict[str, np.ndarray]:
        """Integer per-task sample counts of one update of `total` transitions, proportional to `batch_weights`.

        Largest-remainder rounding over all (env, task) pairs together. With `absent_weights`,
        `total` is this run's tasks' part of the joint run's batch: the joint total is split over
        the joint run's pairs and the absent envs' counts are dropped. Equal remainders (e.g.
        1152 samples over 10 equally weighted tasks) go to the earlier tasks, or, with `rng`, to
        tasks drawn at random so that no task is favoured on average. The counts are what the
        replay consumes, so the update-count metric stays exact either way.
        """
        if total < 0:
            raise ValueError(f"batch total must be >= 0, got {total}")
        if not self.absent_weights:
            return split_counts(self.batch_weights, total, rng)
        own = sum(len(w) for w in self.batch_weights.values())
        absent = sum(len(w) for w in self.absent_weights.values())
        share = 1.0 - float(sum(w.sum() for w in self.absent_weights.values()))
        joint = {e: np.asarray(w) * share for e, w in self.batch_weights.items()}
        counts = split_counts(
            {**joint, **self.absent_weights}, int(round(total * (own + absent) / own)), rng
        )
        return {e: counts[e] for e in self.batch_weights}


def split_counts(
    weights: Mapping[str, np.ndarray], total: int, rng: np.random.Generator | None = None
) -> dict[str, np.ndarray]:
    """Integer per-task counts summing to `total`, proportional to the per-(env, task) `weights`.

    The one ratio -> batch rounding (`Plan.batch_counts`, `counts_from_ratio`): largest remainder
    over all (env, task) pairs together; equal remainders go to the earlier tasks, or, with
    `rng`, to tasks drawn at random so that no task is favoured on average.
    """
    envs = list(weights)
    flat = np.concatenate([np.asarray(weights[e], dtype=np.float64) for e in envs])
    if flat.size == 0 or flat.sum() <= 0:
        counts = np.zeros(flat.size, dtype=np.int64)
    else:
        exact = flat / flat.sum() * total
        counts = np.floor(exact).astype(np.int64)
        remainder = exact - counts
        # A stable sort keeps the earlier (or, with rng, randomly permuted) task first among ties.
        perm = rng.permutation(flat.size) if rng is not None else np.arange(flat.size)
        order = perm[np.argsort(-remainder[perm], kind="stable")]
        counts[order[: total - int(counts.sum())]] += 1
    out: dict[str, np.ndarray] = {}
    start = 0
    for e in envs:
        n = len(weights[e])
        out[e] = counts[start : start + n]
        start += n
    return out


def counts_from_ratio(
    ratios: Mapping[str, float],
    num_tasks: Mapping[str, int],
    batch_per_task: int,
    rng: np.random.Generator | None = None,
) -> dict[str, np.ndarray]:
    """Per-task sample counts of one update from environment proportions.

    The update's total is batch_per_task * (total number of tasks of all envs in `num_tasks`),
    e.g. 128 * 10 = 1280 for MT10 alone; env e's share ratio_e / sum(ratios) is split uniformly
    over its tasks and rounded by `split_counts`, as the runner rounds a scheduler's plan.
    Envs missing from `ratios` get ratio 0.
    """
    unknown = sorted(set(ratios) - set(num_tasks))
    if unknown:
        raise UnknownNameError("environment", unknown[0], list(num_tasks))
    if batch_per_task < 1:
        raise SealError(f"batch_per_task must be >= 1, got {batch_per_task}")
    values = np.array([float(ratios.get(n, 0.0)) for n in num_tasks])
    if (values < 0).any() or not np.isfinite(values).all() or values.sum() <= 0:
        raise SealError(f"data ratios must be finite, >= 0 and not all 0, got {dict(ratios)}")
    weights = {n: np.full(t, float(ratios.get(n, 0.0)) / t) for n, t in num_tasks.items()}
    return split_counts(weights, batch_per_task * sum(num_tasks.values()), rng)


def normalise_weights(raw: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Scale per-env weight arrays so that all envs together sum to 1 (all zeros stay zeros)."""
    total = float(sum(np.asarray(w, dtype=np.float64).sum() for w in raw.values()))
    if total <= 0:
        return {e: np.zeros(len(w)) for e, w in raw.items()}
    return {e: np.asarray(w, dtype=np.float64) / total for e, w in raw.items()}


class Scheduler(abc.ABC):
    """Decides, every epoch, which (env, task) pairs collect and how the update batch is composed.

    Subclasses implement `plan`; every other hook has a do-nothing default. The task order of
    each env is the one given at construction (`env_tasks`), and every array in a `Plan` follows
    it. All state needed to resume lives in `state_dict()` (JSON-serialisable).
    """

    kind: ClassVar[str] = ""

    def __init__(self, env_tasks: Mapping[str, Sequence[str]]) -> None:
        self.env_tasks: dict[str, tuple[str, ...]] = {e: tuple(t) for e, t in env_tasks.items()}
        self.task_keys: tuple[TaskKey, ...] = tuple(
            (e, t) for e, ts in self.env_tasks.items() for t in ts
        )
        self._timeline: list[TimelineRow] = []

    # ---- the runner's calls --------------------------------------------------------------
    @abc.abstractmethod
    def plan(self, progress: Progress) -> Plan:
        """The plan for the epoch that starts now. Called exactly once per epoch."""

    def observe_episodes(
        self,
        env: str,
        task_names: Sequence[str],
        returns: Sequence[float],
        successes: Sequence[float],
        env_steps: Sequence[int],
    ) -> None:
        """Episodes just collected in `env`: entry i is one episode of task `task_names[i]`.

        `returns` are undiscounted episode returns, `successes` 1.0 if the episode succeeded at
        any step, `env_steps` the episode's length in env steps. Called after collection, at most
        once per env per epoch, with the tasks the plan asked to collect.
        """
        return None  # an optional hook: schedulers that need it override it

    def observe_eval(self, epoch: int, success: Mapping[TaskKey, float]) -> None:
        """Success rates of the evaluation run after `epoch` epochs (the curricula's gates)."""
        return None  # an optional hook: schedulers that need it override it

    def wants_scores(self) -> ScoreRequest | None:
        """A request for Eq. 5 scores, or None. Asked at the end of every epoch (after updates).

        When it returns a request, the runner evaluates and passes the scores to
        `observe_scores` before the next `plan` call.
        """
        return None

    def observe_scores(self, scores: Mapping[TaskKey, float]) -> None:
        """The Eq. 5 scores asked for by the last `wants_scores` request."""
        return None  # an optional hook: schedulers that need it override it

    @property
    def done(self) -> bool:
        """True when the schedule has ended and training should stop (e.g. SMT after B1 + B2)."""
        return False

    # ---- resume and logging --------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """Everything needed to resume, as JSON-serialisable values."""
        return {"timeline": list(self._timeline)}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore what `state_dict` returned."""
        self._timeline = [dict(r) for r in state.get("timeline", [])]

    def timeline(self) -> list[TimelineRow]:
        """Records of pool or phase membership over time, one row per (env, task) per snapshot.

        Every record has `epoch`, `env_steps`, `env`, `task`, `status` (pool or phase
        membership), and scheduler-specific extras (SMT: `budget`, `used`, `score`). A snapshot
        of every task is recorded whenever membership changes; the runner writes them to a CSV.
        """
        return list(self._timeline)

    # ---- helpers for subclasses ------------------------------------------------------------
    def _index(self, key: TaskKey) -> int:
        return self.env_tasks[key[0]].index(key[1])

    def _masks(self, keys: Sequence[TaskKey] | set[TaskKey]) -> dict[str, np.ndarray]:
        """Bool masks over each env's tasks, True for the given keys."""
        out = {e: np.zeros(len(ts), dtype=bool) for e, ts in self.env_tasks.items()}
        for key in keys:
            out[key[0]][self._index(key)] = True
        return out

    def _weights(self, weight_of: Mapping[TaskKey, float]) -> dict[str, np.ndarray]:
        """Per-env weight arrays from a {(env, task): weight} map, normalised to sum to 1."""
        out = {e: np.zeros(len(ts), dtype=np.float64) for e, ts in self.env_tasks.items()}
        for key, w in weight_of.items():
            out[key[0]][self._index(key)] = w
        return normalise_weights(out)

    def _record(
        self,
        epoch: int,
        env_steps: int,
        status: Mapping[TaskKey, str],
        **extras: Mapping[TaskKey, float | None],
    ) -> None:
        """Append one snapshot (a row per task) to the timeline."""
        for key in self.task_keys:
            row: TimelineRow = {
                "epoch": int(epoch),
                "env_steps": int(env_steps),
                "env": key[0],
                "task": key[1],
                "status": status[key],
            }
            for name, values in extras.items():
                row[name] = values.get(key)
            self._timeline.append(row)


def scale_duration(value: int, factor: float) -> int:
    """A schedule duration multiplied by `--scale` (rounded), with a floor of 1.

    A value <= 0 is a sentinel ("off", "no limit", e.g. SMT's `budget_stage2 = 0` or a
    curriculum's `max_phase_env_steps = 0`), not a duration: it is kept as it is, never made 1.
    """
    if value <= 0:
        return value
    return max(1, int(round(value * factor)))


@with_config(SCHEMA)
@dataclass(frozen=True, kw_only=True)
class SchedulerConfig:
    """Base of the [scheduler] table's dataclasses: one subclass per `kind`.

    `DURATIONS` names the fields that are schedule durations (in epochs or env steps); `scale`
    multiplies exactly those by `--scale F` with a floor of 1 (0 and other sentinels <= 0 kept),
    never per-epoch quantities.
    """

    kind: ClassVar[str] = ""
    DURATIONS: ClassVar[tuple[str, ...]] = ()

    def scale(self, factor: float) -> Self:
        """A copy with every schedule duration multiplied by `factor` (floor 1; values <= 0 kept)."""
        changes = {name: scale_duration(getattr(self, name), factor) for name in self.DURATIONS}
        return dataclasses.replace(self, **changes)

    def build(
        self,
        env_tasks: Mapping[str, Sequence[str]],
        *,
        seed: int = 0,
        adapters: Mapping[str, str] | None = None,
        episode_lengths: Mapping[str, int] | None = None,
        source: str = "",
    ) -> Scheduler:
        """The scheduler of this config over `env_tasks` (env -> task names, in order).

        `adapters` (env -> adapter name) lets presets find the kitchen and Meta-World envs,
        `episode_lengths` gives SMT's default M and m, `seed` seeds SMT's first pick. Errors are
        ConfigErrors naming `source` (the protocol file) and the `scheduler.key`.
        """
        try:
            return self.make(
                env_tasks,
                seed=seed,
                adapters=adapters,
                episode_lengths=episode_lengths,
                source=source,
            )
        except ConfigError:
            raise
        except (SealError, TypeError, ValueError) as exc:
            raise ConfigError(f"{source}: scheduler: {exc}") from None

    def make(
        self,
        env_tasks: Mapping[str, Sequence[str]],
        *,
        seed: int = 0,
        adapters: Mapping[str, str] | None = None,
        episode_lengths: Mapping[str, int] | None = None,
        source: str = "",
    ) -> Scheduler:
        """`build` without turning other errors into ConfigErrors (`registry.build_scheduler`)."""
        try:
            if not env_tasks or not all(env_tasks.values()):
                raise ConfigError(
                    f"scheduler: every env needs at least one task, got {dict(env_tasks)}"
                )
            return self._build(
                env_tasks, seed=seed, adapters=adapters, episode_lengths=episode_lengths
            )
        except ConfigError as exc:
            raise ConfigError(f"{source}: {exc}" if source else str(exc)) from None

    def _build(
        self,
        env_tasks: Mapping[str, Sequence[str]],
        *,
        seed: int,
        adapters: Mapping[str, str] | None,
        episode_lengths: Mapping[str, int] | None,
    ) -> Scheduler:
        """The scheduler itself; each kind's config defines it."""
        raise ValueError(f"no scheduler for config type {type(self).__name__}")

    def to_table(self) -> dict[str, Any]:
        """The resolved [scheduler] table (for the run's saved config), `kind` first."""
        table: dict[str, Any] = {"kind": self.kind}
        for f in dataclasses.fields(self):
            table[f.name] = _plain(getattr(self, f.name))
        return table


def _plain(value: Any) -> Any:
    """Dataclasses, tuples and mappings as TOML/JSON-friendly dicts and lists."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    return value
