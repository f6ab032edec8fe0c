"""The transfer testbed's statistics: what one run's target cost, and what seeds of arms resolve.

From one run's metrics.csv: the target's transitions and gradient steps until each of its tasks
first reaches 90% (`target_cost`, a `TargetCost`) and the area under each task's success curve
(`target_auc`). Seed for seed against an arm's alone arm (`summarise`): the savings
(`steps_saved`, `updates_saved`) and AUC gains with their 95% CIs (`ARM_CI`: Student's t, cut at
the statistic's range: `SAVED_BOUNDS`, `AUC_GAIN_BOUNDS`) and what the seeds can resolve
(`seal.stats.paired_power`: paired SD, MDE, seeds for an MDE of 0.10).
Beside them: the linear CKA of the source's and the target's representations (`alignment`), how far
the target's success curve moves when only its source changes (`source_sensitivity`), and the
false-positive rate of the arms' CI method on two halves of the alone arm, where no effect exists
(`false_positive_rate`). The methods themselves (intervals, MDE, IQM, the split false-positive
rate) are `seal.stats`'; this module applies them to the testbed's runs.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from seal.errors import SealError
from seal.experiments.arms import TARGET_ENV, TESTBED, Arm
from seal.experiments.records import last_checkpoint
from seal.metrics import DEFAULT_THRESHOLD, first_reach

# ---------------------------------------------------------------- reading one run


@dataclass(frozen=True)
class TargetCost:
    """What one run's target env consumed until its tasks first reached the threshold."""

    consumed: float
    """Transitions consumed by updates until first >= threshold, summed over tasks (censored tasks: their total)."""
    grad_steps: int
    """Gradient steps until every task had first reached the threshold (censored: the run's total)."""
    censored: int
    """Tasks that never reached the threshold."""
    tasks: int
    per_task: dict[str, float]
    """Transitions per task (the summands of `consumed`)."""
    reached: tuple[str, ...]
    """The tasks that reached the threshold."""
    per_task_steps: dict[str, int] = field(default_factory=dict)
    """Gradient steps per task until it first reached the threshold (censored: the run's total)."""

    @property
    def task_steps(self) -> int:
        """Gradient steps summed over the tasks: `consumed` = task_steps x `per_step`, exactly."""
        return int(sum(self.per_task_steps.values()))

    @property
    def per_step(self) -> float:
        """The target's mean per-step batch per task over the spans to 90% (transitions / task-steps)."""
        return self.consumed / self.task_steps if self.task_steps else math.nan


def target_cost(
    metrics: pd.DataFrame,
    env: str = TARGET_ENV,
    threshold: float = DEFAULT_THRESHOLD,
    consecutive: int = 1,
) -> TargetCost:
    """The target's `TargetCost` from one run's metrics table (metrics.csv, one seed, one phase).

    Steps and transitions count from the run's first update: the target's first update in
    every testbed arm (a pre-training is a run of its own). `consecutive` > 1 is the robust
    criterion of `seal.metrics.first_reach`.
    """
    rows = metrics[metrics["env"] == env]
    if rows.empty:
        raise SealError(
            f"metrics table has no rows of env {env!r}; envs: {sorted(set(metrics['env']))}"
        )
    first = (
        first_reach(rows, threshold)
        if consecutive == 1
        else first_reach(rows, threshold, consecutive=consecutive)
    )
    # A task never reached counts as all it consumed, at the run's last evaluation.
    per_task: dict[str, float] = {}
    per_task_steps: dict[str, int] = {}
    for row in first.itertuples(index=False):
        millions = float(row.updates) if row.reached else float(row.run_updates)
        per_task[str(row.task)] = millions * 1e6
        per_task_steps[str(row.task)] = int(row.grad_steps if row.reached else row.run_grad_steps)
    return TargetCost(
        consumed=float(sum(per_task.values())),
        grad_steps=max(per_task_steps.values()),
        censored=int((~first["reached"]).sum()),
        tasks=len(first),
        per_task=per_task,
        reached=tuple(str(t) for t in first.loc[first["reached"], "task"]),
        per_task_steps=per_task_steps,
    )


def target_budget(metrics: pd.DataFrame, env: str = TARGET_ENV) -> int:
    """The gradient step of a run's last evaluation of `env` (its budget, unless it stopped early)."""
    return int(metrics.loc[metrics["env"] == env, "grad_steps"].max())


