"""The SAC update against hand-computed losses, acting, reset, lr factor, transfer and SEAL updates."""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import replace

import numpy as np
import pytest
import torch

from seal.errors import ConfigError, SealError, UnknownNameError
from seal.learner import Agent, AgentConfig, Batch, EnvSpec
from seal.learner.transfer import transfer_from
from seal.typed_config import field_docs

SMALL = {"hidden": (32, 32), "translator_hidden": (32,), "latent_dim": 16, "trunk_hidden": (32, 32)}


def _random_batch(spec: EnvSpec, n: int, seed: int = 0) -> Batch:
    g = torch.Generator().manual_seed(seed)
    return Batch(
        torch.randn(n, spec.obs_dim, generator=g),
        torch.rand(n, spec.act_dim, generator=g) * 2 - 1,
        torch.randn(n, generator=g),
        torch.randn(n, spec.obs_dim, generator=g),
        (torch.rand(n, generator=g) < 0.1).float(),
        torch.randint(0, spec.num_tasks, (n,), generator=g),
    )


def _log_prob(mean: float, log_std: float, eps: float) -> tuple[float, float]:
    """Action and log-prob of one tanh-Gaussian sample, in plain Python."""
    u = mean + math.exp(log_std) * eps
    a = math.tanh(u)
    return a, -0.5 * eps**2 - log_std - 0.5 * math.log(2 * math.pi) - math.log(1 - a * a + 1e-6)


