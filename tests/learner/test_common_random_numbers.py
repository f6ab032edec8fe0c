"""Common random numbers: a target env starts the same alone and in a joint run of the same seed.

Every random stream is keyed by (seed, env name, purpose), never by the set of envs in the run
(`seal.seeding`): the target's initial weights (translator, head, critic; the shared trunk by the
seed alone), its exploration noise, its update noise and its replay draws. So an alone arm and a
joint arm of one seed differ only by what the joint run does, and their difference is paired.
"""

from __future__ import annotations

import numpy as np
import torch

from seal.envs import make_adapter
from seal.evaluation import AgentPolicy
from seal.learner import Agent, AgentConfig, EnvSpec, MultiTaskReplay
from seal.learner.collection import Collector

SMALL = AgentConfig(
    architecture="seal",
    translator_hidden=(16,),
    latent_dim=16,
    trunk_hidden=(16, 16),
    critic_hidden=(16, 16),
    device="cpu",
)


def _spec(name: str, adapter_name: str) -> EnvSpec:
    adapter = make_adapter(adapter_name)
    return EnvSpec(name, adapter.obs_dim, adapter.act_dim, len(adapter.tasks))


def _target_tensors(agent: Agent) -> dict[str, torch.Tensor]:
    """Everything of the target's: its translator, the trunk, its heads, critic and temperatures."""
    out = {}
    for role in ("actor", "critic", "critic_target"):
        for key, value in getattr(agent, role).state_dict().items():
            if "source" not in key:
                out[f"{role}.{key}"] = value
    out["log_alpha"] = agent.log_alpha_of("target").detach()
    return out


def _agents(seed: int) -> tuple[Agent, Agent]:
    source, target = _spec("source", "point"), _spec("target", "point_view")
    return Agent([target], SMALL, seed), Agent([source, target], SMALL, seed)


def test_the_targets_initial_weights_are_the_same_alone_and_joint() -> None:
    alone, joint = _agents(seed=7)
    mine, theirs = _target_tensors(alone), _target_tensors(joint)
    assert sorted(mine) == sorted(theirs)
    assert any(k.startswith("actor.translators.target") for k in mine)
    assert any(k.startswith("actor.trunk") for k in mine)
    assert any(k.startswith("critic.nets.target") for k in mine)
    assert [k for k in mine if not torch.equal(mine[k], theirs[k])] == []
    # ... and the streams are real: another seed draws other weights, the source others again
    other = _target_tensors(_agents(seed=8)[0])
    weight = next(k for k in mine if k.startswith("actor.translators.target") and "weight" in k)
    assert not torch.equal(mine[weight], other[weight])
    # The translators' first layers differ in width (the envs' obs sizes); their second layers
    # have one shape, so the source's own stream shows in their values.
    second = "translators.{}.weights.1"
    actor = joint.actor.state_dict()
    assert actor[second.format("source")].shape == actor[second.format("target")].shape
    assert not torch.equal(actor[second.format("source")], actor[second.format("target")])


def test_the_targets_first_episode_and_first_batch_are_the_same_alone_and_joint() -> None:
    alone, joint = _agents(seed=3)
    adapters = {"source": make_adapter("point"), "target": make_adapter("point_view")}
    episodes = {}
    batches = {}
    for label, agent in (("alone", alone), ("joint", joint)):
        envs = {e: adapters[e] for e in agent.specs}
        replay = MultiTaskReplay(list(agent.specs.values()), capacity=400, seed=11)
        steps: list[tuple] = []

        def sink(env, ids, obs, actions, rewards, next_obs, terms, steps=steps, replay=replay):
            replay.add(env, ids, obs, actions, rewards, next_obs, terms)
            if env == "target":
                steps.append((obs.copy(), actions.copy(), rewards.copy()))

        with Collector(envs, seed=5, backend="sync") as collector:
            # stochastic acting: the exploration noise is part of what must match
            collector.collect_episodes(AgentPolicy(agent, deterministic=False), sink=sink)
        episodes[label] = steps
        counts = {e: np.full(agent.specs[e].num_tasks, 8) for e in agent.specs}
        batches[label] = replay.sample(counts)["target"]
    assert len(episodes["alone"]) == len(episodes["joint"]) == adapters["target"].episode_length
    for (o1, a1, r1), (o2, a2, r2) in zip(episodes["alone"], episodes["joint"], strict=True):
        np.testing.assert_array_equal(o1, o2)
        np.testing.assert_array_equal(a1, a2)
        np.testing.assert_array_equal(r1, r2)
    for field, mine in batches["alone"]._asdict().items():
        assert torch.equal(mine, getattr(batches["joint"], field)), field


def test_the_targets_first_update_noise_is_the_same_alone_and_joint() -> None:
    alone, joint = _agents(seed=4)
    draws = [
        torch.randn(5, 5, generator=agent.update_generators["target"]) for agent in (alone, joint)
    ]
    assert torch.equal(*draws)
