"""Soft Modularization (agent.architecture = "soft_modular", issue 57): routing, parameter count
and the agent."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from seal.learner import AgentConfig, EnvSpec
from seal.learner.mtrl.soft_modular import SoftModular
from seal.learner.sac import Agent
from tests.learner.mtrl.batches import random_batch as _batch

CONFIG = AgentConfig(
    architecture="soft_modular",
    soft_modules=3,
    soft_layers=3,
    soft_width=8,
    soft_embedding=6,
    device="cpu",
)


def _net(
    in_dim: int = 5,
    out_dim: int = 4,
    tasks: int = 3,
    seed: int = 0,
    init: str = "metaworld_algorithms",
    layer_norm: bool = False,
) -> SoftModular:
    net = SoftModular(in_dim, out_dim, tasks, CONFIG, layer_norm)
    net.reset_parameters(torch.Generator().manual_seed(seed), init, 1e-3)
    return net


def _max_abs(t: torch.Tensor) -> float:
    return float(t.detach().abs().max())


def _obs(n: int, in_dim: int = 5, seed: int = 1) -> torch.Tensor:
    return torch.randn(n, in_dim, generator=torch.Generator().manual_seed(seed))


@pytest.mark.parametrize("layer_norm", [False, True])
def test_forward_and_routing_shapes(layer_norm: bool) -> None:
    net = _net(layer_norm=layer_norm)
    tasks = torch.tensor([0, 1, 2, 1, 0])
    out = net(_obs(5), tasks)
    assert out.shape == (5, 4) and out.dtype == torch.float32
    assert bool(torch.isfinite(out).all())
    probs = net.routing(_obs(5), tasks)
    assert [tuple(p.shape) for p in probs] == [(5, 3, 3), (5, 3, 3), (5, 3)]
    assert len(net.norms) == (3 if layer_norm else 0)


@pytest.mark.parametrize("init", ["metaworld_algorithms", "torch"])
def test_routing_probabilities_are_distributions(init: str) -> None:
    net = _net(init=init)
    # Logit kernels drawn N(0, 30^2), not U(+-1e-3), so the softmax is far from uniform.
    g = torch.Generator().manual_seed(2)
    with torch.no_grad():
        for layer in net.logits:
            layer.weight.normal_(0.0, 30.0, generator=g)
        probs = net.routing(_obs(7), torch.arange(7) % 3)
    for p in probs:
        assert float(p.min()) >= 0.0
        torch.testing.assert_close(p.sum(-1), torch.ones(p.shape[:-1]), rtol=0, atol=1e-6)
        assert float((p - 1.0 / 3).abs().max()) > 1e-2  # not all uniform


def test_two_tasks_with_the_same_observation_route_differently() -> None:
    net = _net(seed=5)
    x = _obs(1).expand(2, 5)
    with torch.no_grad():
        probs = net.routing(x, torch.tensor([0, 2]))
        out = net(x, torch.tensor([0, 2]))
        same = net.routing(x, torch.tensor([1, 1]))
    for p in probs:
        assert float((p[0] - p[1]).abs().max()) > 1e-7
    assert not torch.equal(out[0], out[1])
    for p in same:  # the same task twice routes the same
        assert torch.equal(p[0], p[1])


def test_zero_logits_route_uniformly_and_each_layer_averages_its_modules() -> None:
    """With zero routing logits every p is uniform, 1/n: each module of the next layer sees the
    mean of this layer's module outputs, and the last layer's output is ReLU of their mean."""
    net = _net(init="torch")
    with torch.no_grad():
        for layer in net.logits:
            layer.weight.zero_()
            layer.bias.zero_()
    x, tasks = _obs(4), torch.tensor([0, 1, 2, 0])
    for p in net.routing(x, tasks):
        torch.testing.assert_close(p, torch.full_like(p, 1.0 / 3), rtol=0, atol=0)
    f = net.f_out(F.relu(net.f_hidden(x)))
    h = F.relu(f)  # every module of layer 0 sees the activated observation embedding, and with
    # uniform p every module of a later layer sees the same mean
    for layer in net.layers:
        mean = sum(h @ layer.weight[j] + layer.bias[j] for j in range(3)) / 3
        h = F.relu(mean)
    want = h @ net.out.weight[0] + net.out.bias[0]
    torch.testing.assert_close(net(x, tasks), want, rtol=1e-5, atol=1e-6)


def test_a_routing_matrix_mixes_module_outputs_by_rows() -> None:
    """Layer 0 with a fixed p: module i of layer 1 gets sum_j p[i, j] * module_j(x)."""
    net = _net()
    x = _obs(2)
    h0 = F.relu(net.f_out(F.relu(net.f_hidden(x))))
    outs = net.layers[0](h0)  # (n, B, d)
    p = torch.tensor([[1.0, 0.0, 0.0], [0.5, 0.5, 0.0], [0.2, 0.3, 0.5]]).expand(2, 3, 3)
    mixed = torch.einsum("bij,jbd->ibd", p, outs)
    torch.testing.assert_close(mixed[0], outs[0])
    torch.testing.assert_close(mixed[1], 0.5 * outs[0] + 0.5 * outs[1])
    torch.testing.assert_close(mixed[2], 0.2 * outs[0] + 0.3 * outs[1] + 0.5 * outs[2])


def _flax_count(
    in_dim: int, out: int, t: int, n: int, depth: int, w: int, d_embed: int, f_hidden: int
) -> int:
    # metaworld_algorithms/nn/soft_modules.py, SoftModularizationNetwork with use_bias = True:
    # f = MLP(depth=1, head_dim=D) (Dense(h) + Dense(D), h = MLP's default width 400);
    # z = MLP(depth=0, head_dim=D) over the one-hot (Dense(D));
    # task_embedding_fc = MLP(depth=1, width=w, head_dim=w) (Dense(w) + Dense(w), NOTE 1);
    # layers: n vmapped Dense(w) per layer, fan-in D at layer 0 and w after;
    # prob_fcs[i]: prob_embedding_fc Dense(w) over the i * n * n earlier probabilities (only
    # called, so only created, for i > 0, NOTE 3) and prob_output_fc Dense(n * n), Dense(n) last
    # (NOTE 5); output_head Dense(head_dim).
    f = (in_dim * f_hidden + f_hidden) + (f_hidden * d_embed + d_embed)
    z = t * d_embed + d_embed
    task_fc = (d_embed * w + w) + (w * w + w)
    modules = n * (d_embed * w + w) + (depth - 1) * n * (w * w + w)
    gates = sum(i * n * n * w + w for i in range(1, depth))
    logits = (depth - 1) * (w * n * n + n * n) + (w * n + n)
    head = w * out + out
    return f + z + task_fc + modules + gates + logits + head


@pytest.mark.parametrize(
    ("t", "n", "depth", "w", "d_embed"),
    [(10, 2, 2, 256, 400), (10, 4, 4, 32, 400), (3, 3, 3, 8, 6), (5, 2, 1, 7, 9)],
)
def test_parameter_count_is_metaworld_algorithms_soft_modules_network(
    t: int, n: int, depth: int, w: int, d_embed: int
) -> None:
    # flax's f has a hidden width of 400 whatever D is; SoftModular's is D: the same at D = 400
    # (the rows with D = 400 are flax's exact count), D otherwise.
    in_dim, out = 39, 8
    config = AgentConfig(
        architecture="soft_modular",
        soft_modules=n,
        soft_layers=depth,
        soft_width=w,
        soft_embedding=d_embed,
        device="cpu",
    )
    net = SoftModular(in_dim, out, t, config)
    want = _flax_count(in_dim, out, t, n, depth, w, d_embed, f_hidden=d_embed)
    assert sum(p.numel() for p in net.parameters()) == want
    assert [p.shape for p in net.task_parameters()] == [torch.Size([t, d_embed])]


def test_mt10_count_by_hand() -> None:
    """MT10 sizes (n = 2, L = 2, d = 256, D = 400), 39-dim obs, 8 outputs, written out."""
    config = AgentConfig(architecture="soft_modular", device="cpu")
    net = SoftModular(39, 8, 10, config)
    want = (
        (39 * 400 + 400 + 400 * 400 + 400)  # f
        + (10 * 400 + 400)  # z
        + (400 * 256 + 256 + 256 * 256 + 256)  # task MLP
        + 2 * (400 * 256 + 256)  # layer 0's modules
        + 2 * (256 * 256 + 256)  # layer 1's modules
        + (256 * 4 + 4)  # layer 0's logits, n * n
        + (4 * 256 + 256)  # layer 1's gate over layer 0's 4 probabilities
        + (256 * 2 + 2)  # layer 1's logits, n
        + (256 * 8 + 8)  # output
    )
    assert want == 691_022
    assert sum(p.numel() for p in net.parameters()) == want


def test_same_seed_same_draw_and_metaworld_init_zeroes_hidden_biases() -> None:
    a, b = _net(seed=3), _net(seed=3)
    for (name, p), q in zip(a.named_parameters(), b.parameters(), strict=True):
        assert torch.equal(p, q), name
    hidden = [a.f_hidden, a.f_out, a.task_hidden, a.task_out, *a.layers, *a.gates]
    assert all(_max_abs(layer.bias) == 0.0 for layer in hidden)
    assert _max_abs(a.z.bias) == 0.0
    assert all(_max_abs(layer.bias) == 0.0 for layer in a.logits)
    assert all(0.0 < _max_abs(layer.weight) <= 1e-3 for layer in a.logits)
    assert _max_abs(a.out.weight) <= 1e-3  # the output layer's head bound
    assert _max_abs(a.out.bias) > 0.0
    assert not torch.equal(a.layers[0].weight, _net(seed=4).layers[0].weight)
    # The torch scheme draws the hidden biases; the routing logits stay U(+-1e-3), zero bias.
    c = _net(seed=3, init="torch")
    assert _max_abs(c.layers[0].bias) > 0.0
    assert all(_max_abs(layer.bias) == 0.0 for layer in c.logits)


@pytest.mark.parametrize("layer_norm", [False, True])
def test_an_agent_with_soft_modular_acts_and_updates(layer_norm: bool) -> None:
    config = AgentConfig(
        architecture="soft_modular",
        soft_width=16,
        soft_embedding=16,
        critic_layer_norm=layer_norm,
        device="cpu",
    )
    agent = Agent([EnvSpec("mw", 6, 2, 3)], config, seed=0)
    # The critic is two whole networks over [obs, action]; the policy one over obs.
    assert len(agent.critic.members) == 2 and len(agent.actor.members) == 1
    assert agent.actor.members[0].f_hidden.in_dim == 6
    assert agent.critic.members[0].f_hidden.in_dim == 6 + 2
    assert len(agent.critic.members[0].norms) == (2 if layer_norm else 0)
    assert not agent.actor.members[0].norms
    # The per-task component is z's table alone.
    per_task = agent.actor.components()["head.mw"]
    assert [id(p) for p in per_task] == [id(agent.actor.members[0].z.table)]
    before = [p.detach().clone() for p in agent.actor.parameters()]
    logs = agent.update({"mw": _batch(12, 3, 0)})
    assert all(np.isfinite(v) for v in logs.values())
    assert any(not torch.equal(p, b) for p, b in zip(agent.actor.parameters(), before, strict=True))
    actions = agent.act("mw", np.zeros((4, 6), np.float32), np.array([0, 1, 2, 0]))
    assert actions.shape == (4, 2) and actions.dtype == np.float32
    assert np.abs(actions).max() <= 1.0