def test_losses_by_hand_on_a_network_with_known_weights() -> None:
    spec = EnvSpec("toy", obs_dim=2, act_dim=1, num_tasks=1)
    agent = Agent([spec], AgentConfig(hidden=(4,), init_alpha=2.0), seed=0)
    # Zero every weight and bias, so every hidden activation is 0 and each net outputs its head bias:
    # policy mean 0.5, log std -1; qf1 = 1, qf2 = 2 everywhere. The target critics differ from the
    # online ones (qf1_target = 3, qf2_target = 0.5), so bootstrapping from the wrong critic
    # (min 1 instead of 0.5) changes every critic number below.
    with torch.no_grad():
        for p in [*agent.actor.parameters(), *agent.critic.parameters()]:
            p.zero_()
        agent.actor.heads["toy"].bias.copy_(torch.tensor([[[0.5, -1.0]]]))
        agent.critic.heads["toy"].bias.copy_(torch.tensor([[[1.0]], [[2.0]]]))
        agent.critic_target.load_state_dict(agent.critic.state_dict())
        agent.critic_target.heads["toy"].bias.copy_(torch.tensor([[[3.0]], [[0.5]]]))
    rewards, terminations = [0.5, -1.0, 2.0], [0.0, 1.0, 0.0]
    batch = Batch(
        torch.randn(3, 2),
        torch.rand(3, 1),
        torch.tensor(rewards),
        torch.randn(3, 2),
        torch.tensor(terminations),
        torch.zeros(3, dtype=torch.long),
    )
    # The update draws the next-state noise, then the policy noise, from its own generator.
    g = torch.Generator()
    g.set_state(agent.update_generators["toy"].get_state())
    eps_next = torch.randn(3, 1, generator=g)[:, 0].tolist()
    eps_pi = torch.randn(3, 1, generator=g)[:, 0].tolist()
    metrics = agent.update({"toy": batch})

    alpha, gamma = 2.0, 0.99
    next_log_pi = [_log_prob(0.5, -1.0, e)[1] for e in eps_next]
    # next_q_value = r + gamma * (1 - term) * (min(qf1_target, qf2_target) - alpha * next_log_pi), min = 0.5
    y = [
        r + gamma * (1 - d) * (0.5 - alpha * lp)
        for r, d, lp in zip(rewards, terminations, next_log_pi, strict=True)
    ]
    qf1_loss = sum((1.0 - t) ** 2 for t in y) / 3
    qf2_loss = sum((2.0 - t) ** 2 for t in y) / 3
    assert metrics["losses/toy/qf1"] == pytest.approx(qf1_loss, rel=1e-5)
    assert metrics["losses/toy/qf2"] == pytest.approx(qf2_loss, rel=1e-5)
    # The critic loss is the mean over the twin critics (metaworld-algorithms, the prototype, SB3).
    assert metrics["losses/toy/critic"] == pytest.approx((qf1_loss + qf2_loss) / 2, rel=1e-5)
    assert metrics["charts/toy/mean_q"] == pytest.approx(1.5)
    # The critic step moves only the head biases (all activations are 0), g = d (qf_loss / 2) /
    # d bias = mean(q - y). Clipping scales both by c = min(1, 1 / (||(g1, g2)|| + 1e-6))
    # (max_grad_norm 1), then Adam's first step is -lr * c g / (|c g| + eps), eps = 1e-5.
    g1 = sum((1.0 - t) for t in y) / 3
    g2 = sum((2.0 - t) for t in y) / 3
    c = min(1.0, 1.0 / (math.hypot(g1, g2) + 1e-6))
    q1_new = 1.0 - 3e-4 * c * g1 / (abs(c * g1) + 1e-5)
    q2_new = 2.0 - 3e-4 * c * g2 / (abs(c * g2) + 1e-5)
    log_pi = [_log_prob(0.5, -1.0, e)[1] for e in eps_pi]
    # actor_loss = mean(alpha * log_pi - min(qf1, qf2)) with the critic just updated
    actor_loss = sum(alpha * lp - min(q1_new, q2_new) for lp in log_pi) / 3
    assert metrics["losses/toy/actor"] == pytest.approx(actor_loss, rel=1e-5)
    # alpha_loss = mean(-log_alpha * (log_pi + target_entropy)), target entropy -|A| = -1
    alpha_loss = sum(-math.log(alpha) * (lp - 1.0) for lp in log_pi) / 3
    assert metrics["losses/toy/alpha"] == pytest.approx(alpha_loss, rel=1e-5)
    assert metrics["charts/toy/alpha/0"] == pytest.approx(2.0)  # the temperature this update used
    assert metrics["charts/toy/entropy"] == pytest.approx(-sum(log_pi) / 3, rel=1e-5)
    # Polyak: target bias = 0.995 * 3 + 0.005 * q1_new
    assert agent.critic_target.heads["toy"].bias[0, 0, 0].item() == pytest.approx(
        0.995 * 3.0 + 0.005 * q1_new, rel=1e-6
    )
    # Temperature (never clipped): one Adam step of lr 3e-4, -lr * g / (|g| + 1e-5).
    d_log_alpha = sum(-(lp - 1.0) for lp in log_pi) / 3
    assert agent.log_alpha["toy"].item() == pytest.approx(
        math.log(2) - 3e-4 * d_log_alpha / (abs(d_log_alpha) + 1e-5), abs=1e-7
    )


def test_per_task_temperatures_move_only_for_sampled_tasks() -> None:
    spec = EnvSpec("e", 3, 2, 4)
    agent = Agent([spec], AgentConfig(**SMALL), seed=0)
    batch = _random_batch(spec, 16)._replace(task_ids=torch.tensor([0, 2] * 8))
    metrics = agent.update({"e": batch})
    assert sorted(k for k in metrics if "/alpha/" in k) == [f"charts/e/alpha/{t}" for t in range(4)]
    log_alpha = agent.log_alpha["e"].detach()
    assert log_alpha[1] == 0 and log_alpha[3] == 0  # tasks 1 and 3 had no samples
    assert log_alpha[0] != 0 and log_alpha[2] != 0


