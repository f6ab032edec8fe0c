"""Dense layers of the task-conditioned networks, with the agent's two init schemes.

`Dense` is one affine map, or `members` independent ones computed as one batched matmul (PaCo's
parameter sets, MOORE's and CARE's experts, Soft Modularization's modules): weights
(members, in, out), biases (members, 1, out). The init follows `AgentConfig.init` as
`seal.learner.networks.StackedMLP` does: "metaworld_algorithms" draws He-uniform kernels,
U(+-sqrt(6 / fan_in)), and zero biases (flax's he_uniform and zeros, metaworld-algorithms'
defaults); "torch" draws both from nn.Linear's U(+-1 / sqrt(fan_in)). An output layer draws
U(+-bound) for both when given a bound (`networks.HEAD_BOUND` under "metaworld_algorithms").
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn


def _uniform_(tensor: torch.Tensor, bound: float, generator: torch.Generator) -> None:
    with torch.no_grad():
        tensor.uniform_(-bound, bound, generator=generator)


class Dense(nn.Module):
    """`members` affine maps of `in_dim` -> `out_dim` (one when members == 1).

    With one member: (B, in) -> (B, out). With several: a shared input (B, in) or one input per
    member (members, B, in) -> (members, B, out).
    """

    def __init__(self, in_dim: int, out_dim: int, members: int = 1, bias: bool = True) -> None:
        super().__init__()
        self.in_dim, self.out_dim, self.members = in_dim, out_dim, members
        self.weight = nn.Parameter(torch.empty(members, in_dim, out_dim))
        self.bias = nn.Parameter(torch.empty(members, 1, out_dim)) if bias else None

    def reset_parameters(
        self, generator: torch.Generator, init: str, bound: float | None = None
    ) -> None:
        """Hidden-layer init by `init`, or U(+-bound) for kernel and bias (an output layer)."""
        if bound is not None:
            _uniform_(self.weight, bound, generator)
            if self.bias is not None:
                _uniform_(self.bias, bound, generator)
        elif init == "metaworld_algorithms":
            _uniform_(self.weight, math.sqrt(6.0 / self.in_dim), generator)
            if self.bias is not None:
                with torch.no_grad():
                    self.bias.zero_()
        else:
            _uniform_(self.weight, 1.0 / math.sqrt(self.in_dim), generator)
            if self.bias is not None:
                _uniform_(self.bias, 1.0 / math.sqrt(self.in_dim), generator)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """See the class docstring for shapes."""
        if self.members == 1 and x.dim() == 2:
            weight = self.weight.squeeze(0)
            if self.bias is None:
                return x @ weight
            return torch.addmm(self.bias.squeeze(0), x, weight)
        if x.dim() == 2:
            x = x.expand(self.members, *x.shape)
        if self.bias is None:
            return torch.bmm(x, self.weight)
        return torch.baddbmm(self.bias, x, self.weight)


def dense_stack(dims: Sequence[int], members: int = 1) -> nn.ModuleList:
    """Dense layers dims[0] -> dims[1] -> ... -> dims[-1], each of `members` maps."""
    return nn.ModuleList(
        Dense(i, o, members=members) for i, o in zip(dims[:-1], dims[1:], strict=True)
    )


class Embedding(nn.Module):
    """A Dense layer on the one-hot task id, as a table: row t is task t's kernel row, plus the
    shared bias (flax's Dense over the one-hot, metaworld-algorithms' task embeddings)."""

    def __init__(self, num_tasks: int, out_dim: int, bias: bool = True) -> None:
        super().__init__()
        self.num_tasks, self.out_dim = num_tasks, out_dim
        self.table = nn.Parameter(torch.empty(num_tasks, out_dim))
        self.bias = nn.Parameter(torch.empty(out_dim)) if bias else None

    def reset_parameters(self, generator: torch.Generator, init: str) -> None:
        """As a hidden Dense layer of fan-in num_tasks."""
        scale = math.sqrt(6.0) if init == "metaworld_algorithms" else 1.0
        _uniform_(self.table, scale / math.sqrt(self.num_tasks), generator)
        if self.bias is not None:
            if init == "metaworld_algorithms":
                with torch.no_grad():
                    self.bias.zero_()
            else:
                _uniform_(self.bias, 1.0 / math.sqrt(self.num_tasks), generator)

    def forward(self, task_ids: torch.Tensor) -> torch.Tensor:
        """(B,) int64 -> (B, out_dim): one_hot(task_ids) @ table + bias."""
        out = F.embedding(task_ids, self.table)
        return out if self.bias is None else out + self.bias

    def rows(self) -> torch.Tensor:
        """(num_tasks, out_dim): every task's row, bias included (forward of every task id)."""
        return self.table if self.bias is None else self.table + self.bias

    @property
    def per_task(self) -> list[nn.Parameter]:
        """The table: each row reached by one task's samples only."""
        return [self.table]
