"""Uncertainty over seeds: confidence intervals of changes, and the probability of improvement.

The update-count tables compare a few seeds per setting, so a change of -30% may be noise. This
module gives each change of a mean cost (and of a total over tasks, tasks as strata) Fieller's
interval with Student's t quantiles, paired by seed where the seeds pair: at 5 seeds the
percentile bootstrap excluded 0 in 17% of no-effect comparisons. Means, IQMs and curves keep
rliable's percentile and stratified bootstraps (Agarwal et al. 2021, "Deep RL at the Edge of the
Statistical Precipice"), with the probability of improvement. rliable itself needs `arch`, which
does not install here without compiling, so the resampling is `scipy.stats.bootstrap`'s; the
definitions are rliable's.

Costs are the quantities here (transitions or gradient steps to 90%): lower is better. Every
function is pure (numbers in, numbers out) and seeded, so a report is reproducible.

Beside the intervals, what an instrument of n seeds can resolve at all: the minimum detectable
effect of a paired comparison (`mde`, `seeds_for_mde`, `paired_power`), rliable's interquartile
mean (`interquartile_mean`, `iqm_ci`), a bootstrap band around a mean curve (`bootstrap_band`),
and the false-positive rate of a CI method on two halves of one arm (`split_false_positive_rate`).
A statistic with a known range (a saving is at most 1) has its interval cut there (`clip_ci`,
`bounded_t_ci`). Built on these: the seeds-until-MDE rule and its false-positive rate
(`seal.stopping`) and the coverage of cut intervals near their bound (`seal.coverage`).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from scipy import stats as scipy_stats

from seal.errors import SealError

MIN_SEEDS_RESOLVED = 3
"""Below this many seeds in a group, a report calls no change resolved (a CI from 2 seeds is 2 points)."""

DEFAULT_CONFIDENCE = 0.95
DEFAULT_RESAMPLES = 10_000

_Statistic = Callable[..., np.ndarray]


def _finite(values: Sequence[float]) -> np.ndarray:
    array = np.asarray(values, dtype=float).ravel()
    return array[np.isfinite(array)]


def _check(confidence: float, n_resamples: int) -> None:
    if not 0.0 < confidence < 1.0:
        raise SealError(f"confidence {confidence!r} is not a probability; expected 0 < c < 1")
    if n_resamples < 1:
        raise SealError(f"n_resamples {n_resamples!r}: expected >= 1")


def _percentile_ci(
    sizes: Sequence[int],
    statistic: _Statistic,
    confidence: float,
    n_resamples: int,
    seed: int,
) -> tuple[float, float]:
    """Percentile CI of `statistic(*index_arrays)`, each index array resampled independently.

    Resampling indices rather than values lets one index array serve two samples (pairing) while
    other arrays are drawn independently (strata), all through one scipy call.
    """
    _check(confidence, n_resamples)
    data = tuple(np.arange(n) for n in sizes)
    point = float(statistic(*data))
    # Every resample gives the point value (e.g. all values equal): scipy would warn of a
    # degenerate distribution; the CI is that value.
    if all(n == 1 for n in sizes):
        return point, point
    result = scipy_stats.bootstrap(
        data,
        lambda *index, axis=-1: statistic(*index),  # indices arrive as (resamples, n): axis -1
        n_resamples=n_resamples,
        vectorized=True,
        paired=False,
        confidence_level=confidence,
        method="percentile",  # rliable's default; BCa is unstable with a handful of seeds
        rng=np.random.default_rng(seed),
    )
    low, high = float(result.confidence_interval.low), float(result.confidence_interval.high)
    return low, high


def bootstrap_ci(
    values: Sequence[float],
    *,
    confidence: float = DEFAULT_CONFIDENCE,
    n_resamples: int = DEFAULT_RESAMPLES,
    seed: int = 0,
) -> tuple[float, float]:
    """Percentile bootstrap CI of the mean of `values` (NaNs dropped); (nan, nan) below 2 values."""
    x = _finite(values)
    if len(x) < 2:
        return math.nan, math.nan
    if np.all(x == x[0]):
        return float(x[0]), float(x[0])  # no spread to resample; scipy would call it degenerate
    return _percentile_ci([len(x)], lambda i: x[i].mean(axis=-1), confidence, n_resamples, seed)


def _paired_finite(arm: Sequence[float], base: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    a, b = np.asarray(arm, dtype=float).ravel(), np.asarray(base, dtype=float).ravel()
    if len(a) != len(b):
        raise SealError(
            f"paired samples differ in length: {len(a)} arm values, {len(b)} base values; "
            f"pair them by seed, or pass paired=False"
        )
    keep = np.isfinite(a) & np.isfinite(b)  # a pair counts only when both seeds have a value
    return a[keep], b[keep]


def _fieller(
    strata: Sequence[tuple[np.ndarray, np.ndarray]], paired: bool, confidence: float
) -> tuple[float, float]:
    """Fieller's CI of sum_t mean(a_t) / sum_t mean(b_t) - 1 over strata (tasks) of seeds.

    The set of ratios c for which the t-test of sum_t mean(a_t - c b_t) = 0 does not reject
    (Fieller 1954), so the interval keeps the t-test's level for a ratio of means. The variance
    of sum_t (mean(a_t) - c mean(b_t)) adds the strata's (paired: from the per-seed differences;
    unpaired: Welch's), and its degrees of freedom are Welch-Satterthwaite's at the point ratio
    (one paired stratum: n - 1, the paired t-test's). (nan, nan) when the base total is not
    resolved from 0: the set of ratios is then unbounded.
    """
    ma = sum(float(a.mean()) for a, _ in strata)
    mb = sum(float(b.mean()) for _, b in strata)
    point = ma / mb
    var_a = var_b = cov_ab = 0.0
    pieces: list[tuple[float, int]] = []  # (variance at the point ratio, its degrees of freedom)
    for a, b in strata:
        if paired:
            cov = np.cov(a, b, ddof=1) / len(a)  # covariance matrix of the two means
            va, vb, cab = float(cov[0, 0]), float(cov[1, 1]), float(cov[0, 1])
            pieces.append((va - 2 * point * cab + point**2 * vb, len(a) - 1))
        else:
            va, vb, cab = float(a.var(ddof=1)) / len(a), float(b.var(ddof=1)) / len(b), 0.0
            pieces += [(va, len(a) - 1), (point**2 * vb, len(b) - 1)]
        var_a, var_b, cov_ab = var_a + va, var_b + vb, cov_ab + cab
    spread = sum(v**2 / df for v, df in pieces)
    if not spread > 0:  # no spread at the point ratio: the CI is the point
        return point - 1.0, point - 1.0
    df = sum(v for v, _ in pieces) ** 2 / spread
    t2 = float(scipy_stats.t.ppf(0.5 + confidence / 2.0, df)) ** 2
    # (ma - c mb)^2 <= t^2 var(ma - c mb), i.e. quad c^2 - 2 half_lin c + const <= 0
    quad, half_lin, const = mb**2 - t2 * var_b, ma * mb - t2 * cov_ab, ma**2 - t2 * var_a
    if not quad > 0:
        return math.nan, math.nan
    root = math.sqrt(max(half_lin**2 - quad * const, 0.0))
    return (half_lin - root) / quad - 1.0, (half_lin + root) / quad - 1.0


def change_ci(
    arm: Sequence[float],
    base: Sequence[float],
    *,
    paired: bool,
    confidence: float = DEFAULT_CONFIDENCE,
) -> tuple[float, float]:
    """CI of mean(arm) / mean(base) - 1 over seeds (paired: by seed): Fieller's, with t quantiles.

    The percentile bootstrap this replaced excluded 0 in 17% of no-effect splits at 5 seeds
    (docs/transfer_testbed.md, "False-positive rate"): too narrow at a handful of seeds.
    NaNs are dropped (paired: the pair). (nan, nan) when either side has fewer than 2 values, the
    base mean is not positive, or it is not resolved from 0 (`_fieller`).
    """
    return stratified_change_ci({"": arm}, {"": base}, paired=paired, confidence=confidence)


def stratified_change_ci(
    arm: Mapping[str, Sequence[float]],
    base: Mapping[str, Sequence[float]],
    *,
    paired: bool,
    confidence: float = DEFAULT_CONFIDENCE,
) -> tuple[float, float]:
    """CI of the change of the total over tasks, sum_t mean(arm[t]) / sum_t mean(base[t]) - 1.

    Fieller's interval with the tasks as strata (`_fieller`): each task's seeds give its mean's
    variance, tasks independently; paired, a task's arm and base pair by seed. Both mappings must
    name the same tasks; NaNs are dropped (paired: the pair). (nan, nan) when a task has fewer than
    2 values on a side, or when the base total is not positive or not resolved from 0.
    """
    if set(arm) != set(base):
        raise SealError(
            f"stratified change: the arm's tasks {sorted(arm)} differ from the base's {sorted(base)}"
        )
    tasks = sorted(arm)
    if not tasks:
        return math.nan, math.nan
    if paired:
        strata = [_paired_finite(arm[t], base[t]) for t in tasks]
    else:
        strata = [(_finite(arm[t]), _finite(base[t])) for t in tasks]
    if any(len(a) < 2 or len(b) < 2 for a, b in strata):  # 2 values a side at least
        return math.nan, math.nan
    if not sum(b.mean() for _, b in strata) > 0:
        return math.nan, math.nan
    return _fieller(strata, paired, confidence)


def saving(arm: Sequence[float], alone: Sequence[float]) -> np.ndarray:
    """Per pair i: (alone_i - arm_i) / mean(alone), the share of the alone side's mean cost the arm
    saved in pair i; all nan where that mean is not > 0.

    Their mean is the saving of the means, 1 - mean(arm) / mean(alone), and a paired t CI of them
    tests a difference of costs, symmetric about 0 when the arm changes nothing. The choice (issue
    58): the mean of per-pair ratios 1 - arm_i / alone_i is biased under no effect by about
    -CV(alone)^2 (Jensen: E[1 / alone] > 1 / E[alone]): -0.058 on the testbed's 40 alone seeds,
    whose t CI then called 7.0% of no-effect splits resolved, not 5% (docs/transfer_testbed.md,
    "Seeds until the MDE"). A t CI of these values holds mean(alone) fixed, so it leaves out the
    denominator's spread (its CV / sqrt(n): about 5% of the saving at 20 testbed seeds).
    """
    a, b = np.asarray(arm, dtype=float), np.asarray(alone, dtype=float)
    if a.shape != b.shape:
        raise SealError(
            f"{a.size} values of the arm but {b.size} of the alone side to pair them with"
        )
    scale = float(b.mean()) if b.size else 0.0
    if not scale > 0:
        return np.full(a.shape, math.nan)
    return (b - a) / scale


def probability_of_improvement(arm: Sequence[float], base: Sequence[float]) -> float:
    """P(a random arm run costs less than a random base run), ties counting 1/2 (NaNs dropped).

    rliable's probability of improvement, for costs (lower is better): the Mann-Whitney U of base
    against arm divided by n x m. NaN when either side is empty.
    """
    a, b = _finite(arm), _finite(base)
    if len(a) == 0 or len(b) == 0:
        return math.nan
    lower = (a[:, None] < b[None, :]).sum()
    ties = (a[:, None] == b[None, :]).sum()
    return float((lower + 0.5 * ties) / (len(a) * len(b)))


def resolved(ci: tuple[float, float]) -> bool:
    """True when the CI excludes 0: both ends finite, non-zero and of the same sign."""
    low, high = ci
    if not (math.isfinite(low) and math.isfinite(high)):
        return False
    return (low > 0 and high > 0) or (low < 0 and high < 0)


# ---------------------------------------------------------------- resolving power


def mde(sd: float, n: int, *, alpha: float = 0.05, power: float = 0.8) -> float:
    """Minimum detectable effect of a paired comparison: (t_{1-alpha/2,n-1} + t_{power,n-1}) * sd / sqrt(n).

    The smallest true mean of n paired differences (of sample SD `sd`) that a two-sided
    one-sample t-test at level `alpha` detects with probability about `power`, in the unit of
    `sd` (the normal-approximation formula with t quantiles; the exact power from the noncentral
    t is 0.79 at n = 5 for power 0.8). NaN when n < 2 or `sd` is not finite.
    """
    if not (0.0 < alpha < 1.0 and 0.0 < power < 1.0):
        raise SealError(f"alpha {alpha!r} and power {power!r}: expected probabilities in (0, 1)")
    if n < 2 or not math.isfinite(sd):
        return math.nan
    df = n - 1
    quantiles = scipy_stats.t.ppf(1.0 - alpha / 2.0, df) + scipy_stats.t.ppf(power, df)
    return float(quantiles * sd / math.sqrt(n))


def seeds_for_mde(
    sd: float,
    target: float = 0.10,
    *,
    alpha: float = 0.05,
    power: float = 0.8,
    max_seeds: int = 1_000_000,
) -> int | None:
    """The smallest n >= 2 with mde(sd, n) <= target (the t quantiles shrink with n too).

    None when `sd` is not finite or more than `max_seeds` seeds would be needed.
    """
    if not target > 0:
        raise SealError(f"target MDE {target!r}: expected > 0")
    if not math.isfinite(sd) or mde(sd, max_seeds, alpha=alpha, power=power) > target:
        return None
    if mde(sd, 2, alpha=alpha, power=power) <= target:
        return 2
    low, high = 2, max_seeds  # mde(low) > target >= mde(high), and mde falls as n grows
    while high - low > 1:
        middle = (low + high) // 2
        if mde(sd, middle, alpha=alpha, power=power) <= target:
            high = middle
        else:
            low = middle
    return high


def mde_key(target: float) -> str:
    """The suffix of `seeds_for_mde_<target>_...` keys: 0.10 -> "0p10"."""
    return f"{target:.2f}".replace(".", "p")


def paired_power(differences: Sequence[float], name: str, target: float = 0.10) -> dict[str, Any]:
    """`sd_paired_<name>`, `mde_<name>` and `seeds_for_mde_<target>_<name>` of per-seed paired differences.

    NaNs are dropped; the SD is the sample SD (ddof 1), the MDE is at the seeds given (`mde`), and
    the seeds are those an MDE <= `target` needs at that SD (`seeds_for_mde`).
    """
    x = _finite(differences)
    sd = float(np.std(x, ddof=1)) if len(x) >= 2 else math.nan
    return {
        f"sd_paired_{name}": sd,
        f"mde_{name}": mde(sd, len(x)),
        f"seeds_for_mde_{mde_key(target)}_{name}": seeds_for_mde(sd, target),
    }


# ---------------------------------------------------------------- aggregates over runs and tasks


def interquartile_mean(values: Sequence[float]) -> float:
    """rliable's IQM: the mean of the middle 50% of the values (scipy's trim_mean, 25% cut each end)."""
    x = _finite(values)
    return float(scipy_stats.trim_mean(x, 0.25)) if len(x) else math.nan


def iqm_ci(
    runs_by_task: np.ndarray | Sequence[Sequence[float]],
    *,
    confidence: float = DEFAULT_CONFIDENCE,
    n_resamples: int = DEFAULT_RESAMPLES,
    seed: int = 0,
) -> tuple[float, float]:
    """CI of the IQM over (run, task) of a runs x tasks table: rliable's stratified bootstrap.

    Each task's runs are resampled on their own (the task is the stratum), then the IQM is taken
    over every resampled (run, task) value. (nan, nan) below 2 runs or with a NaN in the table.
    """
    table = np.asarray(runs_by_task, dtype=float)
    if table.ndim != 2 or table.shape[0] < 2 or not np.isfinite(table).all():
        return math.nan, math.nan
    if np.all(table == table.flat[0]):
        return float(table.flat[0]), float(table.flat[0])
    columns = [table[:, t] for t in range(table.shape[1])]

    def statistic(*index: np.ndarray) -> np.ndarray:
        stacked = np.concatenate([c[i] for c, i in zip(columns, index, strict=True)], axis=-1)
        return scipy_stats.trim_mean(stacked, 0.25, axis=-1)

    return _percentile_ci([len(c) for c in columns], statistic, confidence, n_resamples, seed)


def bootstrap_band(
    curves: np.ndarray | Sequence[Sequence[float]],
    *,
    confidence: float = DEFAULT_CONFIDENCE,
    n_resamples: int = 2_000,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Pointwise percentile bootstrap CI of the mean of a seeds x points table of curves.

    Seeds are resampled whole (a curve stays one seed's), in numpy, since scipy.stats.bootstrap
    takes a NaN for a degenerate sample; NaNs (a point a seed lacks) are left out of that point's
    mean. One seed: the curve itself, at both ends.
    """
    _check(confidence, n_resamples)
    table = np.atleast_2d(np.asarray(curves, dtype=float))
    if table.shape[0] < 2:
        return table[0].copy(), table[0].copy()
    rng = np.random.default_rng(seed)
    index = rng.integers(0, table.shape[0], size=(n_resamples, table.shape[0]))
    with warnings.catch_warnings():
        # A resample of only seeds that lack a point has no mean there: NaN, left out below.
        warnings.filterwarnings("ignore", "Mean of empty slice", RuntimeWarning)
        means = np.nanmean(table[index], axis=1)  # (resamples, points)
    tail = 100.0 * (1.0 - confidence) / 2.0
    low, high = np.nanpercentile(means, [tail, 100.0 - tail], axis=0)
    return low, high


