"""The one typed-config engine (`seal.typed_config`): its rules, each error's one line, the docs."""

from __future__ import annotations

import datetime

import pytest

from seal.errors import ConfigError
from seal.learner import AgentConfig
from seal.protocols.config import EvaluationConfig, TrainingConfig, TransferConfig
from seal.schedulers.curriculum import CurriculumV2Config
from seal.schedulers.ratio import UniformConfig
from seal.typed_config import _at, build, field_docs


def test_an_int_field_takes_an_integral_float_and_a_float_field_an_int() -> None:
    # TOML's 1e4 is a float: 10,000 exactly, so an int field takes it; 4.5 it refuses.
    assert build(TrainingConfig, {"warmup_steps": 1e4}, "f: training").warmup_steps == 10_000
    assert build(EvaluationConfig, {"threshold": 1}, "f: evaluation").threshold == 1.0
    with pytest.raises(
        ConfigError,
        match=r"^f: training.batch_per_task = 4.5 has the wrong type; expected an integer$",
    ):
        build(TrainingConfig, {"batch_per_task": 4.5}, "f: training")


@pytest.mark.parametrize(
    ("cls", "table", "message"),
    [
        (
            TrainingConfig,
            {"warmup_steps": True},
            "training.warmup_steps = True has the wrong type; expected an integer",
        ),
        (
            TrainingConfig,
            {"warmup_steps": "10"},
            "training.warmup_steps = '10' has the wrong type; expected an integer",
        ),
        (
            TrainingConfig,
            {"warmup_stepz": 1},
            "training.warmup_stepz is not a valid key; valid keys: warmup_steps, batch_per_task, grad_steps_per_epoch, collector, demo_episodes, overlap",
        ),
        (
            TrainingConfig,
            {"batch_per_task": 0},
            "training.batch_per_task = 0 is out of range; valid: >= 1",
        ),
        (
            EvaluationConfig,
            {"threshold": 1.5},
            "training.threshold = 1.5 is out of range; valid: <= 1.0",
        ),
        (
            EvaluationConfig,
            {"threshold": float("inf")},
            "training.threshold = inf is not valid; expected a finite number",
        ),
        (TransferConfig, {"lr_factor": 0}, "training.lr_factor = 0 is out of range; valid: > 0.0"),
        (
            TrainingConfig,
            {"collector": "threads"},
            "training.collector = 'threads' is not valid; valid: 'auto', 'sync', 'subproc-batched', 'inline-batched', 'gym-async'",
        ),
        # a TOML date is no typed value: refused where it stands, shown as the user wrote it
        (
            TrainingConfig,
            {"warmup_steps": datetime.date(2026, 11, 23)},
            "training.warmup_steps = datetime.date(2026, 11, 23) has the wrong type; expected an integer",
        ),
        # nested tables and lists: the path goes down to the bad item, the valid keys are that table's
        (
            CurriculumV2Config,
            {"phases": [{"tasks": ["a"]}, {"tasks": ["b"], "treshold": 0.5}]},
            "training.phases[1].treshold is not a valid key; valid keys: tasks, threshold, max_env_steps",
        ),
        (
            CurriculumV2Config,
            {"phases": [{"tasks": ["a", 3]}]},
            "training.phases[0].tasks[1] = 3 has the wrong type; expected a string",
        ),
        (
            AgentConfig,
            {"hidden": "400"},
            "training.hidden = '400' has the wrong type; expected a list",
        ),
        # a table without settings (its valid keys were an empty list)
        (
            UniformConfig,
            {"ratios": {"pt": 1.0}},
            "training.ratios is not a valid key; this table takes no other keys",
        ),
        # a fixed-length list given too few or too many items (pydantic: "decoder_weights[1]:
        # missing", "Tuple should have at most 3 items after validation")
        (
            AgentConfig,
            {"decoder_weights": [1.0]},
            "training.decoder_weights = [1.0] has 1 items; expected 3",
        ),
        (
            AgentConfig,
            {"decoder_weights": [1.0, 1.0, 1.0, 1.0]},
            "training.decoder_weights = [1.0, 1.0, 1.0, 1.0] has 4 items; expected 3",
        ),
    ],
)
def test_every_error_is_one_line_naming_the_key_value_and_what_is_valid(
    cls: type, table: dict, message: str
) -> None:
    with pytest.raises(ConfigError) as info:
        build(cls, table, "f: training")
    assert str(info.value) == f"f: {message}"
    assert "\n" not in str(info.value)


def test_defaults_fill_what_the_table_leaves_out_and_the_table_wins() -> None:
    agent = build(AgentConfig, {"gamma": 0.9}, "f: agent", {"architecture": "seal", "gamma": 0.5})
    assert (agent.architecture, agent.gamma) == ("seal", 0.9)


def test_a_class_check_is_reported_at_the_table() -> None:
    # AgentConfig.__post_init__ refuses a zero width; the engine names the file first, and the
    # table once (the check's message starts with it: "agent.critic_hidden").
    with pytest.raises(
        ConfigError,
        match=r"^f: agent.critic_hidden: expected a non-empty list of positive ints, got \(0,\)$",
    ):
        build(AgentConfig, {"critic_hidden": [0]}, "f: agent")
    # A message that does not start with the table keeps it in front.
    assert _at("f: agent", "widths must agree") == "f: agent: widths must agree"
    assert _at("f: agent", "agent.hidden: bad") == "f: agent.hidden: bad"


def test_field_docs_are_the_fields_docstrings() -> None:
    docs = field_docs(TrainingConfig)
    assert docs["batch_per_task"] == (
        "Transitions per task in one update at uniform composition (MT10: 10 x 128 = 1280)."
    )
    assert docs["grad_steps_per_epoch"].startswith("Gradient steps after each epoch's collection;")
    assert (
        "longest episode" in docs["grad_steps_per_epoch"]
    )  # the whole docstring, not its first line
    assert field_docs(AgentConfig)["gamma"] == "Discount factor."
