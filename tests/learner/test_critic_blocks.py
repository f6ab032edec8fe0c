"""Critic variants (issue 54): `critic_layer_norm` and `critic_block = "bronet"` — the block
against torch's own layers, parameter counts by hand, eager against compiled, a checkpoint round
trip, and what the memory estimate and the FLOP count see."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from seal.errors import ConfigError
from seal.learner import Agent, AgentConfig, EnvSpec
from seal.learner.checkpoint import read_checkpoint, save_checkpoint
from seal.learner.networks import ResidualMLP
from seal.learner.replay import MultiTaskReplay
from tests.learner.test_shared_update import _batch

SPEC = EnvSpec("fk", 59, 9, 1)
SEAL_SPECS = [EnvSpec("mw", 5, 2, 3), EnvSpec("fk", 7, 3, 2)]
SEAL_SMALL = {"translator_hidden": (16,), "latent_dim": 8, "trunk_hidden": (16, 16)}


@pytest.mark.parametrize("ensemble", [1, 2])
def test_residual_mlp_is_the_bronet_block_in_torch_layers(ensemble: int) -> None:
    """Per member: Linear -> LayerNorm -> ReLU, then per block x + LN(Linear(ReLU(LN(Linear(x)))))."""
    g = torch.Generator().manual_seed(0)
    net = ResidualMLP(5, (6, 6), ensemble)
    net.reset_parameters(g, "metaworld_algorithms")
    assert len(net.weights) == 5 and all(w.shape[-1] == 6 for w in net.weights)
    with torch.no_grad():  # norms away from their identity values
        for gain, shift in zip(net.norm_gains, net.norm_biases, strict=True):
            gain.uniform_(0.5, 2.0, generator=g)
            shift.uniform_(-1.0, 1.0, generator=g)
    x = torch.randn(4, 5, generator=g)
    out = net(x)
    assert out.shape == ((4, 6) if ensemble == 1 else (ensemble, 4, 6))

    def dense_ln(i: int, member: int, h: torch.Tensor) -> torch.Tensor:
        linear, norm = torch.nn.Linear(h.shape[-1], 6), torch.nn.LayerNorm(6)
        with torch.no_grad():
            linear.weight.copy_(net.weights[i][member].T)
            linear.bias.copy_(net.biases[i][member, 0])
            norm.weight.copy_(net.norm_gains[i][member, 0])
            norm.bias.copy_(net.norm_biases[i][member, 0])
        return norm(linear(h))

    for member in range(ensemble):
        h = F.relu(dense_ln(0, member, x))
        for block in range(2):
            h = h + dense_ln(2 + 2 * block, member, F.relu(dense_ln(1 + 2 * block, member, h)))
        torch.testing.assert_close(out if ensemble == 1 else out[member], h)


def _critic_size(config: AgentConfig, specs: list[EnvSpec]) -> int:
    return sum(p.numel() for p in Agent(specs, config, seed=0).critic.parameters())


def test_parameter_counts_by_hand() -> None:
    # The kitchen's MTMHSAC critic: input 59 obs + 1 one-hot + 9 action = 69, one Q head; twins.
    base = AgentConfig(hidden=(512, 512), critic_layer_norm=False, device="cpu")
    head = 512 + 1
    mlp = 69 * 512 + 512 + 512 * 512 + 512 + head
    assert _critic_size(base, [SPEC]) == 2 * mlp
    norms = 2 * 2 * 512  # a gain and a bias per unit of both layers
    assert _critic_size(replace(base, critic_layer_norm=True), [SPEC]) == 2 * (mlp + norms)
    # BroNet: a stem, then 2 blocks of two Dense + LN layers (BRO's code default: ~1.1 M a critic).
    layer = 512 * 512 + 512 + 2 * 512
    bronet = (69 * 512 + 512 + 2 * 512) + 4 * layer + head
    assert bronet == 1_092_097
    assert _critic_size(replace(base, critic_block="bronet"), [SPEC]) == 2 * bronet


def test_bronet_serves_seal_per_env_and_shared_critics() -> None:
    for sharing, key in (("per_env", "critic_hidden"), ("shared", "trunk_hidden")):
        config = AgentConfig(
            architecture="seal", critic_sharing=sharing, critic_block="bronet", device="cpu"
        )
        config = replace(config, critic_hidden=(16, 16), **SEAL_SMALL)
        agent = Agent(SEAL_SPECS, config, seed=0)
        assert AgentConfig.critic_trunk_key.fget(config) == key  # type: ignore[attr-defined]
        trunks = (
            [agent.critic.nets[k].trunk for k in agent.critic.nets]
            if sharing == "per_env"
            else [agent.critic.trunk]
        )
        assert all(isinstance(t, ResidualMLP) and t.blocks == 2 for t in trunks)
        assert not isinstance(agent.actor.trunk, ResidualMLP)  # the policy keeps its MLP


def test_bronet_needs_one_width_and_says_which_key() -> None:
    with pytest.raises(ConfigError, match=r"agent.hidden = \[64, 32\]: .*bronet.* one width"):
        AgentConfig(hidden=(64, 32), critic_block="bronet")
    with pytest.raises(ConfigError, match="agent.critic_block: unknown value 'resnet'"):
        AgentConfig(critic_block="resnet")  # type: ignore[arg-type]


def test_memory_estimate_and_flop_count_learn_the_block() -> None:
    from seal.bench.flops import agent_update_shapes
    from seal.run.resources import _parameter_counts, _widths

    config = AgentConfig(hidden=(64, 64), critic_block="bronet", device="cpu")
    _, critic, _ = _parameter_counts(config, [SPEC])
    assert critic == _critic_size(config, [SPEC])
    assert _widths(config, 1) == (128, 5 * 64)  # the stem and two layers per block
    (shape,) = agent_update_shapes([SPEC], config, per_task=8)
    assert shape.critic_dims == [69, *([64] * 5), 1]
    assert shape.actor_dims == [60, 64, 64, 18]


VARIANTS = {"layer_norm": {"critic_layer_norm": True}, "bronet": {"critic_block": "bronet"}}


@pytest.mark.slow
@pytest.mark.parametrize("variant", list(VARIANTS))
def test_compiled_update_equals_eager(variant: str) -> None:
    config = AgentConfig(
        architecture="seal", critic_hidden=(16, 16), device="cpu", **SEAL_SMALL, **VARIANTS[variant]
    )
    eager = Agent(SEAL_SPECS, config, seed=0)
    compiled = Agent(SEAL_SPECS, replace(config, compile=True), seed=0)
    for step in range(3):
        batches = {s.name: _batch(s, 8, step) for s in SEAL_SPECS}
        got, want = compiled.update(batches), eager.update(batches)
        assert got.keys() == want.keys()
        for key in want:  # fused kernels may round differently: close, not bitwise
            assert got[key] == pytest.approx(want[key], rel=1e-4, abs=1e-5), key
    if not compiled.compiled:
        pytest.skip("torch.compile unavailable (it fell back to eager)")
    for a, b in zip(eager.critic.parameters(), compiled.critic.parameters(), strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_checkpoint_round_trip_then_update_is_bitwise(variant: str, tmp_path: Path) -> None:
    config = AgentConfig(hidden=(16, 16), device="cpu", **VARIANTS[variant])
    agent = Agent([SPEC], config, seed=0)
    replay = MultiTaskReplay([SPEC], capacity=40)
    rng = np.random.default_rng(0)
    for _ in range(20):
        obs = rng.normal(size=(1, SPEC.obs_dim)).astype(np.float32)
        act = agent.act("fk", obs, np.array([0]))
        replay.add("fk", np.array([0]), obs, act, rng.normal(size=1), obs + 1, np.zeros(1))
    counts = {"fk": np.array([8])}
    agent.update(replay.sample(counts))
    path = save_checkpoint(tmp_path / "ckpt.pt", agent, replay, {})
    expected = agent.update(replay.sample(counts))
    resumed = Agent([SPEC], config, seed=5)
    resumed_replay = MultiTaskReplay([SPEC], capacity=40, seed=5)
    saved = read_checkpoint(path)
    resumed.load_state_dict(saved["agent"])
    resumed_replay.load_state_dict(saved["replay"])
    assert resumed.update(resumed_replay.sample(counts)) == expected
    for a, b in zip(agent.critic.parameters(), resumed.critic.parameters(), strict=True):
        assert torch.equal(a, b)