def target_auc(
    metrics: pd.DataFrame, budget: int | None = None, env: str = TARGET_ENV
) -> dict[str, float]:
    """Per task of `env`: the area under its evaluated success over gradient steps 0..budget, / budget.

    Trapezoids between evaluations. The curve starts at the run's evaluation at step 0 where it
    made one (the testbed's first evaluations fall in the warm-up), else at success 0 at step 0
    (an untrained policy succeeds in about 0.6% of point_view's episodes); after its last
    evaluation it holds that value up to `budget` (default: the run's own last evaluated step),
    and evaluations past `budget` are cut there.
    """
    rows = metrics[metrics["env"] == env]
    if rows.empty:
        raise SealError(
            f"metrics table has no rows of env {env!r}; envs: {sorted(set(metrics['env']))}"
        )
    budget = target_budget(metrics, env) if budget is None else int(budget)
    if budget <= 0:
        raise SealError(f"AUC budget {budget} gradient steps: expected > 0")
    out: dict[str, float] = {}
    for task, frame in rows.sort_values(["epoch", "grad_steps"], kind="stable").groupby(
        "task", sort=False
    ):
        steps = frame["grad_steps"].to_numpy(dtype=float)
        success = frame["success"].to_numpy(dtype=float)
        if steps[0] > 0:
            steps, success = np.r_[0.0, steps], np.r_[0.0, success]
        inside = steps < budget
        x = np.r_[steps[inside], budget]
        y = np.r_[success[inside], np.interp(budget, steps, success)]  # holds the last value
        out[str(task)] = float(np.trapezoid(y, x) / budget)
    return out


def saved(arm: Sequence[float], alone: Sequence[float]) -> list[float]:
    """Per seed i: the share of the alone arm's mean cost the arm saved in seed i
    (`seal.stats.saving`: (alone_i - arm_i) / mean(alone), whose mean is 1 - mean(arm) /
    mean(alone)); all nan where the alone arm's mean cost is 0."""
    from seal.stats import saving

    if len(arm) != len(alone):
        raise SealError(f"{len(arm)} seeds of the arm but {len(alone)} of its target-alone arm")
    return saving(arm, alone).tolist()


def updates_saved(arm: Sequence[TargetCost], alone: Sequence[TargetCost]) -> list[float]:
    """Per seed: the saving of the target's consumed transitions (`saved`)."""
    return saved([a.consumed for a in arm], [b.consumed for b in alone])


def steps_saved(arm: Sequence[TargetCost], alone: Sequence[TargetCost]) -> list[float]:
    """Per seed: the saving of the target's gradient steps to 90% (`saved`)."""
    return saved([a.grad_steps for a in arm], [b.grad_steps for b in alone])


# ---------------------------------------------------------------- paired statistics of the arms


SAVED_BOUNDS = (-math.inf, 1.0)
"""The range of a mean saving 1 - mean cost(arm) / mean cost(alone) (steps_saved,
transfer_updates_saved): costs are >= 0, so it is at most 1 (1: the arm reached at its first
evaluation, step 0, in every seed); below, only the arm's budget over the alone arm's cost bounds
it, so no fixed bound. (One seed's value can pass 1 where its alone cost is above the mean.)"""
AUC_GAIN_BOUNDS = (-1.0, 1.0)
"""The range of AUC(arm) - AUC(alone): each AUC is a mean success in [0, 1]."""
CHANGE_BOUNDS = (-1.0, math.inf)
"""The range of mean(arm) / mean(alone) - 1 of costs >= 0 (the changes table's Fieller CI)."""


def ARM_CI(  # noqa: N802 - a named constant
    values: Sequence[float], bounds: tuple[float, float] = (-math.inf, math.inf)
) -> tuple[float, float]:
    """The arms' 95% CI of a mean paired statistic over seeds: Student's t, cut at the statistic's
    range `bounds` (`seal.stats.bounded_t_ci`), which leaves its coverage as it is. Measured
    (`seal bench --learn transfer --fpr`, alone seeds 0-9, 1,000 random 5/5 splits): the
    percentile bootstrap the arms used called 17.2% [14.9, 19.7] of no-effect splits resolved, t
    5.3% [4.0, 6.9]; over 5 pairs the bootstrap's interval is too narrow. Near the bound (values
    piled at 1) t covers less than 95% at 5 seeds, the bootstrap less still
    (docs/transfer_testbed.md, "Intervals of bounded statistics")."""
    from seal.stats import bounded_t_ci

    return bounded_t_ci(values, bounds)


