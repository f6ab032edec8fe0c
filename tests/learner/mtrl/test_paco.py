"""PaCo (agent.architecture = "paco", issue 57): composition, parameter count and the agent."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from seal.learner import AgentConfig, EnvSpec
from seal.learner.mtrl.paco import PaCo
from seal.learner.sac import Agent
from tests.learner.mtrl.batches import random_batch as _batch

CONFIG = AgentConfig(architecture="paco", hidden=(8, 8), paco_sets=3, device="cpu")


def _net(in_dim: int = 5, out_dim: int = 4, tasks: int = 3, seed: int = 0) -> PaCo:
    net = PaCo(in_dim, out_dim, tasks, CONFIG)
    net.reset_parameters(torch.Generator().manual_seed(seed), "metaworld_algorithms", 1e-3)
    return net


def test_with_one_hot_task_vectors_each_task_runs_its_own_parameter_set() -> None:
    """w_tau = e_tau: task tau's network is the plain ReLU MLP of parameter set tau."""
    net = _net()
    with torch.no_grad():
        net.task_weights.table.copy_(torch.eye(3))
        net.task_weights.bias.zero_()
    x = torch.randn(6, 5, generator=torch.Generator().manual_seed(1))
    tasks = torch.tensor([0, 1, 2, 2, 1, 0])
    got = net(x, tasks)
    for i, t in enumerate(tasks.tolist()):
        h = x[i : i + 1]
        for layer in net.hidden:
            h = F.relu(h @ layer.weight[t] + layer.bias[t])
        want = h @ net.out.weight[t] + net.out.bias[t]
        torch.testing.assert_close(got[i : i + 1], want, rtol=1e-6, atol=1e-6)


def test_a_task_vector_mixes_the_sets_linearly_within_a_layer() -> None:
    """Layer output for w = (0.25, 0.75, 0): 0.25 x set 0's affine map + 0.75 x set 1's."""
    net = _net()
    with torch.no_grad():
        net.task_weights.table.zero_()
        net.task_weights.table[2] = torch.tensor([0.25, 0.75, 0.0])
        net.task_weights.bias.zero_()
    x = torch.randn(2, 5, generator=torch.Generator().manual_seed(2))
    w0, w1 = net.hidden[0].weight, net.hidden[0].bias
    mixed = net.compose(net.hidden[0](x), net.task_weights(torch.tensor([2, 2])))
    want = 0.25 * (x @ w0[0] + w1[0]) + 0.75 * (x @ w0[1] + w1[1])
    torch.testing.assert_close(mixed, want, rtol=1e-6, atol=1e-6)


def test_parameter_count_is_metaworld_algorithms_paco_network() -> None:
    # metaworld_algorithms/nn/paco.py, PaCoNetwork with use_bias = True: w_tau = Dense(K) over the
    # one-hot (T * K + K), each of the depth CompositionalDense(width) layers K * (fan_in * width
    # + width), the output CompositionalDense(head_dim) K * (width * head + head).
    t, k, in_dim, width, out = 10, 5, 39, 400, 8
    config = AgentConfig(architecture="paco", hidden=(width,) * 3, paco_sets=k, device="cpu")
    net = PaCo(in_dim, out, t, config)
    want = (t * k + k) + k * (
        (in_dim * width + width) + 2 * (width * width + width) + (width * out + out)
    )
    assert sum(p.numel() for p in net.parameters()) == want
    assert [p.shape for p in net.task_parameters()] == [torch.Size([t, k])]


def test_same_seed_same_draw_and_metaworld_init_zeroes_hidden_biases() -> None:
    a, b = _net(seed=3), _net(seed=3)
    for p, q in zip(a.parameters(), b.parameters(), strict=True):
        assert torch.equal(p, q)
    assert all(not layer.bias.detach().any() for layer in a.hidden)
    assert float(a.out.weight.detach().abs().max()) <= 1e-3  # the output layer's head bound
    assert not torch.equal(a.hidden[0].weight, _net(seed=4).hidden[0].weight)


@pytest.mark.parametrize("layer_norm", [False, True])
def test_an_agent_with_paco_acts_and_updates(layer_norm: bool) -> None:
    config = AgentConfig(
        architecture="paco", hidden=(16, 16), critic_layer_norm=layer_norm, device="cpu"
    )
    agent = Agent([EnvSpec("mw", 6, 2, 3)], config, seed=0)
    # The critic is two whole PaCo networks over [obs, action]; the policy one over obs.
    assert len(agent.critic.members) == 2 and len(agent.actor.members) == 1
    assert agent.actor.members[0].hidden[0].in_dim == 6
    assert agent.critic.members[0].hidden[0].in_dim == 6 + 2
    assert len(agent.critic.members[0].norms) == (2 if layer_norm else 0)
    assert not agent.actor.members[0].norms
    before = [p.detach().clone() for p in agent.actor.parameters()]
    logs = agent.update({"mw": _batch(12, 3, 0)})
    assert all(np.isfinite(v) for v in logs.values())
    assert any(not torch.equal(p, b) for p, b in zip(agent.actor.parameters(), before, strict=True))
    actions = agent.act("mw", np.zeros((4, 6), np.float32), np.array([0, 1, 2, 0]))
    assert actions.shape == (4, 2) and np.abs(actions).max() <= 1.0
    # Two tasks, same observation: the task vector alone tells them apart.
    mean = agent.actor("mw", torch.cat((torch.zeros(2, 6), torch.eye(3)[:2]), 1), torch.arange(2))
    assert not torch.equal(mean[0], mean[1])


@pytest.mark.parametrize(
    "tasks",
    [
        [2, 0, 1, 1, 0, 2],  # every task twice, unsorted: one batched matmul
        [1, 1, 0, 1, 1, 1, 0],  # unequal counts, task 2 absent: one matmul a task
        [],
    ],
)
def test_per_task_path_equals_the_sets_path_in_outputs_and_gradients(tasks: list[int]) -> None:
    """The eager path (compose phi_tau, then each task's rows) is the compiled path's map."""
    net = _net(seed=5)
    for norm in (False, True):
        if norm:
            net = PaCo(5, 4, 3, CONFIG, layer_norm=True)
            net.reset_parameters(torch.Generator().manual_seed(6), "torch", None)
        ids = torch.tensor(tasks, dtype=torch.int64)
        x = torch.randn(len(tasks), 5, generator=torch.Generator().manual_seed(7))
        outs, grads = [], []
        for path in (net.forward_per_task, net.forward_sets):
            net.zero_grad()
            y = path(x, ids)
            (y * torch.arange(1.0, 5.0)).sum().backward()
            outs.append(y)
            grads.append([p.grad.clone() for p in net.parameters()])
        assert outs[0].shape == (len(tasks), 4)
        torch.testing.assert_close(outs[0], outs[1], rtol=1e-5, atol=1e-6)
        for a, b in zip(*grads, strict=True):
            torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)
        torch.testing.assert_close(net(x, ids), outs[0], rtol=0, atol=0)  # eager: per task
