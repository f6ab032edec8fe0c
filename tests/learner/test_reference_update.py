"""The staged update equals the plainly written reference update bit for bit, on any CPU.

Both paths run in one process from one agent state on the same batches (`reference_sac.py`), so
the comparison holds wherever the kernels round differently: it is the guard against a refactor
that reorders a sum or draws noise in another order. Runs: MTMHSAC on data `point` collected,
and a two-env SEAL agent under every `shared_update` mode, with per-env and with shared critics.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

import seal.learner.update as update_module
from seal.envs import make_adapter
from seal.learner import Agent, AgentConfig, Batch, EnvSpec, MultiTaskReplay
from seal.learner.networks import tanh_gaussian
from tests.learner.reference_sac import ReferenceSAC

SMALL = {
    "hidden": (16, 16),
    "translator_hidden": (16,),
    "latent_dim": 16,
    "trunk_hidden": (16, 16),
    "critic_hidden": (16, 16),
    "device": "cpu",
    "ratio_lever_interval": 0,
}
SEAL_RUNS = {
    "seal-weighted": {"shared_update": "weighted"},
    "seal-sequential": {"shared_update": "sequential"},
    "seal-per_env": {"shared_update": "per_env"},
    "seal-weighted-shared-critic": {"shared_update": "weighted", "critic_sharing": "shared"},
    "seal-sequential-shared-critic": {"shared_update": "sequential", "critic_sharing": "shared"},
    "seal-per_env-shared-critic": {"shared_update": "per_env", "critic_sharing": "shared"},
}
UPDATES = 10


def point_data(agent: Agent, updates: int) -> list[dict[str, Batch]]:
    """`agent` (MTMHSAC on `point`) acts for 3 episodes of 20 steps per task; then `updates`
    batches of 8 samples per task from what it collected."""
    adapter = make_adapter("point", episode_length=20)
    spec = agent.specs["point"]
    replay = MultiTaskReplay([spec], capacity=200, seed=3)
    envs = [adapter.make(task, seed=i) for i, task in enumerate(adapter.tasks)]
    ids = np.arange(len(envs))
    for episode in range(3):
        obs = np.stack([env.reset(seed=10 * episode + i)[0] for i, env in enumerate(envs)])
        for _ in range(20):
            actions = agent.act("point", obs.astype(np.float32), ids)
            steps = [env.step(a) for env, a in zip(envs, actions, strict=True)]
            next_obs = np.stack([s[0] for s in steps])
            rewards = np.array([s[1] for s in steps])
            terminated = np.array([s[2] for s in steps])
            replay.add("point", ids, obs, actions, rewards, next_obs, terminated)
            obs = next_obs
    counts = {"point": np.full(len(envs), 8)}
    return [replay.sample(counts) for _ in range(updates)]


def point_spec() -> EnvSpec:
    adapter = make_adapter("point", episode_length=20)
    return EnvSpec("point", adapter.obs_dim, adapter.act_dim, len(adapter.tasks))


def point_run() -> tuple[Agent, list[dict[str, Batch]]]:
    agent = Agent([point_spec()], AgentConfig(**SMALL), seed=3)
    return agent, point_data(agent, UPDATES)


def seal_batches(specs: list[EnvSpec], seed: int) -> dict[str, Batch]:
    """Random batches of two envs at a 75/25-ish data ratio (6 and 2 samples per task)."""
    g = torch.Generator().manual_seed(seed)
    out = {}
    for spec, per_task in zip(specs, (6, 2), strict=True):
        n = per_task * spec.num_tasks
        out[spec.name] = Batch(
            torch.randn(n, spec.obs_dim, generator=g),
            torch.rand(n, spec.act_dim, generator=g) * 2 - 1,
            torch.randn(n, generator=g),
            torch.randn(n, spec.obs_dim, generator=g),
            (torch.rand(n, generator=g) < 0.1).float(),
            torch.arange(spec.num_tasks).repeat_interleave(per_task),
        )
    return out


def seal_run(options: dict[str, str]) -> tuple[Agent, list[dict[str, Batch]]]:
    specs = [EnvSpec("mw", 6, 2, 3), EnvSpec("fk", 8, 3, 2)]
    agent = Agent(specs, AgentConfig(architecture="seal", **SMALL, **options), seed=5)
    return agent, [seal_batches(specs, i) for i in range(UPDATES)]


def build(run: str) -> tuple[Agent, list[dict[str, Batch]]]:
    return point_run() if run == "point" else seal_run(SEAL_RUNS[run])


def differences(agent: Agent, batches: list[dict[str, Batch]]) -> list[str]:
    """What differs, bit for bit, between `agent.update` and the reference on `batches`: each
    update's logged scalars, then every parameter, target parameter and temperature."""
    reference = ReferenceSAC(agent)
    out = []
    for i, batch in enumerate(batches):
        got, want = agent.update(batch), reference.update(batch)
        assert sorted(got) == sorted(want), (sorted(got), sorted(want))
        out += [f"update {i}: {k} {got[k]!r} != {want[k]!r}" for k in want if got[k] != want[k]]
    ref = reference.agent
    for role in ("actor", "critic", "critic_target", "log_alpha"):
        mine, theirs = getattr(agent, role).state_dict(), getattr(ref, role).state_dict()
        out += [f"{role}.{k}" for k in theirs if not torch.equal(mine[k], theirs[k])]
    return out


@pytest.mark.parametrize("run", ["point", *SEAL_RUNS])
def test_update_is_bitwise_the_reference(run: str) -> None:
    agent, batches = build(run)
    assert differences(agent, batches) == []
    # ... and the agent learnt something: the runs are not vacuous
    first = ReferenceSAC(build(run)[0]).agent
    moved = [
        k
        for k, v in agent.actor.state_dict().items()
        if not torch.equal(v, first.actor.state_dict()[k])
    ]
    assert moved


def test_a_reordered_sum_fails_the_comparison(monkeypatch: pytest.MonkeyPatch) -> None:
    """mean(alpha * log_pi - min_q) written as mean(alpha * log_pi) - mean(min_q): equal in exact
    arithmetic, not in float32, and the comparison must say so."""

    def reordered(policy, qf, obs, task_ids, alpha, noise):
        pi, log_pi = tanh_gaussian(policy(obs), noise)
        min_qf_pi = qf(obs, pi).amin(0)
        return (alpha[task_ids] * log_pi).mean() - min_qf_pi.mean(), log_pi

    monkeypatch.setattr(update_module, "actor_loss", reordered)
    agent, batches = build("seal-weighted")
    assert any("losses/" in d for d in differences(agent, batches))