ROBUST_CONSECUTIVE = 2
"""The robust criterion reported beside the paper's: 2 successive evaluations >= 90%."""


def _saving(
    runs: Sequence[TargetCost], alone: Sequence[TargetCost], prefix: str = ""
) -> dict[str, Any]:
    """steps_saved and transfer_updates_saved per seed, their means, their 95% CIs (`ARM_CI`, at
    most 1: `SAVED_BOUNDS`), and what the seeds resolve of steps_saved (`paired_power` as
    `steps`, or `robust_steps`)."""
    from seal.stats import paired_power, probability_of_improvement

    steps, updates = steps_saved(runs, alone), updates_saved(runs, alone)
    return {
        **paired_power(steps, f"{prefix}steps"),
        f"{prefix}steps_saved_per_seed": steps,
        f"{prefix}steps_saved": float(np.nanmean(steps)),
        f"{prefix}ci95": list(ARM_CI(steps, SAVED_BOUNDS)),
        f"{prefix}transfer_updates_saved_per_seed": updates,
        f"{prefix}transfer_updates_saved": float(np.nanmean(updates)),
        f"{prefix}transfer_updates_saved_ci95": list(ARM_CI(updates, SAVED_BOUNDS)),
        # P(a run of the arm needs fewer target steps than a run of its alone arm), ties 1/2.
        f"{prefix}probability_of_improvement": probability_of_improvement(
            [c.grad_steps for c in runs], [c.grad_steps for c in alone]
        ),
    }


def _auc_summary(
    runs: Sequence[Mapping[str, float]], alone: Sequence[Mapping[str, float]] | None
) -> dict[str, Any]:
    """An arm's target AUC (`target_auc`, per seed and task): per seed (the tasks' mean), mean and
    IQM over (seed, task); against its alone arm the paired gain AUC(arm) - AUC(alone) per seed,
    its mean, CI (within [-1, 1]: `AUC_GAIN_BOUNDS`) and `paired_power` (as `auc`), and the IQM
    over (seed, task) of the gains."""
    from seal.stats import interquartile_mean, iqm_ci, paired_power

    tasks = list(runs[0])
    own = np.array([[run[t] for t in tasks] for run in runs])
    out: dict[str, Any] = {
        "auc_per_seed": own.mean(axis=1).tolist(),
        "auc_mean": float(own.mean()),
        "auc_iqm": interquartile_mean(own.ravel()),
    }
    if alone is not None:
        gains = own - np.array([[run[t] for t in tasks] for run in alone])
        per_seed = gains.mean(axis=1).tolist()
        out.update(
            auc_gain_per_seed=per_seed,
            auc_gain=float(np.mean(per_seed)),
            auc_gain_ci95=list(ARM_CI(per_seed, AUC_GAIN_BOUNDS)),
            auc_gain_iqm=interquartile_mean(gains.ravel()),
            auc_gain_iqm_ci95=list(iqm_ci(gains)),
            **paired_power(per_seed, "auc"),
        )
    return out


