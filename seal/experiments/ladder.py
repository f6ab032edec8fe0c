"""The ladder's 2^3 factorial: which mapped piece carries transfer (docs/transfer_testbed.md, "Ladder").

Eight arms share the perfect translator and map every subset of three pieces, the factors, on top
of it: the action head, the critic, the temperatures (`FACTORS`). Code each factor x_f = +1 in an
arm where it is mapped and -1 where it is fresh. For one seed and one statistic y per arm (its
target AUC, its steps_saved against the alone arm), the standard 2^3 contrast of a set S of
factors (`EFFECTS`) is

    effect(S) = mean of y over the 4 arms with prod_{f in S} x_f = +1
              - mean of y over the 4 arms with prod_{f in S} x_f = -1,

so a main effect (S = {f}) is the mean over the 4 arms with f mapped minus the mean over the 4
without it; a 2-way interaction (S = {f, g}) is half the difference between f's effect with g
mapped and f's effect with g fresh; the 3-way one is half the difference between one pair's
interaction with the third factor mapped and with it fresh. Every arm of a seed shares that
seed's random streams (common random numbers), so the effect is taken seed by seed and its
per-seed values are paired differences: the mean over seeds gets the arms' 95% CI (`ARM_CI`,
Student's t, cut at the effect's range) and `seal.stats.paired_power`'s SD, MDE and seeds for an
MDE of 0.10. Pure numbers in, numbers out; `seal.experiments.ladder_bench` feeds it the runs.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Collection, Mapping, Sequence
from typing import Any

import numpy as np

from seal.errors import SealError

FACTORS: tuple[str, ...] = ("head", "critic", "temperature")
"""The pieces the ladder maps or leaves fresh on top of the perfect translator (`seal.pieces`)."""
EFFECTS: tuple[tuple[str, ...], ...] = tuple(
    combo for size in (1, 2, 3) for combo in itertools.combinations(FACTORS, size)
)
"""The seven contrasts: three main effects, three 2-way interactions, the 3-way interaction."""


def effect_name(effect: Sequence[str]) -> str:
    """An effect's name: "head" (main), "head x critic" (an interaction)."""
    return " x ".join(effect)


def design(levels: Mapping[str, Collection[str]]) -> dict[str, dict[str, int]]:
    """Arm -> factor -> +1 (mapped) or -1 (fresh), from each arm's mapped pieces; SealError unless
    the arms are the full factorial, each of the 2^3 cells exactly once."""
    out = {arm: {f: 1 if f in pieces else -1 for f in FACTORS} for arm, pieces in levels.items()}
    cells = sorted(tuple(row.values()) for row in out.values())
    if cells != sorted(itertools.product((-1, 1), repeat=len(FACTORS))):
        shown = {arm: sorted(set(p) & set(FACTORS)) for arm, p in levels.items()}
        raise SealError(
            f"the ladder's arms must map each subset of {', '.join(FACTORS)} exactly once; "
            f"they map {shown}"
        )
    return out


def contrast(row: Mapping[str, int], effect: Sequence[str]) -> int:
    """The sign of one arm (its `design` row) in one effect's contrast."""
    return math.prod(row[f] for f in effect)


def effects_per_seed(
    values: Mapping[str, Sequence[float]], levels: Mapping[str, Collection[str]]
) -> dict[str, list[float]]:
    """Effect name -> its value per seed, from each arm's statistic per seed (NaN where an arm's is)."""
    rows = design(levels)
    seeds = {len(v) for v in values.values()}
    if set(values) != set(rows) or len(seeds) != 1:
        raise SealError(
            f"the ladder needs one value per seed for each of its arms {sorted(rows)}; got "
            f"{ {arm: len(v) for arm, v in values.items()} }"
        )
    table = {arm: np.asarray(v, dtype=float) for arm, v in values.items()}
    out: dict[str, list[float]] = {}
    for effect in EFFECTS:
        plus = [table[arm] for arm, row in rows.items() if contrast(row, effect) > 0]
        minus = [table[arm] for arm, row in rows.items() if contrast(row, effect) < 0]
        out[effect_name(effect)] = (np.mean(plus, axis=0) - np.mean(minus, axis=0)).tolist()
    return out


def summarise_effect(
    per_seed: Sequence[float], bounds: tuple[float, float] = (-math.inf, math.inf)
) -> dict[str, Any]:
    """One effect over seeds: per seed, mean, 95% CI (`ARM_CI` within `bounds`), paired SD, MDE
    and the seeds an MDE of 0.10 needs (`seal.stats.paired_power`)."""
    from seal.experiments.statistics import ARM_CI
    from seal.stats import mde_key, paired_power

    power = paired_power(per_seed, "effect")
    finite = [v for v in per_seed if math.isfinite(v)]
    return {
        "per_seed": list(per_seed),
        "mean": float(np.mean(finite)) if finite else math.nan,
        "ci95": list(ARM_CI(per_seed, bounds)),
        "sd_paired": power["sd_paired_effect"],
        "mde": power["mde_effect"],
        "seeds_for_mde_0p10": power[f"seeds_for_mde_{mde_key(0.10)}_effect"],
    }


def factorial(
    values: Mapping[str, Sequence[float]],
    levels: Mapping[str, Collection[str]],
    bounds: tuple[float, float] = (-math.inf, math.inf),
) -> dict[str, dict[str, Any]]:
    """Effect name -> `summarise_effect` of its per-seed values (`effects_per_seed`)."""
    return {
        name: summarise_effect(per_seed, bounds)
        for name, per_seed in effects_per_seed(values, levels).items()
    }
