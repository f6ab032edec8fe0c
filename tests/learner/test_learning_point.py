"""Learning evidence at CI size: MTMHSAC solves every `point` task; random and no-one-hot do not.

Bounded by env steps (12,000 at most, see seal.bench.POINT_LEARN), never by wall clock. The
observation hides the goal, so only the one-hot tells the policy which of the 4 goals to reach.
"""

from __future__ import annotations

from seal.bench import POINT_LEARN, point_evidence


def test_mtmhsac_solves_every_point_task_and_needs_the_one_hot() -> None:
    result = point_evidence(seed=0)
    # Uniform random actions spread the point ~0.1 * sqrt(50 / 3) = 0.4 per axis in 50 steps, so
    # a goal at distance 1 is rarely within 0.1 (measured: 0 of 20 episodes on every task).
    assert all(rate <= 0.2 for rate in result["random"].values()), result["random"]
    assert all(rate == 1.0 for rate in result["one_hot"]["success"].values()), result["one_hot"]
    assert result["one_hot"]["env_steps"] <= POINT_LEARN["env_steps"]
    # Same env steps without the one-hot: one policy for 4 opposite goals must miss at least one.
    assert result["no_one_hot"]["env_steps"] == result["one_hot"]["env_steps"]
    without = result["no_one_hot"]
    assert any(rate < 1.0 for rate in without["success"].values()), without