def test_act_shapes_bounds_and_determinism() -> None:
    spec = EnvSpec("e", 5, 3, 2)
    agent = Agent([spec], AgentConfig(**SMALL), seed=0)
    obs = np.random.default_rng(0).normal(size=(6, 5)).astype(np.float32) * 10
    ids = np.array([0, 1, 0, 1, 0, 1])
    a = agent.act("e", obs, ids, deterministic=False)
    assert a.shape == (6, 3) and a.dtype == np.float32 and np.all(np.abs(a) <= 1)
    assert not np.array_equal(a, agent.act("e", obs, ids, deterministic=False))
    np.testing.assert_array_equal(
        agent.act("e", obs, ids, deterministic=True), agent.act("e", obs, ids, deterministic=True)
    )
    with pytest.raises(SealError, match=r"expected obs \(N, 5\)"):
        agent.act("e", obs[:, :4], ids)
    with pytest.raises(SealError, match=r"task ids must be in \[0, 2\)"):
        agent.act("e", obs, ids + 1)
    with pytest.raises(UnknownNameError):
        agent.act("nope", obs, ids)


def test_one_hot_is_appended_inside_the_agent() -> None:
    spec = EnvSpec("e", 3, 1, 2)
    with_hot = Agent([spec], AgentConfig(**SMALL), seed=0)
    without = Agent(
        [spec], AgentConfig(task_encoder="none", multi_head_policy=False, **SMALL), seed=0
    )
    assert (
        with_hot.actor.trunk.weights[0].shape[1] == 5
        and without.actor.trunk.weights[0].shape[1] == 3
    )
    obs = np.ones((2, 3), np.float32)
    # without one-hot or heads, the policy cannot tell tasks apart
    a = without.act("e", obs, np.array([0, 1]), deterministic=True)
    assert a[0, 0] == a[1, 0]
    b = with_hot.act("e", obs, np.array([0, 1]), deterministic=True)
    assert b[0, 0] != b[1, 0]


def test_learns_a_different_action_per_task_in_a_one_step_bandit() -> None:
    # One-step episodes (termination 1): reward -(a - target_t)^2 with targets +0.6 / -0.6.
    spec = EnvSpec("bandit", 2, 1, 2)
    agent = Agent([spec], AgentConfig(**SMALL, actor_lr=1e-3, critic_lr=1e-3), seed=0)
    rng = np.random.default_rng(0)
    targets = torch.tensor([0.6, -0.6])
    for _ in range(300):  # bounded by updates; seeds 0-2 reach |a| > 0.37 by update 250
        ids = torch.from_numpy(rng.integers(0, 2, 64))
        actions = torch.from_numpy(rng.uniform(-1, 1, (64, 1)).astype(np.float32))
        obs = torch.zeros(64, 2)
        rewards = -((actions[:, 0] - targets[ids]) ** 2)
        agent.update({"bandit": Batch(obs, actions, rewards, obs, torch.ones(64), ids)})
    a = agent.act("bandit", np.zeros((2, 2), np.float32), np.array([0, 1]), deterministic=True)[
        :, 0
    ]
    assert a[0] > 0.3 and a[1] < -0.3


def test_reset_parameters_redraws_networks_and_clears_optimisers() -> None:
    spec = EnvSpec("e", 3, 2, 2)
    agent = Agent([spec], AgentConfig(**SMALL), seed=0)
    for _ in range(3):
        agent.update({"e": _random_batch(spec, 8)})
    before = [p.detach().clone() for p in agent.actor.parameters()]
    assert agent.actor_optimizers[0].state and not torch.all(agent.log_alpha["e"] == 0)
    agent.reset_parameters()
    assert all(not torch.equal(a, b) for a, b in zip(before, agent.actor.parameters(), strict=True))
    assert (
        not agent.actor_optimizers[0].state
        and not agent.critic_optimizers[0].state
        and not agent.alpha_optimizer.state
    )
    assert torch.all(agent.log_alpha["e"] == 0)
    for p, q in zip(agent.critic.parameters(), agent.critic_target.parameters(), strict=True):
        assert torch.equal(p, q)
    agent.update({"e": _random_batch(spec, 8)})  # the fresh optimisers own the live parameters
    assert agent.actor_optimizers[0].state


