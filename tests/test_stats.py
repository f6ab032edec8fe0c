"""seal.stats: bootstrap CIs against scipy and hand-worked cases, probability of improvement, the
minimum detectable effect (by hand and by simulation), the IQM, the false-positive rate, and
intervals of bounded statistics (in their bounds, their coverage by simulation)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats as scipy_stats

from seal.coverage import (
    COVERAGE_CASES,
    bounded_ci_coverage,
    format_coverage,
    near_bound_case,
    normal_case,
)
from seal.errors import SealError
from seal.stats import (
    MIN_SEEDS_RESOLVED,
    binomial_ci,
    bootstrap_band,
    bootstrap_ci,
    bounded_t_ci,
    change_ci,
    clip_ci,
    interquartile_mean,
    iqm_ci,
    mde,
    paired_power,
    probability_of_improvement,
    resolved,
    saving,
    seeds_for_mde,
    split_false_positive_rate,
    stratified_change_ci,
    t_ci,
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


def test_change_ci_paired_is_the_ratios_the_paired_t_test_keeps() -> None:
    # Fieller: at each end c of the CI of mean(arm) / mean(base), scipy's paired t-test of
    # arm_i - c * base_i = 0 sits exactly at p = 0.05, and inside the CI it does not reject.
    low, high = change_ci(ARM, BASE, paired=True)
    a, b = np.array(ARM), np.array(BASE)
    for end in (low, high):
        assert scipy_stats.ttest_1samp(a - (1 + end) * b, 0.0).pvalue == pytest.approx(0.05)
    point = a.mean() / b.mean() - 1  # 0.114 / 0.174 - 1 = -34.5%
    assert low < point < high < 0
    assert scipy_stats.ttest_1samp(a - (1 + point) * b, 0.0).pvalue == pytest.approx(1.0)


def test_change_ci_unpaired_is_welchs_t_at_the_point_ratio() -> None:
    # Unpaired: at each end c, Welch's t of mean(arm) - c mean(base) equals the t quantile at the
    # Welch-Satterthwaite degrees of freedom of the point ratio, computed here by hand.
    a, b = np.array(ARM), np.array(BASE)
    low, high = change_ci(ARM, BASE, paired=False)
    r = a.mean() / b.mean()
    va, vb = a.var(ddof=1) / 5, r**2 * b.var(ddof=1) / 5
    df = (va + vb) ** 2 / (va**2 / 4 + vb**2 / 4)
    quantile = scipy_stats.t.ppf(0.975, df)
    for end in (low, high):
        c = 1 + end
        t = abs(a.mean() - c * b.mean()) / math.sqrt(va + c**2 * b.var(ddof=1) / 5)
        assert t == pytest.approx(quantile)
    assert low < r - 1 < high < 0


def test_change_ci_keeps_its_level_where_the_bootstrap_did_not() -> None:
    # No effect planted: 5 paired seeds whose arm and base costs are draws of one law (a seed
    # effect shared by the pair, then noise). Fieller's CI excludes 0 in about 5% of 2,000
    # replications (binomial SD 0.5 points); the percentile bootstrap of the same ratio, which
    # the reports used before, in about twice as many.
    rng = np.random.default_rng(0)
    seed_effect = rng.normal(1.0, 0.3, (2_000, 1, 5))
    costs = seed_effect + rng.normal(0.0, 0.2, (2_000, 2, 5))
    fieller = np.mean([resolved(change_ci(x[0], x[1], paired=True)) for x in costs])
    assert 0.035 <= fieller <= 0.065
    ratio = lambda x, y, axis=-1: np.mean(x, axis=axis) / np.mean(y, axis=axis) - 1.0  # noqa: E731
    boot = np.mean([resolved(_scipy_ci((x[0], x[1]), ratio, paired=True)) for x in costs[:300]])
    assert boot > 0.09


def test_change_ci_hand_worked() -> None:
    # Every seed of the arm uses exactly half of its paired base: arm_i - 0.5 base_i = 0 in every
    # seed, so no other ratio passes the t-test and the CI is the point -50%.
    base = [0.2, 0.4, 0.6, 0.8]
    arm = [v / 2 for v in base]
    assert change_ci(arm, base, paired=True) == pytest.approx((-0.5, -0.5))
    # Unpaired, the spreads of arm and base count, so the CI widens around -50%.
    low, high = change_ci(arm, base, paired=False)
    assert low < -0.5 < high
    # Constant on both sides: 0.1 / 0.2 - 1, exactly.
    assert change_ci([0.1, 0.1], [0.2, 0.2], paired=False) == (-0.5, -0.5)
    # A constant base: the CI is the t CI of the arm's mean, divided by the base.
    t_low, t_high = t_ci([0.02, 0.02, 0.04])
    assert change_ci([0.02, 0.02, 0.04], [0.192] * 3, paired=True) == pytest.approx(
        (t_low / 0.192 - 1, t_high / 0.192 - 1)
    )
    # A base whose mean the seeds do not resolve from 0: the set of ratios is unbounded.
    assert all(math.isnan(v) for v in change_ci([1.0, 2.0, 3.0], [0.1, 5.0, -4.0], paired=False))


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


def test_stratified_change_ci_adds_the_tasks_variances() -> None:
    # Two tasks, unpaired: at each end c, (total arm - c total base)^2 equals t^2 times the sum of
    # the four means' variances (c^2 on the base's), t at the Welch-Satterthwaite df of the point.
    arm = {"a": [1.0, 2.0, 3.0], "b": [5.0, 6.0]}
    base = {"a": [2.0, 3.0, 4.0, 4.0], "b": [6.0, 7.0, 9.0]}
    means = {k: {t: np.mean(v) for t, v in side.items()} for k, side in (("a", arm), ("b", base))}
    var = {
        k: {t: np.var(v, ddof=1) / len(v) for t, v in s.items()}
        for k, s in (("a", arm), ("b", base))
    }
    ma, mb = sum(means["a"].values()), sum(means["b"].values())
    r = ma / mb
    pieces = [
        (var["a"]["a"], 2),
        (var["a"]["b"], 1),
        (r**2 * var["b"]["a"], 3),
        (r**2 * var["b"]["b"], 2),
    ]
    df = sum(v for v, _ in pieces) ** 2 / sum(v**2 / d for v, d in pieces)
    quantile = scipy_stats.t.ppf(0.975, df)
    low, high = stratified_change_ci(arm, base, paired=False)
    for end in (low, high):
        c = 1 + end
        spread = sum(var["a"].values()) + c**2 * sum(var["b"].values())
        assert abs(ma - c * mb) / math.sqrt(spread) == pytest.approx(quantile)
    assert low < r - 1 < high


def test_stratified_change_ci_of_one_task_is_change_ci() -> None:
    for paired in (False, True):
        one = stratified_change_ci({"t": ARM}, {"t": BASE}, paired=paired)
        assert one == change_ci(ARM, BASE, paired=paired)


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


# ---------------------------------------------------------------- the minimum detectable effect


def test_mde_by_hand() -> None:
    # SD 0.44 of the paired per-seed savings over 5 seeds (issue 34's testbed figure). From
    # scipy.stats.t.ppf: t(0.975, 4) = 2.7764451051977934, t(0.80, 4) = 0.9409645772351816, so
    # MDE = (2.7764451 + 0.9409646) * 0.44 / sqrt(5) = 3.7174097 * 0.1967727 = 0.7314895.
    assert mde(0.44, 5) == pytest.approx((2.7764451051977934 + 0.9409645772351816) * 0.44 / 5**0.5)
    assert mde(0.44, 5) == pytest.approx(0.7314895060119713, rel=1e-12)
    # n = 2: t(0.975, 1) = 12.706204736174698, t(0.80, 1) = 1.3763819204711736.
    assert mde(1.0, 2) == pytest.approx((12.706204736174698 + 1.3763819204711736) / 2**0.5)
    assert mde(0.0, 5) == 0.0
    assert math.isnan(mde(0.44, 1)) and math.isnan(mde(math.nan, 5))


def test_seeds_for_mde_is_the_smallest_n_and_the_quantiles_move_with_n() -> None:
    # At n = 154: t(0.975, 153) = 1.97559, t(0.80, 153) = 0.84398, MDE = 2.81957 * 0.44 / sqrt(154)
    # = 0.09997 <= 0.10; at n = 153 it is above 0.10. The normal quantiles (1.95996 + 0.84162)
    # would give 152: the t quantiles, recomputed at every n, add two seeds.
    assert seeds_for_mde(0.44) == 154
    assert mde(0.44, 154) <= 0.10 < mde(0.44, 153)
    assert seeds_for_mde(0.0) == 2
    assert seeds_for_mde(math.nan) is None
    assert seeds_for_mde(0.44, max_seeds=100) is None
    with pytest.raises(SealError, match="target MDE"):
        seeds_for_mde(0.44, target=0.0)


def test_paired_power_keys() -> None:
    power = paired_power([0.1, 0.2, 0.3, math.nan], "steps")
    assert set(power) == {"sd_paired_steps", "mde_steps", "seeds_for_mde_0p10_steps"}
    assert power["sd_paired_steps"] == pytest.approx(0.1)  # NaN dropped: SD of 0.1, 0.2, 0.3
    assert power["mde_steps"] == pytest.approx(mde(0.1, 3))
    assert power["seeds_for_mde_0p10_steps"] == seeds_for_mde(0.1)
    one = paired_power([0.5], "auc")
    assert math.isnan(one["sd_paired_auc"]) and one["seeds_for_mde_0p10_auc"] is None


def test_a_planted_effect_at_the_mde_is_found_with_power_near_08() -> None:
    # 20,000 experiments of n = 5 paired differences ~ N(MDE, 1), each judged by a two-sided
    # one-sample t-test at 0.05. The formula is the normal approximation with t quantiles: the
    # exact power is the noncentral t's, scipy.stats.nct with df 4 and noncentrality
    # 2.7764 + 0.9410 = 3.7174, which is 0.7913. The simulation's SE is about 0.003.
    n, experiments = 5, 20_000
    effect = mde(1.0, n)
    rng = np.random.default_rng(0)
    differences = rng.normal(effect, 1.0, size=(experiments, n))
    p_values = scipy_stats.ttest_1samp(differences, 0.0, axis=1).pvalue
    power = float(np.mean(p_values < 0.05))
    assert power == pytest.approx(0.7913, abs=0.012)
    assert power == pytest.approx(0.80, abs=0.025)
    # Half the MDE is found far less often; no effect at about the test's level.
    half = float(
        np.mean(scipy_stats.ttest_1samp(differences - effect / 2, 0.0, axis=1).pvalue < 0.05)
    )
    null = float(np.mean(scipy_stats.ttest_1samp(differences - effect, 0.0, axis=1).pvalue < 0.05))
    assert half < 0.45 and null == pytest.approx(0.05, abs=0.01)


# ---------------------------------------------------------------- IQM and bands


def test_interquartile_mean_is_rliables_trimmed_mean() -> None:
    # Of 8 values the middle 4 (3, 4, 5, 6): the outlier 100 does not move it.
    assert interquartile_mean([1, 2, 3, 4, 5, 6, 7, 100]) == pytest.approx(4.5)
    assert interquartile_mean([2.0, math.nan, 2.0]) == 2.0
    assert math.isnan(interquartile_mean([]))


def test_iqm_ci_resamples_runs_within_each_task() -> None:
    table = np.array([[0.1, 0.5], [0.2, 0.6], [0.3, 0.9], [0.4, 0.7]])
    low, high = iqm_ci(table)
    assert low <= interquartile_mean(table.ravel()) <= high
    # Replicated by hand: one index draw per task (column), in order, then the IQM of all 8.
    rng = np.random.default_rng(0)
    draws = [rng.integers(0, 4, (10_000, 4)) for _ in range(2)]
    stacked = np.concatenate([table[:, t][d] for t, d in enumerate(draws)], axis=-1)
    iqms = scipy_stats.trim_mean(stacked, 0.25, axis=-1)
    assert (low, high) == pytest.approx((np.percentile(iqms, 2.5), np.percentile(iqms, 97.5)))
    assert iqm_ci(np.full((3, 2), 0.5)) == (0.5, 0.5)
    assert all(math.isnan(v) for v in iqm_ci([[0.1, 0.2]]))


def test_bootstrap_band_brackets_the_mean_curve() -> None:
    curves = np.array([[0.0, 0.5, 1.0], [0.0, 0.3, 0.9], [0.0, 0.7, 1.0], [0.0, 0.4, 1.0]])
    low, high = bootstrap_band(curves)
    mean = curves.mean(axis=0)
    assert (low <= mean).all() and (mean <= high).all()
    # Where every seed agrees the band is the point; elsewhere it lies within the seeds' range.
    assert (low[0], high[0]) == (0.0, 0.0)
    assert curves[:, 1].min() <= low[1] < high[1] <= curves[:, 1].max()
    one_low, one_high = bootstrap_band(curves[:1])
    assert (one_low == curves[0]).all() and (one_high == curves[0]).all()


# ---------------------------------------------------------------- the false-positive rate


def test_binomial_ci_is_clopper_pearson() -> None:
    # 0 of 1,000: the exact upper end is 1 - 0.025 ** (1 / 1000) = 0.00368.
    assert binomial_ci(0, 1000) == pytest.approx((0.0, 1 - 0.025 ** (1 / 1000)))
    low, high = binomial_ci(50, 1000)
    assert low < 0.05 < high and high - low == pytest.approx(0.028, abs=0.002)
    with pytest.raises(SealError, match="trials"):
        binomial_ci(3, 2)


def test_false_positive_rate_without_spread_is_zero() -> None:
    result = split_false_positive_rate([2000.0] * 10, splits=50)
    assert (result["excluding_0"], result["rate"], result["splits"]) == (0, 0.0, 50)
    assert result["rate_ci95"] == pytest.approx(list(binomial_ci(0, 50)))
    with pytest.raises(SealError, match="two disjoint halves of 5"):
        split_false_positive_rate([1.0] * 9)
    with pytest.raises(SealError, match="finite positive"):
        split_false_positive_rate([1.0] * 9 + [0.0])


def test_the_saving_of_the_means_is_unbiased_where_the_mean_of_ratios_is_not() -> None:
    # Two arms with the same cost distribution (a gamma of CV 0.23, as the testbed's alone G),
    # 20 pairs, 4,000 draws. The mean of per-seed ratios 1 - a / b sits near -CV^2 = -0.053
    # (Jensen), so its t CI calls more than 5% resolved; `saving`'s mean is 1 - mean(a) / mean(b),
    # near 0, and its t CI tests a difference of costs (issue 58).
    rng = np.random.default_rng(58)
    shape = 0.23**-2
    means, ratios, calls = [], [], {"saving": 0, "ratio": 0}
    for _ in range(4000):
        a, b = rng.gamma(shape, 2600 / shape, 20), rng.gamma(shape, 2600 / shape, 20)
        per_seed = {"saving": saving(a, b), "ratio": 1 - a / b}
        means.append(per_seed["saving"].mean())
        ratios.append(per_seed["ratio"].mean())
        for name, values in per_seed.items():
            calls[name] += resolved(t_ci(values))
    assert abs(np.mean(means)) < 3 * np.std(means) / np.sqrt(4000)
    assert np.mean(ratios) < -0.04
    assert 0.035 <= calls["saving"] / 4000 <= 0.06 < calls["ratio"] / 4000


def test_false_positive_rate_on_synthetic_data_with_no_effect() -> None:
    # Ten alone-arm seeds drawn from one distribution (mean 2,500 steps, SD 250): any difference
    # between two halves is noise. Averaged over 10 such arms of 200 splits each, Student's t
    # interval (exact for normal differences) calls about 5% of them resolved; the arms'
    # percentile bootstrap over 5 pairs is narrower than its nominal 95% and calls more.
    rng = np.random.default_rng(5)
    arms = [rng.normal(2500.0, 250.0, 10) for _ in range(10)]

    def mean_rate(ci) -> float:
        rates = [
            split_false_positive_rate(a, splits=200, seed=i, ci=ci)["rate"]
            for i, a in enumerate(arms)
        ]
        return float(np.mean(rates))

    t_rate = mean_rate(t_ci)
    assert 0.02 <= t_rate <= 0.09
    boot_rate = mean_rate(lambda v: bootstrap_ci(v, n_resamples=1000))
    assert t_rate < boot_rate <= 0.25
    # The report's CI of mean(a) / mean(b) - 1 (Fieller's, paired) on the same splits: about 5%.
    fieller = [
        split_false_positive_rate(
            a, splits=200, seed=i, change=lambda x, y: change_ci(x, y, paired=True)
        )["rate"]
        for i, a in enumerate(arms)
    ]
    assert 0.02 <= float(np.mean(fieller)) <= 0.09
    # Reproducible: the same seed draws the same splits.
    assert split_false_positive_rate(arms[0], splits=100, ci=t_ci) == split_false_positive_rate(
        arms[0], splits=100, ci=t_ci
    )


def test_t_ci() -> None:
    x = [0.1, 0.3, 0.2, 0.4]
    half = scipy_stats.t.ppf(0.975, 3) * np.std(x, ddof=1) / 2
    assert t_ci(x) == pytest.approx((0.25 - half, 0.25 + half))
    assert t_ci([0.2, 0.2]) == (0.2, 0.2)
    assert all(math.isnan(v) for v in t_ci([0.2]))


# ---------------------------------------------------------------- bounded statistics

# oracle_policy's per-seed 1 - G(arm) / G(alone) in round 5 (docs/transfer_testbed.md; steps_saved's
# definition before issue 58): values piled at their bound, exactly 1 in 2 seeds.
ORACLE = [0.913, 0.840, 1.0, 0.923, 1.0]


def test_bounded_t_ci_is_t_cut_at_the_bound() -> None:
    low, high = t_ci(ORACLE)
    assert high > 1  # the t interval claims savings above 1, which no seed can have
    assert bounded_t_ci(ORACLE, (-math.inf, 1.0)) == (low, 1.0)
    assert bounded_t_ci(ORACLE) == (low, high)  # no bounds: Student's t
    # Within the bounds nothing changes; each end is cut on its own.
    assert bounded_t_ci([0.1, 0.3, 0.2, 0.4], (-1.0, 1.0)) == t_ci([0.1, 0.3, 0.2, 0.4])
    assert clip_ci((-1.2, -0.8), (-1.0, math.inf)) == (-1.0, -0.8)
    assert clip_ci((0.9, 1.3), (-1.0, 1.0)) == (0.9, 1.0)
    assert all(math.isnan(v) for v in clip_ci((math.nan, math.nan), (-1.0, 1.0)))
    assert all(math.isnan(v) for v in bounded_t_ci([0.5], (-1.0, 1.0)))
    assert bounded_t_ci([1.0, 1.0, math.nan], (-math.inf, 1.0)) == (1.0, 1.0)
    # The range is the mean's: one value may pass it (a seed's saving over the alone mean).
    assert bounded_t_ci([0.9, 1.02], (-math.inf, 1.0)) == (t_ci([0.9, 1.02])[0], 1.0)
    with pytest.raises(SealError, match="leaves the statistic's range"):
        bounded_t_ci([0.5, 1.6], (-1.0, 1.0))
    with pytest.raises(SealError, match="expected low <= high"):
        clip_ci((0.0, 1.0), (1.0, -1.0))


def test_bounded_ci_coverage_stays_in_bounds_and_keeps_ts_coverage() -> None:
    near = [near_bound_case(0.4, 0.1), near_bound_case(0.9, 0.1)]  # means 0.94 and 0.99
    rows = bounded_ci_coverage(near, seeds=(5,), replicates=400, seed=1)
    assert [r["mean"] for r in rows] == pytest.approx([0.94, 0.99])
    for r in rows:
        assert r["outside"]["bounded t"] == 0.0  # never above 1
        assert r["outside"]["t"] > 0  # where t's interval leaves [.., 1]
        # The mean lies in the bounds, so cutting there loses no coverage: the same share.
        assert r["coverage"]["bounded t"] == r["coverage"]["t"]
        assert r["above"]["bounded t"] == r["above"]["t"] <= 1 - r["coverage"]["t"]
    # 90% of the seeds at 1: at 5 seeds about 0.9^5 = 59% of samples have no spread at all.
    assert rows[1]["no_spread"] == pytest.approx(0.9**5, abs=0.08)
    assert bounded_ci_coverage(near, seeds=(5,), replicates=400, seed=1) == rows


def test_bounded_ci_coverage_is_nominal_away_from_the_bound() -> None:
    # Normal values far from the bound (like High Src's steps_saved): Student's t is exact there,
    # so the coverage of 1,000 replicates lies within 3 binomial SEs of 0.95.
    replicates = 1_000
    tolerance = 3 * math.sqrt(0.95 * 0.05 / replicates)  # 0.021
    for r in bounded_ci_coverage([normal_case(0.1, 0.15)], (5, 10), replicates, seed=2):
        assert r["outside"]["bounded t"] == 0.0
        assert abs(r["coverage"]["bounded t"] - 0.95) <= tolerance
        low, high = r["coverage_ci95"]["bounded t"]
        assert low <= r["coverage"]["bounded t"] <= high


def test_format_coverage_and_the_default_cases() -> None:
    assert len(COVERAGE_CASES) == 7 and COVERAGE_CASES[0].mean == pytest.approx(0.94)
    assert COVERAGE_CASES[0].label == "1 w.p. 0.4, else 1 - Exp(mean 0.1)"
    uniform = near_bound_case(0.4, 0.08, "uniform")
    assert (uniform.label, uniform.mean) == (
        "1 w.p. 0.4, else 1 - U(0, 0.16)",
        pytest.approx(0.952),
    )
    text = format_coverage(bounded_ci_coverage(COVERAGE_CASES[:1], (5,), 20))
    lines = text.splitlines()
    assert lines[0] == (
        "| case | mean | n | coverage t | coverage bounded t | above t | above bounded t "
        "| outside t | outside bounded t | no spread |"
    )
    assert lines[2].startswith("| 1 w.p. 0.4, else 1 - Exp(mean 0.1) | 0.940 | 5 |")
    with pytest.raises(SealError, match="expected 0 <= at_bound <= 1"):
        near_bound_case(1.5, 0.1)
    with pytest.raises(SealError, match="replicates"):
        bounded_ci_coverage(replicates=0)
