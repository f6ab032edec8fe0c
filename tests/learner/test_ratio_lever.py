"""`Agent.ratio_lever_expected`: the lever of the expected trunk steps, by hand and on a real agent."""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest
import torch

from seal.errors import SealError
from seal.learner import Agent, AgentConfig, Batch, EnvSpec


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


def _batch(spec: EnvSpec, n: int, seed: int, first_obs: float | None = None) -> Batch:
    g = torch.Generator().manual_seed(seed)
    obs = torch.randn(n, spec.obs_dim, generator=g)
    if first_obs is not None:
        obs[:, 0] = first_obs
    return Batch(
        obs,
        torch.rand(n, spec.act_dim, generator=g) * 2 - 1,
        torch.randn(n, generator=g),
        torch.randn(n, spec.obs_dim, generator=g),
        torch.zeros(n),
        torch.randint(0, spec.num_tasks, (n,), generator=g),
    )


def _draw(c_a: float, c_b: float, seed: int) -> dict[str, Batch]:
    """3 samples of a and 1 of b (weights 0.75 / 0.25), whose first observation is c_a / c_b."""
    return {"a": _batch(SPECS[0], 3, seed, c_a), "b": _batch(SPECS[1], 1, seed + 1, c_b)}


def _adam_step(grads: list[float], lr: float = 3e-4, eps: float = 1e-5) -> float:
    """The last parameter change of torch's Adam (betas 0.9, 0.999) fed `grads`, in plain Python."""
    m = v = 0.0
    for g in grads:
        m = 0.9 * m + 0.1 * g
        v = 0.999 * v + 0.001 * g * g
    t = len(grads)
    return -lr * (m / (1 - 0.9**t)) / (math.sqrt(v / (1 - 0.999**t)) + eps)


def _lever(full: float, minus_a: float, minus_b: float) -> float:
    return abs(full - minus_a) / (abs(full - minus_a) + abs(full - minus_b))


