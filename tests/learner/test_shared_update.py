"""shared_update and critic_sharing: the ratio lever by hand, resume and cross-process determinism
in every mode, and transfer across critic layouts."""

from __future__ import annotations

import io
import json
import math
import subprocess
import sys
import textwrap
from collections.abc import Callable

import numpy as np
import pytest
import torch

from seal.errors import SealError
from seal.learner import Agent, AgentConfig, Batch, EnvSpec
from seal.learner.transfer import transfer_from


class _EnvPolicy:
    """`Agent.policy` as a callable that also names its agent and env, for a hand-made actor loss."""

    def __init__(self, agent: Agent, name: str, task_ids: torch.Tensor) -> None:
        self.agent, self.name, self.task_ids = agent, name, task_ids

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        return self.agent.actor(self.agent._keys[self.name], x, self.task_ids)


def _patch_actor_loss(monkeypatch: pytest.MonkeyPatch, loss: Callable[..., object]) -> None:
    """Every actor loss (the update's and the lever's gradient norms) replaced by `loss`."""
    from seal.learner import lever, update

    monkeypatch.setattr(Agent, "policy", lambda agent, name, ids: _EnvPolicy(agent, name, ids))
    monkeypatch.setattr(update, "actor_loss", loss)
    monkeypatch.setattr(lever, "actor_loss", loss)


SMALL = {"translator_hidden": (8,), "latent_dim": 4, "trunk_hidden": (3,), "critic_hidden": (8,)}
SPECS = [EnvSpec("a", 3, 2, 2), EnvSpec("b", 4, 1, 1)]
MODES = [
    (mode, critics)
    for mode in ("weighted", "sequential", "per_env")
    for critics in ("per_env", "shared")
]


def _batch(spec: EnvSpec, n: int, seed: int) -> Batch:
    g = torch.Generator().manual_seed(seed)
    return Batch(
        torch.randn(n, spec.obs_dim, generator=g),
        torch.rand(n, spec.act_dim, generator=g) * 2 - 1,
        torch.randn(n, generator=g),
        torch.randn(n, spec.obs_dim, generator=g),
        torch.zeros(n),
        torch.randint(0, spec.num_tasks, (n,), generator=g),
    )


def _adam_step(grads: list[float], lr: float = 3e-4, eps: float = 1e-5) -> float:
    """The last parameter change of torch's Adam (betas 0.9, 0.999) fed `grads`, in plain Python."""
    m = v = 0.0
    for g in grads:
        m = 0.9 * m + 0.1 * g
        v = 0.999 * v + 0.001 * g * g
    t = len(grads)
    return -lr * (m / (1 - 0.9**t)) / (math.sqrt(v / (1 - 0.999**t)) + eps)