# ---------------------------------------------------------------- false positives


def t_ci(values: Sequence[float], *, confidence: float = DEFAULT_CONFIDENCE) -> tuple[float, float]:
    """Student's t CI of the mean of `values` (NaNs dropped); (nan, nan) below 2 values."""
    x = _finite(values)
    if len(x) < 2:
        return math.nan, math.nan
    sem = float(np.std(x, ddof=1)) / math.sqrt(len(x))
    if sem == 0:
        return float(x.mean()), float(x.mean())
    half = float(scipy_stats.t.ppf(0.5 + confidence / 2.0, len(x) - 1)) * sem
    return float(x.mean()) - half, float(x.mean()) + half


UNBOUNDED = (-math.inf, math.inf)
"""The range of a statistic with no bound: `clip_ci` leaves its interval as it is."""


def clip_ci(ci: tuple[float, float], bounds: tuple[float, float]) -> tuple[float, float]:
    """`ci` cut at the range `bounds` = (low, high) of the statistic (either end may be infinite).

    A mean of values in [low, high] lies in [low, high], so an interval that covers it covers it
    still once cut there: the coverage is the interval's own, and only values the statistic cannot
    take go. NaN ends stay NaN.
    """
    low, high = bounds
    if not low <= high:
        raise SealError(f"bounds {bounds!r}: expected low <= high")
    return float(np.clip(ci[0], low, high)), float(np.clip(ci[1], low, high))


