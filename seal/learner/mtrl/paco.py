"""PaCo, parameter-compositional multi-task RL (Sun et al., NeurIPS 2022), for one actor or critic.

Every layer holds K parameter sets Phi = [phi_1 .. phi_K], and task tau's layer is their
composition phi_tau = Phi w_tau with a learned task vector w_tau (K,). Since a layer is affine,
x phi_tau = sum_k w_tau,k (x phi_k): the K maps run as one batched matmul and the outputs are mixed
by the sample's w_tau. The hidden layers are agent.hidden wide (ReLU after the mix), and the output
layer composes too, so there are no per-task heads: what is per task is w_tau alone.

From metaworld-algorithms' nn/paco.py (the paper's MT10 setting, K = 5): w_tau is a Dense layer
with bias over the one-hot task id (here the `Embedding` table plus bias), the whole network
including its output layer is compositional, and nothing normalises w_tau. Left out: the paper's
loss-maskout and w-reset for tasks whose loss explodes (its stability add-on, not the network).
With layer_norm (a critic's agent.critic_layer_norm) a LayerNorm follows each hidden layer's mix,
before its ReLU.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from seal.learner.config import AgentConfig
from seal.learner.mtrl.layers import Dense, Embedding, dense_stack


class PaCo(nn.Module):
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
        k = config.paco_sets
        self.task_weights = Embedding(num_tasks, k)
        dims = (in_dim, *config.hidden)
        self.hidden = dense_stack(dims, members=k)
        self.norms = nn.ModuleList(nn.LayerNorm(o) for o in (config.hidden if layer_norm else ()))
        self.out = Dense(dims[-1], out_dim, members=k)

    def reset_parameters(
        self, generator: torch.Generator, init: str, head_bound: float | None
    ) -> None:
        """Draw w's table, then each layer's K sets in order; the output layer with head_bound."""
        self.task_weights.reset_parameters(generator, init)
        for layer in self.hidden:
            layer.reset_parameters(generator, init)
        for norm in self.norms:
            norm.reset_parameters()
        self.out.reset_parameters(generator, init, head_bound)

    def compose(self, sets: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
        """(K, B, n) outputs of the K sets and (B, K) task vectors -> (B, n) = sum_k w_k out_k."""
        return torch.einsum("kbn,bk->bn", sets, w)

    def forward(self, x: torch.Tensor, task_ids: torch.Tensor) -> torch.Tensor:
        """(B, in_dim), (B,) -> (B, out_dim)."""
        w = self.task_weights(task_ids)
        for i, layer in enumerate(self.hidden):
            x = self.compose(layer(x), w)
            if self.norms:
                x = self.norms[i](x)
            x = F.relu(x)
        return self.compose(self.out(x), w)

    def task_parameters(self) -> list[nn.Parameter]:
        """Parameters whose every entry only one task's samples reach: w's table."""
        return self.task_weights.per_task
