"""The reference update: multi-task SAC / SEAL written out plainly, as a second code path.

`seal.learner.update` stages the update for speed (pre-drawn noise, losses and gradients as one
function per stage, a fused Adam call, foreach clipping, one stacked Polyak step). This module
computes the same update the way cleanrl's sac_continuous_action.py writes it: forward, `backward()`,
`nn.utils.clip_grad_norm_`, `torch.optim.Adam.step()`, noise drawn where it is used. It uses the
agent's networks (what is learnt) but none of its update machinery or optimisers, so running both
paths from one agent state in one process checks the staged update bit for bit on any CPU (a
stored float holds only on the CPU that wrote it). What the reference must share with the update,
because it is the update's definition rather than its implementation: the loss formulas of
SEAL §3.3 (twin critics' mean, per-task temperatures, sum_i (n_i / N) L_i under "weighted"), the
order critic, actor, temperature, target, and the Polyak step as torch's lerp.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping

import torch
import torch.nn.functional as F
from torch import nn

from seal.learner import Agent, Batch
from seal.learner.networks import tanh_gaussian


def _unique(params: list[nn.Parameter]) -> list[nn.Parameter]:
    seen: set[int] = set()
    return [p for p in params if not (id(p) in seen or seen.add(id(p)))]


class ReferenceSAC:
    """A deep copy of `agent`'s networks and temperatures, updated by `update` with Adams of its own."""

    def __init__(self, agent: Agent) -> None:
        self.agent = copy.deepcopy(agent)
        a, c = self.agent, agent.config
        names = list(a.specs)
        key = {n: a._keys[n] for n in names}

        def adam(params: list[nn.Parameter], lr: float) -> torch.optim.Adam:
            return torch.optim.Adam(_unique(params), lr=lr, eps=c.adam_eps, fused=True)

        def per_env(net: nn.Module) -> dict[str, list[nn.Parameter]]:
            return {n: net.env_parameters(key[n]) for n in names}

        # The policy: one Adam over translators, trunk and heads, or one per env under "per_env".
        actor = per_env(a.actor)
        if c.shared_update == "per_env":
            self.actor_adam = {n: adam(actor[n], c.actor_lr) for n in names}
        else:
            one = adam([p for n in names for p in actor[n]], c.actor_lr)
            self.actor_adam = dict.fromkeys(names, one)
        # The critics: per-env critics share nothing (an Adam each); a shared critic is one Adam
        # unless shared_update is "per_env".
        critic = per_env(a.critic)
        shared_critic = len(names) > 1 and c.critic_sharing == "shared"
        if shared_critic and c.shared_update != "per_env":
            one = adam([p for n in names for p in critic[n]], c.critic_lr)
            self.critic_adam = dict.fromkeys(names, one)
        else:
            self.critic_adam = {n: adam(critic[n], c.critic_lr) for n in names}
        self.alpha_adam = torch.optim.Adam(
            list(a.log_alpha.values()), lr=c.alpha_lr, eps=c.adam_eps, fused=True
        )
        self.key = key

    def _x(self, name: str, obs: torch.Tensor, ids: torch.Tensor) -> torch.Tensor:
        return torch.cat((obs, F.one_hot(ids, self.agent.specs[name].num_tasks).float()), -1)

    def _q(self, net: nn.Module, name: str, x: torch.Tensor, act: torch.Tensor, ids: torch.Tensor):
        act = F.pad(act, (0, self.agent.specs[name].critic_act_dim - act.shape[-1]))
        return net(self.key[name], torch.cat((x, act), -1), ids).squeeze(-1)  # (2, B)

    def _pi(self, name: str, x: torch.Tensor, ids: torch.Tensor):
        a = self.agent
        noise = torch.randn(
            x.shape[0], a.specs[name].act_dim, generator=a.update_generators[name], dtype=x.dtype
        )
        return tanh_gaussian(a.actor(self.key[name], x, ids), noise)

    @staticmethod
    def _step(adams: list[torch.optim.Adam], loss: torch.Tensor, max_norm: float) -> None:
        for adam in adams:
            adam.zero_grad()
        loss.backward()
        for adam in adams:
            params = [p for g in adam.param_groups for p in g["params"] if p.grad is not None]
            if max_norm > 0 and params:
                nn.utils.clip_grad_norm_(params, max_norm)
            adam.step()

    def update(self, batches: Mapping[str, Batch]) -> dict[str, float]:
        """One update of every env in `batches` (spec order); returns `Agent.update`'s scalars."""
        a, c = self.agent, self.agent.config
        names = [n for n in a.specs if n in batches and batches[n].obs.shape[0] > 0]
        total = sum(batches[n].obs.shape[0] for n in names)
        weight = {n: batches[n].obs.shape[0] / total for n in names}
        alpha = {n: a.log_alpha_of(n).detach().exp() for n in names}
        x = {n: self._x(n, batches[n].obs, batches[n].task_ids) for n in names}
        nx = {n: self._x(n, batches[n].next_obs, batches[n].task_ids) for n in names}
        logs: dict[str, float] = {}
        for n in names:
            for t, value in enumerate(alpha[n].tolist()):
                logs[f"charts/{n}/alpha/{t}"] = value
        stages = [names] if c.shared_update == "weighted" else [[n] for n in names]
        for stage in stages:
            # ---- critic
            losses = {}
            for n in stage:
                b, ids = batches[n], batches[n].task_ids
                with torch.no_grad():
                    next_a, next_log_pi = self._pi(n, nx[n], ids)
                    target = self._q(a.critic_target, n, nx[n], next_a, ids).amin(0)
                    target = target - alpha[n][ids] * next_log_pi
                    next_q = b.rewards + (1.0 - b.terminations) * c.gamma * target
                q = self._q(a.critic, n, x[n], b.actions, ids)
                qf1, qf2 = F.mse_loss(q[0], next_q), F.mse_loss(q[1], next_q)
                losses[n] = 0.5 * (qf1 + qf2)
                logs |= {
                    f"losses/{n}/qf1": qf1.item(),
                    f"losses/{n}/qf2": qf2.item(),
                    f"losses/{n}/critic": losses[n].item(),
                    f"charts/{n}/mean_q": q.mean().item(),
                }
            adams = _unique_adams(self.critic_adam[n] for n in stage)
            shared = len(adams) == 1 and len(stage) > 1
            self._step(adams, _combined(losses, weight, shared), c.max_grad_norm)
            # ---- actor, against the critics just stepped
            losses, alpha_losses = {}, {}
            for n in stage:
                ids = batches[n].task_ids
                pi, log_pi = self._pi(n, x[n], ids)
                min_q = self._q(a.critic, n, x[n], pi, ids).amin(0)
                losses[n] = (alpha[n][ids] * log_pi - min_q).mean()
                target_entropy = a.target_entropy[n]
                log_alpha = a.log_alpha_of(n)
                alpha_losses[n] = (-log_alpha[ids] * (log_pi.detach() + target_entropy)).mean()
                logs |= {
                    f"losses/{n}/actor": losses[n].item(),
                    f"losses/{n}/alpha": alpha_losses[n].item(),
                    f"charts/{n}/entropy": -log_pi.mean().item(),
                }
            adams = _unique_adams(self.actor_adam[n] for n in stage)
            shared = len(adams) == 1 and len(stage) > 1
            self._step(adams, _combined(losses, weight, shared), c.max_grad_norm)
            for n in stage:  # the temperatures' gradients wait for their one step below
                alpha_losses[n].backward(inputs=[a.log_alpha_of(n)])
        # ---- temperatures (never clipped), then the Polyak target
        self.alpha_adam.step()
        self.alpha_adam.zero_grad()
        with torch.no_grad():
            for target, online in zip(
                a.critic_target.parameters(), a.critic.parameters(), strict=True
            ):
                target.lerp_(online, c.tau)
        return logs


def _unique_adams(adams) -> list[torch.optim.Adam]:
    out: list[torch.optim.Adam] = []
    for adam in adams:
        if all(adam is not o for o in out):
            out.append(adam)
    return out


def _combined(losses: dict[str, torch.Tensor], weight: dict[str, float], shared: bool):
    """sum_i (n_i / N) L_i when one Adam steps several envs, else sum_i L_i (independent Adams)."""
    terms = [loss * weight[n] if shared else loss for n, loss in losses.items()]
    return terms[0] if len(terms) == 1 else torch.stack(terms).sum()