def test_set_lr_factor_scales_actor_and_critic_only() -> None:
    agent = Agent([EnvSpec("e", 3, 2, 2)], AgentConfig(lr_factor=0.5, **SMALL), seed=0)
    assert agent.actor_optimizers[0].param_groups[0]["lr"] == pytest.approx(1.5e-4)
    agent.set_lr_factor(0.1)
    assert agent.actor_optimizers[0].param_groups[0]["lr"] == pytest.approx(3e-5)
    assert agent.critic_optimizers[0].param_groups[0]["lr"] == pytest.approx(3e-5)
    assert agent.alpha_optimizer.param_groups[0]["lr"] == pytest.approx(3e-4)
    with pytest.raises(SealError):
        agent.set_lr_factor(0.0)


def test_transfer_mt1_to_mt10_keeps_all_but_the_policy_head_and_zeroes_new_one_hot_columns() -> (
    None
):
    source = Agent([EnvSpec("mt1", 39, 4, 1)], AgentConfig(**SMALL), seed=0)
    for _ in range(2):
        source.update({"mt1": _random_batch(source.specs["mt1"], 8)})
    target = Agent([EnvSpec("mt10", 39, 4, 10)], AgentConfig(**SMALL), seed=1)
    fresh_head = target.actor.heads["mt10"].weight.detach().clone()
    transfer_from(target, source.state_dict())
    for net in ("actor", "critic"):
        old, new = getattr(source, net).trunk, getattr(target, net).trunk
        w_old, w_new = old.weights[0].detach(), new.weights[0].detach()
        # input columns: obs 0..38, one-hot 39 (old) -> 39..48 (new), action 40..43 -> 49..52
        torch.testing.assert_close(w_new[:, :40], w_old[:, :40], rtol=0, atol=0)
        assert torch.all(w_new[:, 40:49] == 0)  # one-hot ids 1..9 are new: zero columns
        if net == "critic":
            torch.testing.assert_close(w_new[:, 49:53], w_old[:, 40:44], rtol=0, atol=0)
        for a, b in zip(old.weights[1:], new.weights[1:], strict=True):
            assert torch.equal(a, b)
    assert torch.equal(
        target.actor.heads["mt10"].weight, fresh_head
    )  # policy last layer re-initialised
    # per-task Q heads (the default): MT1's one head becomes MT10's head 0, heads 1..9 stay fresh
    fresh_q = Agent([EnvSpec("mt10", 39, 4, 10)], AgentConfig(**SMALL), seed=1).critic.heads["mt10"]
    assert torch.equal(
        target.critic.heads["mt10"].weight[..., :1], source.critic.heads["mt1"].weight
    )
    assert torch.equal(target.critic.heads["mt10"].weight[..., 1:], fresh_q.weight[..., 1:])
    for p, q in zip(target.critic.parameters(), target.critic_target.parameters(), strict=True):
        assert torch.equal(p, q)
    assert (
        target.log_alpha["mt10"][0] == source.log_alpha["mt1"][0]
        and target.log_alpha["mt10"][1] == 0
    )
    # on the tasks it knew, the transferred critic computes what the source did
    obs = torch.randn(5, 39)
    act = torch.rand(5, 4)
    ids = torch.zeros(5, dtype=torch.long)
    with torch.no_grad():
        q_src = source.critic(
            "mt1", source._critic_input("mt1", source._actor_input("mt1", obs, ids), act), ids
        )
        q_new = target.critic(
            "mt10", target._critic_input("mt10", target._actor_input("mt10", obs, ids), act), ids
        )
    torch.testing.assert_close(q_src, q_new)
    target.update({"mt10": _random_batch(target.specs["mt10"], 8)})


