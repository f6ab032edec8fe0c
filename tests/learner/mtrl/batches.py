"""A random update batch for the task-conditioned agents' tests (6-wide obs, 2-wide actions)."""

from __future__ import annotations

import torch

from seal.learner.config import Batch


def random_batch(n: int, tasks: int, seed: int) -> Batch:
    """`n` random transitions of obs width 6 and action width 2, task ids 0..tasks-1 in turn."""
    g = torch.Generator().manual_seed(seed)
    return Batch(
        torch.randn(n, 6, generator=g),
        torch.rand(n, 2, generator=g) * 2 - 1,
        torch.randn(n, generator=g),
        torch.randn(n, 6, generator=g),
        torch.zeros(n),
        torch.arange(n) % tasks,
    )
