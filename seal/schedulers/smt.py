"""SMT, Scheduled Multi-Task training, hard tasks first (Cho et al., Algorithm 1, App. G.1, Table 6).

Every task sits in one of four pools: main, training (at most K slots), solved, unsolvable.

Stage 1 (the first B1 env steps):
- Only training-pool tasks collect. A task entering training gets the budget
  kappa * (B1 - B_used) / K env steps (App. G.1), B_used the stage-1 env steps spent so far.
- After each of its training episodes: if the mean return of its last n training episodes
  exceeds M it is solved; otherwise, once its budget is spent, it is unsolvable if that mean is
  below m and goes back to main if it is in between.
- An empty slot is refilled with the main-pool task of lowest Eq. 5 score (discounted return
  plus policy entropy, mean of n_eval trajectories, recomputed every T_eval env steps); before
  the first scores exist the choice is random (App. H). With main empty, fewer slots train.
- Every T_reset env steps the agent's parameters are re-initialised (`Plan.reset_agent`), the
  replay buffers kept.

Stage 2 (the next B2 env steps): only the unsolvable pool collects. Then `done` is True. If
stage 1 runs out of tasks early (main and training empty), stage 2 starts at once and also gets
the stage-1 budget left over, so B1 + B2 stays the total; with no unsolvable task it ends at once.

Budgets count env steps of the episodes the scheduler asked for (`observe_episodes`), so the
stage-1 and stage-2 spending add up to B1 + B2 (plus at most one epoch's collection of
overshoot per stage, since an epoch is never cut short).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import with_config

from seal.errors import ConfigError
from seal.schedulers.base import (
    GRAD_STEPS_COLLECTED,
    Plan,
    Progress,
    Scheduler,
    SchedulerConfig,
    ScoreRequest,
    TaskKey,
)
from seal.typed_config import SCHEMA

MAIN, TRAINING, SOLVED, UNSOLVABLE = "main", "training", "solved", "unsolvable"
POOLS: tuple[str, ...] = (MAIN, TRAINING, SOLVED, UNSOLVABLE)

# The paper prints no default M or m; its ablations (Table 3) try M in {2000, 3000} and m in
# {500, 2000}, both M values hurting the easy tasks, so we read the defaults as M = 4000, m = 1000.
PAPER_SOLVED_RETURN = 4000.0
PAPER_UNSOLVABLE_RETURN = 1000.0
PAPER_EPISODE_LENGTH = 500
# Episode lengths of the built-in adapters, for the per-env defaults of M and m.
KNOWN_EPISODE_LENGTHS: dict[str, int] = {"metaworld": 500, "franka_kitchen_dense": 280}


@with_config(SCHEMA)
@dataclass(frozen=True, kw_only=True)
class SMTConfig(SchedulerConfig):
    """kind = "smt": hard-tasks-first scheduling with budgets, resets and a second stage (Table 6, MT10)."""

    kind: ClassVar[str] = "smt"
    DURATIONS: ClassVar[tuple[str, ...]] = (
        "budget_stage1",
        "budget_stage2",
        "score_interval",
        "reset_interval",
    )
    budget_stage1: int = 17_000_000
    """B1: env steps of stage 1 (Table 6, MT10: 1.7e7); a schedule duration."""
    budget_stage2: int = 3_000_000
    """B2: env steps of stage 2, unsolvable pool only (Table 6, MT10: 3e6); a schedule duration."""
    kappa: float = 0.8
    """A task entering training gets kappa * (B1 - B_used) / K env steps (Table 6, MT10: 0.8)."""
    slots: int = 3
    """K: tasks trained at once (Table 6, MT10: 3)."""
    solved_return: dict[str, float] = field(default_factory=dict)
    """M per env: solved when the recent mean return exceeds it; missing env = 4000 * episode_length / 500."""
    unsolvable_return: dict[str, float] = field(default_factory=dict)
    """m per env: unsolvable when the budget runs out below it; missing env = 1000 * episode_length / 500."""
    recent_episodes: int = 5
    """n: training episodes whose mean return is compared with M and m (App. G.1: the latest five)."""
    score_episodes: int = 5
    """n_eval: stochastic trajectories per task for the Eq. 5 score (App. G.2: 5)."""
    score_interval: int = 500_000
    """T_eval: env steps between score evaluations (App. H: synchronised with T_reset); a schedule duration."""
    reset: bool = True
    """Re-initialise the agent every reset_interval env steps of stage 1 (Table 4 ablates it)."""
    reset_interval: int = 500_000
    """T_reset: env steps between resets (Table 6, MT10: 5e5); a schedule duration."""
    discount: float = 0.99
    """gamma of the Eq. 5 score's discounted return (Table 6: 0.99)."""
    batch: Literal["all", "collecting"] = "all"
    """"all": the batch is uniform over every task with data (the paper's loss over C, §4.1); "collecting": only this epoch's tasks."""
    grad_steps: int = 0
    """Gradient steps per epoch: 0 = the runner's default, -1 = as many as env steps collected, n > 0 = n."""

    def _build(
        self,
        env_tasks: Mapping[str, Sequence[str]],
        *,
        seed: int,
        adapters: Mapping[str, str] | None,
        episode_lengths: Mapping[str, int] | None,
    ) -> Scheduler:
        return build_smt_scheduler(
            self, env_tasks, seed=seed, adapters=adapters, episode_lengths=episode_lengths
        )