def test_transfer_between_padded_pseudo_envs_with_different_action_sizes() -> None:
    # Aligned obs already carry the one-hot; the critic's action input is fixed at 9 for both phases.
    kitchen = Agent(
        [EnvSpec("aligned-kitchen", 40, 9, 12, act_pad_to=9)],
        AgentConfig(task_encoder="none", **SMALL),
        seed=0,
    )
    metaworld = Agent(
        [EnvSpec("aligned-metaworld", 40, 4, 12, act_pad_to=9)],
        AgentConfig(task_encoder="none", **SMALL),
        seed=1,
    )
    assert (
        metaworld.critic.trunk.weights[0].shape[1] == 49
        and metaworld.actor.heads["aligned-metaworld"].weight.shape[-1] == 12 * 8
    )
    transfer_from(metaworld, kitchen.state_dict())
    for a, b in zip(kitchen.critic.parameters(), metaworld.critic.parameters(), strict=True):
        assert torch.equal(a, b)
    reinit = Agent(
        [EnvSpec("aligned-metaworld", 40, 4, 12, act_pad_to=9)],
        AgentConfig(task_encoder="none", reinit_critic_on_transfer=True, **SMALL),
        seed=1,
    )
    before = [p.detach().clone() for p in reinit.critic.parameters()]
    transfer_from(reinit, kitchen.state_dict())
    assert all(torch.equal(a, b) for a, b in zip(before, reinit.critic.parameters(), strict=True))
    assert torch.equal(reinit.actor.trunk.weights[1], kitchen.actor.trunk.weights[1])
    m = metaworld.update(
        {"aligned-metaworld": _random_batch(metaworld.specs["aligned-metaworld"], 8)}
    )
    assert math.isfinite(m["losses/aligned-metaworld/critic"])


def test_seal_update_steps_only_the_envs_in_the_batches() -> None:
    specs = [EnvSpec("mw", 6, 2, 3), EnvSpec("fk", 8, 3, 2)]
    agent = Agent(specs, AgentConfig(architecture="seal", **SMALL), seed=0)
    fk_translator = [p.detach().clone() for p in agent.actor.translators["fk"].parameters()]
    trunk = [p.detach().clone() for p in agent.actor.trunk.parameters()]
    metrics = agent.update({"mw": _random_batch(specs[0], 12)})
    assert all(
        torch.equal(a, b)
        for a, b in zip(fk_translator, agent.actor.translators["fk"].parameters(), strict=True)
    )
    assert not any(
        torch.equal(a, b) for a, b in zip(trunk, agent.actor.trunk.parameters(), strict=True)
    )
    assert "losses/mw/critic" in metrics and not any("/fk/" in k for k in metrics)
    metrics = agent.update({"mw": _random_batch(specs[0], 12), "fk": _random_batch(specs[1], 8)})
    assert {"losses/mw/actor", "losses/fk/actor", "charts/fk/alpha/1"} <= set(metrics)
    with pytest.raises(UnknownNameError):
        agent.update({"other": _random_batch(specs[0], 4)})


def test_config_errors_name_the_key_and_valid_values() -> None:
    with pytest.raises(ConfigError, match="agent.architecture.*mtmhsac, seal"):
        AgentConfig(architecture="sac")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="agent.hidden"):
        AgentConfig(hidden=())
    with pytest.raises(ConfigError, match="agent.tau"):
        AgentConfig(tau=0.0)
    with pytest.raises(SealError, match="mtmhsac.*trains one environment"):
        Agent([EnvSpec("a", 2, 1, 1), EnvSpec("b", 2, 1, 1)], AgentConfig(**SMALL), seed=0)
    # per-task Q outputs are the default for both architectures (both references' MTMHSAC)
    assert AgentConfig().critic_multi_head and AgentConfig(architecture="seal").critic_multi_head
    for key, value, valid in (
        ("shared_update", "shared", "weighted, sequential, per_env"),
        ("critic_sharing", "none", "per_env, shared"),
        ("init", "xavier", "torch, metaworld_algorithms"),
    ):
        with pytest.raises(
            ConfigError, match=f"agent.{key}: unknown value '{value}'; valid: {valid}"
        ):
            AgentConfig(**{key: value})
    with pytest.raises(ConfigError, match="agent.max_grad_norm.*0 = no clipping"):
        AgentConfig(max_grad_norm=-1.0)
    with pytest.raises(ConfigError, match="agent.critic_hidden"):
        AgentConfig(critic_hidden=(0,))
    assert (
        "zero-padded" not in field_docs(AgentConfig)["hidden"]
        and field_docs(AgentConfig)["gamma"] == "Discount factor."
    )


