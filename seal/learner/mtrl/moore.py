"""MOORE, a mixture of orthogonal experts (Hendawy et al., ICLR 2024), for one actor or critic.

k experts encode the input each into a width-wide representation; Gram-Schmidt makes the k
representations of every sample orthonormal, and the task's learned weights w_tau (k,) mix them
into one shared feature, tanh(sum_i w_tau,i u_i), that the sample's task's output head reads.
What is per task is w_tau and the heads; the experts are shared by all tasks.

From metaworld-algorithms' nn/moore.py (its MLP is nn/base.py's; MOOREConfig in config/nn.py):
- w_tau is a Dense layer without bias over the one-hot task id (here the `Embedding` table, no bias).
- Each expert is its MLP(width, depth - 1, width, activate_last=False): depth - 1 ReLU hidden layers
  and a last Dense of the width with no activation; here the hidden layers are agent.hidden[:-1] and
  the last layer agent.hidden[-1] wide, so len(agent.hidden) Dense layers an expert.
- The k experts run as one batched matmul a layer (`Dense` with members = k).
- Gram-Schmidt is its orthogonal_1d: classical (each expert's output minus its projection on the
  basis so far), eps 1e-8 added to every norm; orthonormal when k <= agent.hidden[-1].
- The mix is a weighted sum over the experts by w_tau (no softmax or normalisation of w_tau), then tanh.
- The output heads are one Dense (with bias) per task on the mixed feature, the sample's task's
  taken: computed as one matmul for all heads and a gather (cheaper here than gathering each
  sample's kernel); only the sample's head gets gradient.
With layer_norm (a critic's agent.critic_layer_norm) a LayerNorm, with a gain and bias of its own
per expert, normalises each expert hidden layer over its width before the ReLU; not on an expert's
last layer, the mixed feature or the heads.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from seal.learner.config import AgentConfig
from seal.learner.mtrl.layers import Dense, Embedding, dense_stack

EPS = 1e-8  # metaworld-algorithms' orthogonal_1d: added to each norm


class ExpertLayerNorm(nn.Module):
    """LayerNorm over the last dim of (members, B, width), a gain and bias per member."""

    def __init__(self, members: int, width: int) -> None:
        super().__init__()
        self.width = width
        self.weight = nn.Parameter(torch.ones(members, 1, width))
        self.bias = nn.Parameter(torch.zeros(members, 1, width))

    def reset_parameters(self) -> None:
        """Gain 1, bias 0 (nn.LayerNorm's)."""
        with torch.no_grad():
            self.weight.fill_(1.0)
            self.bias.zero_()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(members, B, width) -> the same shape."""
        return F.layer_norm(x, (self.width,)) * self.weight + self.bias


def gram_schmidt(x: torch.Tensor) -> torch.Tensor:
    """(B, k, n) -> (B, k, n): each sample's k rows made orthonormal in order (classical GS).

    Row i's projections are taken with its own input (classical, as orthogonal_1d), each as an
    elementwise product summed over n: on a CPU, cheaper forward and backward than k batched
    matmuls of B tiny matrices and the slices of x they need."""
    basis: list[torch.Tensor] = []
    for v in x.unbind(1):  # (B, n) each; contiguous when x is the experts' (k, B, n) transposed
        w = v
        for b in basis:
            w = w - (v * b).sum(-1, keepdim=True) * b
        basis.append(w / (torch.linalg.vector_norm(w, dim=-1, keepdim=True) + EPS))
    return torch.stack(basis, dim=1)


class Moore(nn.Module):
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
        k = config.moore_experts
        self.num_tasks, self.out_dim = num_tasks, out_dim
        self.task_weights = Embedding(num_tasks, k, bias=False)
        dims = (in_dim, *config.hidden)
        self.layers = dense_stack(dims, members=k)
        self.norms = nn.ModuleList(
            ExpertLayerNorm(k, o) for o in (config.hidden[:-1] if layer_norm else ())
        )
        self.heads = Dense(dims[-1], out_dim, members=num_tasks)

    def reset_parameters(
        self, generator: torch.Generator, init: str, head_bound: float | None
    ) -> None:
        """Draw w's table, then each expert layer's k maps in order; the heads with head_bound."""
        self.task_weights.reset_parameters(generator, init)
        for layer in self.layers:
            layer.reset_parameters(generator, init)
        for norm in self.norms:
            norm.reset_parameters()
        self.heads.reset_parameters(generator, init, head_bound)

    def experts(self, x: torch.Tensor) -> torch.Tensor:
        """(B, in_dim) -> (B, k, width): the experts' outputs, orthonormal per sample."""
        last = len(self.layers) - 1
        for i, layer in enumerate(self.layers):
            x = layer(x)  # (k, B, o)
            if i < last:
                if self.norms:
                    x = self.norms[i](x)
                x = F.relu(x)
        return gram_schmidt(x.transpose(0, 1))

    def forward(self, x: torch.Tensor, task_ids: torch.Tensor) -> torch.Tensor:
        """(B, in_dim), (B,) -> (B, out_dim)."""
        w = self.task_weights(task_ids)  # (B, k)
        # The mix as a product and a sum over k, not an einsum (B matmuls of 1 x k by k x n).
        features = torch.tanh((self.experts(x) * w.unsqueeze(-1)).sum(1))
        # Every head at once, one matmul (B, n) @ (n, T * out), then the sample's task's head.
        n = features.shape[-1]
        kernels = self.heads.weight.transpose(0, 1).reshape(n, self.num_tasks * self.out_dim)
        biases = self.heads.bias.reshape(self.num_tasks * self.out_dim)
        out = torch.addmm(biases, features, kernels).view(-1, self.num_tasks, self.out_dim)
        return out[torch.arange(out.shape[0], device=out.device), task_ids]

    def task_parameters(self) -> list[nn.Parameter]:
        """Parameters whose every entry only one task's samples reach: w's table and the heads."""
        return [*self.task_weights.per_task, self.heads.weight, self.heads.bias]
