"""Scheduler values that used to pass `seal protocol check` and then fail (or do something else)
in the run: each is refused when the scheduler is built at load, naming the key and the value."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from seal.errors import ConfigError
from seal.protocols.loader import load_protocol
from seal.schedulers import (
    CurriculumV2Config,
    Progress,
    SMTConfig,
    build_scheduler,
    config_from_table,
)
from seal.schedulers.base import scale_duration
from seal.schedulers.ratio import MAX_ABSENT_TASKS

PT = {"pt": ("east", "north", "south", "west")}
CONSTANT = {"kind": "constant", "ratios": {"pt": 0.5, "g": 0.5}}
POINT = Path(__file__).resolve().parents[2] / "protocols" / "learn" / "point.toml"


# ---- 1. scheduler.absent sizes every epoch's batch split: bounded ------------------------------
def test_a_huge_absent_task_count_is_refused() -> None:
    with pytest.raises(
        ConfigError,
        match=r"^scheduler.absent.g = 1000000000000: expected a task count of at most 1,000",
    ):
        build_scheduler({**CONSTANT, "absent": {"g": 10**12}}, PT)
    with pytest.raises(ConfigError, match=r"scheduler.absent.g = 1001: expected a task count"):
        build_scheduler({**CONSTANT, "absent": {"g": MAX_ABSENT_TASKS + 1}}, PT)


def test_the_largest_absent_task_count_still_runs() -> None:
    sched = build_scheduler({**CONSTANT, "absent": {"g": MAX_ABSENT_TASKS}}, PT)
    plan = sched.plan(Progress(epoch=0))
    # Alone: 64 per task x 4 tasks = 256; half the joint batch of 64 x 1,004 goes to pt's 4 tasks.
    assert plan.batch_counts(256)["pt"].tolist() == [8032, 8032, 8032, 8032]


# ---- 2. with absent envs, this run's envs need a share > 0 ------------------------------------
@pytest.mark.parametrize(
    ("table", "key"),
    [
        ({"kind": "constant", "ratios": {"pt": 0.0, "g": 1.0}}, "scheduler.ratios"),
        ({"kind": "stepped", "start": {"pt": 0.0, "g": 1.0}}, "scheduler.start"),
        (
            {"kind": "stepped", "start": {"pt": 0.5, "g": 0.5}, "end": {"pt": 0.0, "g": 1.0}},
            "scheduler.end",
        ),
    ],
)
def test_no_share_for_the_runs_own_envs_is_refused(table: dict, key: str) -> None:
    with pytest.raises(
        ConfigError,
        match=rf"^{key} = \{{'pt': 0.0, 'g': 1.0\}}: no env of this run \(pt\) has a share > 0, "
        r"only the absent g, .* give at least one of pt a fraction > 0$",
    ):
        build_scheduler({**table, "absent": {"g": 4}}, PT)


def test_a_small_share_draws_at_every_epoch() -> None:
    table = {
        "kind": "stepped",
        "start": {"pt": 0.1, "g": 0.9},
        "end": {"pt": 0.5, "g": 0.5},
        "interval": 2,
        "absent": {"g": 4},
    }
    sched = build_scheduler(table, PT)
    for epoch in range(12):
        assert sched.plan(Progress(epoch=epoch)).batch_counts(256)["pt"].sum() > 0
    # Without absent envs a 0 share of one env is fine: the others draw the whole batch.
    two = build_scheduler(
        {"kind": "constant", "ratios": {"pt": 0.0, "q": 1.0}}, {**PT, "q": ("a",)}
    )
    assert two.plan(Progress(epoch=0)).batch_counts(10)["q"].tolist() == [10]


# ---- 3. --scale keeps 0 ("off", "no limit"); negative limits are refused -----------------------
def test_scaling_keeps_zero_and_sentinels() -> None:
    assert scale_duration(0, 0.5) == 0 and scale_duration(-1, 0.5) == -1
    assert scale_duration(3, 0.5) == 2 and scale_duration(1, 1e-6) == 1
    assert SMTConfig(budget_stage2=0).scale(0.5).budget_stage2 == 0
    v2 = CurriculumV2Config(preset="sequential", max_phase_env_steps=0).scale(0.5)
    assert v2.max_phase_env_steps == 0


def test_load_with_scale_keeps_smt_budget_stage2_zero() -> None:
    config = load_protocol(
        POINT,
        [
            'scheduler.kind="smt"',
            "scheduler.budget_stage2=0",
            "scheduler.solved_return={pt=1.0}",
            "scheduler.unsolvable_return={pt=0.0}",
        ],
        scale=0.5,
    )
    assert isinstance(config.scheduler, SMTConfig)
    assert config.scheduler.budget_stage2 == 0
    assert config.scheduler.budget_stage1 == 8_500_000


def test_a_negative_preset_step_limit_is_refused_like_a_phase_limit() -> None:
    preset = {"kind": "curriculum_v2", "preset": "sequential", "max_phase_env_steps": -5}
    with pytest.raises(
        ConfigError, match=r"^scheduler.max_phase_env_steps = -5: must be >= 0 \(0 = no limit\)$"
    ):
        build_scheduler(preset, PT)
    phases = {"kind": "curriculum_v2", "phases": [{"tasks": ["east"], "max_env_steps": -5}]}
    with pytest.raises(
        ConfigError, match=r"^scheduler.phases\[0\].max_env_steps = -5: must be >= 0"
    ):
        build_scheduler(phases, PT)


def test_load_refuses_the_negative_limit_before_scaling() -> None:
    overrides = [
        'scheduler.kind="curriculum_v2"',
        'scheduler.preset="sequential"',
        "scheduler.max_phase_env_steps=-5",
    ]
    with pytest.raises(ConfigError, match=rf"^{POINT}: scheduler.max_phase_env_steps = -5"):
        load_protocol(POINT, overrides, scale=0.5)


# ---- 4. keys that do nothing beside another key: refused, naming both ------------------------
@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ({"order": ["bogus"]}, r"scheduler.order = \['bogus'\]: applies only to a preset"),
        ({"threshold": 0.5}, r"scheduler.threshold = 0.5: applies only to a preset"),
        (
            {"max_phase_env_steps": 100},
            r"scheduler.max_phase_env_steps = 100: applies only to a preset",
        ),
    ],
)
def test_preset_keys_beside_phases_are_refused(extra: dict, message: str) -> None:
    table = {"kind": "curriculum_v2", "phases": [{"tasks": ["east"]}], **extra}
    with pytest.raises(ConfigError, match=rf"^{message}, not to scheduler.phases; remove it"):
        build_scheduler(table, PT)


def test_start_fraction_beside_start_is_refused() -> None:
    table = {"kind": "stepped", "start": {"pt": 1.0}, "start_fraction": 0.7}
    with pytest.raises(
        ConfigError,
        match=r"^scheduler.start_fraction = 0.7: applies only to a preset, not to scheduler.start",
    ):
        build_scheduler(table, PT)
    with pytest.raises(ConfigError, match=r"^scheduler.start_fraction = 1.5: must be in \[0, 1\]"):
        build_scheduler(
            {"kind": "stepped", "preset": "high_fk", "start_fraction": 1.5},
            {"fk": ("a",), "mw": ("b",)},
            adapters={"fk": "franka_kitchen_dense", "mw": "metaworld"},
        )


def test_a_saved_resolved_table_still_loads() -> None:
    """A run's config.toml lists every key at its default: those defaults are not refused."""
    for table in (
        {"kind": "curriculum_v2", "phases": [{"tasks": ["east"]}, {"tasks": ["east", "west"]}]},
        {"kind": "stepped", "start": {"pt": 1.0}},
    ):
        config = config_from_table(table)
        again = config_from_table(config.to_table())
        assert again == config
        build_scheduler(again, PT)


