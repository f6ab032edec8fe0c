"""One gradient update of multi-task SAC / SEAL: critic, actor, temperature, target, in that order.

`sac_update` is the update, top to bottom, as cleanrl's sac_continuous_action.py writes it; the
losses are `seal.learner.losses`'. How the environments of one update step the shared parameters
(`AgentConfig.shared_update`, SEAL §3.3) is its one branch:

- "weighted": one Adam over the whole policy (and over the whole critic when critics are shared);
  one step on sum_i (n_i / N) L_i, L_i env i's mean loss over its n_i samples, N = sum_i n_i. At a
  90/10 ratio the 90% env carries ~90% of the trunk's gradient.
- "sequential": the same single Adam, stepped once per env on that env's mean loss, env after env
  (critic then actor for env 1, then env 2, ...): the authors' prototype.
- "per_env": one Adam per env over its translator, the shared trunk and its head (SEAL §3.3:
  "optimizer i is operating on f_theta_i, g_phi_i and pi_eta"), stepped env after env. Adam is
  invariant to a loss's scale, so the data ratio then changes only gradient noise.

Per-env critics (`critic_sharing = "per_env"`) share nothing, so each has its own Adam stepped on
its own mean loss in every mode. Every actor and critic step clips the global gradient norm of that
optimiser's parameters to `max_grad_norm` (0: off); the temperatures' Adam is never clipped.

With `AgentConfig.gradient = "pcgrad"` (one env) the critic's and the actor's gradients on the
shared parameters are PCGrad's (`seal.learner.mtrl.pcgrad`: one backward pass per task of the
env, each on that task's share of the batch's mean loss, then the surgery), the per-task heads
take the plain gradient, and the clipping above applies to the result; the temperature's is as
ever.

Each stage (`critic_stage`, then `actor_stage`) computes its losses and their gradients as one
function of pre-drawn policy noise (`draw_noise`); with `AgentConfig.compile` that function is
torch.compiled (`seal.learner.staging`), and the optimiser steps (`seal.learner.optim`) stay eager.

What comes from where: cleanrl's sac_continuous_action.py gives the order (critic, then the actor
against the critic just updated, then the temperature, then the Polyak target) and the names;
LeanRL's torchcompile version gives the split into a critic and a policy function, each compiled
whole (losses, backward) and replayed as a CUDA graph, the target update as one `lerp_` over
stacked parameters, and no `.item()` inside the update; metaworld-algorithms' mtsac.py gives the
per-task log temperature, the mean over the twin critics' losses, the gradient clipping as part of
each network's optimiser and an unclipped temperature optimiser.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import NamedTuple, Protocol

import torch
from torch import nn

from seal.learner.config import AgentConfig, Batch, EnvSpec
from seal.learner.losses import CriticLoss, Policy, TwinQ, actor_loss, alpha_loss, critic_loss
from seal.learner.mtrl.pcgrad import pcgrad
from seal.learner.optim import AdamCache, Slots, fused_adam_step
from seal.learner.staging import Stages, mark_step


class EnvInputs(NamedTuple):
    """What both stages read of one env: its batch, its tasks' temperatures (detached) and the
    actor's inputs (observations with the one-hot appended) of `obs` and `next_obs`."""

    batch: Batch
    alpha: torch.Tensor
    obs: torch.Tensor
    next_obs: torch.Tensor


class PolicyNoise(NamedTuple):
    """One env's standard normal policy noise (B, act_dim): the critic target's next actions,
    then the actor loss's actions."""

    critic: torch.Tensor
    actor: torch.Tensor


class ActorTerms(NamedTuple):
    """`actor_stage`'s losses of one env (detached)."""

    actor_loss: torch.Tensor
    log_pi: torch.Tensor
    alpha_loss: torch.Tensor


class CriticStage(NamedTuple):
    """Critic losses of the stage's envs (detached) and the critic Adams' gradients; under
    gradient = "pcgrad" the number of projections PCGrad made."""

    terms: dict[str, CriticLoss]
    grads: tuple[torch.Tensor | None, ...]
    conflicts: torch.Tensor | None = None


