"""Every learner of issue 57 as an agent: a checkpoint round trip updates bitwise as without it,
eager equals compiled, and a short CPU `seal run` of each learns its way through the loop."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from seal.learner import AgentConfig, EnvSpec
from seal.learner.checkpoint import read_checkpoint, save_checkpoint
from seal.learner.replay import MultiTaskReplay
from seal.learner.sac import Agent
from seal.protocols import load_protocol
from seal.run.runner import run_seed

SPEC = EnvSpec("mw", 5, 2, 3)
TINY = {"soft_width": 8, "soft_embedding": 8, "care_embedding": 8, "care_encoder_hidden": (8,)}
LEARNERS = [
    {"architecture": "paco"},
    {"architecture": "soft_modular"},
    {"architecture": "moore"},
    {"architecture": "care"},
    {"gradient": "pcgrad"},
]
IDS = ["paco", "soft_modular", "moore", "care", "pcgrad"]
POINT = Path(__file__).resolve().parents[3] / "protocols" / "learn" / "point.toml"


def _config(learner: dict[str, str], **extra: object) -> AgentConfig:
    return AgentConfig(hidden=(16, 16), device="cpu", **TINY, **learner, **extra)  # type: ignore[arg-type]


def _filled(config: AgentConfig, seed: int = 0) -> tuple[Agent, MultiTaskReplay]:
    agent = Agent([SPEC], config, seed=seed)
    replay = MultiTaskReplay([SPEC], capacity=60, seed=seed)
    rng = np.random.default_rng(seed)
    for _ in range(8):
        obs = rng.normal(size=(3, 5)).astype(np.float32)
        replay.add(
            "mw",
            np.arange(3),
            obs,
            rng.uniform(-1, 1, size=(3, 2)).astype(np.float32),
            rng.normal(size=3).astype(np.float32),
            obs + 0.1,
            np.zeros(3, np.float32),
        )
    return agent, replay


def _state(agent: Agent) -> list[torch.Tensor]:
    nets = (agent.actor, agent.critic, agent.critic_target)
    return [p.detach().clone() for net in nets for p in net.parameters()]


@pytest.mark.parametrize("learner", LEARNERS, ids=IDS)
def test_a_checkpoint_round_trip_updates_bitwise_as_without_it(
    tmp_path: Path, learner: dict[str, str]
) -> None:
    counts = {"mw": np.array([4, 4, 4])}
    agent, replay = _filled(_config(learner))
    for _ in range(2):
        agent.update(replay.sample(counts))
    path = save_checkpoint(tmp_path / "ckpt.pt", agent, replay, {})
    expected = agent.update(replay.sample(counts))
    resumed, resumed_replay = _filled(_config(learner), seed=7)  # other weights, other draws
    saved = read_checkpoint(path)
    resumed.load_state_dict(saved["agent"])
    resumed_replay.load_state_dict(saved["replay"])
    assert resumed.update(resumed_replay.sample(counts)) == expected
    for a, b in zip(_state(agent), _state(resumed), strict=True):
        assert torch.equal(a, b)
    obs = np.ones((2, 5), np.float32)
    ids = np.array([0, 2])
    np.testing.assert_array_equal(agent.act("mw", obs, ids), resumed.act("mw", obs, ids))


@pytest.mark.slow
@pytest.mark.parametrize("learner", LEARNERS[:4], ids=IDS[:4])
def test_eager_equals_compiled(learner: dict[str, str]) -> None:
    """Three updates of the same agent eager and compiled: the same losses (PCGrad refuses
    compile: test_pcgrad)."""
    counts = {"mw": np.array([4, 4, 4])}
    eager, replay = _filled(_config(learner))
    compiled, replay_c = _filled(_config(learner, compile=True))
    for _ in range(3):
        want = eager.update(replay.sample(counts))
        got = compiled.update(replay_c.sample(counts))
        assert got.keys() == want.keys()
        for key, value in want.items():
            assert got[key] == pytest.approx(value, rel=1e-4, abs=1e-5), key
    if not compiled.compiled:  # no C++ compiler here (it fell back to eager)
        pytest.skip("torch.compile unavailable")


@pytest.mark.parametrize("learner", LEARNERS, ids=IDS)
def test_a_short_seal_run_of_each_learner(tmp_path: Path, learner: dict[str, str]) -> None:
    overrides = [f"agent.{k}={v}" for k, v in learner.items()]
    overrides += [
        "agent.soft_width=8",
        "agent.soft_embedding=8",
        "agent.care_embedding=8",
        "agent.care_encoder_hidden=[8]",
        "protocol.epochs=4",
        "protocol.threads=1",
        "envs.pt.episode_length=10",
        "training.warmup_steps=40",
        "evaluation.interval=2",
        "evaluation.stop_when_reached=false",
        "logging.tensorboard=false",
        "agent.hidden=[16]",
    ]
    run = run_seed(load_protocol(POINT, overrides), 0, tmp_path).run_dir
    metrics = pd.read_csv(run / "metrics.csv")
    assert sorted(set(metrics["epoch"])) == [2, 4]
    assert metrics.groupby("epoch")["task"].nunique().tolist() == [4, 4]  # every point task
    train = pd.read_csv(run / "train.csv")
    losses = train[train["key"] == "critic_loss"]["value"]
    assert len(losses) and np.isfinite(losses).all()


@pytest.mark.parametrize("architecture", ["paco", "soft_modular", "moore", "care"])
def test_clip_per_component_clips_the_shared_and_the_per_task_parameters_apart(
    architecture: str,
) -> None:
    """Each component is one run of the slot's parameters (shared first, then per task), so
    clip_per = "component" builds and steps."""
    agent, replay = _filled(_config({"architecture": architecture}, clip_per="component"))
    for net in (agent.actor, agent.critic):
        parts = net.components()
        assert net.env_parameters("mw") == [*parts["trunk"], *parts["head.mw"]]
    logs = agent.update(replay.sample({"mw": np.array([4, 4, 4])}))
    assert all(np.isfinite(v) for v in logs.values())
