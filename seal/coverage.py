"""Coverage of a bounded statistic's 95% interval near its bound, by simulation.

`bounded_ci_coverage` draws per-seed values from `CoverageCase`s (`near_bound_case`: a point mass
at the bound and a tail below it, as the oracle's steps_saved; `normal_case`: away from it) and
counts how often Student's t and the same interval cut at the range (`seal.stats.bounded_t_ci`)
cover the true mean; `format_coverage` prints the table docs/transfer_testbed.md holds.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from seal.errors import SealError
from seal.stats import DEFAULT_CONFIDENCE, _check, binomial_ci, bounded_t_ci, t_ci


@dataclass(frozen=True)
class CoverageCase:
    """A distribution of per-seed values for `bounded_ci_coverage`: its label, its mean, and
    `draw(rng, replicates, n)`, a replicates x n table of values."""

    label: str
    mean: float
    draw: Callable[[np.random.Generator, int, int], np.ndarray]


def near_bound_case(
    at_bound: float, shortfall: float, tail: str = "exponential", bound: float = 1.0
) -> CoverageCase:
    """Values exactly at `bound` with probability `at_bound` (a saving of 1: the arm reached at its
    first evaluation), else `bound` minus a shortfall of mean `shortfall`: exponential (no lower
    bound, as steps_saved's) or uniform on [0, 2 shortfall]. Mean bound - (1 - at_bound) shortfall.
    """
    if not (0.0 <= at_bound <= 1.0 and shortfall > 0 and tail in ("exponential", "uniform")):
        raise SealError(
            f"near-bound case {at_bound!r}, {shortfall!r}, {tail!r}: expected 0 <= at_bound <= 1, "
            "shortfall > 0 and tail 'exponential' or 'uniform'"
        )

    def draw(rng: np.random.Generator, replicates: int, n: int) -> np.ndarray:
        shape = (replicates, n)
        if tail == "exponential":
            below = rng.exponential(shortfall, shape)
        else:
            below = rng.uniform(0.0, 2.0 * shortfall, shape)
        return bound - np.where(rng.random(shape) < at_bound, 0.0, below)

    what = f"Exp(mean {shortfall:g})" if tail == "exponential" else f"U(0, {2 * shortfall:g})"
    label = f"{bound:g} - {what}"
    if at_bound > 0:
        label = f"{bound:g} w.p. {at_bound:g}, else {label}"
    return CoverageCase(label, bound - (1.0 - at_bound) * shortfall, draw)


def normal_case(mean: float, sd: float) -> CoverageCase:
    """Normal values, away from any bound (where Student's t is exact)."""
    return CoverageCase(
        f"Normal({mean:g}, {sd:g})", mean, lambda rng, r, n: rng.normal(mean, sd, (r, n))
    )


COVERAGE_CASES: tuple[CoverageCase, ...] = (
    near_bound_case(0.4, 0.1),  # like oracle_policy's steps_saved: .913, .840, 1, .923, 1
    near_bound_case(0.5, 0.1),
    near_bound_case(0.4, 0.08, "uniform"),
    near_bound_case(0.7, 0.1),
    near_bound_case(0.9, 0.1),
    near_bound_case(0.0, 0.05),  # near the bound without a point mass at it
    normal_case(0.1, 0.15),  # away from it: like High Src's steps_saved
)
"""`bounded_ci_coverage`'s distributions: means 0.94-0.99 with a point mass at the bound 1 (as
oracle_policy's steps_saved, exactly 1 in 2 of its 5 seeds), and one away from the bound."""


def bounded_ci_coverage(
    cases: Sequence[CoverageCase] = COVERAGE_CASES,
    seeds: Sequence[int] = (5, 10, 20),
    replicates: int = 10_000,
    *,
    bounds: tuple[float, float] = (-math.inf, 1.0),
    methods: Mapping[str, Callable[[Sequence[float]], tuple[float, float]]] | None = None,
    confidence: float = DEFAULT_CONFIDENCE,
    seed: int = 0,
) -> list[dict[str, Any]]:
    """Simulated coverage of CI methods for a mean of per-seed values in `bounds`, near the bound.

    Per case and n in `seeds`: `replicates` samples of n values (`case.draw`, from a generator
    seeded by (seed, case, n)), and per method (default: Student's t, `t_ci`, against the same cut
    at `bounds`, `bounded_t_ci`) the share of its `confidence` intervals that cover the case's
    mean (`coverage`, with its Clopper-Pearson 95% CI), the share that miss it from above (`above`:
    the lower end above the mean) and the share with an end outside `bounds` (`outside`);
    `no_spread`, the share of samples whose n values are all equal (at the bound, so any interval
    from the sample's spread is a point).
    """
    _check(confidence, 1)
    if replicates < 1:
        raise SealError(f"replicates {replicates!r}: expected >= 1")
    if methods is None:
        methods = {
            "t": lambda v: t_ci(v, confidence=confidence),
            "bounded t": lambda v: bounded_t_ci(v, bounds, confidence=confidence),
        }
    low, high = bounds
    rows = []
    for index, case in enumerate(cases):
        for n in seeds:
            sample = case.draw(np.random.default_rng([seed, index, n]), replicates, n)
            row: dict[str, Any] = {
                "case": case.label,
                "mean": case.mean,
                "n": n,
                "replicates": replicates,
                "no_spread": float(np.mean(np.ptp(sample, axis=1) == 0)),
                "coverage": {},
                "coverage_ci95": {},
                "above": {},
                "outside": {},
            }
            for name, ci in methods.items():
                ends = np.array([ci(values) for values in sample])
                covered = int(np.sum((ends[:, 0] <= case.mean) & (case.mean <= ends[:, 1])))
                row["coverage"][name] = covered / replicates
                row["coverage_ci95"][name] = list(binomial_ci(covered, replicates))
                row["above"][name] = float(np.mean(ends[:, 0] > case.mean))
                row["outside"][name] = float(np.mean((ends[:, 0] < low) | (ends[:, 1] > high)))
            rows.append(row)
    return rows


def format_coverage(rows: Sequence[Mapping[str, Any]]) -> str:
    """`bounded_ci_coverage`'s rows as a Markdown table: per case and n, each method's coverage,
    its misses from above, its intervals outside the bounds, and the samples without spread."""
    names = list(rows[0]["coverage"]) if rows else []
    header = [
        "case",
        "mean",
        "n",
        *(f"coverage {m}" for m in names),
        *(f"above {m}" for m in names),
        *(f"outside {m}" for m in names),
        "no spread",
    ]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for r in rows:
        cells = [
            r["case"],
            f"{r['mean']:.3f}",
            str(r["n"]),
            *(f"{r['coverage'][m]:.3f}" for m in names),
            *(f"{r['above'][m]:.3f}" for m in names),
            *(f"{r['outside'][m]:.3f}" for m in names),
            f"{r['no_spread']:.3f}",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