def bounded_t_ci(
    values: Sequence[float],
    bounds: tuple[float, float] = UNBOUNDED,
    *,
    confidence: float = DEFAULT_CONFIDENCE,
) -> tuple[float, float]:
    """Student's t CI of the mean of `values` (`t_ci`), cut at the range `bounds` (`clip_ci`).

    For a mean in a known range, such as the saving 1 - mean cost(arm) / mean cost(alone) <= 1
    (`saving`): the t interval's coverage, and no end beyond the range (the t interval of the
    oracle's five savings ends above 1). Where the values pile up at the bound the t interval's
    coverage is below nominal (`bounded_ci_coverage`); the cut does not change it. The range is
    the mean's: one seed's `saving` can pass 1. Raises SealError when the mean lies outside
    `bounds` (beyond rounding): the bounds would be wrong.
    """
    low, high = bounds
    x = _finite(values)
    slack = 1e-9 * max([1.0, *(abs(b) for b in bounds if math.isfinite(b))])
    if len(x) and not low - slack <= x.mean() <= high + slack:
        raise SealError(
            f"values {x.tolist()}: their mean {x.mean():.6g} leaves the statistic's range "
            f"[{low}, {high}]"
        )
    return clip_ci(t_ci(x, confidence=confidence), bounds)


def binomial_ci(
    successes: int, trials: int, confidence: float = DEFAULT_CONFIDENCE
) -> tuple[float, float]:
    """Clopper-Pearson (exact) CI of a binomial proportion (scipy.stats.binomtest)."""
    if trials < 1 or not 0 <= successes <= trials:
        raise SealError(f"{successes} of {trials} trials: expected 0 <= successes <= trials >= 1")
    interval = scipy_stats.binomtest(successes, trials).proportion_ci(confidence, method="exact")
    return float(interval.low), float(interval.high)