class ActorStage(NamedTuple):
    """Actor and temperature losses (detached), the actor Adams' gradients and each env's
    log_alpha gradient (in the stage's order)."""

    terms: dict[str, ActorTerms]
    grads: tuple[torch.Tensor | None, ...]
    alpha_grads: tuple[torch.Tensor | None, ...]
    conflicts: torch.Tensor | None = None  # gradient = "pcgrad": projections PCGrad made


class Learner(Protocol):
    """What an update reads and steps (`seal.learner.sac.Agent` is one)."""

    config: AgentConfig
    specs: dict[str, EnvSpec]
    device: torch.device
    target_entropy: dict[str, float]
    actor_slots: Slots
    critic_slots: Slots
    alpha_optimizer: torch.optim.Adam
    adam_cache: AdamCache
    stages: Stages
    update_generators: dict[str, torch.Generator]
    pcgrad_generators: dict[str, torch.Generator]  # gradient = "pcgrad": each env's orders

    def policy(self, name: str, task_ids: torch.Tensor) -> Policy: ...
    def qf(self, name: str, task_ids: torch.Tensor) -> TwinQ: ...
    def qf_target(self, name: str, task_ids: torch.Tensor) -> TwinQ: ...
    def log_alpha_of(self, name: str) -> nn.Parameter: ...
    def alpha_position(self, name: str) -> int: ...
    def polyak_pairs(self) -> tuple[list[nn.Parameter], list[nn.Parameter]]: ...


def stages_of(names: list[str], shared_update: str) -> list[list[str]]:
    """The envs stepped together: all at once under "weighted", else one after another."""
    return [names] if shared_update == "weighted" else [[n] for n in names]


def batch_shares(inputs: Mapping[str, EnvInputs]) -> dict[str, float]:
    """n_i / N of every env: its share of the update's samples."""
    total = sum(env.batch.obs.shape[0] for env in inputs.values())
    return {name: env.batch.obs.shape[0] / total for name, env in inputs.items()}


def draw_noise(learner: Learner, inputs: Mapping[str, EnvInputs]) -> dict[str, PolicyNoise]:
    """The update's policy noise from each env's `learner.update_generators`, in the order the update uses it
    (stage by stage: the critic's of the stage's envs, then the actor's)."""
    drawn: dict[str, dict[str, torch.Tensor]] = {name: {} for name in inputs}
    for stage in stages_of(list(inputs), learner.config.shared_update):
        for role in ("critic", "actor"):
            for name in stage:
                drawn[name][role] = policy_noise(learner, name, inputs[name])
    return {name: PolicyNoise(**noise) for name, noise in drawn.items()}


def policy_noise(learner: Learner, name: str, env: EnvInputs) -> torch.Tensor:
    """One draw of standard normal noise (B, act_dim) for env `name`'s batch."""
    return torch.randn(
        env.batch.obs.shape[0],
        learner.specs[name].act_dim,
        generator=learner.update_generators[name],
        device=learner.device,
        dtype=env.obs.dtype,
    )


def sac_update(
    learner: Learner,
    inputs: Mapping[str, EnvInputs],
    noise: Mapping[str, PolicyNoise],
    weights: Mapping[str, float],
) -> list[torch.Tensor]:
    """One update of every env in `inputs` (with `weights` n_i / N); returns each env's logged
    scalars (the names `Agent.update` logs) then its temperatures, env after env."""
    mark_step(learner.stages.compiled, learner.device)
    sizes = tuple((name, env.batch.obs.shape[0]) for name, env in inputs.items())
    scalars: list[torch.Tensor] = []
    alpha_grads: list[torch.Tensor | None] = [None] * len(
        learner.alpha_optimizer.param_groups[0]["params"]
    )
    # "weighted": all envs in one stage, on sum_i (n_i / N) L_i; else one stage per env (SEAL §3.3)
    for stage in stages_of(list(inputs), learner.config.shared_update):
        key = (tuple(stage), sizes, tuple(sorted(weights.items())))
        # ---- critic: twin soft Q losses, one step of the stage's critic Adams
        critic = learner.stages.run(critic_stage, key, learner, stage, inputs, noise, weights)
        learner.critic_slots.step(stage, critic.grads, learner.adam_cache)

        # ---- actor and temperature losses: with the critic just updated, as in cleanrl
        actor = learner.stages.run(actor_stage, key, learner, stage, inputs, noise, weights)
        learner.actor_slots.step(stage, actor.grads, learner.adam_cache)
        for name, grad in zip(stage, actor.alpha_grads, strict=True):
            alpha_grads[learner.alpha_position(name)] = grad
        for name in stage:
            scalars.append(_logged(critic.terms[name], actor.terms[name]))
            if critic.conflicts is not None and actor.conflicts is not None:
                conflicts = torch.stack((critic.conflicts, actor.conflicts))
                scalars.append(conflicts.to(inputs[name].alpha.dtype))
            scalars.append(inputs[name].alpha)

    # ---- temperature: one step for every env's log_alpha, after all stages
    if any(g is not None for g in alpha_grads):
        fused_adam_step([learner.alpha_optimizer], alpha_grads, learner.adam_cache)
        if learner.config.min_alpha > 0:
            with torch.no_grad():
                torch._foreach_clamp_min_(
                    learner.alpha_optimizer.param_groups[0]["params"],
                    math.log(learner.config.min_alpha),
                )

    # ---- target critics: Polyak averaging in place
    with torch.no_grad():
        torch._foreach_lerp_(*learner.polyak_pairs(), learner.config.tau)
    return scalars


