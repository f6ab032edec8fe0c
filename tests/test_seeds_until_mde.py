"""The seeds-until-MDE rule (issue 58 item 4): the SD's upper limit, the stopping decision, and
the false-positive rate under the rule, on hand-made numbers (no runs)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats as scipy_stats

from seal.errors import SealError
from seal.stats import binomial_ci, mde
from seal.stopping import (
    mde_upper,
    sd_upper_bound,
    seeds_until_mde_schedule,
    seeds_until_mde_step,
    sequential_false_positive_rate,
)


def test_sd_upper_bound_by_hand() -> None:
    # chi2.ppf(0.20, 4) = 1.648777 (the 20% point of chi-square with 4 df): at n = 5, s = 0.1,
    # sigma <= 0.1 sqrt(4 / 1.648777) = 0.1 x 1.557575 = 0.155758 with 80% confidence.
    assert sd_upper_bound(0.1, 5) == pytest.approx(0.155758, abs=1e-6)
    # chi2.ppf(0.20, 9) = 5.380053: at n = 10, 0.2 sqrt(9 / 5.380053) = 0.258677.
    assert sd_upper_bound(0.2, 10) == pytest.approx(0.258677, abs=1e-6)
    # A 95% limit is wider: chi2.ppf(0.05, 4) = 0.710723, sqrt(4 / 0.710723) = 2.372356.
    assert sd_upper_bound(1.0, 5, confidence=0.95) == pytest.approx(2.372356, abs=1e-5)
    assert math.isnan(sd_upper_bound(0.1, 1)) and math.isnan(sd_upper_bound(math.nan, 5))
    with pytest.raises(SealError, match="not a probability"):
        sd_upper_bound(0.1, 5, confidence=1.0)


def test_mde_upper_is_mde_at_the_sds_upper_limit() -> None:
    values = [0.0, 0.1, -0.1, 0.2, -0.2]  # mean 0, SD sqrt(0.1 / 4) = 0.158114
    got = mde_upper(values + [math.nan])  # the NaN is dropped
    assert got["n"] == 5 and got["sd"] == pytest.approx(0.158114, abs=1e-6)
    assert got["sd_upper"] == pytest.approx(0.158114 * 1.557575, abs=1e-6)
    # (t(0.975, 4) + t(0.80, 4)) = 3.717410, / sqrt(5): the project's `mde` at the upper SD.
    assert got["mde_upper"] == pytest.approx(3.717410 * 0.158114 * 1.557575 / math.sqrt(5), 1e-5)
    assert got["mde_upper"] == mde(got["sd_upper"], 5)


def _spread(sd: float, n: int = 5, mean: float = 0.0) -> list[float]:
    """n values of sample SD exactly `sd` around `mean`."""
    z = np.linspace(-1.0, 1.0, n)
    return (mean + sd * z / np.std(z, ddof=1)).tolist()


# At n = 5 the MDE from the upper SD is 3.717410 x 1.557575 / sqrt(5) = 2.589 x the sample SD:
# a sample SD of 0.03 gives 0.078, of 0.05 gives 0.129.
SMALL, LARGE = _spread(0.03), _spread(0.05)


def test_the_rule_stops_when_every_named_mde_is_at_most_the_target() -> None:
    look = seeds_until_mde_step({"a/steps": SMALL, "a/auc": SMALL}, 5, 0.10, 20)
    assert look["stop"] and look["reason"] == "target reached" and look["above_target"] == []
    assert look["statistics"]["a/steps"]["mde_upper"] == pytest.approx(2.5894 * 0.03, abs=1e-4)


def test_the_rule_goes_on_while_one_named_mde_is_above_the_target() -> None:
    look = seeds_until_mde_step({"a/steps": SMALL, "b/steps": LARGE}, 5, 0.10, 20)
    assert not look["stop"] and look["reason"] is None
    assert look["above_target"] == ["b/steps"]


def test_the_rule_stops_at_max_seeds() -> None:
    look = seeds_until_mde_step({"a/steps": SMALL, "b/steps": LARGE}, 20, 0.10, 20)
    assert look["stop"] and look["reason"] == "max seeds" and look["above_target"] == ["b/steps"]
    # Reached at the last look: the target, not the cap, is why it stopped.
    assert seeds_until_mde_step({"a": SMALL}, 20, 0.10, 20)["reason"] == "target reached"


def test_arms_that_never_reach_have_no_mde_and_do_not_count() -> None:
    look = seeds_until_mde_step({"a/steps": SMALL, "sparse/steps": None}, 5, 0.10, 20)
    assert look["reason"] == "target reached" and look["counted"] == ["a/steps"]
    assert look["statistics"]["sparse/steps"] is None
    # Nothing counted: nothing is precise yet, so the rule goes on to its cap.
    assert seeds_until_mde_step({"sparse/steps": None}, 5, 0.10, 20)["reason"] is None
    assert seeds_until_mde_step({"sparse/steps": None}, 20, 0.10, 20)["reason"] == "max seeds"
    # A counted statistic without an MDE (fewer than 2 finite pairs) is not reached.
    look = seeds_until_mde_step({"a": SMALL, "b": [0.1, math.nan]}, 5, 0.10, 20)
    assert look["above_target"] == ["b"] and not look["stop"]


def test_the_rule_never_looks_at_the_effect_or_its_sign() -> None:
    rng = np.random.default_rng(3)
    for _ in range(50):
        values = {name: rng.normal(rng.normal(), rng.uniform(0.01, 0.2), 7) for name in "abc"}
        looks = [
            seeds_until_mde_step({k: transform(v) for k, v in values.items()}, 7, 0.10, max_seeds=9)
            for transform in (lambda v: v, lambda v: -v, lambda v: v + 5.0, lambda v: 0.3 - v)
        ]
        for look in looks[1:]:
            assert (look["stop"], look["reason"]) == (looks[0]["stop"], looks[0]["reason"])
            for name in values:
                assert look["statistics"][name]["mde_upper"] == pytest.approx(
                    looks[0]["statistics"][name]["mde_upper"], rel=1e-9
                )


def test_schedule_adds_batches_up_to_max_seeds() -> None:
    assert seeds_until_mde_schedule(5, 2, 12) == [5, 7, 9, 11, 12]
    assert seeds_until_mde_schedule(5, 2, 5) == [5]
    assert seeds_until_mde_schedule(8, 8, 20) == [8, 16, 20]
    assert seeds_until_mde_schedule(16, 16, 10) == [10]
    with pytest.raises(SealError):
        seeds_until_mde_schedule(5, 0, 10)


def test_target_must_be_positive() -> None:
    with pytest.raises(SealError, match="target MDE"):
        seeds_until_mde_step({"a": SMALL}, 5, 0.0, 20)


# ---------------------------------------------------------------- false positives under the rule

RULE = {"target": 1.5, "max_seeds": 20, "batch": 2, "first": 5}
"""On N(0, 1) halves (differences of SD sqrt 2), MDE <= 1.5 is reached at about 11-15 pairs."""


def _direct_rate(replicates: int, seed: int) -> float:
    """The rule's false-positive rate on i.i.d. normal pairs, computed directly (vectorised, from
    the formulas, not through `seal.stats`): SD's 80% upper limit, MDE, stop, t-test at 5%."""
    rng = np.random.default_rng(seed)
    d = rng.normal(0.0, 1.0, (replicates, 20)) - rng.normal(0.0, 1.0, (replicates, 20))
    stopped = np.zeros(replicates, dtype=bool)
    rejected = np.zeros(replicates, dtype=bool)
    for n in (5, 7, 9, 11, 13, 15, 17, 19, 20):
        x = d[:, :n]
        sd = x.std(axis=1, ddof=1)
        upper = sd * np.sqrt((n - 1) / scipy_stats.chi2.ppf(0.2, n - 1))
        k = scipy_stats.t.ppf(0.975, n - 1) + scipy_stats.t.ppf(0.8, n - 1)
        stop_now = ~stopped & ((k * upper / np.sqrt(n) <= RULE["target"]) | (n == 20))
        t = np.abs(x.mean(axis=1)) / (sd / np.sqrt(n))
        rejected |= stop_now & (t > scipy_stats.t.ppf(0.975, n - 1))
        stopped |= stop_now
    assert stopped.all()
    return float(rejected.mean())