def split_false_positive_rate(
    costs: Sequence[float],
    *,
    half: int = 5,
    splits: int = 1_000,
    seed: int = 0,
    ci: Callable[[Sequence[float]], tuple[float, float]] = bootstrap_ci,
    change: Callable[[np.ndarray, np.ndarray], tuple[float, float]] | None = None,
) -> dict[str, Any]:
    """How often a CI method calls a difference between two halves of one arm resolved.

    `costs` are one arm's per-seed costs (e.g. gradient steps to 90%), so there is no effect to
    find. Each of `splits` draws takes two disjoint random sets of `half` seeds, pairs them at
    random, forms the per-pair saving of a over b (`saving`, as `steps_saved` does), and applies
    `ci` (default: the percentile bootstrap) to their mean; or, with `change`, applies `change`
    to the paired halves (a, b) themselves (a report's CI of mean(a) / mean(b) - 1, say). Returns
    the share of CIs that exclude 0 (`rate`), its Clopper-Pearson 95% CI (`rate_ci95`), and the
    counts.
    """
    x = np.asarray(costs, dtype=float).ravel()
    if not np.isfinite(x).all() or not (x > 0).all():
        raise SealError(f"costs {x.tolist()}: expected finite positive values, one per seed")
    if half < 2 or 2 * half > len(x):
        raise SealError(f"{len(x)} seeds cannot make two disjoint halves of {half} (half >= 2)")
    if splits < 1:
        raise SealError(f"splits {splits!r}: expected >= 1")
    rng = np.random.default_rng(seed)
    excluded = 0
    for _ in range(splits):
        order = rng.permutation(len(x))
        a, b = x[order[:half]], x[order[half : 2 * half]]  # b's order is random: a random pairing
        if resolved(ci(saving(a, b)) if change is None else change(a, b)):
            excluded += 1
    return {
        "seeds": len(x),
        "half": half,
        "splits": splits,
        "excluding_0": excluded,
        "rate": excluded / splits,
        "rate_ci95": list(binomial_ci(excluded, splits)),
    }
