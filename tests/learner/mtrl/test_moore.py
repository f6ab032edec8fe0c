"""MOORE (agent.architecture = "moore", issue 57): orthogonal experts, heads, count and the agent."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from seal.learner import AgentConfig, EnvSpec
from seal.learner.mtrl.moore import Moore, gram_schmidt
from seal.learner.sac import Agent
from tests.learner.mtrl.batches import random_batch as _batch

CONFIG = AgentConfig(architecture="moore", hidden=(8, 8), moore_experts=3, device="cpu")


def _net(
    in_dim: int = 5, out_dim: int = 4, tasks: int = 3, seed: int = 0, layer_norm: bool = False
) -> Moore:
    net = Moore(in_dim, out_dim, tasks, CONFIG, layer_norm)
    net.reset_parameters(torch.Generator().manual_seed(seed), "metaworld_algorithms", 1e-3)
    return net


def _x(n: int = 6, seed: int = 1) -> torch.Tensor:
    return torch.randn(n, 5, generator=torch.Generator().manual_seed(seed))


@pytest.mark.parametrize("layer_norm", [False, True])
def test_expert_outputs_are_orthonormal_per_sample(layer_norm: bool) -> None:
    u = _net(layer_norm=layer_norm).experts(_x())
    assert u.shape == (6, 3, 8)
    gram = u @ u.transpose(1, 2)
    torch.testing.assert_close(gram, torch.eye(3).expand(6, 3, 3), rtol=0, atol=1e-5)


def test_gram_schmidt_is_qr_up_to_signs() -> None:
    """Row i of the basis is the i-th column of Q in x^T = QR, up to its sign."""
    x = torch.randn(4, 3, 7, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    basis = gram_schmidt(x)
    q = torch.linalg.qr(x.transpose(1, 2)).Q.transpose(1, 2)  # (4, 3, 7)
    signs = torch.sign((basis * q).sum(-1, keepdim=True))
    torch.testing.assert_close(basis, signs * q, rtol=0, atol=1e-7)


def test_gram_schmidt_gradient_matches_qr() -> None:
    """Its gradient is that of the same basis taken from torch.linalg.qr (signs held fixed)."""
    gen = torch.Generator().manual_seed(3)
    x = torch.randn(4, 3, 7, generator=gen, dtype=torch.float64, requires_grad=True)
    weights = torch.randn(4, 3, 7, generator=gen, dtype=torch.float64)
    (got,) = torch.autograd.grad((gram_schmidt(x) * weights).sum(), x)
    q = torch.linalg.qr(x.transpose(1, 2)).Q.transpose(1, 2)
    signs = torch.sign((gram_schmidt(x) * q).sum(-1, keepdim=True)).detach()
    (want,) = torch.autograd.grad((signs * q * weights).sum(), x)
    torch.testing.assert_close(got, want, rtol=0, atol=1e-7)  # QR has no EPS in its norms


def test_forward_mixes_the_experts_by_the_task_weights_then_the_tasks_head() -> None:
    net = _net()
    x, tasks = _x(), torch.tensor([0, 1, 2, 2, 1, 0])
    got = net(x, tasks)
    assert got.shape == (6, 4)
    u = net.experts(x)
    for i, t in enumerate(tasks.tolist()):
        feature = torch.tanh(net.task_weights.table[t] @ u[i])  # no bias on w_tau
        want = feature @ net.heads.weight[t] + net.heads.bias[t, 0]
        torch.testing.assert_close(got[i], want, rtol=1e-6, atol=1e-6)


def test_two_tasks_give_different_outputs_and_only_the_samples_head_gets_gradient() -> None:
    net = _net()
    x = _x(1).expand(2, 5)
    out = net(x, torch.tensor([0, 2]))
    assert not torch.allclose(out[0], out[1])
    out[0].sum().backward()  # task 0's sample alone
    grad = net.heads.weight.grad
    assert grad[0].abs().sum() > 0 and not grad[1:].any() and not net.heads.bias.grad[1:].any()
    assert not net.task_weights.table.grad[1:].any()


def test_parameter_count_is_metaworld_algorithms_moore_network() -> None:
    # metaworld_algorithms/nn/moore.py, MOORENetwork with use_bias = True (its MLP from
    # nn/base.py): w_tau = Dense(k, use_bias=False) over the one-hot (T * k), each of the k experts
    # MLP(width, depth - 1, width): depth - 1 ReLU layers and a last Dense(width), so
    # (in_dim * width + width) + (depth - 1) * (width * width + width), and T heads
    # Dense(head_dim) T * (width * head + head).
    t, k, in_dim, width, out = 10, 4, 39, 400, 8
    config = AgentConfig(architecture="moore", hidden=(width,) * 3, moore_experts=k, device="cpu")
    net = Moore(in_dim, out, t, config)
    want = (
        t * k
        + k * ((in_dim * width + width) + 2 * (width * width + width))
        + t * (width * out + out)
    )
    assert sum(p.numel() for p in net.parameters()) == want
    shapes = [p.shape for p in net.task_parameters()]
    assert shapes == [torch.Size([t, k]), torch.Size([t, width, out]), torch.Size([t, 1, out])]


def test_same_seed_same_draw_and_heads_within_the_bound() -> None:
    a, b = _net(seed=3), _net(seed=3)
    for p, q in zip(a.parameters(), b.parameters(), strict=True):
        assert torch.equal(p, q)
    assert all(not layer.bias.detach().any() for layer in a.layers)  # zero hidden biases
    assert float(a.heads.weight.detach().abs().max()) <= 1e-3
    assert float(a.heads.bias.detach().abs().max()) <= 1e-3
    assert not torch.equal(a.layers[0].weight, _net(seed=4).layers[0].weight)


@pytest.mark.parametrize("layer_norm", [False, True])
def test_an_agent_with_moore_acts_and_updates(layer_norm: bool) -> None:
    config = AgentConfig(
        architecture="moore", hidden=(16, 16), critic_layer_norm=layer_norm, device="cpu"
    )
    agent = Agent([EnvSpec("mw", 6, 2, 3)], config, seed=0)
    # The critic is two whole MOORE networks over [obs, action]; the policy one over obs.
    assert len(agent.critic.members) == 2 and len(agent.actor.members) == 1
    assert agent.actor.members[0].layers[0].in_dim == 6
    assert agent.critic.members[0].layers[0].in_dim == 6 + 2
    assert len(agent.critic.members[0].norms) == (1 if layer_norm else 0)
    assert not agent.actor.members[0].norms
    assert len(agent.actor.components()["head.mw"]) == 3  # w's table and the heads
    before = [p.detach().clone() for p in agent.actor.parameters()]
    logs = agent.update({"mw": _batch(12, 3, 0)})
    assert all(np.isfinite(v) for v in logs.values())
    assert any(not torch.equal(p, b) for p, b in zip(agent.actor.parameters(), before, strict=True))
    actions = agent.act("mw", np.zeros((4, 6), np.float32), np.array([0, 1, 2, 0]))
    assert actions.shape == (4, 2) and np.abs(actions).max() <= 1.0
