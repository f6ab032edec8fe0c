"""Data-ratio schedules (SEAL §4.3) as schedulers: literal fractions at given epochs."""

from __future__ import annotations

import numpy as np
import pytest

from seal.errors import ConfigError
from seal.schedulers import ConstantRatioConfig, Progress, SteppedRatioConfig, build_scheduler
from seal.schedulers.base import Plan

ENVS = {"mw": ("reach-v3", "push-v3"), "fk": ("microwave", "kettle", "slide")}
ADAPTERS = {"mw": "metaworld", "fk": "franka_kitchen_dense"}


def fractions(plan: Plan) -> tuple[float, float]:
    return round(plan.env_fraction("fk"), 9), round(plan.env_fraction("mw"), 9)


@pytest.mark.parametrize(
    ("epoch", "fk", "mw"),
    [
        (0, 0.9, 0.1),
        (999, 0.9, 0.1),
        (1000, 0.8, 0.2),
        (2000, 0.7, 0.3),
        (2999, 0.7, 0.3),
        (3000, 0.6, 0.4),
        (4000, 0.5, 0.5),
        (9999, 0.5, 0.5),
    ],
)
def test_high_fk_steps_ten_points_every_1000_epochs(epoch: int, fk: float, mw: float) -> None:
    sched = build_scheduler({"kind": "high_fk"}, ENVS, adapters=ADAPTERS)
    plan = sched.plan(Progress(epoch=epoch))
    assert fractions(plan) == (fk, mw)
    # Uniform over tasks within an env: fk's fraction over 3 tasks, mw's over 2.
    np.testing.assert_allclose(plan.batch_weights["fk"], [fk / 3] * 3)
    np.testing.assert_allclose(plan.batch_weights["mw"], [mw / 2] * 2)
    assert all(m.all() for m in plan.collect.values())  # every task collects (issue 4 default)


def test_high_mw_mirrors_high_fk() -> None:
    sched = build_scheduler({"kind": "stepped", "preset": "high_mw"}, ENVS, adapters=ADAPTERS)
    assert [fractions(sched.plan(Progress(epoch=e))) for e in (0, 1000, 4000)] == [
        (0.1, 0.9),
        (0.2, 0.8),
        (0.5, 0.5),
    ]


def test_explicit_stepped_and_constant() -> None:
    stepped = build_scheduler(
        SteppedRatioConfig(start={"mw": 0.9, "fk": 0.1}, step=0.25, interval=10), ENVS
    )
    # mw: 0.9 -> 0.65 at epoch 10 -> 0.4 would pass 0.5, so 0.5 from epoch 20 on.
    assert [fractions(stepped.plan(Progress(epoch=e))) for e in (0, 9, 10, 20, 30)] == [
        (0.1, 0.9),
        (0.1, 0.9),
        (0.35, 0.65),
        (0.5, 0.5),
        (0.5, 0.5),
    ]
    constant = build_scheduler(ConstantRatioConfig(ratios={"mw": 0.5, "fk": 0.5}), ENVS)
    plan = constant.plan(Progress(epoch=123))
    assert fractions(plan) == (0.5, 0.5)
    # 1280 samples: mw 640 over 2 tasks, fk 640 over 3 (213.33: the first task takes the extra one).
    counts = plan.batch_counts(1280)
    assert counts["mw"].tolist() == [320, 320] and counts["fk"].tolist() == [214, 213, 213]
    shuffled = plan.batch_counts(1280, np.random.default_rng(0))
    assert sorted(shuffled["fk"].tolist()) == [213, 213, 214] and shuffled["mw"].tolist() == [
        320,
        320,
    ]


def test_stepped_clips_each_env_at_its_end() -> None:
    # mw from 0.7 toward 0.5 in steps of 0.25: one step would overshoot, so it stops at 0.5.
    sched = build_scheduler(
        SteppedRatioConfig(start={"mw": 0.7, "fk": 0.3}, step=0.25, interval=10), ENVS
    )
    assert fractions(sched.plan(Progress(epoch=10))) == (0.5, 0.5)


def test_collect_following_the_ratio() -> None:
    sched = build_scheduler(
        ConstantRatioConfig(ratios={"mw": 0.9, "fk": 0.1}, collect="ratio"), ENVS
    )
    plans = [sched.plan(Progress(epoch=e)) for e in range(20)]
    # fk's credit starts at 1 and gains 0.1 / 0.9 = 1/9 per epoch: it collects at 0, then every
    # 9th epoch (1 episode per task of fk for 9 of mw); mw (the largest fraction) every epoch.
    assert [e for e, p in enumerate(plans) if p.collect["fk"].all()] == [0, 9, 18]
    assert all(p.collect["mw"].all() for p in plans)
    assert not any(p.collect["fk"].any() for e, p in enumerate(plans) if e not in (0, 9, 18))
    # fk collected at epoch 0, so its 10% of the batch is drawn from the start.
    assert fractions(plans[1]) == (0.1, 0.9)


def test_scale_shrinks_the_interval_with_a_floor_of_one() -> None:
    config = SteppedRatioConfig(preset="high_fk")
    assert config.scale(0.01).interval == 10
    assert config.scale(1e-9).interval == 1
    assert (
        config.scale(0.01).step == 0.1 and config.scale(0.01).start_fraction == 0.9
    )  # not durations


def test_bad_ratio_tables_name_the_key() -> None:
    with pytest.raises(ConfigError, match=r"scheduler.ratios .* sum to 1, they sum to 0.9"):
        build_scheduler(ConstantRatioConfig(ratios={"mw": 0.5, "fk": 0.4}), ENVS)
    with pytest.raises(ConfigError, match=r"scheduler.start: env names \['kitchen', 'mw'\]"):
        build_scheduler(SteppedRatioConfig(start={"mw": 0.5, "kitchen": 0.5}), ENVS)
    with pytest.raises(ConfigError, match=r"scheduler.preset = 'high_fk' needs exactly two envs"):
        build_scheduler(
            SteppedRatioConfig(preset="high_fk"), ENVS, adapters={"mw": "metaworld", "fk": "point"}
        )