def default_return_thresholds(
    config: SMTConfig, envs: Sequence[str], episode_lengths: Mapping[str, int]
) -> tuple[dict[str, float], dict[str, float]]:
    """M and m per env: the config's values, else the paper's values scaled by episode_length / 500."""
    solved, unsolvable = {}, {}
    for key, given in (
        ("solved_return", config.solved_return),
        ("unsolvable_return", config.unsolvable_return),
    ):
        unknown = sorted(set(given) - set(envs))
        if unknown:
            raise ConfigError(
                f"scheduler.{key}: unknown env(s) {unknown}; the protocol's envs are {list(envs)}"
            )
    for env in envs:
        length = episode_lengths.get(env)
        if length is None and (
            env not in config.solved_return or env not in config.unsolvable_return
        ):
            raise ConfigError(
                f"scheduler.solved_return.{env} / scheduler.unsolvable_return.{env}: no default for env {env!r} "
                f"(episode length unknown); set both (paper, 500-step episodes: M = {PAPER_SOLVED_RETURN:g}, m = {PAPER_UNSOLVABLE_RETURN:g})"
            )
        ratio = (length or PAPER_EPISODE_LENGTH) / PAPER_EPISODE_LENGTH
        solved[env] = float(config.solved_return.get(env, PAPER_SOLVED_RETURN * ratio))
        unsolvable[env] = float(config.unsolvable_return.get(env, PAPER_UNSOLVABLE_RETURN * ratio))
        if unsolvable[env] > solved[env]:
            raise ConfigError(
                f"scheduler.unsolvable_return.{env} = {unsolvable[env]:g} exceeds scheduler.solved_return.{env} = {solved[env]:g}"
            )
    return solved, unsolvable