def _logged(critic: CriticLoss, actor: ActorTerms) -> torch.Tensor:
    """One env's logged scalars, in the order of `Agent.update`'s names."""
    qf1, qf2, qf_a_values = critic
    return torch.stack(
        (
            qf1,
            qf2,
            0.5 * (qf1 + qf2),
            actor.actor_loss,
            actor.alpha_loss,
            qf_a_values.mean(),
            -actor.log_pi.mean(),
        )
    )


def _total(
    losses: Mapping[str, torch.Tensor], weights: Mapping[str, float], weighted: bool
) -> torch.Tensor:
    """sum_i w_i L_i when one Adam steps several envs under "weighted", else sum_i L_i (one env,
    or independent critics whose Adams share no parameter)."""
    if weighted:
        terms = [loss if weights[n] == 1.0 else loss * weights[n] for n, loss in losses.items()]
    else:
        terms = list(losses.values())
    return terms[0] if len(terms) == 1 else torch.stack(terms).sum()


def _weighted(learner: Learner, slots: Slots) -> bool:
    return learner.config.shared_update == "weighted" and slots.shared


def critic_stage(
    learner: Learner,
    stage: Sequence[str],
    inputs: Mapping[str, EnvInputs],
    noise: Mapping[str, PolicyNoise],
    weights: Mapping[str, float],
) -> CriticStage:
    """Critic losses of the envs of `stage` and the gradients of the critic Adams they use."""
    surgery = learner.config.gradient == "pcgrad"
    per_sample = {"reduce": False} if surgery else {}  # PCGrad takes each sample's loss
    terms = {}
    for name in stage:
        batch, alpha, obs, next_obs = inputs[name]
        ids = batch.task_ids
        terms[name] = critic_loss(
            learner.qf(name, ids),
            learner.qf_target(name, ids),
            learner.policy(name, ids),
            batch,
            obs,
            next_obs,
            alpha,
            noise[name].critic,
            learner.config.gamma,
            **per_sample,
        )
    # Mean over the twin critics, as metaworld-algorithms, the prototype and SB3: with
    # max_grad_norm the loss's scale sets how often clipping bites, so it must match.
    losses = {n: 0.5 * (t.qf1_loss + t.qf2_loss) for n, t in terms.items()}
    conflicts = None
    if surgery:
        grads, conflicts = _pcgrad_grads(learner, learner.critic_slots, stage, inputs, losses)
        terms = {
            n: CriticLoss(t.qf1_loss.mean(), t.qf2_loss.mean(), t.qf_a_values)
            for n, t in terms.items()
        }
    else:
        loss = _total(losses, weights, _weighted(learner, learner.critic_slots))
        grads = learner.critic_slots.grads(loss, stage)
    detached = {n: CriticLoss(*(x.detach() for x in t)) for n, t in terms.items()}
    return CriticStage(detached, grads, conflicts)


