"""Issue 5's ablation switches: one-hot, multi-head policy and multi-head critic in every protocol."""

from __future__ import annotations

import itertools
from pathlib import Path

import pytest

from seal.learner.checkpoint import read_checkpoint
from seal.protocols import load_protocol
from seal.run.runner import run_seed

PROTOCOLS = sorted((Path(__file__).resolve().parents[2] / "protocols").glob("*.toml"))
SWITCHES = ("one_hot", "multi_head_policy", "multi_head_critic")


@pytest.mark.parametrize("path", PROTOCOLS, ids=lambda p: p.stem)
def test_every_shipped_protocol_takes_the_switches_from_set(path: Path) -> None:
    base = load_protocol(path).agent
    for switch in SWITCHES:
        # multi_head_critic may be None (the learner's per-architecture default): "on" flips it.
        flipped = not bool(getattr(base, switch))
        value = "true" if flipped else "false"
        if switch == "one_hot":  # a property of agent.task_encoder
            key, value = "task_encoder", '"one_hot"' if flipped else '"none"'
        else:
            key = switch
        agent = load_protocol(path, [f"agent.{key}={value}"]).agent
        assert getattr(agent, switch) is flipped, (path.name, switch)
        # The other switches are untouched.
        for other in set(SWITCHES) - {switch}:
            assert getattr(agent, other) == getattr(base, other), (path.name, switch, other)


TINY = """
[protocol]
kind = "baseline"
epochs = 2
seeds = 1
device = "cpu"
threads = 1
[envs.pt]
adapter = "point"
tasks = ["east", "north"]
episode_length = 10
[agent]
hidden = [8, 8]
task_encoder = {one_hot}
multi_head_policy = {mhp}
multi_head_critic = {mhc}
[training]
warmup_steps = 0
batch_per_task = 4
collector = "sync"
[evaluation]
interval = 1
episodes = 1
[logging]
tensorboard = false
"""


@pytest.mark.parametrize(
    ("one_hot", "mhp", "mhc"), list(itertools.product([True, False], repeat=3))
)
def test_switches_from_the_agent_table_shape_the_trained_networks(
    tmp_path: Path, one_hot: bool, mhp: bool, mhc: bool
) -> None:
    path = tmp_path / "abl.toml"
    low = {True: "true", False: "false"}
    path.write_text(
        TINY.format(one_hot='"one_hot"' if one_hot else '"none"', mhp=low[mhp], mhc=low[mhc])
    )
    run = run_seed(load_protocol(path), 0, tmp_path / "r").run_dir
    agent = read_checkpoint(run / "checkpoints" / "best.pt")["agent"]
    # Point: 4 obs floats, 2 actions, 2 tasks. Actor input = obs (+ 2 one-hot columns); its head
    # outputs mean and log-std per action (4), per task when multi-head (2 x 4 = 8). Critic input
    # = obs (+ one-hot) + action; its head gives one Q, or one per task when multi-head.
    assert agent["actor"]["trunk.weights.0"].shape[-2] == (6 if one_hot else 4)
    assert agent["actor"]["heads.pt.weight"].shape[-1] == (8 if mhp else 4)
    assert agent["critic"]["trunk.weights.0"].shape[-2] == (8 if one_hot else 6)
    assert agent["critic"]["heads.pt.weight"].shape[-1] == (2 if mhc else 1)
