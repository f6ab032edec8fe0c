"""Seeds until the answer is precise enough: the seeds-until-MDE rule and its false-positive rate.

The rule (`seeds_until_mde_step` on the looks of `seeds_until_mde_schedule`) stops adding seeds
once the MDE of every named statistic, taken from a one-sided upper confidence limit on its paired
SD (`sd_upper_bound`, `mde_upper`), is at most the target; it looks at SDs only, never at an
effect or its sign. `sequential_false_positive_rate` simulates the arms' CI under the rule on
seeds where no effect exists. `seal.experiments.until_mde` runs it on the transfer testbed
(docs/transfer_testbed.md, "Seeds until the MDE").
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from scipy import stats as scipy_stats

from seal.errors import SealError
from seal.stats import _finite, binomial_ci, mde, resolved, saving, t_ci

SD_BOUND_CONFIDENCE = 0.80
"""Confidence of the one-sided upper limit on the paired SD that the seeds-until-MDE rule uses."""


def sd_upper_bound(sd: float, n: int, confidence: float = SD_BOUND_CONFIDENCE) -> float:
    """One-sided upper `confidence` limit of a normal SD from the sample SD `sd` of n values.

    (n - 1) s^2 / sigma^2 is chi-square with n - 1 degrees of freedom, so sigma <=
    s sqrt((n - 1) / chi2.ppf(1 - confidence, n - 1)) with probability `confidence`. NaN when
    n < 2 or `sd` is not finite.
    """
    if not 0.0 < confidence < 1.0:
        raise SealError(f"confidence {confidence!r} is not a probability; expected 0 < c < 1")
    if n < 2 or not math.isfinite(sd):
        return math.nan
    return float(sd * math.sqrt((n - 1) / scipy_stats.chi2.ppf(1.0 - confidence, n - 1)))


def mde_upper(
    differences: Sequence[float], confidence: float = SD_BOUND_CONFIDENCE
) -> dict[str, float | int]:
    """The rule's precision of one paired statistic: `n` (finite differences), their sample `sd`
    (ddof 1), its upper limit `sd_upper` (`sd_upper_bound`) and `mde_upper`, the MDE of `mde` at
    n with `sd_upper` in place of the SD. Only the spread of the differences enters, never their
    mean or sign."""
    x = _finite(differences)
    sd = float(np.std(x, ddof=1)) if len(x) >= 2 else math.nan
    upper = sd_upper_bound(sd, len(x), confidence)
    return {"n": len(x), "sd": sd, "sd_upper": upper, "mde_upper": mde(upper, len(x))}


def seeds_until_mde_step(
    differences: Mapping[str, Sequence[float] | None],
    seeds: int,
    target: float,
    max_seeds: int,
    confidence: float = SD_BOUND_CONFIDENCE,
) -> dict[str, Any]:
    """One look of the seeds-until-MDE rule, after `seeds` seeds: stop or add seeds?

    `differences` maps each named statistic to its per-seed paired differences, or to None where
    it has no MDE (an arm that never reached, with its alone arm): those do not count. The rule
    stops with "target reached" when at least one statistic counts and every counted one has
    `mde_upper` <= `target` (a NaN MDE is not reached), else with "max seeds" at `seeds` >=
    `max_seeds`, else goes on (reason None). It reads the differences' SDs only (`mde_upper`).
    """
    if not target > 0:
        raise SealError(f"target MDE {target!r}: expected > 0")
    per = {
        name: None if values is None else mde_upper(values, confidence)
        for name, values in differences.items()
    }
    counted = [name for name, p in per.items() if p is not None]
    above = [name for name in counted if not per[name]["mde_upper"] <= target]  # NaN: above
    if counted and not above:
        reason: str | None = "target reached"
    elif seeds >= max_seeds:
        reason = "max seeds"
    else:
        reason = None
    return {
        "seeds": seeds,
        "statistics": per,
        "counted": counted,
        "above_target": above,
        "stop": reason is not None,
        "reason": reason,
    }


def seeds_until_mde_schedule(first: int, batch: int, max_seeds: int) -> list[int]:
    """The seed counts at which the rule looks: `first`, then `batch` more each time, the last
    capped at `max_seeds` (all capped there)."""
    if batch < 1 or first < 2 or max_seeds < 2:
        raise SealError(f"schedule {first}, +{batch}, max {max_seeds}: expected >= 2, >= 1, >= 2")
    counts = [min(first, max_seeds)]
    while counts[-1] < max_seeds:
        counts.append(min(counts[-1] + batch, max_seeds))
    return counts


def sequential_false_positive_rate(
    values: Sequence[float],
    *,
    target: float,
    max_seeds: int,
    batch: int,
    first: int,
    splits: int = 1_000,
    seed: int = 0,
    confidence: float = SD_BOUND_CONFIDENCE,
    difference: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
    ci: Callable[[Sequence[float]], tuple[float, float]] = t_ci,
) -> dict[str, Any]:
    """The false-positive rate of `ci` under the seeds-until-MDE rule, on one arm's seeds.

    `values` are one arm's per-seed values (e.g. the alone arm's gradient steps to 90%), so there
    is no effect. Each of `splits` draws permutes them and takes two disjoint halves of
    `max_seeds` (pair i: the i-th seed of each half, a random pairing). The rule looks at pairs
    0..n-1 for n in `seeds_until_mde_schedule(first, batch, max_seeds)`, as the bench would add
    them, and stops at the first n where `seeds_until_mde_step` stops on the one statistic
    `difference(a[:n], b[:n])`, recomputed at each look as the bench recomputes it from the seeds
    it has (default: the saving of a over b, `seal.stats.saving`, as `steps_saved`); the draw
    counts when `ci` of those n differences excludes 0 (`resolved`). Returns the rate, its Clopper-Pearson
    95% CI, how many stopped for each reason, and the seeds used.
    """
    x = np.asarray(values, dtype=float).ravel()
    if not np.isfinite(x).all():
        raise SealError(f"values {x.tolist()}: expected finite values, one per seed")
    if max_seeds < 2 or 2 * max_seeds > len(x):
        raise SealError(
            f"{len(x)} seeds cannot make two disjoint halves of --max-seeds {max_seeds} "
            f"(need >= {2 * max_seeds})"
        )
    if splits < 1:
        raise SealError(f"splits {splits!r}: expected >= 1")
    if difference is None:
        if not (x > 0).all():
            raise SealError(f"values {x.tolist()}: a saving of costs needs positive costs")
        difference = saving

    schedule = seeds_until_mde_schedule(first, batch, max_seeds)
    rng = np.random.default_rng(seed)
    excluded = 0
    reasons = {"target reached": 0, "max seeds": 0}
    used: dict[int, int] = {}
    for _ in range(splits):
        order = rng.permutation(len(x))
        a, b = x[order[:max_seeds]], x[order[max_seeds : 2 * max_seeds]]
        for n in schedule:
            d = difference(a[:n], b[:n])
            look = seeds_until_mde_step({"d": d}, n, target, max_seeds, confidence)
            if look["stop"]:
                break
        reasons[look["reason"]] += 1
        used[n] = used.get(n, 0) + 1
        if resolved(ci(d)):
            excluded += 1
    return {
        "seeds": len(x),
        "splits": splits,
        "schedule": schedule,
        "excluding_0": excluded,
        "rate": excluded / splits,
        "rate_ci95": list(binomial_ci(excluded, splits)),
        "stopped": reasons,
        "seeds_used": {str(n): used[n] for n in sorted(used)},
        "seeds_used_mean": sum(n * k for n, k in used.items()) / splits,
    }
