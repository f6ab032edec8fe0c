"""train.csv rows that an evaluation's results add, per task: the critic probe's
(`critic_rows`) and, for an evaluation that could decide early, the episodes each task ran
(`decision_rows`). Both name their keys `<key>/<task>` (`result_rows`)."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

from seal.protocols.evaluation_cost import DECIDED_KEY, EPISODES_KEY

if TYPE_CHECKING:
    from seal.run.rundir import MetricsRow, TrainRow

Results = Mapping[str, Mapping[str, Mapping[str, float]]]
"""env -> task -> an evaluation's figures (success, return, and what the options add)."""


def result_rows(
    rows: Sequence[MetricsRow],
    results: Results,
    values_of: Callable[[Mapping[str, float]], Mapping[str, float]],
) -> list[TrainRow]:
    """train.csv rows, per metrics row (one task), of the values `values_of` takes from the
    task's results: key `<key>/<task>`, in the metrics row's seed, phase, epoch and steps."""
    out: list[TrainRow] = []
    for row in rows:
        values = values_of(results[row["env"]][row["task"]])
        out += [
            {
                "seed": row["seed"],
                "phase": row["phase"],
                "epoch": row["epoch"],
                "grad_steps": row["grad_steps"],
                "env": row["env"],
                "key": f"{key}/{row['task']}",
                "value": float(value),
            }
            for key, value in values.items()
        ]
    return out


def critic_rows(rows: Sequence[MetricsRow], results: Results) -> list[TrainRow]:
    """train.csv rows of an evaluation's critic probe (`seal.learner.critic_probe`), per task:
    `eval_q/<task>` (the critic's mean Q at the episodes' first states), `eval_earned/<task>` (what
    they earned, bootstrapped past the time limit) and `eval_q_ratio/<task>` (their ratio, left out
    where the episodes earned nothing positive)."""
    from seal.learner.critic_probe import overestimation

    def values(r: Mapping[str, float]) -> dict[str, float]:
        if "q_start" not in r:
            return {}
        ratio = overestimation(r["q_start"], r["earned"])
        probe = {"eval_q": r["q_start"], "eval_earned": r["earned"], "eval_q_ratio": ratio}
        return {key: value for key, value in probe.items() if np.isfinite(value)}

    return result_rows(rows, results, values)


def decision_rows(rows: Sequence[MetricsRow], results: Results) -> list[TrainRow]:
    """train.csv rows of an evaluation that could decide early: per task `eval_episodes/<task>`
    and `eval_decided_early/<task>` (none for an evaluation that ran in full by design)."""

    def values(r: Mapping[str, float]) -> dict[str, float]:
        if "decided_early" not in r:
            return {}
        return {EPISODES_KEY: r["episodes"], DECIDED_KEY: r["decided_early"]}

    return result_rows(rows, results, values)