def summarise(
    costs: Mapping[str, Sequence[TargetCost]],
    chosen: Sequence[Arm],
    robust: Mapping[str, Sequence[TargetCost]] | None = None,
    cka: Mapping[str, Sequence[Mapping[str, float]]] | None = None,
    pretrain: Mapping[str, Any] | None = None,
    auc: Mapping[str, Sequence[Mapping[str, float]]] | None = None,
) -> dict[str, Any]:
    """Per target arm: the target's transitions, gradient steps and per-step batch to 90%, censored tasks,
    and against its alone arm steps_saved and transfer_updates_saved with 95% CIs, under the paper's
    criterion and (`robust`, `robust_` keys) under ROBUST_CONSECUTIVE, with what the seeds resolve
    of each; `alignment_cka` from `cka`; the AUC statistics (`_auc_summary`) from `auc`, per arm
    and seed the target's `target_auc` over its alone arm's budget."""
    out: dict[str, Any] = {}
    for arm in chosen:
        if not arm.has_target:
            continue
        runs = costs[arm.name]
        entry: dict[str, Any] = {
            "label": arm.label,
            "protocol": str(arm.protocol.relative_to(TESTBED.parents[1])),
            "consumed_per_seed": [c.consumed for c in runs],
            "consumed_mean": float(np.mean([c.consumed for c in runs])),
            "grad_steps_to_90_per_seed": [c.grad_steps for c in runs],
            "grad_steps_to_90_mean": float(np.mean([c.grad_steps for c in runs])),
            "task_steps_per_seed": [c.task_steps for c in runs],
            "per_step_batch_per_seed": [c.per_step for c in runs],
            "per_step_batch_mean": float(np.mean([c.per_step for c in runs])),
            "censored_per_seed": [c.censored for c in runs],
            "censored": int(sum(c.censored for c in runs)),
            "task_runs": int(sum(c.tasks for c in runs)),
        }
        # An alone arm is its own reference: its savings are None (the JSON keys of every arm).
        entry.update(steps_saved=None, ci95=None, transfer_updates_saved=None, alignment_cka=None)
        if arm.alone is not None:
            entry["against"] = arm.alone
            entry.update(_saving(runs, costs[arm.alone]))
            base = float(np.mean([c.consumed for c in costs[arm.alone]]))
            # Beside it, the ratio of the seed means (less sensitive to one slow alone seed).
            entry["saved_of_means"] = 1.0 - entry["consumed_mean"] / base if base > 0 else math.nan
            if robust is not None:
                entry.update(_saving(robust[arm.name], robust[arm.alone], prefix="robust_"))
        if robust is not None:
            entry["robust_grad_steps_to_90_per_seed"] = [c.grad_steps for c in robust[arm.name]]
            entry["robust_censored"] = int(sum(c.censored for c in robust[arm.name]))
        if auc is not None and arm.name in auc:
            entry.update(_auc_summary(auc[arm.name], auc.get(arm.alone) if arm.alone else None))
        if cka is not None and arm.name in cka:
            per_seed = cka[arm.name]
            entry["alignment_cka_per_seed"] = [dict(v) for v in per_seed]
            entry["alignment_cka"] = {
                key: float(np.mean([v[key] for v in per_seed])) for key in per_seed[0]
            }
        if arm.pretrain is not None and pretrain is not None:
            entry["pretrain"] = pretrain[arm.pretrain]
        out[arm.name] = entry
    return out


def pretrain_cost(metrics: pd.DataFrame, threshold: float = DEFAULT_THRESHOLD) -> dict[str, Any]:
    """A source-only pre-training run: its gradient steps, the source's transitions, and whether every task reached."""
    env = str(metrics["env"].iloc[0])
    cost = target_cost(metrics, env=env, threshold=threshold)
    return {
        "grad_steps": int(metrics["grad_steps"].max()),
        "consumed": float(metrics.groupby("task")["updates"].max().sum() * 1e6),
        "reached_all": cost.censored == 0,
    }


# ---------------------------------------------------------------- what the target learned beside its cost


def alignment(
    run_dirs: Mapping[tuple[str, int], Path], chosen: Sequence[Arm], seeds: int
) -> dict[str, list[dict[str, float]]]:
    """Per target arm and seed: linear CKA of the source's and the target's translator (and trunk) outputs on shared states.

    A joint arm: its own two envs, from its last checkpoint. An alone arm: its target against
    the source of the pre-training run of the same seed, two runs that never met (the baseline).
    An arm some of whose runs kept no checkpoint (a committed record: results/) has no entry.
    """
    from seal.learner.probes import cka_from_checkpoints

    # An alone arm's source: the pre-training of the arms set against it, else the first one run.
    first = next((a.name for a in chosen if not a.has_target), None)
    partner = {a.alone: a.pretrain for a in chosen if a.pretrain is not None}
    out: dict[str, list[dict[str, float]]] = {}
    for arm in chosen:
        pre = partner.get(arm.name, first)
        if not arm.has_target or (arm.alone is None and pre is None):
            continue
        dirs = [run_dirs[(arm.name, s)] for s in range(seeds)]
        if arm.alone is None:
            dirs += [run_dirs[(pre, s)] for s in range(seeds)]
        if not all(any(d.glob("checkpoints/ckpt-*.pt")) for d in dirs):
            continue
        out[arm.name] = []
        for seed in range(seeds):
            target = last_checkpoint(run_dirs[(arm.name, seed)])
            source = target if arm.alone is not None else last_checkpoint(run_dirs[(pre, seed)])
            out[arm.name].append(cka_from_checkpoints(source, "source", target, TARGET_ENV))
    return out