# ---- 5. a task named twice (qualified and not) --------------------------------------------------
@pytest.mark.parametrize(
    ("weights", "first", "second"),
    [
        ({"pt/east": 1, "east": 5, "west": 1}, "pt/east", "east"),
        ({"east": 1, "pt/east": 0}, "east", "pt/east"),
    ],
)
def test_v1_weights_naming_a_task_twice_are_refused(weights: dict, first: str, second: str) -> None:
    table = {"kind": "curriculum_v1", "phases": [{"env_steps": 100, "weights": weights}]}
    with pytest.raises(
        ConfigError,
        match=rf"^scheduler.phases\[0\].weights: '{first}' and '{second}' both name task pt/east; "
        "name each task once$",
    ):
        build_scheduler(table, PT)


def test_v2_phase_tasks_naming_a_task_twice_are_refused() -> None:
    table = {"kind": "curriculum_v2", "phases": [{"tasks": ["east", "pt/east"]}]}
    with pytest.raises(
        ConfigError, match=r"^scheduler.phases\[0\].tasks: 'east' and 'pt/east' both name task"
    ):
        build_scheduler(table, PT)


def test_v1_weights_each_named_once_keep_their_values() -> None:
    table = {
        "kind": "curriculum_v1",
        "phases": [{"env_steps": 100, "weights": {"pt/east": 3, "west": 1}}],
    }
    plan = build_scheduler(table, PT).plan(Progress(epoch=0))
    np.testing.assert_allclose(plan.batch_weights["pt"], [0.75, 0.0, 0.0, 0.25])
