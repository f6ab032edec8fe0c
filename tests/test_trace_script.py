"""scripts/trace_kitchen_policy.py: what it says of a critic is computed as its docstring says."""

from __future__ import annotations

import numpy as np

from tests.script_module import load_script


def test_earned_is_the_discounted_return_with_the_last_state_bootstrapped() -> None:
    # rewards 1 and 2 at gamma 0.5, then the critic's 8 for the state past the limit:
    # 1 + 0.5 * 2 + 0.25 * 8 = 4.
    def q(obs: np.ndarray, action: np.ndarray) -> float:
        assert obs.tolist() == [7.0] and action.tolist() == [0.5]  # the last state's own action
        return 8.0

    line = load_script("trace_kitchen_policy")._q_against_earned(
        (q, 0.5), 120.4, [1.0, 2.0], np.array([7.0]), np.array([0.5])
    )
    assert line == "critic's Q at reset 120 against 4 earned (discounted)"
