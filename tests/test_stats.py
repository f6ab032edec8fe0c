"""seal.stats: bootstrap CIs against scipy and hand-worked cases, probability of improvement."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats as scipy_stats

from seal.errors import SealError
from seal.stats import (
    MIN_SEEDS_RESOLVED,
    bootstrap_ci,
    change_ci,
    probability_of_improvement,
    resolved,
    stratified_change_ci,
)

# Five seeds' transitions to 90% (millions) for an arm and its base, seed i against seed i.
ARM = [0.12, 0.10, 0.15, 0.09, 0.11]
BASE = [0.16, 0.19, 0.14, 0.18, 0.20]


def _scipy_ci(data: tuple, statistic, paired: bool = False) -> tuple[float, float]:
    result = scipy_stats.bootstrap(
        data,
        statistic,
        n_resamples=10_000,
        paired=paired,
        confidence_level=0.95,
        method="percentile",
        rng=np.random.default_rng(0),
    )
    return float(result.confidence_interval.low), float(result.confidence_interval.high)


def test_bootstrap_ci_is_scipys_percentile_interval() -> None:
    expected = _scipy_ci((np.array(ARM),), np.mean)
    assert bootstrap_ci(ARM) == pytest.approx(expected, rel=1e-12)
    low, high = bootstrap_ci(ARM)
    assert low < np.mean(ARM) < high


def test_bootstrap_ci_drops_nans_and_handles_degenerate_samples() -> None:
    assert bootstrap_ci([*ARM, math.nan]) == bootstrap_ci(ARM)
    assert all(math.isnan(v) for v in bootstrap_ci([0.3, math.nan]))
    assert all(math.isnan(v) for v in bootstrap_ci([]))
    assert bootstrap_ci([0.1, 0.1, 0.1]) == (0.1, 0.1)  # no spread: the CI is the value


def test_bootstrap_ci_is_seeded() -> None:
    assert bootstrap_ci(ARM, seed=3) == bootstrap_ci(ARM, seed=3)
    assert bootstrap_ci(ARM, seed=3) != bootstrap_ci(ARM, seed=4)


def _ratio(x: np.ndarray, y: np.ndarray, axis: int = -1) -> np.ndarray:
    return np.mean(x, axis=axis) / np.mean(y, axis=axis) - 1.0


def test_change_ci_paired_and_unpaired_match_scipy() -> None:
    a, b = np.array(ARM), np.array(BASE)
    assert change_ci(ARM, BASE, paired=True) == pytest.approx(
        _scipy_ci((a, b), _ratio, paired=True), rel=1e-12
    )
    assert change_ci(ARM, BASE, paired=False) == pytest.approx(
        _scipy_ci((a, b), _ratio, paired=False), rel=1e-12
    )
    # Point change: 0.114 / 0.174 - 1 = -34.5%, inside both intervals.
    for paired in (True, False):
        low, high = change_ci(ARM, BASE, paired=paired)
        assert low < 0.114 / 0.174 - 1 < high < 0


def test_change_ci_hand_worked() -> None:
    # Every seed of the arm uses exactly half of its paired base: every paired resample gives
    # mean(arm) / mean(base) = 0.5, so the CI is the point -50%.
    base = [0.2, 0.4, 0.6, 0.8]
    arm = [v / 2 for v in base]
    assert change_ci(arm, base, paired=True) == pytest.approx((-0.5, -0.5))
    # Unpaired, the resamples of arm and base differ, so the CI widens around -50%.
    low, high = change_ci(arm, base, paired=False)
    assert low < -0.5 < high
    # Constant on both sides: 0.1 / 0.2 - 1, exactly.
    assert change_ci([0.1, 0.1], [0.2, 0.2], paired=False) == (-0.5, -0.5)


def test_change_ci_nans_and_errors() -> None:
    # Paired: seed 1 of the arm never reached, so the pair (seed 1) is dropped on both sides.
    arm = [0.12, math.nan, 0.15, 0.09, 0.11]
    kept = [0, 2, 3, 4]
    assert change_ci(arm, BASE, paired=True) == change_ci(
        [arm[i] for i in kept], [BASE[i] for i in kept], paired=True
    )
    assert all(math.isnan(v) for v in change_ci([0.1], BASE, paired=False))
    assert all(math.isnan(v) for v in change_ci(ARM, [0.0, 0.0, 0.0], paired=False))
    with pytest.raises(SealError, match="paired samples differ in length"):
        change_ci(ARM, BASE[:3], paired=True)


def test_stratified_change_ci_replicates_the_resampling_by_hand() -> None:
    arm = {"a": [1.0, 2.0, 3.0], "b": [5.0, 6.0]}
    base = {"a": [2.0, 3.0, 4.0, 4.0], "b": [6.0, 7.0, 9.0]}
    # Unpaired: scipy draws one index array per sample in order (a arm, a base, b arm, b base).
    rng = np.random.default_rng(0)
    draws = [
        rng.integers(0, len(x), (10_000, len(x)))
        for x in (arm["a"], base["a"], arm["b"], base["b"])
    ]
    arm_total = np.array(arm["a"])[draws[0]].mean(-1) + np.array(arm["b"])[draws[2]].mean(-1)
    base_total = np.array(base["a"])[draws[1]].mean(-1) + np.array(base["b"])[draws[3]].mean(-1)
    change = arm_total / base_total - 1
    expected = (np.percentile(change, 2.5), np.percentile(change, 97.5))
    assert stratified_change_ci(arm, base, paired=False) == pytest.approx(expected, rel=1e-12)


def test_stratified_change_ci_of_one_task_is_change_ci() -> None:
    one = stratified_change_ci({"t": ARM}, {"t": BASE}, paired=False)
    assert one == change_ci(ARM, BASE, paired=False)
    assert stratified_change_ci({"t": ARM}, {"t": BASE}, paired=True) == change_ci(
        ARM, BASE, paired=True
    )


def test_stratified_change_ci_paired_is_exact_when_every_task_halves() -> None:
    base = {"a": [2.0, 4.0, 6.0], "b": [10.0, 30.0]}
    arm = {t: [v / 2 for v in vs] for t, vs in base.items()}
    assert stratified_change_ci(arm, base, paired=True) == pytest.approx((-0.5, -0.5))


def test_stratified_change_ci_undefined_cases() -> None:
    with pytest.raises(SealError, match="differ"):
        stratified_change_ci({"a": [1.0]}, {"b": [1.0]}, paired=False)
    nan_side = stratified_change_ci({"a": [1.0, 2.0]}, {"a": [math.nan, math.nan]}, paired=False)
    assert all(math.isnan(v) for v in nan_side)
    assert all(math.isnan(v) for v in stratified_change_ci({}, {}, paired=True))
    one_seed = stratified_change_ci({"a": ARM, "b": [0.5]}, {"a": BASE, "b": [0.6]}, paired=False)
    assert all(math.isnan(v) for v in one_seed)  # task b has one value: as change_ci, undefined


def test_probability_of_improvement_is_mann_whitney_u_for_costs() -> None:
    arm = [0.12, 0.10, 0.15, 0.09, 0.16]
    base = [0.16, 0.19, 0.14, 0.18]  # one tie: arm 0.16 against base 0.16
    # U of base against arm counts base > arm (= arm cheaper) plus half the ties.
    u = scipy_stats.mannwhitneyu(base, arm).statistic
    assert probability_of_improvement(arm, base) == pytest.approx(u / (len(arm) * len(base)))
    # By hand: arm 0.12, 0.10, 0.09 beat all 4; 0.15 beats 3; 0.16 beats 2, ties 1 -> 17.5 / 20.
    assert probability_of_improvement(arm, base) == pytest.approx(17.5 / 20)
    assert probability_of_improvement([1.0], [1.0]) == 0.5
    assert math.isnan(probability_of_improvement([], base))


@pytest.mark.parametrize(
    ("ci", "expected"),
    [
        ((-0.5, -0.1), True),
        ((0.1, 0.3), True),
        ((-0.2, 0.1), False),
        ((-0.2, 0.0), False),
        ((0.0, 0.0), False),
        ((math.nan, -0.1), False),
        ((-math.inf, -0.1), False),
    ],
)
def test_resolved_means_the_ci_excludes_zero(ci: tuple[float, float], expected: bool) -> None:
    assert resolved(ci) is expected


def test_min_seeds_resolved() -> None:
    assert MIN_SEEDS_RESOLVED == 3