def test_seal_transfer_keeps_translators_and_trunk_and_redraws_action_heads() -> None:
    specs = [EnvSpec("mw", 6, 2, 3), EnvSpec("fk", 8, 3, 2)]
    source = Agent(specs, AgentConfig(architecture="seal", **SMALL), seed=0)
    target = Agent(specs, AgentConfig(architecture="seal", **SMALL), seed=1)
    fresh = {
        n: p.detach().clone() for n, p in target.actor.named_parameters() if n.startswith("heads.")
    }
    transfer_from(target, source.state_dict())
    for name, p in target.actor.named_parameters():
        if name.startswith("heads."):
            assert torch.equal(p, fresh[name])  # each env's action head keeps its fresh init
        else:
            assert torch.equal(p, source.actor.get_parameter(name)), name
    for (name, p), q in zip(
        target.critic.named_parameters(), source.critic.parameters(), strict=True
    ):
        assert torch.equal(p, q), name
    with pytest.raises(SealError, match="cannot transfer a 'mtmhsac' agent"):
        transfer_from(target, Agent([specs[0]], AgentConfig(**SMALL), seed=0).state_dict())


def test_log_prob_of_given_actions_matches_the_sampling_density() -> None:
    spec = EnvSpec("e", 4, 3, 2)
    agent = Agent([spec], AgentConfig(**SMALL), seed=0)
    obs = np.random.default_rng(0).normal(size=(5, 4)).astype(np.float32)
    ids = np.array([0, 1, 1, 0, 1])
    with torch.no_grad():
        obs_t, ids_t = torch.from_numpy(obs), torch.from_numpy(ids)
        actions, log_pi = agent._policy(
            "e",
            agent._actor_input("e", obs_t, ids_t),
            ids_t,
            torch.Generator().manual_seed(3),
            False,
        )
    got = agent.log_prob("e", obs, actions.numpy(), ids)
    assert got.shape == (5,)
    np.testing.assert_allclose(got, log_pi.numpy(), rtol=1e-4, atol=1e-4)
    with pytest.raises(SealError, match=r"expected actions \(N, 3\)"):
        agent.log_prob("e", obs, actions.numpy()[:, :2], ids)


def test_q_values_are_the_twin_critics_on_obs_one_hot_and_action() -> None:
    """q_values(obs, actions, ids) is the stacked critic on [obs, one-hot(id), action], built by hand
    here; a wrong action shape is one line."""
    spec = EnvSpec("e", 4, 3, 2)
    agent = Agent([spec], AgentConfig(**SMALL), seed=0)
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(5, 4)).astype(np.float32)
    actions = rng.uniform(-1, 1, size=(5, 3)).astype(np.float32)
    ids = np.array([0, 1, 1, 0, 1])
    got = agent.q_values("e", obs, actions, ids)
    assert got.shape == (2, 5)
    one_hot = np.eye(2, dtype=np.float32)[ids]
    x = torch.from_numpy(np.concatenate([obs, one_hot, actions], axis=1))
    with torch.no_grad():
        expected = agent.critic.trunk(x)  # (2, 5, hidden): both twins
        heads = agent.critic.heads["e"]  # one Q output per task: each row takes its task's
        expected = torch.stack(
            [
                expected[m, i] @ heads.weight[m, :, ids[i]] + heads.bias[m, 0, ids[i]]
                for m in range(2)
                for i in range(5)
            ]
        ).reshape(2, 5)
    np.testing.assert_allclose(got, expected.numpy(), rtol=1e-5, atol=1e-6)
    with pytest.raises(SealError, match=r"q_values\('e'\): expected actions \(N, 3\)"):
        agent.q_values("e", obs, actions[:, :2], ids)


