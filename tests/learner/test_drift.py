"""Kept or relearned: each piece's ||W - W0|| / ||W0||, against hand-computed ratios."""

from __future__ import annotations

import math

import pytest
import torch

from seal.learner import Agent, AgentConfig, EnvSpec
from seal.learner.drift import piece_tensors, relative_drift, start_weights
from seal.pieces import PIECES

SOURCE = EnvSpec("source", obs_dim=4, act_dim=2, num_tasks=4)
TARGET = EnvSpec("tar.get", obs_dim=6, act_dim=5, num_tasks=3)  # a dot: module keys differ
SMALL = {"translator_hidden": (8,), "latent_dim": 8, "trunk_hidden": (8,), "critic_hidden": (8,)}
ENVS = {"source": "source", "target": "tar.get"}  # run env -> the agent's env name


def _agent(**changes: object) -> Agent:
    return Agent([SOURCE, TARGET], AgentConfig(architecture="seal", **SMALL, **changes), seed=0)


def test_a_known_perturbation_of_one_piece_gives_its_hand_computed_ratio() -> None:
    agent = _agent()
    start = start_weights(agent, ENVS)
    assert {e: sorted(p) for e, p in start.items()} == {e: sorted(PIECES) for e in ENVS}
    first = relative_drift(agent, start, ENVS)
    assert first == {(e, p): 0.0 for e in ENVS for p in PIECES}  # before any change: exactly 0

    head = agent.actor.heads["tar_get"]
    weight, bias = head.weight.detach().clone(), head.bias.detach().clone()
    with torch.no_grad():
        head.weight.add_(0.25)  # every entry of one of the head's two tensors moves by 0.25
    # By hand: the head's tensors concatenated are (weight, bias); only weight moved.
    moved = 0.25 * math.sqrt(weight.numel())
    norm = math.sqrt(float(weight.double().square().sum() + bias.double().square().sum()))
    drift = relative_drift(agent, start, ENVS)
    assert drift[("target", "head")] == pytest.approx(moved / norm, rel=1e-9)
    assert {k: v for k, v in drift.items() if k != ("target", "head")} == {
        k: 0.0 for k in drift if k != ("target", "head")
    }

    # Temperatures are compared as alpha: log alpha 0 -> log 3 on every task is alpha 1 -> 3.
    with torch.no_grad():
        agent.log_alpha["source"].fill_(math.log(3.0))
    assert relative_drift(agent, start, ENVS)[("source", "temperature")] == pytest.approx(2.0)


def test_the_start_is_a_copy_on_the_agents_device() -> None:
    agent = _agent()
    start = start_weights(agent, ENVS)
    with torch.no_grad():
        for p in agent.actor.translators["source"].parameters():
            p.mul_(2.0)  # W = 2 W0: the ratio is 1
    assert relative_drift(agent, start, ENVS)[("source", "translator")] == pytest.approx(1.0)
    assert all(t.device == torch.device(agent.device) for e in start.values() for t in e.values())


@pytest.mark.parametrize("critic_sharing", ["per_env", "shared"])
def test_the_critic_piece_is_the_envs_own_online_critic(critic_sharing: str) -> None:
    agent = _agent(critic_sharing=critic_sharing)
    own = {id(p) for p in piece_tensors(agent, "tar.get")["critic"]}
    critic = agent.critic
    if critic_sharing == "per_env":
        expected = {id(p) for p in critic.nets["tar_get"].parameters()}
    else:  # its translator and heads; the shared trunk is no env's piece
        expected = {
            id(p)
            for m in (critic.translators["tar_get"], critic.heads["tar_get"])
            for p in m.parameters()
        }
        assert not own & {id(p) for p in critic.trunk.parameters()}
    assert own == expected
    assert not own & {id(p) for p in agent.critic_target.parameters()}


def test_a_single_env_agent_without_translators_has_no_translator_piece() -> None:
    agent = Agent([SOURCE], AgentConfig(architecture="mtmhsac", hidden=(8,)), seed=0)
    pieces = piece_tensors(agent, "source")
    assert sorted(pieces) == ["critic", "head", "temperature"]
    # One env: its critic is all of the critic.
    assert {id(p) for p in pieces["critic"]} == {id(p) for p in agent.critic.parameters()}
