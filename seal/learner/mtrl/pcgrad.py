"""PCGrad (Yu et al., NeurIPS 2020, "Gradient Surgery for Multi-Task Learning", Algorithm 1):
`agent.gradient = "pcgrad"`.

Algorithm 1: for each task i, g_i^PC = g_i; for each other task j in a random order, if
g_i^PC . g_j < 0 then g_i^PC -= (g_i^PC . g_j / ||g_j||^2) g_j (g_j the task's own gradient, never
its surgered one); the step is sum_i g_i^PC. `pcgrad` does this on flat gradients (T, P).

Choices, and where they depart from metaworld-algorithms' optim/pcgrad.py:

- Order: each task its own uniformly random order of the other tasks, drawn afresh for every
  task and every call from the caller's generator (the paper's "in random order" per task);
  metaworld-algorithms permutes the tasks once per step and loops over every j, i itself included.
- Sum, not mean: `pcgrad` returns sum_i g_i^PC, as the paper. The update hands it row i = the
  gradient of task i's share of the batch's mean loss, (1 / N) sum over task i's samples of the
  per-sample loss, so the rows sum to the "mean" gradient and, with no conflict, the step is the
  "mean" step. Surgery is positively homogeneous in each row (g_i^PC scales with g_i, and the
  conflict test and the projection ignore g_j's scale), so on a batch of n samples of every task
  this is metaworld-algorithms' mean over tasks of each task's mean-loss gradient, surgered.
- A task without samples in the batch has a zero row: it is never projected, nor projected on.
- Conflicts counted: projections made, ordered pairs (i, j) with g_i^PC . g_j < 0 when j's turn
  came (metaworld-algorithms halves its count of the same kind).

In the update (`seal.learner.update`, the critic's and the actor's steps alike, as the paper's
MT-SAC experiments; the temperature loss keeps its plain gradient): each task's gradient is taken,
by one backward pass per task, on the shared parameters of the slot stepped: every parameter but
the per-task ones (`task_parameters`). For MTMHSAC those are the hidden layers ("trunk"), and the
output layer too where it is one head for all tasks (multi_head_policy / multi_head_critic =
false); for a single-env SEAL agent the translator, the trunk and a head's hidden layers shared by
the env's tasks too; for a task-conditioned network (`seal.learner.mtrl.network`) its "trunk"
component.
The per-task parameters (the per-task output heads, "head.<env>"; a task-conditioned network's
`task_parameters`) take the plain gradient of the summed task shares, the "mean" gradient. Then
max_grad_norm clips the final gradient (surgered shared part and head part together), as in
"mean". The orders come from the agent's "pcgrad" stream of the env (`seal.seeding.stream(seed,
"pcgrad", env)`), saved and restored with the agent's state.

What it refuses, in one line each: several envs in one agent (`check_config`, at the agent's
construction: the tasks of one env make the task set) and agent.compile (`AgentConfig`: the
surgery runs eager).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from seal.errors import SealError
from seal.learner.config import AgentConfig, EnvSpec
from seal.learner.networks import MultiHeadLinear


def draw_orders(num_tasks: int, generator: torch.Generator) -> torch.Tensor:
    """(T, T - 1) int64: row i a uniformly random order of the tasks other than i, every row drawn
    independently (argsort of T x T uniforms from `generator`, i's own key put last)."""
    keys = torch.rand(num_tasks, num_tasks, generator=generator, device=generator.device)
    keys.diagonal().fill_(2.0)
    return keys.argsort(dim=1)[:, : num_tasks - 1]


def surgery(grads: torch.Tensor, orders: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Algorithm 1 on task gradients `grads` (T, P), task i visiting the others in `orders[i]`
    (T, T - 1): (sum_i g_i^PC (P,), the number of projections made (a 0-d int64 tensor)).

    Vectorised over i: step k projects every task's g_i^PC on g_{orders[i, k]} at once."""
    surgered = grads.clone()
    squared_norms = grads.square().sum(dim=1)
    conflicts = torch.zeros((), dtype=torch.int64, device=grads.device)
    for k in range(orders.shape[1]):
        j = orders[:, k]
        others = grads[j]
        dots = (surgered * others).sum(dim=1)
        conflict = dots < 0  # a zero g_j (a task without samples) never conflicts
        coefficient = torch.where(conflict, dots / squared_norms[j], torch.zeros_like(dots))
        surgered -= coefficient.unsqueeze(1) * others
        conflicts += conflict.sum()
    return surgered.sum(dim=0), conflicts


def pcgrad(grads: torch.Tensor, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """PCGrad of task gradients `grads` (T, P): (sum_i g_i^PC (P,), projections made), each
    task's order of the others drawn from `generator` (`draw_orders`, then `surgery`)."""
    if grads.dim() != 2:
        raise ValueError(f"pcgrad: expected task gradients (T, P), got shape {tuple(grads.shape)}")
    return surgery(grads, draw_orders(grads.shape[0], generator))


def task_parameters(net: nn.Module) -> list[nn.Parameter]:
    """The parameters of `net` whose every entry only one task's samples reach: each multi-head
    output layer (`MultiHeadLinear` with one head per task) and whatever a submodule names with
    `task_parameters()` (`seal.learner.mtrl`'s networks). PCGrad steps them with the plain gradient."""
    found: dict[int, nn.Parameter] = {}
    for module in net.modules():
        if isinstance(module, MultiHeadLinear) and module.num_heads > 1:
            params: Sequence[nn.Parameter] = (module.weight, module.bias)
        elif callable(getattr(module, "task_parameters", None)):
            params = module.task_parameters()
        else:
            continue
        found.update((id(p), p) for p in params)
    return list(found.values())


def check_config(config: AgentConfig, specs: Sequence[EnvSpec]) -> None:
    """SealError, one line, for what agent.gradient = "pcgrad" does not support that the config
    alone cannot tell (AgentConfig refuses compile): several environments."""
    if config.gradient != "pcgrad":
        return
    if len(specs) != 1:
        names = ", ".join(s.name for s in specs)
        raise SealError(
            f'agent.gradient = "pcgrad" does surgery on the tasks of one environment, got {len(specs)} ({names}); train one env, or use agent.gradient = "mean"'
        )