def test_ratio_lever_by_hand(monkeypatch: pytest.MonkeyPatch) -> None:
    # The actor loss is replaced by c_env * sum(first trunk weight): every coordinate of that
    # weight gets the same gradient, nothing else in the trunk gets one, so every coordinate takes
    # the same step and the sqrt(#coordinates) of each norm cancels in the lever. "weighted", A has
    # 3 samples and B 1: w_A = 0.75, w_B = 0.25; c_A = 1, c_B = -2. Clipping off (max_grad_norm 0)
    # so Adam alone is worked out here:
    #   warm-up update: g = 0.75 * 1 + 0.25 * (-2) = 0.25
    #   next update, Adam's step for g' = 0.25 (full), -0.5 (A dropped), 0.75 (B dropped):
    #     m = 0.9 * 0.025 + 0.1 g',  v = 0.999 * 6.25e-5 + 0.001 g'^2, bias corrections 0.19, 0.001999
    #     full: m^ = 0.25, sqrt(v^) = 0.25          -> step -lr * 0.99996
    #     -A:   m^ = -0.144737, sqrt(v^) = 0.395344 -> step +lr * 0.366100
    #     -B:   m^ = 0.513158, sqrt(v^) = 0.559129  -> step -lr * 0.917766
    #   lever = 1.36606 / (1.36606 + 0.08219) = 0.94325
    coefficient = {"a": 1.0, "b": -2.0}

    def actor_loss(
        policy: _EnvPolicy,
        qf: object,
        obs_in: torch.Tensor,
        task_ids: torch.Tensor,
        alpha: torch.Tensor,
        noise: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        weight = policy.agent.actor.trunk.weights[0]
        # (weight * ones) gives a dense gradient: the gradient of a bare sum is a stride-0
        # expanded tensor, which torch's fused CPU Adam misreads (only its first element).
        loss = coefficient[policy.name] * (weight * torch.ones_like(weight)).sum()
        return loss, torch.zeros(obs_in.shape[0])

    _patch_actor_loss(monkeypatch, actor_loss)
    config = AgentConfig(architecture="seal", max_grad_norm=0.0, ratio_lever_interval=0, **SMALL)
    agent = Agent(SPECS, config, seed=0)
    batches = {"a": _batch(SPECS[0], 3, 0), "b": _batch(SPECS[1], 1, 1)}
    agent.update(batches)
    weight = agent.actor.trunk.weights[0].detach().clone()
    result = agent.ratio_lever(batches)
    full, minus_a, minus_b = (
        _adam_step([0.25, 0.25]),
        _adam_step([0.25, -0.5]),
        _adam_step([0.25, 0.75]),
    )
    assert full / -3e-4 == pytest.approx(0.99996, abs=1e-5)
    assert minus_a / 3e-4 == pytest.approx(0.366100, abs=1e-5)
    assert minus_b / -3e-4 == pytest.approx(0.917766, abs=1e-5)
    # Steps are differences of float32 weights of size ~0.3 (spacing ~3e-8) against steps of
    # ~2.5e-5 (the B effect): agreement to ~1e-3 relative is what float32 allows.
    coords = math.sqrt(weight.numel())
    assert result["effect"]["a"] == pytest.approx(abs(full - minus_a) * coords, rel=1e-3)
    assert result["effect"]["b"] == pytest.approx(abs(full - minus_b) * coords, rel=2e-3)
    assert result["lever"] == pytest.approx(0.94325, abs=2e-4)
    assert result["env"] == "a" and result["share"] == 0.75
    # each env's own gradient on the trunk: |c| per coordinate
    assert result["grad_norm"]["b"] / result["grad_norm"]["a"] == pytest.approx(2.0)
    # measuring leaves the agent as it was
    assert torch.equal(agent.actor.trunk.weights[0], weight)
    with pytest.raises(SealError, match="ratio_lever needs batches of >= 2 envs"):
        agent.ratio_lever({"a": batches["a"]})


def test_update_logs_the_lever_every_interval_and_keeps_it_between() -> None:
    config = AgentConfig(architecture="seal", ratio_lever_interval=2, **SMALL)
    agent = Agent(SPECS, config, seed=0)
    batches = {"a": _batch(SPECS[0], 9, 0), "b": _batch(SPECS[1], 1, 1)}
    twin = Agent(SPECS, config, seed=0)
    expected = twin.ratio_lever(batches)["lever"]
    first = agent.update(batches)
    assert first["charts/ratio_lever"] == expected and 0 < expected < 1
    assert agent.update(batches)["charts/ratio_lever"] == expected  # not measured at update 1
    assert agent.update(batches)["charts/ratio_lever"] != expected  # measured again at update 2
    # the measurement draws nothing from the agent's own streams: losses as without it
    quiet = Agent(SPECS, AgentConfig(architecture="seal", ratio_lever_interval=0, **SMALL), seed=0)
    losses = quiet.update(batches)
    assert {k: v for k, v in first.items() if k != "charts/ratio_lever"} == losses
    assert "charts/ratio_lever" not in losses


@pytest.mark.parametrize(("mode", "critics"), MODES)
def test_save_load_resume_is_bitwise_in_every_mode(mode: str, critics: str) -> None:
    config = AgentConfig(
        architecture="seal",
        shared_update=mode,
        critic_sharing=critics,
        ratio_lever_interval=2,
        **SMALL,
    )
    agent = Agent(SPECS, config, seed=0)
    for i in range(3):
        agent.update({"a": _batch(SPECS[0], 6, i), "b": _batch(SPECS[1], 2, 10 + i)})
    buffer = io.BytesIO()
    torch.save(agent.state_dict(), buffer)
    buffer.seek(0)
    resumed = Agent(SPECS, config, seed=7)
    resumed.load_state_dict(torch.load(buffer, weights_only=True))
    for i in range(3, 6):
        batches = {"a": _batch(SPECS[0], 6, i), "b": _batch(SPECS[1], 2, 10 + i)}
        assert resumed.update(batches) == agent.update(batches)
    for net in ("actor", "critic", "critic_target"):
        for p, q in zip(
            getattr(agent, net).parameters(), getattr(resumed, net).parameters(), strict=True
        ):
            assert torch.equal(p, q)


# Runs in a fresh interpreter: 30 updates of a small SEAL agent in one mode; prints the losses.
_SCRIPT = textwrap.dedent(
    """
    import json, sys
    import torch
    torch.set_num_threads(1)
    from seal.learner import Agent, AgentConfig, Batch, EnvSpec

    mode, critics = sys.argv[1], sys.argv[2]
    specs = [EnvSpec("a", 3, 2, 2), EnvSpec("b", 4, 1, 1)]
    config = AgentConfig(architecture="seal", shared_update=mode, critic_sharing=critics,
                         translator_hidden=(16,), latent_dim=8, trunk_hidden=(16,),
                         critic_hidden=(16,), ratio_lever_interval=10, device="cpu")
    agent = Agent(specs, config, seed=3)
    g = torch.Generator().manual_seed(0)
    def batch(spec, n):
        return Batch(torch.randn(n, spec.obs_dim, generator=g), torch.rand(n, spec.act_dim, generator=g) * 2 - 1,
                     torch.randn(n, generator=g), torch.randn(n, spec.obs_dim, generator=g), torch.zeros(n),
                     torch.randint(0, spec.num_tasks, (n,), generator=g))
    out = []
    for _ in range(30):
        m = agent.update({"a": batch(specs[0], 12), "b": batch(specs[1], 4)})
        out.append([m["losses/a/critic"], m["losses/a/actor"], m["losses/b/critic"], m["losses/b/actor"], m["charts/ratio_lever"]])
    print(json.dumps(out))
    """
)


@pytest.mark.parametrize(("mode", "critics"), MODES)
@pytest.mark.slow
def test_same_seed_same_losses_in_two_processes_in_every_mode(mode: str, critics: str) -> None:
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", _SCRIPT, mode, critics],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for _ in range(2)
    ]
    runs = []
    for proc in procs:
        out, err = proc.communicate()
        assert proc.returncode == 0, err
        runs.append(np.array(json.loads(out.strip().splitlines()[-1])))
    assert runs[0].shape == (30, 5)
    np.testing.assert_array_equal(runs[0], runs[1])  # bitwise, every update