def test_expected_lever_by_hand(monkeypatch: pytest.MonkeyPatch) -> None:
    # The actor loss is replaced by c_X * sum(first trunk weight), c_X = the mean first observation
    # of env X's batch: every coordinate of that weight gets the same gradient and nothing else in
    # the trunk gets one, so every coordinate takes the same step and the sqrt(#coordinates) of the
    # norms cancels in the lever. "weighted", 3 samples of A, 1 of B: w_A = 0.75, w_B = 0.25.
    # Clipping off, so Adam alone is worked out here. Warm-up on (c_A, c_B) = (1, -2): g = 0.25.
    # Adam's next step for gradient g' (m^ = (0.0225 + 0.1 g') / 0.19,
    # v^ = (6.24375e-5 + 0.001 g'^2) / 0.001999), in units of lr:
    #   draw 1, (c_A, c_B) = (1, -2): full g' = 0.25 -> -0.99996, -A g' = -0.5 -> +0.366094,
    #                                 -B g' = 0.75 -> -0.917765; lever 1.36606 / 1.44825 = 0.94325
    #   draw 2, (c_A, c_B) = (1, 6):  full g' = 2.25 -> -0.813544, -A g' = 1.5 -> -0.844117,
    #                                 -B g' = 0.75 -> -0.917765; lever 0.030573 / 0.134794 = 0.22682
    # Expected steps over the two draws: full -0.906752, -A -0.239012, -B -0.917765, so
    #   lever = 0.667740 / (0.667740 + 0.011013) = 0.98378,
    # where the mean of the two single-draw levers is 0.58503: averaging the steps first is what
    # lets B's opposite-signed draws cancel. Had the agent moved between the draws (no restore),
    # draw 2 would be Adam's third step and the figure would differ.
    def actor_loss(
        policy: _EnvPolicy,
        qf: object,
        obs_in: torch.Tensor,
        task_ids: torch.Tensor,
        alpha: torch.Tensor,
        noise: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        weight = policy.agent.actor.trunk.weights[0]
        # (weight * ones): a dense gradient (torch's fused CPU Adam misreads a stride-0 one)
        return obs_in[:, 0].mean() * (weight * torch.ones_like(weight)).sum(), torch.zeros(
            obs_in.shape[0]
        )

    _patch_actor_loss(monkeypatch, actor_loss)
    config = AgentConfig(architecture="seal", max_grad_norm=0.0, ratio_lever_interval=0, **SMALL)
    agent = Agent(SPECS, config, seed=0)
    agent.update(_draw(1.0, -2.0, 0))
    weight = agent.actor.trunk.weights[0].detach().clone()
    adam_state = {
        k: v.clone()
        for k, v in agent.actor_optimizers[0].state[agent.actor.trunk.weights[0]].items()
    }
    draws = [_draw(1.0, -2.0, 10), _draw(1.0, 6.0, 20)]

    result = agent.ratio_lever_expected(draws)

    steps = [
        [_adam_step([0.25, g]) / 3e-4 for g in gs] for gs in ((0.25, -0.5, 0.75), (2.25, 1.5, 0.75))
    ]
    assert steps[0] == pytest.approx([-0.99996, 0.366094, -0.917765], abs=1e-5)
    assert steps[1] == pytest.approx([-0.813544, -0.844117, -0.917765], abs=1e-5)
    expected = [(x + y) / 2 for x, y in zip(*steps, strict=True)]
    assert _lever(*expected) == pytest.approx(0.98378, abs=1e-5)
    # float32 weights of ~0.3 against B's expected effect of ~3e-6: ~1e-3 is what float32 allows
    assert result["lever"] == pytest.approx(0.98378, abs=1e-3)
    assert result["single_draw_lever_mean"] == pytest.approx(0.58503, abs=1e-3)
    coords = math.sqrt(weight.numel())
    assert result["effect"]["a"] == pytest.approx(0.667740 * 3e-4 * coords, rel=1e-3)
    assert result["env"] == "a" and result["share"] == 0.75 and result["draws"] == 2
    # K identical draws: exactly the single-batch lever, ratio_lever's (noise plays no part here)
    same = agent.ratio_lever_expected([draws[0]] * 3)
    assert same["lever"] == pytest.approx(agent.ratio_lever(draws[0])["lever"], abs=1e-6)
    assert same["lever"] == pytest.approx(0.94325, abs=2e-4)
    # measuring leaves the agent as it was: weights and Adam's moments
    assert torch.equal(agent.actor.trunk.weights[0], weight)
    state = agent.actor_optimizers[0].state[agent.actor.trunk.weights[0]]
    assert all(torch.equal(state[k], v) for k, v in adam_state.items())


@pytest.mark.parametrize("mode", ["weighted", "sequential", "per_env"])
def test_expected_lever_on_a_real_agent_leaves_it_unchanged(mode: str) -> None:
    config = AgentConfig(
        architecture="seal", shared_update=mode, ratio_lever_interval=0, device="cpu", **SMALL
    )
    agent = Agent(SPECS, config, seed=0)
    agent.update(_draw(0.0, 0.0, 0))
    twin = Agent(SPECS, config, seed=0)
    twin.update(_draw(0.0, 0.0, 0))
    draws = [
        {"a": _batch(SPECS[0], 9, 2 * k), "b": _batch(SPECS[1], 1, 2 * k + 1)} for k in range(4)
    ]
    result = agent.ratio_lever_expected(draws)
    assert 0.0 < result["lever"] < 1.0 and result["draws"] == 4 and result["share"] == 0.9
    assert result["lever"] == agent.ratio_lever_expected(draws)["lever"]  # deterministic
    # the agent's next update is the one it would have taken without the measurement
    after, untouched = agent.update(draws[0]), twin.update(draws[0])
    assert after == untouched
    with pytest.raises(SealError, match="every draw needs the same sizes"):
        agent.ratio_lever_expected([draws[0], _draw(0.0, 0.0, 5)])
    with pytest.raises(SealError, match="at least one batch draw"):
        agent.ratio_lever_expected([])