def test_false_positive_rate_under_the_rule_structure_and_interval() -> None:
    values = np.random.default_rng(0).normal(2500.0, 250.0, 40)
    got = sequential_false_positive_rate(
        values, target=0.10, max_seeds=20, batch=2, first=5, splits=200, seed=1
    )
    assert (got["seeds"], got["splits"]) == (40, 200)
    assert got["schedule"] == [5, 7, 9, 11, 13, 15, 17, 19, 20]
    assert got["rate"] == got["excluding_0"] / 200
    assert got["rate_ci95"] == pytest.approx(list(binomial_ci(got["excluding_0"], 200)))
    low, high = got["rate_ci95"]
    assert 0.0 <= low <= got["rate"] <= high <= 1.0
    assert sum(got["stopped"].values()) == 200 == sum(got["seeds_used"].values())
    assert set(map(int, got["seeds_used"])) <= set(got["schedule"])
    assert 5 <= got["seeds_used_mean"] <= 20
    # Seeded: the same call gives the same rate.
    again = sequential_false_positive_rate(
        values, target=0.10, max_seeds=20, batch=2, first=5, splits=200, seed=1
    )
    assert again == got


def test_false_positive_rate_under_the_rule_matches_a_direct_computation() -> None:
    # A large pool, so that splits of it are close to i.i.d. draws; 200 splits, fixed seeds.
    pool = np.random.default_rng(7).normal(0.0, 1.0, 2_000)
    got = sequential_false_positive_rate(
        pool, **RULE, splits=200, seed=0, difference=lambda a, b: a - b
    )
    direct = _direct_rate(20_000, seed=1)
    se = math.sqrt(direct * (1 - direct) / 200)
    assert abs(got["rate"] - direct) <= 3 * se, (got["rate"], direct, se)
    # Both stop mostly on the target, not the cap, so the rule is what is measured.
    assert got["stopped"]["target reached"] > got["stopped"]["max seeds"]


def test_false_positive_rate_under_the_rule_errors() -> None:
    with pytest.raises(SealError, match="need >= 40"):
        sequential_false_positive_rate(np.ones(39), target=0.1, max_seeds=20, batch=2, first=5)
    with pytest.raises(SealError, match="positive costs"):
        sequential_false_positive_rate(-np.ones(40), target=0.1, max_seeds=20, batch=2, first=5)