class SMTScheduler(Scheduler):
    """Algorithm 1 of SMT as a scheduler: pools, budgets, refill by Eq. 5 score, resets, stage 2."""

    kind = "smt"

    def __init__(
        self,
        env_tasks: Mapping[str, Sequence[str]],
        config: SMTConfig,
        solved_return: Mapping[str, float],
        unsolvable_return: Mapping[str, float],
        seed: int = 0,
    ) -> None:
        super().__init__(env_tasks)
        self.config = config
        self.solved_return = dict(solved_return)
        self.unsolvable_return = dict(unsolvable_return)
        self._rng = np.random.default_rng(seed)
        self.pool: dict[TaskKey, str] = {k: MAIN for k in self.task_keys}
        self.training: list[TaskKey] = []  # slot order, for stable plans and logs
        self.budget: dict[TaskKey, int] = {k: 0 for k in self.task_keys}
        self.visit_used: dict[TaskKey, int] = {k: 0 for k in self.task_keys}
        self.used: dict[TaskKey, int] = {k: 0 for k in self.task_keys}
        self.recent: dict[TaskKey, list[float]] = {k: [] for k in self.task_keys}
        self.scores: dict[TaskKey, float] | None = None
        self.stage = 1
        self.stage_used = {1: 0, 2: 0}
        self.stage2_budget = config.budget_stage2
        self.resets_done = 0
        self.scores_done = 0
        self.has_data: set[TaskKey] = set()
        self._collecting: set[TaskKey] = set()
        self._epoch = 0
        self._dirty = True
        self._done = False
        self._started = False

    # ---- pools ---------------------------------------------------------------------------
    def members(self, pool: str) -> list[TaskKey]:
        """The tasks in `pool`, in task order (training: slot order)."""
        if pool == TRAINING:
            return list(self.training)
        return [k for k in self.task_keys if self.pool[k] == pool]

    def _move(self, key: TaskKey, pool: str) -> None:
        if self.pool[key] == TRAINING:
            self.training.remove(key)
        self.pool[key] = pool
        if pool == TRAINING:
            self.training.append(key)
        self._dirty = True

    def _recent_mean(self, key: TaskKey) -> float:
        window = self.recent[key][-self.config.recent_episodes :]
        return float(np.mean(window)) if window else -math.inf

    def _enter_training(self, key: TaskKey) -> None:
        """App. G.1: the budget is kappa * (B1 - B_used) / K env steps (at least 1)."""
        remaining = self.config.budget_stage1 - self.stage_used[1]
        self.budget[key] = max(1, int(self.config.kappa * remaining / self.config.slots))
        self.visit_used[key] = 0
        self._move(key, TRAINING)

    def _pick_from_main(self) -> TaskKey:
        main = self.members(MAIN)
        if self.scores is None:
            return main[int(self._rng.integers(len(main)))]
        # Hard task first: the lowest Eq. 5 score; ties go to the earlier task.
        return min(main, key=lambda k: (self.scores.get(k, -math.inf), self.task_keys.index(k)))

    # ---- the runner's calls --------------------------------------------------------------
    def plan(self, progress: Progress) -> Plan:
        """Collect the training pool (stage 1) or the unsolvable pool (stage 2); reset on schedule."""
        self._epoch = progress.epoch
        config = self.config
        if not self._started:
            # Algorithm 1 lines 4-6: K random tasks start in training.
            self._started = True
            for _ in range(min(config.slots, len(self.task_keys))):
                self._enter_training(self._pick_from_main())
        reset = False
        if self.stage == 1 and (
            self.stage_used[1] >= config.budget_stage1 or not (self.training or self.members(MAIN))
        ):
            # Stage 1 ends after B1 env steps, or early when no task is left to train. Tasks
            # still in training were not judged: they go back to main.
            for key in list(self.training):
                self._move(key, MAIN)
            self.stage = 2
            # B_total = B1 + B2 is fixed (§4.3): stage-1 budget left by an early end goes to stage 2.
            self.stage2_budget = config.budget_stage2 + max(
                0, config.budget_stage1 - self.stage_used[1]
            )
            self._dirty = True
        if self.stage == 1:
            if config.reset and self.stage_used[1] // config.reset_interval > self.resets_done:
                self.resets_done = self.stage_used[1] // config.reset_interval
                reset = True
            while len(self.training) < config.slots and self.members(MAIN):
                self._enter_training(self._pick_from_main())
            collecting = set(self.training)
        else:
            if self.stage_used[2] >= self.stage2_budget or not self.members(UNSOLVABLE):
                if not self._done:
                    self._done = True
                    self._dirty = True
                collecting = set()
            else:
                collecting = set(self.members(UNSOLVABLE))
        self._collecting = collecting
        with_data = self.has_data | collecting
        weighted = with_data if config.batch == "all" or not collecting else collecting
        weights = self._weights({k: 1.0 for k in weighted})
        if self._dirty:
            self._snapshot()
        label = "done" if self._done else f"stage{self.stage}"
        grad_steps = (
            None
            if config.grad_steps == 0
            else (GRAD_STEPS_COLLECTED if config.grad_steps < 0 else config.grad_steps)
        )
        return Plan(
            collect=self._masks(collecting),
            batch_weights=weights,
            reset_agent=reset,
            grad_steps=grad_steps,
            phase=label,
        )

    def observe_episodes(
        self,
        env: str,
        task_names: Sequence[str],
        returns: Sequence[float],
        successes: Sequence[float],
        env_steps: Sequence[int],
    ) -> None:
        """Spend budgets and move tasks between pools (Algorithm 1 lines 9-19)."""
        for name, ret, steps in zip(task_names, returns, env_steps, strict=True):
            key = (env, name)
            self.has_data.add(key)
            if key not in self._collecting:
                continue  # e.g. the runner's warm-up episodes: not a training episode
            self.stage_used[self.stage] += int(steps)
            self.used[key] += int(steps)
            self.recent[key] = (self.recent[key] + [float(ret)])[-self.config.recent_episodes :]
            if self.stage != 1 or self.pool[key] != TRAINING:
                continue
            self.visit_used[key] += int(steps)
            mean = self._recent_mean(key)
            if mean > self.solved_return[env]:
                self._move(key, SOLVED)
            elif self.visit_used[key] >= self.budget[key]:
                self._move(key, UNSOLVABLE if mean < self.unsolvable_return[env] else MAIN)

    def wants_scores(self) -> ScoreRequest | None:
        """Every T_eval stage-1 env steps: Eq. 5 scores of every task (used to refill from main)."""
        if self.stage != 1 or self.stage_used[1] // self.config.score_interval <= self.scores_done:
            return None
        return ScoreRequest(
            tasks=self.task_keys, episodes=self.config.score_episodes, discount=self.config.discount
        )

    def observe_scores(self, scores: Mapping[TaskKey, float]) -> None:
        """Store the new scores; the next refills use them."""
        self.scores = {tuple(k): float(v) for k, v in scores.items()}  # type: ignore[misc]
        self.scores_done = self.stage_used[1] // self.config.score_interval
        self._dirty = True

    @property
    def done(self) -> bool:
        """True once stage 2 has spent its budget (or had no unsolvable task to train)."""
        return self._done

    @property
    def budget_used(self) -> int:
        """Env steps spent so far, stage 1 and stage 2 together."""
        return self.stage_used[1] + self.stage_used[2]

    # ---- logging and resume ----------------------------------------------------------------
    def _snapshot(self) -> None:
        status = {
            k: ("done:" + self.pool[k]) if self._done else self.pool[k] for k in self.task_keys
        }
        scores = self.scores or {}
        self._record(
            self._epoch,
            self.budget_used,
            status,
            stage={k: self.stage for k in self.task_keys},
            budget={k: self.budget[k] for k in self.task_keys},
            used={k: self.used[k] for k in self.task_keys},
            recent_return={
                k: (self._recent_mean(k) if self.recent[k] else None) for k in self.task_keys
            },
            score={k: scores.get(k) for k in self.task_keys},
        )
        self._dirty = False

    def state_dict(self) -> dict[str, Any]:
        """Pools, budgets, spending, recent returns, scores, counters and the RNG, as JSON values."""

        def keyed(d: Mapping[TaskKey, Any]) -> list[list[Any]]:
            return [[k[0], k[1], v] for k, v in d.items()]

        return {
            **super().state_dict(),
            "pool": keyed(self.pool),
            "training": [list(k) for k in self.training],
            "budget": keyed(self.budget),
            "visit_used": keyed(self.visit_used),
            "used": keyed(self.used),
            "recent": keyed(self.recent),
            "scores": None if self.scores is None else keyed(self.scores),
            "stage": self.stage,
            "stage_used": [self.stage_used[1], self.stage_used[2]],
            "stage2_budget": self.stage2_budget,
            "resets_done": self.resets_done,
            "scores_done": self.scores_done,
            "has_data": [list(k) for k in sorted(self.has_data)],
            "collecting": [list(k) for k in sorted(self._collecting)],
            "epoch": self._epoch,
            "dirty": self._dirty,
            "done": self._done,
            "started": self._started,
            "rng": self._rng.bit_generator.state,
        }

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore what `state_dict` returned."""
        super().load_state_dict(state)

        def unkeyed(rows: list[list[Any]]) -> dict[TaskKey, Any]:
            return {(r[0], r[1]): r[2] for r in rows}

        self.pool = unkeyed(state["pool"])
        self.training = [(k[0], k[1]) for k in state["training"]]
        self.budget = {k: int(v) for k, v in unkeyed(state["budget"]).items()}
        self.visit_used = {k: int(v) for k, v in unkeyed(state["visit_used"]).items()}
        self.used = {k: int(v) for k, v in unkeyed(state["used"]).items()}
        self.recent = {k: [float(x) for x in v] for k, v in unkeyed(state["recent"]).items()}
        self.scores = (
            None
            if state["scores"] is None
            else {k: float(v) for k, v in unkeyed(state["scores"]).items()}
        )
        self.stage = int(state["stage"])
        self.stage_used = {1: int(state["stage_used"][0]), 2: int(state["stage_used"][1])}
        self.stage2_budget = int(state["stage2_budget"])
        self.resets_done = int(state["resets_done"])
        self.scores_done = int(state["scores_done"])
        self.has_data = {(k[0], k[1]) for k in state["has_data"]}
        self._collecting = {(k[0], k[1]) for k in state["collecting"]}
        self._epoch = int(state["epoch"])
        self._dirty = bool(state["dirty"])
        self._done = bool(state["done"])
        self._started = bool(state["started"])
        self._rng.bit_generator.state = state["rng"]


def build_smt_scheduler(
    config: SMTConfig,
    env_tasks: Mapping[str, Sequence[str]],
    seed: int = 0,
    adapters: Mapping[str, str] | None = None,
    episode_lengths: Mapping[str, int] | None = None,
) -> SMTScheduler:
    """An SMTScheduler with validated settings and per-env M and m."""
    checks = [
        ("budget_stage1", config.budget_stage1 >= 1, ">= 1 env step"),
        ("budget_stage2", config.budget_stage2 >= 0, ">= 0 env steps"),
        ("kappa", 0.0 < config.kappa <= 1.0, "in (0, 1]"),
        ("slots", config.slots >= 1, ">= 1"),
        ("recent_episodes", config.recent_episodes >= 1, ">= 1"),
        ("score_episodes", config.score_episodes >= 1, ">= 1"),
        ("score_interval", config.score_interval >= 1, ">= 1 env step"),
        ("reset_interval", config.reset_interval >= 1, ">= 1 env step"),
        ("discount", 0.0 <= config.discount <= 1.0, "in [0, 1]"),
        ("batch", config.batch in ("all", "collecting"), '"all" or "collecting"'),
        ("grad_steps", config.grad_steps >= -1, "-1, 0 or a positive number"),
    ]
    for key, ok, valid in checks:
        if not ok:
            raise ConfigError(f"scheduler.{key} = {getattr(config, key)!r}: must be {valid}")
    lengths: dict[str, int] = {}
    for env in env_tasks:
        adapter = (adapters or {}).get(env, env)
        if episode_lengths and env in episode_lengths:
            lengths[env] = int(episode_lengths[env])
        elif adapter in KNOWN_EPISODE_LENGTHS:
            lengths[env] = KNOWN_EPISODE_LENGTHS[adapter]
    solved, unsolvable = default_return_thresholds(config, list(env_tasks), lengths)
    return SMTScheduler(env_tasks, config, solved, unsolvable, seed=seed)