def curve_distance(a: pd.DataFrame, b: pd.DataFrame, env: str = TARGET_ENV) -> float:
    """Mean |success difference| of `env`'s tasks between two runs, over the evaluations both made."""
    curves = [
        m[m["env"] == env].pivot_table(index="grad_steps", columns="task", values="success")
        for m in (a, b)
    ]
    left, right = curves[0].align(curves[1], join="inner")
    return float(np.abs(left.to_numpy() - right.to_numpy()).mean())


def source_sensitivity(
    metrics: Mapping[tuple[str, int], pd.DataFrame], chosen: Sequence[Arm], seeds: int
) -> dict[str, float] | None:
    """How much the target's success curve moves when only its source changes, against seed noise.

    Every joint arm shares high_source's target (its init and random streams: same seed, same
    source shapes), so `curve_distance` to high_source's run of the same seed measures what the
    source's goals or pre-training change for the target; `between_seeds` (high_source seed s
    against seed s + 1) is the scale of a change that matters. None without high_source.
    """
    names = {a.name for a in chosen}
    if "high_source" not in names or seeds < 2:
        return None
    out = {
        arm.name: float(
            np.mean(
                [
                    curve_distance(metrics[(arm.name, s)], metrics[("high_source", s)])
                    for s in range(seeds)
                ]
            )
        )
        for arm in chosen
        if arm.alone == "alone" and arm.name != "high_source"
    }
    out["between_seeds"] = float(
        np.mean(
            [
                curve_distance(
                    metrics[("high_source", s)], metrics[("high_source", (s + 1) % seeds)]
                )
                for s in range(seeds)
            ]
        )
    )
    return out


# ---------------------------------------------------------------- the false-positive rate

FPR_HALF = 5
"""Seeds a half: the bench's 5 seeds an arm."""
FPR_SPLITS = 1_000
FPR_GOAL = 0.10
"""The share of CIs that may exclude 0 where there is no effect; above it, change the CI method."""


def false_positive_rate(
    run_dirs: Sequence[Path], splits: int = FPR_SPLITS, half: int = FPR_HALF, seed: int = 0
) -> dict[str, Any]:
    """The arms' CI method on two halves of one arm's seeds, where there is no effect to find.

    `run_dirs` are runs of one arm (the alone arm, seeds 0-9); G = the target's gradient steps
    until every task first reaches 90% (`target_cost`, censored at the run's total).
    `seal.stats.split_false_positive_rate` draws `splits` random half/half splits, pairs the halves'
    seeds at random, and applies the arms' CI (`ARM_CI`: Student's t) and, for comparison, the
    percentile bootstrap it replaced, to the saving of G(a) over G(b) (`seal.stats.saving`); and
    `seal report`'s CI of a change (`seal.stats.change_ci`, paired) to mean(G(a)) / mean(G(b)) - 1
    on the same splits.
    """
    from functools import partial

    from seal import load_run
    from seal.stats import bootstrap_ci, change_ci, split_false_positive_rate

    costs = [target_cost(load_run(path).metrics) for path in run_dirs]
    steps = [c.grad_steps for c in costs]
    split = partial(split_false_positive_rate, steps, half=half, splits=splits, seed=seed)
    rate = split(ci=ARM_CI)
    return {
        "grad_steps_to_90_per_seed": steps,
        "censored_per_seed": [c.censored for c in costs],
        "ci_method": "Student's t CI of the mean saving (the arms' ci95)",
        "false_positive_rate": rate,
        "false_positive_rate_bootstrap": split(ci=bootstrap_ci),
        # `seal report`'s CI of a change of the mean (Fieller's, paired), on the same splits
        "false_positive_rate_report": split(change=partial(change_ci, paired=True)),
        "goal": {"rate_le": FPR_GOAL, "met": rate["rate"] <= FPR_GOAL},
    }
