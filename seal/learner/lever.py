"""The ratio lever: how much of the shared policy trunk's step each environment causes.

Measured off the hot path on copies of the agent: Δ is the trunk's change under one
`seal.learner.update.sac_update`, Δ₋X the change under the same update without env X's batch
(the same noise draws for every other env, X's samples still counted in N, so every other env's
weight n_i / N is Δ's). `Agent.update` measures it every `AgentConfig.ratio_lever_interval`
updates; `seal bench --only ratio_lever` reports it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Protocol, TypedDict

import numpy as np
import torch

from seal.errors import SealError
from seal.learner.config import Batch
from seal.learner.losses import actor_loss
from seal.learner.networks import TaskNetwork
from seal.learner.update import (
    EnvInputs,
    Learner,
    batch_shares,
    draw_noise,
    policy_noise,
    sac_update,
)
from seal.seeding import derive_seed


class Measured(Learner, Protocol):
    """What the lever reads of an agent besides what an update does."""

    seed: int
    num_updates: int
    actor: TaskNetwork

    def clone(self) -> Measured: ...
    def inputs(self, batches: Mapping[str, Batch]) -> dict[str, EnvInputs]: ...


class RatioLever(TypedDict):
    """`ratio_lever`'s measurement (see its docstring)."""

    lever: float
    env: str
    share: float
    step_norm: float
    effect: dict[str, float]
    grad_norm: dict[str, float]


class RatioLeverExpected(TypedDict):
    """`ratio_lever_expected`'s measurement (see its docstring)."""

    lever: float
    env: str
    share: float
    draws: int
    step_norm: float
    effect: dict[str, float]
    single_draw_lever_mean: float


def _lever_effects(steps: Mapping[str | None, torch.Tensor]) -> dict[str, float]:
    """||Δ - Δ₋X|| for every X of `Agent._trunk_steps`' steps (Δ under the key None)."""
    return {n: float((steps[None] - step).norm()) for n, step in steps.items() if n is not None}


def _lever(effect: Mapping[str, float], env_a: str) -> float:
    """||Δ - Δ₋A|| / sum_X ||Δ - Δ₋X|| (NaN when no env moves the trunk)."""
    total = sum(effect.values())
    return effect[env_a] / total if total > 0 else float("nan")


def _lever(effect: Mapping[str, float], env_a: str) -> float:
    """||Δ - Δ₋A|| / sum_X ||Δ - Δ₋X|| (NaN when no env moves the trunk)."""
    total = sum(effect.values())
    return effect[env_a] / total if total > 0 else float("nan")


def _lever_envs(agent: Measured, batches: Mapping[str, Batch]) -> tuple[dict[str, int], str]:
    """(samples of each env with samples, in spec order; A = the env with the most samples)."""
    sizes = {
        n: batches[n].obs.shape[0] for n in agent.specs if n in batches and batches[n].obs.shape[0]
    }
    if len(sizes) < 2:
        raise SealError(f"ratio_lever needs batches of >= 2 envs, got {sorted(sizes)}")
    first = max(sizes.values())
    return sizes, next(n for n in sizes if sizes[n] == first)


def _trunk_steps(
    agent: Measured,
    batches: Mapping[str, Batch],
    drops: Sequence[str],
    noise_seed: int | None = None,
) -> dict[str | None, torch.Tensor]:
    """Δ (key None) and Δ₋X for X in `drops`: the shared policy trunk's parameter change of one
    `sac_update` on a fresh copy of the agent each (clipping and Adam included), flattened.

    The copies share the agent's update noise stream, so Δ and every Δ₋X draw the same noise;
    `noise_seed` reseeds that stream in every copy first. The agent is unchanged.
    """
    before = [p.detach().clone() for p in agent.actor.trunk.parameters()]
    steps: dict[str | None, torch.Tensor] = {}
    for drop in (None, *drops):
        clone = agent.clone()
        if noise_seed is not None:
            for name, generator in clone.update_generators.items():
                generator.manual_seed(derive_seed(noise_seed, name))
        inputs = clone.inputs(batches)
        weights = batch_shares(inputs)  # X's samples stay in N
        noise = draw_noise(clone, inputs)  # X's draws too: every other env's noise is Δ's
        sac_update(clone, {n: env for n, env in inputs.items() if n != drop}, noise, weights)
        steps[drop] = torch.cat(
            [
                (p.detach() - b).flatten()
                for p, b in zip(clone.actor.trunk.parameters(), before, strict=True)
            ]
        )
    return steps


