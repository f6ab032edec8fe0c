"""The [scheduler] table: parsing, errors naming the key, dispatch, and the resolved-table round trip."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from seal.errors import ConfigError
from seal.schedulers import (
    SCHEDULER_CONFIGS,
    CurriculumV1Config,
    CurriculumV2Config,
    Progress,
    SMTConfig,
    SteppedRatioConfig,
    build_scheduler,
    config_from_table,
)
from seal.schedulers.base import SchedulerConfig

TOML = """
[scheduler]
kind = "curriculum_v2"
grad_steps = -1

[[scheduler.phases]]
tasks = ["reach-v3"]
threshold = 0.9

[[scheduler.phases]]
tasks = ["reach-v3", "push-v3"]
max_env_steps = 1e6
"""


def test_toml_table_parses_into_the_config() -> None:
    config = config_from_table(tomllib.loads(TOML)["scheduler"])
    assert isinstance(config, CurriculumV2Config)
    assert config.phases[0].tasks == ("reach-v3",) and config.phases[0].threshold == 0.9
    assert config.phases[1].max_env_steps == 1_000_000 and config.phases[1].threshold == 0.8
    sched = build_scheduler(config, {"mw": ("reach-v3", "push-v3")})
    assert sched.plan(Progress(epoch=0)).grad_steps == -1


def test_empty_table_is_uniform_over_all_tasks() -> None:
    sched = build_scheduler({}, {"mw": ("a", "b", "c"), "fk": ("d",)})
    plan = sched.plan(Progress(epoch=0))
    np.testing.assert_allclose(plan.batch_weights["mw"], [0.25] * 3)
    np.testing.assert_allclose(plan.batch_weights["fk"], [0.25])
    assert (
        all(m.all() for m in plan.collect.values())
        and not plan.reset_agent
        and plan.grad_steps is None
    )


@pytest.mark.parametrize(
    ("table", "message"),
    [
        (
            {"kappa": 0.5},
            r"scheduler.kind: required; valid: uniform, constant, stepped, smt, curriculum_v1, curriculum_v2",
        ),
        ({"kind": "smt2"}, r"scheduler.kind = 'smt2': unknown"),
        (
            {"kind": "smt", "kapa": 0.5},
            r"scheduler.kapa is not a valid key; valid keys: budget_stage1, ",
        ),
        (
            {"kind": "smt", "slots": "three"},
            r"scheduler.slots = 'three' has the wrong type; expected an integer",
        ),
        (
            {"kind": "smt", "slots": 2.5},
            r"scheduler.slots = 2.5 has the wrong type; expected an integer",
        ),
        (
            {"kind": "smt", "solved_return": {"mw": "high"}},
            r"scheduler.solved_return.mw = 'high' has the wrong type; expected a number",
        ),
        (
            {"kind": "constant", "collect": "some"},
            r"scheduler.collect = 'some' is not valid; valid: 'all', 'ratio'",
        ),
        (
            {"kind": "curriculum_v1", "phases": [{"weights": {"a": 1}}]},
            r"scheduler.phases\[0\].env_steps: required key is missing",
        ),
        (
            {"kind": "curriculum_v2", "phases": [{"tasks": "a"}]},
            r"scheduler.phases\[0\].tasks = 'a' has the wrong type; expected a list",
        ),
    ],
)
def test_bad_tables_name_file_and_key(table: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=rf"^protocols/x.toml: {message}"):
        config_from_table(table, "protocols/x.toml")


def test_build_errors_name_the_file() -> None:
    with pytest.raises(ConfigError, match=r"^p.toml: scheduler.kappa = 0.0: must be in \(0, 1\]"):
        build_scheduler({"kind": "smt", "kappa": 0.0}, {"metaworld": ("a",)}, source="p.toml")


def test_unknown_config_type_is_a_clear_value_error() -> None:
    class Other(SchedulerConfig):
        pass

    with pytest.raises(
        ValueError, match=r"no scheduler for config type Other; valid kinds: uniform, constant"
    ):
        build_scheduler(Other(), {"mw": ("a",)})


@pytest.mark.parametrize(
    "config",
    [
        SMTConfig(solved_return={"metaworld": 10.0}),
        SteppedRatioConfig(preset="high_mw"),
        CurriculumV1Config(preset="table_b3"),
        CurriculumV2Config(preset="mixed", order=("a", "b")),
        *[cls() for cls in SCHEDULER_CONFIGS.values() if cls.kind in ("uniform", "constant")],
    ],
)
def test_resolved_table_round_trips_after_scaling(config: SchedulerConfig) -> None:
    scaled = config.scale(0.01)
    assert config_from_table(scaled.to_table()) == scaled


def test_smt_scale_multiplies_every_duration_with_a_floor_of_one() -> None:
    scaled = SMTConfig().scale(1e-3)
    assert (
        scaled.budget_stage1,
        scaled.budget_stage2,
        scaled.score_interval,
        scaled.reset_interval,
    ) == (17_000, 3_000, 500, 500)
    tiny = SMTConfig().scale(1e-12)
    assert (tiny.budget_stage1, tiny.budget_stage2, tiny.score_interval, tiny.reset_interval) == (
        1,
        1,
        1,
        1,
    )
    # Per-epoch quantities and thresholds are not durations.
    assert (tiny.kappa, tiny.slots, tiny.recent_episodes, tiny.score_episodes) == (0.8, 3, 5, 5)
