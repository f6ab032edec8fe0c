"""The kitchen bench's arms: one protocol each under `protocols/kitchen_learn/`, named by task and
by what it changes (a suffix: `V4_SUFFIX` the reward, `LEARNERS` the critic), and the groups the
goals and rules read (`rule_tasks`, `v4_arms`, `default_arms`)."""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from seal.errors import SealWarning
from seal.experiments.arms import Arm, arms_in, chosen
from seal.protocols import load_protocol

if TYPE_CHECKING:
    from seal.protocols.config import ProtocolConfig

KITCHEN_LEARN = Path(__file__).resolve().parents[2] / "protocols" / "kitchen_learn"
"""The kitchen learning protocols."""
LEARNER_KEYS = ("critic_layer_norm", "critic_block")
"""The agent keys that tell the kitchen arms' learners apart (`LEARNERS`)."""


ARMS: tuple[Arm, ...] = arms_in(
    KITCHEN_LEARN,
    (
        ("slide_cabinet", "slide-cabinet"),
        ("slide_cabinet_demos", "slide-cabinet + demos"),
        ("light_switch", "light-switch"),
        ("light_switch_demos", "light-switch + demos"),
        ("bottom_left_burner", "bottom-left-burner"),
        ("bottom_left_burner_demos", "bottom-left-burner + demos"),
        ("microwave", "microwave"),
        ("bottom_right_burner", "bottom-right-burner"),
        ("slide_cabinet_v4", "slide-cabinet v4"),
        ("light_switch_v4", "light-switch v4"),
        ("bottom_left_burner_v4", "bottom-left-burner v4"),
        ("microwave_v4", "microwave v4"),
        ("bottom_right_burner_v4", "bottom-right-burner v4"),
        ("light_switch_v4_critic_ln", "light-switch v4 + critic LN"),
        ("microwave_v4_critic_ln", "microwave v4 + critic LN"),
        ("slide_cabinet_v4_critic_ln", "slide-cabinet v4 + critic LN"),
        ("bottom_left_burner_v4_critic_ln", "bottom-left-burner v4 + critic LN"),
        ("bottom_right_burner_v4_critic_ln", "bottom-right-burner v4 + critic LN"),
        ("slide_cabinet_critic_ln", "slide-cabinet + critic LN"),
        ("light_switch_critic_ln", "light-switch + critic LN"),
        ("bottom_left_burner_critic_ln", "bottom-left-burner + critic LN"),
        ("microwave_critic_ln", "microwave + critic LN"),
        ("bottom_right_burner_critic_ln", "bottom-right-burner + critic LN"),
        ("slide_cabinet_bronet", "slide-cabinet + BroNet critic"),
        ("light_switch_bronet", "light-switch + BroNet critic"),
        ("bottom_left_burner_bronet", "bottom-left-burner + BroNet critic"),
        ("microwave_bronet", "microwave + BroNet critic"),
        ("bottom_right_burner_bronet", "bottom-right-burner + BroNet critic"),
    ),
)
"""The arms, each pinned to a reward version by its protocol's `options.reward_version`: v3, and
v4 for the `*_v4` arms (which run all 535 epochs: `evaluation.stop_when_reached = false`)
and for the collapse test's `*_v4_critic_ln` arms (v4 with `agent.critic_layer_norm`)."""
COLLAPSE_TEST_SUFFIX = "_critic_ln"
"""A collapse-test arm is its v4 arm's name with this suffix: the same protocol with one change."""
LEARNERS: dict[str, str] = {COLLAPSE_TEST_SUFFIX: "critic LN", "_bronet": "BroNet"}
"""Issue 54's learner changes on v3: an arm's suffix, and what the learner test calls it."""
LEARNER_TESTS: tuple[tuple[str, str], ...] = (
    (COLLAPSE_TEST_SUFFIX, ""),
    ("_bronet", ""),
    ("_bronet", COLLAPSE_TEST_SUFFIX),
)
"""The learner tests the bench applies, as (new side's suffix, old side's suffix; "" the plain
critic). Rule 1 sets each change against the plain critic; BroNet is also set against LayerNorm,
today's default, since a flip to BroNet should beat the learner it would replace."""
V4_SUFFIX = "_v4"
"""A reward-v4 arm is its v3 arm's name with this suffix: the same protocol on reward v4."""


def arm_config(arm: Arm) -> ProtocolConfig:
    """An arm's protocol, read to classify it: the reward-version warning a run of it gives is not
    the reader's to see (the goals read every arm, run or not)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SealWarning)
        return load_protocol(arm.protocol)


def pinned_version(arm: Arm) -> str | None:
    """The kitchen reward version an arm's protocol pins (None if it pins none)."""
    config = arm_config(arm)
    return next(iter(config.envs.values())).options.get("reward_version")


def arms(only: Sequence[str] | None = None) -> list[Arm]:
    """All arms, or the named ones."""
    return chosen(ARMS, only, "kitchen arm")


def v4_arms() -> list[str]:
    """The reward-v4 arms (the collapse test's are a learner change on v4, not v4's evidence)."""
    return [
        a.name for a in ARMS if pinned_version(a) == "v4" and not a.name.endswith(tuple(LEARNERS))
    ]


def default_arms() -> list[str]:
    """The demonstration-free arms that run the default learner (every `LEARNER_KEYS` key at
    `AgentConfig`'s default) on the default reward (`franka_kitchen_dense.REWARD_VERSION`, pinned or
    followed): one per task, whichever arms today's defaults make these."""
    from franka_kitchen_dense import REWARD_VERSION

    from seal.learner.config import AgentConfig

    default = AgentConfig()
    return [
        arm.name
        for arm in ARMS
        if (config := arm_config(arm)).training.demo_episodes == 0
        and (pinned_version(arm) or REWARD_VERSION) == REWARD_VERSION
        and all(getattr(config.agent, k) == getattr(default, k) for k in LEARNER_KEYS)
    ]


def rule_tasks() -> list[str]:
    """The five demonstration-free tasks the rules compare, as their v3 arms' names."""
    return [name.removesuffix(V4_SUFFIX) for name in v4_arms()]
