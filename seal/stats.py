"""Uncertainty over seeds: bootstrap confidence intervals and the probability of improvement.

The update-count tables compare a few seeds per setting, so a change of -30% may be noise. This
module gives each change a percentile bootstrap CI over seeds, the stratified bootstrap of a total
over tasks (runs resampled within each task), and the probability of improvement, as rliable
does (Agarwal et al. 2021, "Deep RL at the Edge of the Statistical Precipice"). rliable itself
needs `arch`, which does not install here without compiling, so the resampling is
`scipy.stats.bootstrap`'s; the definitions are rliable's.

Costs are the quantities here (transitions or gradient steps to 90%): lower is better. Every
function is pure (numbers in, numbers out) and seeded, so a report is reproducible.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence

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


def _relative(arm_mean: np.ndarray, base_mean: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        return arm_mean / base_mean - 1.0


def _paired_finite(arm: Sequence[float], base: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    a, b = np.asarray(arm, dtype=float).ravel(), np.asarray(base, dtype=float).ravel()
    if len(a) != len(b):
        raise SealError(
            f"paired samples differ in length: {len(a)} arm values, {len(b)} base values; "
            f"pair them by seed, or pass paired=False"
        )
    keep = np.isfinite(a) & np.isfinite(b)  # a pair counts only when both seeds have a value
    return a[keep], b[keep]


def change_ci(
    arm: Sequence[float],
    base: Sequence[float],
    *,
    paired: bool,
    confidence: float = DEFAULT_CONFIDENCE,
    n_resamples: int = DEFAULT_RESAMPLES,
    seed: int = 0,
) -> tuple[float, float]:
    """CI of mean(arm) / mean(base) - 1, resampling seeds (paired: one index draw for both).

    NaNs are dropped (paired: the pair). (nan, nan) when either side has fewer than 2 values, or
    the base mean is not positive.
    """
    if paired:
        a, b = _paired_finite(arm, base)
    else:
        a, b = _finite(arm), _finite(base)
    if len(a) < 2 or len(b) < 2 or not b.mean() > 0:
        return math.nan, math.nan
    if np.all(a == a[0]) and np.all(b == b[0]):
        change = float(_relative(a[0], b[0]))
        return change, change
    if paired:
        return _percentile_ci(
            [len(a)],
            lambda i: _relative(a[i].mean(axis=-1), b[i].mean(axis=-1)),
            confidence,
            n_resamples,
            seed,
        )
    return _percentile_ci(
        [len(a), len(b)],
        lambda i, j: _relative(a[i].mean(axis=-1), b[j].mean(axis=-1)),
        confidence,
        n_resamples,
        seed,
    )


def stratified_change_ci(
    arm: Mapping[str, Sequence[float]],
    base: Mapping[str, Sequence[float]],
    *,
    paired: bool,
    confidence: float = DEFAULT_CONFIDENCE,
    n_resamples: int = DEFAULT_RESAMPLES,
    seed: int = 0,
) -> tuple[float, float]:
    """CI of the change of the total over tasks, sum_t mean(arm[t]) / sum_t mean(base[t]) - 1.

    Stratified bootstrap (rliable's): runs are resampled within each task, tasks independently;
    paired, a task's arm and base share one index draw. Both mappings must name the same tasks;
    NaNs are dropped (paired: the pair). (nan, nan) when a task has fewer than 2 values on a side
    (as `change_ci`), or when the base total is not positive.
    """
    if set(arm) != set(base):
        raise SealError(
            f"stratified change: the arm's tasks {sorted(arm)} differ from the base's {sorted(base)}"
        )
    tasks = sorted(arm)
    if not tasks:
        return math.nan, math.nan
    if paired:
        pairs = [_paired_finite(arm[t], base[t]) for t in tasks]
    else:
        pairs = [(_finite(arm[t]), _finite(base[t])) for t in tasks]
    if any(len(a) < 2 or len(b) < 2 for a, b in pairs):  # as change_ci: 2 values a side
        return math.nan, math.nan
    if not sum(b.mean() for _, b in pairs) > 0:
        return math.nan, math.nan
    if paired:
        sizes = [len(a) for a, _ in pairs]

        def statistic(*index: np.ndarray) -> np.ndarray:
            arm_total = sum(a[i].mean(axis=-1) for (a, _), i in zip(pairs, index, strict=True))
            base_total = sum(b[i].mean(axis=-1) for (_, b), i in zip(pairs, index, strict=True))
            return _relative(arm_total, base_total)

    else:
        sizes = [n for a, b in pairs for n in (len(a), len(b))]

        def statistic(*index: np.ndarray) -> np.ndarray:
            arm_total = sum(
                a[i].mean(axis=-1) for (a, _), i in zip(pairs, index[0::2], strict=True)
            )
            base_total = sum(
                b[i].mean(axis=-1) for (_, b), i in zip(pairs, index[1::2], strict=True)
            )
            return _relative(arm_total, base_total)

    if all(np.all(a == a[0]) and np.all(b == b[0]) for a, b in pairs):
        change = float(statistic(*(np.zeros(1, dtype=int) for _ in sizes)))
        return change, change
    return _percentile_ci(sizes, statistic, confidence, n_resamples, seed)


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
