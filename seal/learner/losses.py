"""The SAC losses of one environment's batch, as the papers write them.

SAC (Haarnoja et al. 2018, with the twin critics and the learnt temperature of the applications
paper), in cleanrl's names; MTMHSAC and SEAL (§3.3) keep one temperature per task, so alpha and
log_alpha are indexed by each sample's task id t:

    a', log_pi(a'|s')  ~ pi(. | s')                                  (no gradient)
    min_qf_next_target = min(qf1_target, qf2_target)(s', a') - alpha_t * log_pi(a'|s')
    next_q_value       = r + gamma * (1 - termination) * min_qf_next_target
    qf1_loss, qf2_loss = mse(qf1(s, a), next_q_value), mse(qf2(s, a), next_q_value)
    actor_loss         = mean(alpha_t * log_pi(a~|s) - min(qf1, qf2)(s, a~)),  a~ ~ pi(. | s)
    alpha_loss         = mean(-log_alpha_t * (log_pi(a~|s) + target_entropy))  (log_pi detached)

The temperature loss uses log_alpha rather than alpha, as garage's MTSAC (the Meta-World MTMHSAC)
and stable-baselines3 do: the same sign of gradient as cleanrl's alpha form, and Adam makes the
scale immaterial. Policy noise is drawn outside (`noise`, standard normal (B, act_dim)), so each
loss is a pure function of its inputs. `policy(s)` is the actor's (B, 2 * act_dim) mean and log
std of each row's task; `qf(s, a)` and `qf_target(s, a)` are the twin critics' (2, B) values.
How the environments' losses are combined into steps is `seal.learner.update`'s business.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import torch
import torch.nn.functional as F

from seal.learner.config import Batch
from seal.learner.networks import tanh_gaussian

Policy = Callable[[torch.Tensor], torch.Tensor]
"""obs -> (B, 2 * act_dim) tanh-Gaussian mean and log std, each row at its task's head."""
TwinQ = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
"""(obs, actions) -> (2, B): qf1 and qf2, each row at its task's head."""


class CriticLoss(NamedTuple):
    """`critic_loss`'s terms: the twin losses and the (2, B) values they were taken of."""

    qf1_loss: torch.Tensor
    qf2_loss: torch.Tensor
    qf_a_values: torch.Tensor


def critic_loss(
    qf: TwinQ,
    qf_target: TwinQ,
    policy: Policy,
    batch: Batch,
    obs: torch.Tensor,
    next_obs: torch.Tensor,
    alpha: torch.Tensor,
    noise: torch.Tensor,
    gamma: float,
    reduce: bool = True,
) -> CriticLoss:
    """The twin soft Q losses of `batch` (obs / next_obs: the actor's inputs of its observations);
    with `reduce` False each sample's squared errors (B,) instead of their means (PCGrad's task
    losses, `seal.learner.mtrl.pcgrad`)."""
    with torch.no_grad():
        next_state_actions, next_state_log_pi = tanh_gaussian(policy(next_obs), noise)
        qf_next_target = qf_target(next_obs, next_state_actions)
        min_qf_next_target = qf_next_target.amin(0) - alpha[batch.task_ids] * next_state_log_pi
        next_q_value = batch.rewards + (1.0 - batch.terminations) * gamma * min_qf_next_target
    qf_a_values = qf(obs, batch.actions)
    qf1_a_values, qf2_a_values = qf_a_values
    reduction = "mean" if reduce else "none"
    qf1_loss = F.mse_loss(qf1_a_values, next_q_value, reduction=reduction)
    qf2_loss = F.mse_loss(qf2_a_values, next_q_value, reduction=reduction)
    return CriticLoss(qf1_loss, qf2_loss, qf_a_values)


def actor_loss(
    policy: Policy,
    qf: TwinQ,
    obs: torch.Tensor,
    task_ids: torch.Tensor,
    alpha: torch.Tensor,
    noise: torch.Tensor,
    reduce: bool = True,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The policy loss against the critics just updated (with `reduce` False each sample's (B,)
    instead of their mean), and the log-probabilities it sampled."""
    pi, log_pi = tanh_gaussian(policy(obs), noise)
    min_qf_pi = qf(obs, pi).amin(0)
    loss = alpha[task_ids] * log_pi - min_qf_pi
    return (loss.mean() if reduce else loss), log_pi


def alpha_loss(
    log_alpha: torch.Tensor, task_ids: torch.Tensor, log_pi: torch.Tensor, target_entropy: float
) -> torch.Tensor:
    """The temperature loss: each task's log_alpha towards the environment's target entropy."""
    return (-log_alpha[task_ids] * (log_pi.detach() + target_entropy)).mean()
