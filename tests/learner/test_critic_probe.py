"""The critic probe: Q at an evaluation episode's first state against what the episode earned,
bootstrapped past the time limit, on hand-made critics and episodes (issue 54)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from seal.learner.collection import Collector
from seal.learner.critic_probe import CriticProbe, overestimation
from tests.learner.test_collection import adapters, half_policy

GAMMA = 0.9


def critic(env: str, obs: np.ndarray, task_ids: np.ndarray, actions: np.ndarray) -> np.ndarray:
    """A hand-made critic: 10 x + 100 a + the task id."""
    return 10 * obs[:, 0] + 100 * actions[:, 0] + task_ids


def discounted(rewards: list[float], gamma: float = GAMMA) -> float:
    return sum(gamma**t * r for t, r in enumerate(rewards))


@pytest.mark.parametrize("replicas", [1, 2])
def test_q_start_and_earned_are_hand_computed_through_evaluate(replicas: int) -> None:
    # The toy envs: reward = x after the step, x += 0.5 a step under the half policy.
    policy = half_policy([])
    with Collector(adapters(), seed=0, backend="sync", replicas=replicas) as col:
        out = col.evaluate(policy, 2, probe=CriticProbe(critic, policy, GAMMA))
    # At reset x = 0 and the action is 0.5: Q = 50 + task id.
    for env, tasks in (("toy", "abc"), ("toy2", ["a", "stop"])):
        for i, task in enumerate(tasks):
            assert out[env][task]["q_start"] == pytest.approx(50 + i)
    # toy: 4 steps, cut at the limit with x = 2: bootstrapped by 0.9^4 Q(x=2, a=0.5) = 0.9^4 (70 + id).
    for i, task in enumerate("abc"):
        want = discounted([0.5, 1.0, 1.5, 2.0]) + GAMMA**4 * (70 + i)
        assert out["toy"][task]["earned"] == pytest.approx(want)
    # toy2 "a": 6 steps, cut with x = 3: 0.9^6 (80 + 0); "stop" terminates at step 3: no bootstrap.
    assert out["toy2"]["a"]["earned"] == pytest.approx(
        discounted([0.5 * (t + 1) for t in range(6)]) + GAMMA**6 * 80
    )
    assert out["toy2"]["stop"]["earned"] == pytest.approx(0.5 + 0.9 * 1.0 + 0.81 * 1.5)
    # The undiscounted returns are unchanged by the probe.
    assert out["toy"]["a"]["mean_return"] == pytest.approx(5.0)


def test_without_a_probe_the_results_have_no_critic_keys() -> None:
    with Collector(adapters(), seed=0, backend="sync") as col:
        out = col.evaluate(half_policy([]), 1)
    assert set(out["toy"]["a"]) == {"success_rate", "mean_return", "episodes"}


def test_ratio_is_q_over_earned_and_nan_without_positive_earnings() -> None:
    assert overestimation(1_000.0, 250.0) == 4.0
    assert math.isnan(overestimation(5.0, 0.0)) and math.isnan(overestimation(5.0, -1.0))


def test_critic_rows_name_each_task_and_leave_out_a_ratio_without_meaning() -> None:
    from seal.run.eval_rows import critic_rows

    base = {"seed": 0, "phase": "train", "epoch": 10, "grad_steps": 300, "env": "fk"}
    rows = [{**base, "task": "microwave"}, {**base, "task": "kettle"}]
    results = {
        "fk": {
            "microwave": {"success": 1.0, "return": 9.0, "q_start": 800.0, "earned": 200.0},
            "kettle": {"success": 0.0, "return": 0.0, "q_start": 3.0, "earned": 0.0},
        }
    }
    got = {(r["key"], r["value"]) for r in critic_rows(rows, results)}  # type: ignore[arg-type]
    assert got == {
        ("eval_q/microwave", 800.0),
        ("eval_earned/microwave", 200.0),
        ("eval_q_ratio/microwave", 4.0),
        ("eval_q/kettle", 3.0),
        ("eval_earned/kettle", 0.0),
    }
