"""Soft Modularization (Yang et al., NeurIPS 2020), for one actor or critic.

A base network of L layers of n modules (each a Dense of width d, agent.soft_width) and a routing
network that, from the task and the observation, gives each sample a soft choice of modules:
layer l's outputs are mixed by probabilities p_l (B, n, n), a softmax over the last axis, so
module i of layer l+1 takes sum_j p_l[i, j] * module_j(x) of layer l. The observation embedding
f(s) and the task embedding z(task) are D wide (agent.soft_embedding); the routing network
multiplies them into the task embedding, then each routing layer turns it, gated by the earlier
layers' probabilities, into the next probabilities.

From metaworld-algorithms' nn/soft_modules.py, which follows the official code where it departs
from the paper (its NOTE 1-6), and here:
- NOTE 1: z(task) * f(s) passes ReLU and one more MLP (Dense(D, d), ReLU, Dense(d, d)) before the
  routing layers, so the routing network is d wide, not D.
- NOTE 2: the observation embedding is activated (ReLU) before it enters layer 0's modules.
- NOTE 3: routing layer l > 0 is gated by all earlier layers' flattened probabilities concatenated
  (skip connections), Dense(l * n * n, d), not by p_{l-1} alone.
- NOTE 4: ReLU follows the weighted sum of the module outputs, not each module (paper Eq. 8).
- NOTE 5: the last layer has its own routing layer with n outputs: the output embedding is the
  p_L-weighted sum of its n module outputs, then ReLU and the output Dense(d, out_dim).
- NOTE 6 (softmax over log alpha, times the number of tasks) concerns the SAC temperatures, not the
  network: left out, the agent keeps its own per-task temperatures.
Also as there: f is an MLP with one hidden layer (Dense(in, h), ReLU, Dense(h, D), no activation
on its output before z * f), whose hidden width h is flax's MLP default 400; here h = D, the same
at the default D = 400. z is a Dense over the one-hot task id (the `Embedding` table plus bias).
Each routing layer's logits come from a Dense drawn U(+-1e-3) with zero bias, under either init,
so the first routing is near uniform. With layer_norm (a critic's agent.critic_layer_norm) a
LayerNorm follows each module layer's mix (the last layer's weighted sum included), before its
ReLU.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from seal.learner.config import AgentConfig
from seal.learner.mtrl.layers import Dense, Embedding

ROUTING_BOUND = 1e-3
"""U(+-ROUTING_BOUND) for the routing logits' kernels (metaworld-algorithms' uniform(1e-3))."""


class SoftModular(nn.Module):
    """(B, in_dim) inputs and (B,) task ids -> (B, out_dim); see the module docstring."""

    def __init__(
        self,
        in_dim: int,
        out_dim: int,
        num_tasks: int,
        config: AgentConfig,
        layer_norm: bool = False,
    ) -> None:
        super().__init__()
        n, depth = config.soft_modules, config.soft_layers
        width, embed = config.soft_width, config.soft_embedding
        self.num_modules, self.depth = n, depth
        # The observation embedding f and the task embedding z, both D wide.
        self.f_hidden = Dense(in_dim, embed)
        self.f_out = Dense(embed, embed)
        self.z = Embedding(num_tasks, embed)
        # NOTE 1: ReLU(z * f) -> Dense(D, d) -> ReLU -> Dense(d, d).
        self.task_hidden = Dense(embed, width)
        self.task_out = Dense(width, width)
        # The base network: layer l's n modules, D wide in at l = 0, d wide in after.
        self.layers = nn.ModuleList(
            Dense(embed if i == 0 else width, width, members=n) for i in range(depth)
        )
        # The routing network: gates from the earlier probabilities (none for layer 0; NOTE 3)
        # and logits, n * n per layer, n for the last (NOTE 5).
        self.gates = nn.ModuleList(Dense(i * n * n, width) for i in range(1, depth))
        self.logits = nn.ModuleList(
            Dense(width, n if i == depth - 1 else n * n) for i in range(depth)
        )
        self.norms = nn.ModuleList(nn.LayerNorm(width) for _ in range(depth if layer_norm else 0))
        self.out = Dense(width, out_dim)

    def reset_parameters(
        self, generator: torch.Generator, init: str, head_bound: float | None
    ) -> None:
        """Draw f, z's table, the task MLP, then each layer's modules, gate and logits in order;
        the logits U(+-ROUTING_BOUND) with zero bias, the output layer with head_bound."""
        for layer in (self.f_hidden, self.f_out):
            layer.reset_parameters(generator, init)
        self.z.reset_parameters(generator, init)
        for layer in (self.task_hidden, self.task_out):
            layer.reset_parameters(generator, init)
        for i in range(self.depth):
            self.layers[i].reset_parameters(generator, init)
            if i > 0:
                self.gates[i - 1].reset_parameters(generator, init)
            logits = self.logits[i]
            with torch.no_grad():
                logits.weight.uniform_(-ROUTING_BOUND, ROUTING_BOUND, generator=generator)
                logits.bias.zero_()
        for norm in self.norms:
            norm.reset_parameters()
        self.out.reset_parameters(generator, init, head_bound)

    def _embed(self, x: torch.Tensor, task_ids: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The activated observation embedding (B, D) (NOTE 2) and the task embedding (B, d)."""
        obs = self.f_out(F.relu(self.f_hidden(x)))
        task = F.relu(self.z(task_ids) * obs)
        task = self.task_out(F.relu(self.task_hidden(task)))  # NOTE 1
        return F.relu(obs), task

    def _route(self, i: int, task: torch.Tensor, earlier: list[torch.Tensor]) -> torch.Tensor:
        """Layer i's probabilities: (B, n, n) softmax over the last axis, (B, n) for the last."""
        if i > 0:  # NOTE 3: gated by every earlier layer's flattened probabilities
            task = task * self.gates[i - 1](torch.cat(earlier, dim=-1))
        logits = self.logits[i](F.relu(task))
        if i < self.depth - 1:
            logits = logits.unflatten(-1, (self.num_modules, self.num_modules))
        return torch.softmax(logits, dim=-1)

    def _run(
        self, x: torch.Tensor, task_ids: torch.Tensor
    ) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """The output (B, out_dim) and every layer's routing probabilities."""
        h, task = self._embed(x, task_ids)  # h: (B, D), shared by layer 0's modules
        probs: list[torch.Tensor] = []
        for i in range(self.depth):
            p = self._route(i, task, [q.flatten(1) for q in probs])
            probs.append(p)
            outs = self.layers[i](h)  # (n, B, d): module j's output on its own input
            if i < self.depth - 1:
                h = torch.einsum("bij,jbd->ibd", p, outs)  # module i's input of layer i + 1
            else:
                h = torch.einsum("bj,jbd->bd", p, outs)  # NOTE 5
            if self.norms:
                h = self.norms[i](h)
            h = F.relu(h)  # NOTE 4: after the mix
        return self.out(h), probs

    def forward(self, x: torch.Tensor, task_ids: torch.Tensor) -> torch.Tensor:
        """(B, in_dim), (B,) -> (B, out_dim)."""
        return self._run(x, task_ids)[0]

    def routing(self, x: torch.Tensor, task_ids: torch.Tensor) -> list[torch.Tensor]:
        """Each layer's routing probabilities: (B, n, n) before the last layer, (B, n) for it."""
        return self._run(x, task_ids)[1]

    def task_parameters(self) -> list[nn.Parameter]:
        """Parameters whose every entry only one task's samples reach: z's table."""
        return self.z.per_task