def test_compile_failure_falls_back_to_eager_with_a_warning(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    def broken_compile(fn: object, **_: object) -> object:
        def run(*args: object) -> object:
            raise RuntimeError("no C++ compiler")

        return run

    monkeypatch.setattr(torch, "compile", broken_compile)
    spec = EnvSpec("e", 3, 2, 2)
    eager = Agent([spec], AgentConfig(**SMALL), seed=0)
    compiled = Agent([spec], AgentConfig(compile=True, **SMALL), seed=0)
    batch = _random_batch(spec, 8)
    with pytest.warns(
        UserWarning, match="torch.compile failed .*no C\\+\\+ compiler.*running eager"
    ):
        got = compiled.update({"e": batch})
    assert got == eager.update({"e": batch})
    assert compiled.update({"e": batch}) == eager.update(
        {"e": batch}
    )  # stays eager, no new warning


def test_compiled_stages_are_cuda_graphs_on_cuda_only(monkeypatch: pytest.MonkeyPatch) -> None:
    from seal.learner.staging import compile_mode

    assert compile_mode(torch.device("cuda")) == compile_mode(torch.device("cuda:1"))
    assert compile_mode(torch.device("cuda")) == "reduce-overhead"
    assert compile_mode(torch.device("cpu")) is None
    modes: list[object] = []

    def recording_compile(fn: object, **kwargs: object) -> object:
        modes.append(kwargs["mode"])
        return fn

    monkeypatch.setattr(torch, "compile", recording_compile)
    Agent([EnvSpec("e", 3, 2, 2)], AgentConfig(compile=True, device="cpu", **SMALL), seed=0)
    assert modes == [None, None]  # the critic's and the actor's stage, CPU's default mode


@pytest.mark.slow
def test_compiled_update_agrees_with_eager_and_is_deterministic() -> None:
    # A SEAL agent with both kinds of env (3 and 1 tasks: gathered and single Q heads), weighted.
    specs = [EnvSpec("mw", 6, 2, 3), EnvSpec("fk", 8, 3, 1)]
    config = AgentConfig(architecture="seal", device="cpu", **SMALL)
    eager = Agent(specs, config, seed=0)
    first, second = (Agent(specs, replace(config, compile=True), seed=0) for _ in range(2))
    batches = [{s.name: _random_batch(s, 12, seed=i) for s in specs} for i in range(20)]
    losses: dict[str, list[list[float]]] = {"eager": [], "first": [], "second": []}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for batch in batches:
            for name, agent in (("eager", eager), ("first", first), ("second", second)):
                metrics = agent.update(batch)
                losses[name].append([v for k, v in sorted(metrics.items()) if "losses" in k])
    if not first.compiled:  # no C++ compiler here: the fallback test covers this case
        pytest.skip(f"torch.compile unavailable: {[str(w.message) for w in caught]}")
    assert second.compiled and first.compile_seconds > 0 and eager.compile_seconds == 0
    assert losses["first"] == losses["second"]  # compiled updates are deterministic
    got, want = np.array(losses["first"]), np.array(losses["eager"])
    np.testing.assert_allclose(got[0], want[0], rtol=1e-4)
    np.testing.assert_allclose(got[19], want[19], rtol=1e-3)


@pytest.mark.slow
def test_cuda_mode_compiles_wherever_the_cpu_mode_does_and_agrees(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The stages compiled as on CUDA (mode "reduce-overhead"). On CPU tensors inductor records no
    CUDA graph, so this checks the tracing and the arithmetic, not the graphs (no GPU here)."""
    import seal.learner.staging as staging

    specs = [EnvSpec("mw", 6, 2, 3), EnvSpec("fk", 8, 3, 1)]
    config = AgentConfig(architecture="seal", device="cpu", **SMALL)
    batches = [{s.name: _random_batch(s, 12, seed=i) for s in specs} for i in range(3)]
    probe = Agent(specs, replace(config, compile=True), seed=0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        probe.update(batches[0])
    if not probe.compiled:  # no C++ compiler here: the fallback test covers this case
        pytest.skip(f"torch.compile unavailable: {[str(w.message) for w in caught]}")
    monkeypatch.setattr(staging, "compile_mode", lambda device: "reduce-overhead")
    eager = Agent(specs, config, seed=0)
    graphed = Agent(specs, replace(config, compile=True), seed=0)
    for batch in batches:
        want, got = eager.update(batch), graphed.update(batch)
        losses = sorted(k for k in want if k.startswith("losses"))
        np.testing.assert_allclose([got[k] for k in losses], [want[k] for k in losses], rtol=1e-4)
    assert graphed.compiled and graphed.compile_seconds > 0


def test_min_alpha_holds_every_temperature_at_its_floor() -> None:
    """A target entropy far below the policy's drives every sampled task's temperature down at
    each step; with min_alpha = init_alpha it stays exactly at the floor, a task unsampled
    included, while without one it falls below."""
    spec = EnvSpec("e", 3, 2, 4)
    batch = _random_batch(spec, 16)._replace(task_ids=torch.tensor([0, 2] * 8))
    logs = {}
    for floor in (0.0, 0.5):
        config = AgentConfig(**SMALL, init_alpha=0.5, target_entropy=-100.0, min_alpha=floor)
        agent = Agent([spec], config, seed=0)
        for _ in range(3):
            agent.update({"e": batch})
        logs[floor] = agent.log_alpha["e"].detach().clone()
    floored, free = logs[0.5], logs[0.0]
    assert torch.equal(floored, torch.full((4,), math.log(0.5)))
    assert (free[[0, 2]] < math.log(0.5)).all() and free[1] == free[3] == math.log(0.5)
    with pytest.raises(ConfigError, match="agent.min_alpha: expected a finite number >= 0"):
        AgentConfig(min_alpha=-0.1)


def test_capped_kernels_get_their_own_inductor_cache(monkeypatch: pytest.MonkeyPatch) -> None:
    """A kernel cap moves an unset inductor cache to the default directory suffixed with the caps
    (code compiled under another cap crashes when loaded); a user's directory, or no cap, stays."""
    from torch._inductor.runtime.cache_dir_utils import default_cache_dir

    from seal.learner.staging import KERNEL_CAPS, isolate_inductor_cache

    for key in (*KERNEL_CAPS, "TORCHINDUCTOR_CACHE_DIR"):
        monkeypatch.delenv(key, raising=False)
    isolate_inductor_cache()
    assert "TORCHINDUCTOR_CACHE_DIR" not in os.environ  # no cap: torch's own default
    monkeypatch.setenv("ATEN_CPU_CAPABILITY", "avx2")
    monkeypatch.setenv("DNNL_MAX_CPU_ISA", "AVX2")
    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", default_cache_dir())  # torch's, once it ran
    isolate_inductor_cache()
    assert os.environ["TORCHINDUCTOR_CACHE_DIR"] == (
        f"{default_cache_dir()}-ATEN_CPU_CAPABILITY=avx2-DNNL_MAX_CPU_ISA=AVX2"
    )
    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", "/somewhere/mine")
    isolate_inductor_cache()
    assert os.environ["TORCHINDUCTOR_CACHE_DIR"] == "/somewhere/mine"