def actor_stage(
    learner: Learner,
    stage: Sequence[str],
    inputs: Mapping[str, EnvInputs],
    noise: Mapping[str, PolicyNoise],
    weights: Mapping[str, float],
) -> ActorStage:
    """Actor and temperature losses of `stage`'s envs, the actor Adams' gradients and the gradient
    of each env's log_alpha."""
    surgery = learner.config.gradient == "pcgrad"
    per_sample = {"reduce": False} if surgery else {}  # PCGrad takes each sample's loss
    terms = {}
    for name in stage:
        batch, alpha, obs, _ = inputs[name]
        ids = batch.task_ids
        loss, log_pi = actor_loss(
            learner.policy(name, ids),
            learner.qf(name, ids),
            obs,
            ids,
            alpha,
            noise[name].actor,
            **per_sample,
        )
        log_alpha = learner.log_alpha_of(name)
        terms[name] = (
            loss,
            log_pi,
            alpha_loss(log_alpha, ids, log_pi, learner.target_entropy[name]),
        )
    conflicts = None
    if surgery:
        losses = {n: t[0] for n, t in terms.items()}
        grads, conflicts = _pcgrad_grads(learner, learner.actor_slots, stage, inputs, losses)
        terms = {n: (t[0].mean(), *t[1:]) for n, t in terms.items()}
    else:
        loss = _total(
            {n: t[0] for n, t in terms.items()}, weights, _weighted(learner, learner.actor_slots)
        )
        grads = learner.actor_slots.grads(loss, stage)
    temperature = torch.stack([terms[n][2] for n in stage]).sum()
    alpha_grads = torch.autograd.grad(temperature, [learner.log_alpha_of(n) for n in stage])
    detached = {n: ActorTerms(*(x.detach() for x in t)) for n, t in terms.items()}
    return ActorStage(detached, grads, alpha_grads, conflicts)


def _pcgrad_grads(
    learner: Learner,
    slots: Slots,
    stage: Sequence[str],
    inputs: Mapping[str, EnvInputs],
    losses: Mapping[str, torch.Tensor],
) -> tuple[tuple[torch.Tensor | None, ...], torch.Tensor]:
    """gradient = "pcgrad": the gradients of the slots `stage` uses from its one env's per-sample
    losses (B,), clipped as `Slots.grads`', and the number of projections PCGrad made.

    Task t's row is the gradient of its share of the batch's mean loss, sum over its samples / N,
    on the shared parameters (one backward pass per task; a task without samples has a zero row);
    the rows' surgered sum steps them. The per-task parameters take the gradient of the sum of
    the shares, which is the mean loss: with no conflict everything is the "mean" gradient."""
    (name,) = stage  # one env (seal.learner.mtrl.pcgrad.check_config)
    per_sample, task_ids = losses[name], inputs[name].batch.task_ids
    num_tasks = learner.specs[name].num_tasks
    shares = per_sample.new_zeros(num_tasks).index_add(0, task_ids, per_sample)
    shares = shares / per_sample.shape[0]
    params, per_task = slots.parameters_of(stage), slots.per_task_of(stage)
    shared = [i for i, flag in enumerate(per_task) if not flag]
    heads = [i for i, flag in enumerate(per_task) if flag]
    rows = [
        torch.autograd.grad(
            shares[t], [params[i] for i in shared], retain_graph=True, allow_unused=True
        )
        for t in range(num_tasks)
    ]
    # A parameter outside the loss's graph is outside every task's (one graph): it rests, as in
    # "mean" (its gradient None).
    used = [k for k, g in enumerate(rows[0]) if g is not None]
    grads: list[torch.Tensor | None] = [None] * len(params)
    conflicts = torch.zeros((), dtype=torch.int64, device=per_sample.device)
    if used:
        flat = torch.stack([torch.cat([row[k].reshape(-1) for k in used]) for row in rows])
        step, conflicts = pcgrad(flat, learner.pcgrad_generators[name])
        sizes = [params[shared[k]].numel() for k in used]
        for k, part in zip(used, step.split(sizes), strict=True):
            grads[shared[k]] = part.view_as(params[shared[k]])
    if heads:
        head_grads = torch.autograd.grad(
            shares.sum(), [params[i] for i in heads], allow_unused=True
        )
        for i, grad in zip(heads, head_grads, strict=True):
            grads[i] = grad
    return slots.clip(grads, stage), conflicts
