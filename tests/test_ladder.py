"""The ladder's 2^3 factorial (seal.experiments.ladder) on hand-made numbers, and its arms'
protocols: each cell differs from oracle_translator in what it maps and nothing else."""

from __future__ import annotations

import math

import pytest
from scipy import stats as scipy_stats

from seal.errors import SealError
from seal.experiments.arms import LADDER_ARMS, TESTBED, arms
from seal.experiments.ladder import EFFECTS, design, effect_name, effects_per_seed, factorial
from seal.stats import mde

LEVELS = {
    "oracle_translator": set(),
    "ladder_head": {"head"},
    "ladder_critic": {"critic"},
    "ladder_temperature": {"temperature"},
    "ladder_head_critic": {"head", "critic"},
    "ladder_head_temperature": {"head", "temperature"},
    "ladder_critic_temperature": {"critic", "temperature"},
    "oracle_policy": {"head", "critic", "temperature"},
}
# Seed 0 by hand, e.g. head: mean(.5, .7, .5, .9) - mean(.1, .2, .1, .2) = .65 - .15 = .50; head x
# critic: mean of the arms with both or neither (.1, .1, .7, .9) - the others' (.5, .2, .5, .2) =
# .45 - .35 = .10 (= half of head's effect with the critic mapped, .6, less without it, .4).
SEED_0 = {
    "oracle_translator": 0.1,
    "ladder_head": 0.5,
    "ladder_critic": 0.2,
    "ladder_temperature": 0.1,
    "ladder_head_critic": 0.7,
    "ladder_head_temperature": 0.5,
    "ladder_critic_temperature": 0.2,
    "oracle_policy": 0.9,
}
EXPECTED_0 = {
    "head": 0.50,
    "critic": 0.20,
    "temperature": 0.05,  # .425 - .375
    "head x critic": 0.10,
    "head x temperature": 0.05,  # (.1, .2, .5, .9) - (.5, .1, .7, .2)
    "critic x temperature": 0.05,  # (.1, .5, .2, .9) - (.2, .1, .7, .5)
    "head x critic x temperature": 0.05,  # (.9, .5, .2, .1) - (.1, .7, .5, .2)
}
# Seed 1: oracle_policy .9 -> .7, in every contrast's + side: every effect -.2 / 4 = -.05.
# Seed 2: oracle_translator .1 -> .3, on the - side of the main and 3-way effects and the + side
# of the 2-way ones: those -.05, these +.05.
SEED_1 = {**SEED_0, "oracle_policy": 0.7}
SEED_2 = {**SEED_0, "oracle_translator": 0.3}
EXPECTED = {
    name: [
        value,
        value - 0.05,
        value + (0.05 if name.count(" x ") == 1 else -0.05),
    ]
    for name, value in EXPECTED_0.items()
}


def _values() -> dict[str, list[float]]:
    return {arm: [SEED_0[arm], SEED_1[arm], SEED_2[arm]] for arm in LEVELS}


def test_effects_per_seed_are_the_hand_computed_contrasts() -> None:
    assert [effect_name(e) for e in EFFECTS] == list(EXPECTED_0)
    got = effects_per_seed(_values(), LEVELS)
    assert list(got) == list(EXPECTED)
    for name, per_seed in EXPECTED.items():
        assert got[name] == pytest.approx(per_seed, abs=1e-12), name


def test_each_effect_gets_the_paired_t_ci_and_mde_over_seeds() -> None:
    summary = factorial(_values(), LEVELS, bounds=(-1.0, 1.0))
    head = EXPECTED["head"]  # .50, .45, .45
    mean = sum(head) / 3
    sd = math.sqrt(sum((v - mean) ** 2 for v in head) / 2)
    half = scipy_stats.t.ppf(0.975, 2) * sd / math.sqrt(3)
    s = summary["head"]
    assert s["per_seed"] == pytest.approx(head)
    assert s["mean"] == pytest.approx(mean)
    assert s["ci95"] == pytest.approx([mean - half, mean + half])
    assert s["sd_paired"] == pytest.approx(sd)
    assert s["mde"] == pytest.approx(mde(sd, 3))
    assert s["seeds_for_mde_0p10"] >= 2
    # temperature: .05, 0, 0: a CI that covers 0.
    low, high = summary["temperature"]["ci95"]
    assert low < 0 < high


def test_a_set_of_arms_that_is_not_the_full_factorial_is_refused() -> None:
    assert design(LEVELS)["ladder_head_critic"] == {"head": 1, "critic": 1, "temperature": -1}
    broken = {**LEVELS, "ladder_head": {"critic"}}  # two arms map the critic alone
    with pytest.raises(SealError, match="exactly once"):
        design(broken)
    with pytest.raises(SealError, match="one value per seed"):
        effects_per_seed({**_values(), "oracle_policy": [0.9]}, LEVELS)


def test_the_ladders_protocols_differ_from_oracle_translator_in_what_they_map() -> None:
    from seal.protocols import load_protocol
    from seal.protocols.loader import config_to_dict

    base = config_to_dict(load_protocol(TESTBED / "oracle_translator.toml"))
    policy = config_to_dict(load_protocol(TESTBED / "oracle_policy.toml"))
    assert [a.name for a in arms(only=LADDER_ARMS)] == [
        "alone",
        "pretrain_source",
        *[a for a in LADDER_ARMS if a.startswith("oracle")],
        *[a for a in LADDER_ARMS if a.startswith("ladder")],
    ]
    levels = {}
    for arm in LADDER_ARMS:
        config = load_protocol(TESTBED / f"{arm}.toml")
        levels[arm] = set(config.transfer.pieces) - {"translator"}
        assert "translator" in config.transfer.pieces and config.logging.drift
        tables = config_to_dict(config)
        for table, values in tables.items():
            if table == "protocol":
                keep = {"name", "description"}
                values = {k: v for k, v in values.items() if k not in keep}
                assert values == {k: v for k, v in base[table].items() if k not in keep}
            elif table == "transfer":
                head = "head" in levels[arm]
                assert values == {
                    **base["transfer"],
                    "map_modules": values["map_modules"],
                    "map_unmapped_log_std": (policy if head else base)["transfer"][
                        "map_unmapped_log_std"
                    ],
                }
            else:
                assert values == base[table], (arm, table)
    assert levels == LEVELS
    design(levels)  # the full factorial
    # The default and --full sets run no ladder cell of their own.
    assert not [a for a in arms(full=True) if a.ladder]