def ratio_lever(agent: Measured, batches: Mapping[str, Batch]) -> RatioLever:
    """How much of the shared policy trunk's step each env causes, measured on copies of the agent.

    Δ = the trunk's parameter change of one full update (clipping and Adam included); Δ₋X =
    the same update without env X's batch (X's samples still in N, X's noise still drawn). For
    A the env with the most samples, lever = ||Δ - Δ₋A|| / sum_X ||Δ - Δ₋X|| (two envs:
    ||Δ - Δ₋A|| / (||Δ - Δ₋A|| + ||Δ - Δ₋B||)); ~n_A / N means the ratio is the lever it
    should be, ~0.5 at 90/10 means it is not. Also returns the trunk gradient norm of each
    env's own mean actor loss at the current parameters (`grad_norm`). The agent is unchanged.
    """
    sizes, env_a = _lever_envs(agent, batches)
    steps = _trunk_steps(agent, batches, list(sizes))
    effect = _lever_effects(steps)
    clone = agent.clone()
    grad_norm = {}
    inputs = clone.inputs(batches)
    for name, (batch, alpha, obs_in, _) in inputs.items():
        noise = policy_noise(clone, name, inputs[name])
        ids = batch.task_ids
        loss, _ = actor_loss(
            clone.policy(name, ids), clone.qf(name, ids), obs_in, ids, alpha, noise
        )
        trunk = list(clone.actor.trunk.parameters())
        grads = torch.autograd.grad(loss, trunk, allow_unused=True)
        flat = [g.flatten() for g in grads if g is not None]
        grad_norm[name] = float(torch.linalg.vector_norm(torch.cat(flat))) if flat else 0.0
    return {
        "lever": _lever(effect, env_a),
        "env": env_a,
        "share": sizes[env_a] / sum(sizes.values()),
        "step_norm": float(steps[None].norm()),
        "effect": effect,
        "grad_norm": grad_norm,
    }


def ratio_lever_expected(
    agent: Measured, batch_draws: Sequence[Mapping[str, Batch]]
) -> RatioLeverExpected:
    """`ratio_lever` of the expected steps: batch noise averaged out before the norms are taken.

    For each of the K = len(batch_draws) draws (independent batches with the same env sizes),
    Δ and Δ₋X are taken as `ratio_lever` takes them (`_trunk_steps`), every draw from this
    agent's current state (fresh copies: parameters and optimiser states do not move between
    draws). With E the mean over the K draws, for A the env with the most samples,
        lever = ||E[Δ] - E[Δ₋A]|| / sum_X ||E[Δ] - E[Δ₋X]||
    (two envs: ||E[Δ] - E[Δ₋A]|| / (||E[Δ] - E[Δ₋A]|| + ||E[Δ] - E[Δ₋B]||)).
    Chosen: the mean over independent minibatches, not each env's gradient over its whole
    replay, so that every step averaged is the optimiser's own step on a training-sized batch.
    Draw k reseeds the copies' policy noise (k-th seed of SeedSequence((seed, num_updates))),
    so that noise averages out too; within a draw Δ and Δ₋X share it. Also returns the mean
    over draws of the single-draw (`ratio_lever`-style) levers, for comparison.
    """
    if not batch_draws:
        raise SealError("ratio_lever_expected needs at least one batch draw, got 0")
    sizes, env_a = _lever_envs(agent, batch_draws[0])
    for k, draw in enumerate(batch_draws):
        draw_sizes = _lever_envs(agent, draw)[0]
        if draw_sizes != sizes:
            raise SealError(
                f"ratio_lever_expected: batch draw {k} has env sizes {draw_sizes}, "
                f"draw 0 has {sizes}; every draw needs the same sizes"
            )
    seeds = np.random.SeedSequence((agent.seed, agent.num_updates)).generate_state(
        len(batch_draws), np.uint32
    )
    sums: dict[str | None, torch.Tensor] = {}
    single: list[float] = []
    for draw, seed in zip(batch_draws, seeds.tolist(), strict=True):
        steps = _trunk_steps(agent, draw, list(sizes), noise_seed=seed)
        for key, step in steps.items():
            sums[key] = sums[key] + step if key in sums else step
        single.append(_lever(_lever_effects(steps), env_a))
    means = {key: total / len(batch_draws) for key, total in sums.items()}
    effect = _lever_effects(means)
    return {
        "lever": _lever(effect, env_a),
        "env": env_a,
        "share": sizes[env_a] / sum(sizes.values()),
        "draws": len(batch_draws),
        "step_norm": float(means[None].norm()),
        "effect": effect,
        "single_draw_lever_mean": float(np.mean(single)),
    }
