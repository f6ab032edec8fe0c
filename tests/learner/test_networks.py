"""Batched MLPs and heads compute what per-member / per-task loops would; default shapes; SEAL wiring."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from seal.learner import Agent, AgentConfig, Batch, EnvSpec
from seal.learner.networks import LOG_STD_MIN, MultiHeadLinear, StackedMLP, tanh_gaussian

SMALL = {"hidden": (32, 32), "translator_hidden": (32,), "latent_dim": 16, "trunk_hidden": (32, 32)}


def test_stacked_mlp_equals_each_member_as_its_own_mlp() -> None:
    g = torch.Generator().manual_seed(0)
    mlp = StackedMLP(5, (7, 3), ensemble=2)
    mlp.reset_parameters(g)
    x = torch.randn(4, 5, generator=g)
    out = mlp(x)
    assert out.shape == (2, 4, 3)
    for member in range(2):
        h = x
        for w, b in zip(mlp.weights, mlp.biases, strict=True):
            h = F.relu(h @ w[member] + b[member, 0])
        torch.testing.assert_close(out[member], h)


def test_multi_head_linear_picks_each_samples_task_head() -> None:
    g = torch.Generator().manual_seed(1)
    head = MultiHeadLinear(6, 2, num_heads=5, ensemble=2)
    head.reset_parameters(g)
    x = torch.randn(2, 7, 6, generator=g)
    task_ids = torch.tensor([0, 4, 2, 2, 1, 3, 0])
    out = head(x, task_ids)
    assert out.shape == (2, 7, 2)
    for member in range(2):
        for row, task in enumerate(task_ids.tolist()):
            # head `task` owns columns [2 * task, 2 * task + 2) of the stacked weight
            w = head.weight[member, :, 2 * task : 2 * task + 2]
            b = head.bias[member, 0, 2 * task : 2 * task + 2]
            torch.testing.assert_close(out[member, row], x[member, row] @ w + b)


def test_single_head_ignores_task_ids() -> None:
    head = MultiHeadLinear(3, 4, num_heads=1)
    head.reset_parameters(torch.Generator().manual_seed(0))
    x = torch.randn(5, 3)
    expected = x @ head.weight[0] + head.bias[0, 0]  # the one head, by hand, for every task id
    torch.testing.assert_close(head(x, torch.arange(5)), expected)
    torch.testing.assert_close(head(x, torch.zeros(5, dtype=torch.long)), expected)


def test_tanh_gaussian_log_prob_by_hand() -> None:
    # mean 0, log std 0, noise 0: action tanh(0) = 0 and per dimension
    # log N(0; 0, 1) - log(1 - 0 + 1e-6) = -0.5 * log(2 pi) - 1e-6 = -0.9189395 (to 1e-7).
    action, log_prob = tanh_gaussian(torch.zeros(1, 8), torch.zeros(1, 4))
    assert action.abs().max() == 0
    assert log_prob.item() == pytest.approx(
        4 * (-0.5 * math.log(2 * math.pi) - math.log(1 + 1e-6)), abs=1e-5
    )
    # mean 0.5, log std -1, noise 2: u = 0.5 + 2 e^-1 = 1.2357589, a = tanh(u) = 0.8444...,
    # log p = -0.5 * 4 + 1 - 0.9189385 - log(1 - a^2 + 1e-6)
    u = 0.5 + 2 * math.exp(-1)
    expected = -2.0 + 1.0 - 0.5 * math.log(2 * math.pi) - math.log(1 - math.tanh(u) ** 2 + 1e-6)
    action, log_prob = tanh_gaussian(torch.tensor([[0.5, -1.0]]), torch.tensor([[2.0]]))
    assert action.item() == pytest.approx(math.tanh(u), rel=1e-6)
    assert log_prob.item() == pytest.approx(expected, rel=1e-5)


def test_tanh_gaussian_matches_torch_distributions_and_clamps_log_std() -> None:
    g = torch.Generator().manual_seed(3)
    out = torch.randn(6, 6, generator=g)
    noise = torch.randn(6, 3, generator=g)
    action, log_prob = tanh_gaussian(out, noise)
    mean, log_std = out[:, :3], out[:, 3:]
    u = mean + log_std.exp() * noise
    reference = torch.distributions.Normal(mean, log_std.exp()).log_prob(u) - torch.log(
        1 - torch.tanh(u) ** 2 + 1e-6
    )
    torch.testing.assert_close(log_prob, reference.sum(-1), rtol=1e-5, atol=1e-5)
    # a log std of -100 is clamped to LOG_STD_MIN = -20: the term -log std contributes +20
    _, clamped = tanh_gaussian(torch.tensor([[0.0, -100.0]]), torch.tensor([[0.0]]))
    assert clamped.item() == pytest.approx(-LOG_STD_MIN - 0.5 * math.log(2 * math.pi), abs=1e-5)


def test_default_mtmhsac_shapes_match_metaworld_mt10() -> None:
    # MT10: obs 39 + one-hot 10 = 49 inputs, 3 x 400 ReLU, 10 heads of 2 * 4 outputs
    agent = Agent([EnvSpec("metaworld", 39, 4, 10)], AgentConfig(), seed=0)
    actor = [tuple(w.shape) for w in agent.actor.trunk.weights]
    assert actor == [(1, 49, 400), (1, 400, 400), (1, 400, 400)]
    assert tuple(agent.actor.heads["metaworld"].weight.shape) == (1, 400, 10 * 8)
    critic = [tuple(w.shape) for w in agent.critic.trunk.weights]
    assert critic == [(2, 53, 400), (2, 400, 400), (2, 400, 400)]  # twin Q, obs + one-hot + action
    # one Q output per task by default, as both references' MTMHSAC critics
    assert tuple(agent.critic.heads["metaworld"].weight.shape) == (2, 400, 10)
    assert tuple(agent.log_alpha["metaworld"].shape) == (10,)
    assert torch.allclose(agent.log_alpha["metaworld"], torch.zeros(10))  # init alpha 1


def test_default_seal_shapes_translators_trunk_heads() -> None:
    # Rewritten when critic_sharing arrived: the default SEAL critic is now the authors' (one
    # independent twin critic per env on its own obs, one-hot and action), no longer a shared trunk.
    specs = [EnvSpec("metaworld", 39, 4, 10), EnvSpec("kitchen", 59, 9, 10)]
    agent = Agent(specs, AgentConfig(architecture="seal"), seed=0)
    # translator f_theta_i: (obs_i + one-hot) -> 400 -> latent 400 ("2 x 400")
    assert [tuple(w.shape) for w in agent.actor.translators["kitchen"].weights] == [
        (1, 69, 400),
        (1, 400, 400),
    ]
    assert [tuple(w.shape) for w in agent.actor.trunk.weights] == [(1, 400, 400)] * 3
    assert tuple(agent.actor.heads["kitchen"].weight.shape) == (1, 400, 10 * 18)
    assert tuple(agent.actor.heads["metaworld"].weight.shape) == (1, 400, 10 * 8)
    # kitchen's critic: (obs 59 + one-hot 10 + action 9 = 78) -> 3 x 400 -> one Q per task
    kitchen = agent.critic.nets["kitchen"]
    assert [tuple(w.shape) for w in kitchen.trunk.weights] == [(2, 78, 400)] + [(2, 400, 400)] * 2
    assert tuple(kitchen.heads["kitchen"].weight.shape) == (2, 400, 10)
    assert tuple(agent.critic.nets["metaworld"].trunk.weights[0].shape) == (2, 53, 400)
    kitchen_ids = {id(p) for p in kitchen.parameters()}
    assert not kitchen_ids & {id(p) for p in agent.critic.nets["metaworld"].parameters()}
    shared = Agent(specs, AgentConfig(architecture="seal", critic_sharing="shared"), seed=0)
    assert tuple(shared.critic.translators["kitchen"].weights[0].shape) == (2, 78, 400)
    assert tuple(shared.critic.heads["kitchen"].weight.shape) == (2, 400, 10)


def _owned(optimizer: torch.optim.Optimizer) -> set[int]:
    return {id(p) for group in optimizer.param_groups for p in group["params"]}


def _ids(*modules: torch.nn.Module) -> set[int]:
    return {id(p) for m in modules for p in m.parameters()}


def test_seal_per_env_optimisers_own_translator_trunk_and_head() -> None:
    # Rewritten when shared_update replaced agent.optimizer: "per_env" is no longer the default,
    # so it is asked for; the other modes' ownership is pinned beside it.
    specs = [EnvSpec("a", 3, 2, 2), EnvSpec("b", 5, 1, 3)]
    for critics in ("per_env", "shared"):
        agent = Agent(
            specs,
            AgentConfig(
                architecture="seal", shared_update="per_env", critic_sharing=critics, **SMALL
            ),
            seed=0,
        )
        assert len(agent.actor_optimizers) == 2 and len(agent.critic_optimizers) == 2
        for i, env in enumerate(("a", "b")):
            assert _owned(agent.actor_optimizers[i]) == _ids(
                agent.actor.translators[env], agent.actor.trunk, agent.actor.heads[env]
            )
            assert _owned(agent.critic_optimizers[i]) == {
                id(p) for p in agent.critic.env_parameters(env)
            }
    for mode in ("weighted", "sequential"):
        # one actor Adam over the whole policy; independent critics keep one Adam each
        agent = Agent(specs, AgentConfig(architecture="seal", shared_update=mode, **SMALL), seed=0)
        assert [_owned(o) for o in agent.actor_optimizers] == [_ids(agent.actor)]
        assert [_owned(o) for o in agent.critic_optimizers] == [
            _ids(agent.critic.nets["a"]),
            _ids(agent.critic.nets["b"]),
        ]
        shared = Agent(
            specs,
            AgentConfig(architecture="seal", shared_update=mode, critic_sharing="shared", **SMALL),
            seed=0,
        )
        assert [_owned(o) for o in shared.critic_optimizers] == [_ids(shared.critic)]


def test_target_critics_share_no_storage_with_online_ones() -> None:
    for config in (AgentConfig(**SMALL), AgentConfig(architecture="seal", **SMALL)):
        specs = (
            [EnvSpec("a", 3, 2, 2)]
            if config.architecture == "mtmhsac"
            else [EnvSpec("a", 3, 2, 2), EnvSpec("b", 4, 3, 2)]
        )
        agent = Agent(specs, config, seed=0)
        online = {p.untyped_storage().data_ptr() for p in agent.critic.parameters()}
        target = {p.untyped_storage().data_ptr() for p in agent.critic_target.parameters()}
        assert not online & target
        assert all(not p.requires_grad for p in agent.critic_target.parameters())
        for p, q in zip(agent.critic.parameters(), agent.critic_target.parameters(), strict=True):
            assert torch.equal(p, q)
        agent.reset_parameters()  # the reset re-copies the targets, still without sharing
        assert not {p.untyped_storage().data_ptr() for p in agent.critic_target.parameters()} & {
            p.untyped_storage().data_ptr() for p in agent.critic.parameters()
        }


def test_device_auto_resolves_to_cpu_without_cuda_and_bad_names_raise() -> None:
    from seal.device import resolve_device
    from seal.errors import SealError

    expected = "cuda" if torch.cuda.is_available() else "cpu"
    assert resolve_device("auto").type == expected
    assert resolve_device("cpu") == torch.device("cpu")
    with pytest.raises(SealError, match="valid: auto, cpu, cuda"):
        resolve_device("tpu0")
    if not torch.cuda.is_available():
        with pytest.raises(SealError, match="has 0 CUDA device"):
            resolve_device("cuda:1")
    assert Agent([EnvSpec("e", 2, 1, 1)], AgentConfig(**SMALL), seed=0).device.type == expected


@pytest.mark.parametrize("ensemble", [1, 2])
def test_stacked_mlp_layer_norm_is_torch_layer_norm_per_member(ensemble: int) -> None:
    """With layer_norm, each member is Linear -> nn.LayerNorm (its own gain and bias) -> ReLU per
    layer; the weights drawn are those of the same stack without norms (gains 1, biases 0)."""
    g = torch.Generator().manual_seed(3)
    plain, normed = (
        StackedMLP(5, (7, 3), ensemble),
        StackedMLP(5, (7, 3), ensemble, layer_norm=True),
    )
    plain.reset_parameters(torch.Generator().manual_seed(0), "metaworld_algorithms")
    normed.reset_parameters(torch.Generator().manual_seed(0), "metaworld_algorithms")
    for a, b in zip(plain.weights, normed.weights, strict=True):
        assert torch.equal(a, b)
    assert all((gain == 1).all() for gain in normed.norm_gains)
    assert all((shift == 0).all() for shift in normed.norm_biases)
    with torch.no_grad():  # gains and biases away from their identity values
        for gain, shift in zip(normed.norm_gains, normed.norm_biases, strict=True):
            gain.uniform_(0.5, 2.0, generator=g)
            shift.uniform_(-1.0, 1.0, generator=g)
    x = torch.randn(4, 5, generator=g)
    out = normed(x)
    assert out.shape == ((4, 3) if ensemble == 1 else (ensemble, 4, 3))
    for member in range(ensemble):
        h = x
        for i, (w, b) in enumerate(zip(normed.weights, normed.biases, strict=True)):
            norm = torch.nn.LayerNorm(w.shape[-1])
            with torch.no_grad():
                norm.weight.copy_(normed.norm_gains[i][member, 0])
                norm.bias.copy_(normed.norm_biases[i][member, 0])
            h = F.relu(norm(h @ w[member] + b[member, 0]))
        torch.testing.assert_close(out if ensemble == 1 else out[member], h)


def test_critic_layer_norm_bounds_q_far_from_the_data() -> None:
    """The reason for `critic_layer_norm`: scaling an input by s scales an unnormalised ReLU
    critic's Q by ~s, while with LayerNorm Q stays bounded by its weights; the actor has no norms."""
    spec = EnvSpec("e", 6, 3, 2)
    qs = {}
    for norm in (False, True):
        agent = Agent([spec], AgentConfig(**SMALL, critic_layer_norm=norm), seed=0)
        assert bool(list(agent.critic.trunk.norm_gains)) is norm
        assert not list(agent.actor.trunk.norm_gains)
        x = torch.randn(1, 6 + 2 + 3, generator=torch.Generator().manual_seed(0))
        task = torch.zeros(1, dtype=torch.long)
        with torch.no_grad():
            qs[norm] = [agent.critic("e", x * s, task).abs().max().item() for s in (1.0, 1e4)]
    assert qs[False][1] > 1e3 * qs[False][0]
    assert qs[True][1] < 10 * qs[True][0]
    g = torch.Generator().manual_seed(1)
    batch = Batch(
        torch.randn(8, 6, generator=g),
        torch.rand(8, 3, generator=g) * 2 - 1,
        torch.randn(8, generator=g),
        torch.randn(8, 6, generator=g),
        torch.zeros(8),
        torch.randint(0, 2, (8,), generator=g),
    )
    agent.update({"e": batch})  # the norms' gains and biases learn with the critic
    assert not torch.equal(
        agent.critic.trunk.norm_gains[0], torch.ones_like(agent.critic.trunk.norm_gains[0])
    )
    assert not agent.critic_target.trunk.norm_biases[0].eq(0).all()  # Polyak-averaged too