def test_modes_differ_in_how_the_trunk_moves() -> None:
    # Same seed and batches: the three modes take different trunk steps (per_env and sequential
    # step the trunk twice, weighted once), and critic layouts differ in what they own.
    steps = {}
    for mode in ("weighted", "sequential", "per_env"):
        agent = Agent(SPECS, AgentConfig(architecture="seal", shared_update=mode, **SMALL), seed=0)
        before = agent.actor.trunk.weights[0].detach().clone()
        agent.update({"a": _batch(SPECS[0], 6, 0), "b": _batch(SPECS[1], 2, 1)})
        steps[mode] = agent.actor.trunk.weights[0].detach() - before
    assert not torch.equal(steps["weighted"], steps["sequential"])
    assert not torch.equal(steps["sequential"], steps["per_env"])


def _old_layout_state() -> dict:
    """A SEAL agent state as saved before critic_sharing existed: shared critics, format 1."""
    source = Agent(
        SPECS, AgentConfig(architecture="seal", critic_sharing="shared", **SMALL), seed=0
    )
    source.update({"a": _batch(SPECS[0], 6, 0), "b": _batch(SPECS[1], 2, 1)})
    state = source.state_dict()
    state["format"] = 1
    del state["config"]["critic_sharing"]
    return state


def test_transfer_from_the_old_critic_layout_is_refused_in_one_line_or_maps_cleanly() -> None:
    state = _old_layout_state()
    target = Agent(SPECS, AgentConfig(architecture="seal", **SMALL), seed=1)
    fresh = [p.detach().clone() for p in target.actor.parameters()]
    with pytest.raises(SealError) as info:
        transfer_from(target, state)
    message = str(info.value)
    assert "\n" not in message and "shared critics" in message and "reinit_critic = true" in message
    # refused before anything was copied
    assert all(torch.equal(a, b) for a, b in zip(fresh, target.actor.parameters(), strict=True))
    transfer_from(target, state, reinit_critic=True)  # fresh per-env critics, policy transferred
    assert torch.equal(target.actor.trunk.weights[0], state["actor"]["trunk.weights.0"])
    # into an agent with the old (shared) layout, everything maps
    shared = Agent(
        SPECS, AgentConfig(architecture="seal", critic_sharing="shared", **SMALL), seed=1
    )
    transfer_from(shared, state)
    for name, p in shared.critic.named_parameters():
        assert torch.equal(p, state["critic"][name]), name
    # resuming (load_state_dict) an old state is refused in one line
    with pytest.raises(SealError, match=r"format 1; this seal resumes format 2[^\n]*$"):
        shared.load_state_dict(state)


def test_transfer_between_per_env_critics_copies_each_envs_critic() -> None:
    source = Agent(SPECS, AgentConfig(architecture="seal", **SMALL), seed=0)
    source.update({"a": _batch(SPECS[0], 6, 0), "b": _batch(SPECS[1], 2, 1)})
    target = Agent(SPECS, AgentConfig(architecture="seal", **SMALL), seed=1)
    transfer_from(target, source.state_dict())
    for (name, p), q in zip(
        target.critic.named_parameters(), source.critic.parameters(), strict=True
    ):
        assert torch.equal(p, q), name
    for p, q in zip(target.critic.parameters(), target.critic_target.parameters(), strict=True):
        assert torch.equal(p, q)
