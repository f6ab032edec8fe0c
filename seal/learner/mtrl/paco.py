"""PaCo, parameter-compositional multi-task RL (Sun et al., NeurIPS 2022), for one actor or critic.

Every layer holds K parameter sets Phi = [phi_1 .. phi_K], and task tau's layer is their
composition phi_tau = Phi w_tau with a learned task vector w_tau (K,). Eager, each layer is
composed per task first and each task's rows then run through their own phi_tau: B in out + T K
in out multiply-adds a layer. Compiled (where the rows' task counts cannot be read on the host), the
K maps run on every row as one batched matmul and the outputs are mixed by the row's w_tau, which is
the same map since a layer is affine (x phi_tau = sum_k w_tau,k x phi_k) at K B in out: 2.8-3.3x
the eager path's time on the bench's shapes (K = 5, 2 tasks x 128 rows, 256 wide; `seal bench
--only paco_update_speedup`). The hidden layers are agent.hidden wide (ReLU after the mix), and
the output layer composes too, so there are no per-task heads: what is per task is w_tau alone.

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

    compose_first = True
    """False runs the compiled path's map eagerly too (`seal bench`'s paco_update_speedup reference)."""

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
        """(B, in_dim), (B,) -> (B, out_dim): per task eager, by the K sets compiled."""
        if torch.compiler.is_compiling() or not self.compose_first:
            return self.forward_sets(x, task_ids)
        return self.forward_per_task(x, task_ids)

    def forward_sets(self, x: torch.Tensor, task_ids: torch.Tensor) -> torch.Tensor:
        """Every row through the K sets, the outputs mixed by its w_tau (the compiled path)."""
        w = self.task_weights(task_ids)
        for i, layer in enumerate(self.hidden):
            x = self._activate(i, self.compose(layer(x), w))
        return self.compose(self.out(x), w)

    def forward_per_task(self, x: torch.Tensor, task_ids: torch.Tensor) -> torch.Tensor:
        """Rows sorted by task, each task's layers composed, each task's rows through its own."""
        w = self.task_weights.rows()
        sizes = torch.bincount(task_ids, minlength=w.shape[0]).tolist()
        order = torch.argsort(task_ids, stable=True)
        x = x[order]
        for i, layer in enumerate(self.hidden):
            x = self._activate(i, _per_task(layer, w, x, sizes))
        return _per_task(self.out, w, x, sizes)[torch.argsort(order)]

    def _activate(self, i: int, x: torch.Tensor) -> torch.Tensor:
        if self.norms:
            x = self.norms[i](x)
        return F.relu(x)

    def task_parameters(self) -> list[nn.Parameter]:
        """Parameters whose every entry only one task's samples reach: w's table."""
        return self.task_weights.per_task


def _per_task(layer: Dense, w: torch.Tensor, x: torch.Tensor, sizes: list[int]) -> torch.Tensor:
    """(B, in) rows grouped by task, sizes[t] of task t -> (B, out) = x_t phi_t, phi_t = Phi w_t.
    One batched matmul when every task has the same number of rows, else one matmul a task that
    has rows (only those tasks' layers are composed: acting on one row composes one)."""
    if len(set(sizes)) == 1:
        weight = torch.einsum("tk,kio->tio", w, layer.weight)
        bias = torch.einsum("tk,kio->tio", w, layer.bias)
        rows = x.view(len(sizes), sizes[0], x.shape[-1])
        return torch.baddbmm(bias, rows, weight).reshape(x.shape[0], layer.out_dim)
    parts = [
        torch.addmm(
            torch.einsum("k,ko->o", w[t], layer.bias[:, 0]),
            rows,
            torch.einsum("k,kio->io", w[t], layer.weight),
        )
        for t, rows in enumerate(x.split(sizes))
        if sizes[t]
    ]
    return torch.cat(parts) if parts else x.new_zeros(0, layer.out_dim)
