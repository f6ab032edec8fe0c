"""CARE (agent.architecture = "care", issue 57): attention, mixture, count and the agent."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from seal.learner import AgentConfig, EnvSpec
from seal.learner.mtrl.care import Care
from seal.learner.sac import Agent
from tests.learner.mtrl.batches import random_batch as _batch

CONFIG = AgentConfig(
    architecture="care",
    hidden=(8, 8),
    care_experts=3,
    care_embedding=4,
    care_encoder_hidden=(6,),
    care_temperature=2.0,
    device="cpu",
)


def _net(in_dim: int = 5, out_dim: int = 4, tasks: int = 3, seed: int = 0) -> Care:
    net = Care(in_dim, out_dim, tasks, CONFIG)
    net.reset_parameters(torch.Generator().manual_seed(seed), "metaworld_algorithms", 1e-3)
    return net


def _x(n: int = 6, seed: int = 1) -> torch.Tensor:
    return torch.randn(n, 5, generator=torch.Generator().manual_seed(seed))


def test_attention_sums_to_one_and_differs_between_tasks() -> None:
    net = _net()
    alpha = net.attention(net.context(torch.tensor([0, 1, 2, 0])))
    assert alpha.shape == (4, 3) and bool((alpha > 0).all())
    torch.testing.assert_close(alpha.sum(-1), torch.ones(4), rtol=0, atol=1e-6)
    assert not torch.allclose(alpha[0], alpha[1]) and not torch.allclose(alpha[1], alpha[2])
    torch.testing.assert_close(alpha[0], alpha[3], rtol=0, atol=0)  # same task, same weights


def test_forward_is_the_attention_mixture_of_encoders_then_the_torso() -> None:
    net = _net()
    x, tasks = _x(), torch.tensor([0, 1, 2, 2, 1, 0])
    got = net(x, tasks)
    assert got.shape == (6, 4)
    for i, t in enumerate(tasks.tolist()):
        z = F.relu(net.table[t])
        z = F.relu(z @ net.context_mlp[0].weight[0] + net.context_mlp[0].bias[0, 0])
        z = z @ net.context_mlp[1].weight[0] + net.context_mlp[1].bias[0, 0]
        a = F.relu(z @ net.attention_mlp[0].weight[0] + net.attention_mlp[0].bias[0, 0])
        logits = a @ net.attention_mlp[1].weight[0] + net.attention_mlp[1].bias[0, 0]
        alpha = torch.softmax(logits / 2.0, -1)  # care_temperature
        encoding = torch.zeros(4)
        for j in range(3):
            e = F.relu(x[i] @ net.encoders[0].weight[j] + net.encoders[0].bias[j, 0])
            encoding += alpha[j] * (e @ net.encoders[1].weight[j] + net.encoders[1].bias[j, 0])
        h = torch.cat((encoding, z))
        for layer in net.torso:
            h = F.relu(h @ layer.weight[0] + layer.bias[0, 0])
        want = h @ net.out.weight[0] + net.out.bias[0, 0]
        torch.testing.assert_close(got[i], want, rtol=1e-5, atol=1e-6)


def test_two_tasks_give_different_outputs_and_only_the_samples_row_gets_gradient() -> None:
    net = _net()
    x = _x(1).expand(2, 5)
    out = net(x, torch.tensor([0, 2]))
    assert not torch.allclose(out[0], out[1])
    out[0].sum().backward()
    assert net.table.grad[0].abs().sum() > 0 and not net.table.grad[1:].any()


def test_parameter_count_is_metaworld_algorithms_care_network() -> None:
    # metaworld_algorithms/nn/care.py, CARENetwork with use_bias = True (MLP from nn/base.py:
    # `depth` ReLU Dense(width) layers, then Dense(head_dim)), CAREConfig's MT10 defaults:
    # nn.Embed (T * E); task_embedding_mlp MLP(ew, ed, E) on E;
    # task_embedding_attn_mlp MLP(ew, ed, k) on E; k moe_mlp MLP(ew, ed, E) on in_dim;
    # torso MLP(width, depth, head_dim) on 2E.
    t, k, e, ew, in_dim, width, out = 10, 6, 50, 50, 39, 400, 8
    config = AgentConfig(
        architecture="care",
        hidden=(width,) * 3,
        care_experts=k,
        care_embedding=e,
        care_encoder_hidden=(ew, ew),
        device="cpu",
    )
    net = Care(in_dim, out, t, config)
    context = (e * ew + ew) + (ew * ew + ew) + (ew * e + e)
    attention = (e * ew + ew) + (ew * ew + ew) + (ew * k + k)
    encoders = k * ((in_dim * ew + ew) + (ew * ew + ew) + (ew * e + e))
    torso = (2 * e * width + width) + 2 * (width * width + width) + (width * out + out)
    want = t * e + context + attention + encoders + torso
    assert sum(p.numel() for p in net.parameters()) == want
    assert [p.shape for p in net.task_parameters()] == [torch.Size([t, e])]


def test_same_seed_same_draw_and_the_two_inits() -> None:
    a, b = _net(seed=3), _net(seed=3)
    for p, q in zip(a.parameters(), b.parameters(), strict=True):
        assert torch.equal(p, q)
    assert all(not layer.bias.detach().any() for layer in a.torso)  # zero hidden biases
    assert float(a.out.weight.detach().abs().max()) <= 1e-3
    assert not torch.equal(a.table, _net(seed=4).table)
    # The table as an embedding: N(0, 1 / E) (flax's nn.Embed) or N(0, 1) (nn.Embedding).
    config = AgentConfig(architecture="care", care_embedding=100, device="cpu")
    for init, std in (("metaworld_algorithms", 0.1), ("torch", 1.0)):
        net = Care(5, 4, 100, config)
        net.reset_parameters(torch.Generator().manual_seed(0), init, None)
        assert abs(float(net.table.detach().std()) / std - 1) < 0.05


@pytest.mark.parametrize("layer_norm", [False, True])
def test_an_agent_with_care_acts_and_updates(layer_norm: bool) -> None:
    config = AgentConfig(
        architecture="care",
        hidden=(16, 16),
        care_embedding=8,
        care_encoder_hidden=(8,),
        critic_layer_norm=layer_norm,
        device="cpu",
    )
    agent = Agent([EnvSpec("mw", 6, 2, 3)], config, seed=0)
    # The critic is two whole CARE networks over [obs, action]; the policy one over obs.
    assert len(agent.critic.members) == 2 and len(agent.actor.members) == 1
    assert agent.actor.members[0].encoders[0].in_dim == 6
    assert agent.critic.members[0].encoders[0].in_dim == 6 + 2
    assert len(agent.critic.members[0].norms) == (2 if layer_norm else 0)
    assert not agent.actor.members[0].norms
    before = [p.detach().clone() for p in agent.actor.parameters()]
    logs = agent.update({"mw": _batch(12, 3, 0)})
    assert all(np.isfinite(v) for v in logs.values())
    assert any(not torch.equal(p, b) for p, b in zip(agent.actor.parameters(), before, strict=True))
    actions = agent.act("mw", np.zeros((4, 6), np.float32), np.array([0, 1, 2, 0]))
    assert actions.shape == (4, 2) and np.abs(actions).max() <= 1.0
