"""Layer 2: the learner. Networks, multi-task SAC, replay, checkpoints and collection."""

from __future__ import annotations

from typing import TYPE_CHECKING

from seal.learner.config import AgentConfig, Batch, EnvSpec
from seal.learner.replay import MultiTaskReplay
from seal.learner.sac import Agent

if TYPE_CHECKING:
    from seal.learner.collection import Collector

__all__ = [
    "Agent",
    "AgentConfig",
    "Batch",
    "Collector",
    "EnvSpec",
    "MultiTaskReplay",
]


def __getattr__(name: str) -> type[Collector]:
    """`seal.learner.Collector`, imported on first use (collection pulls in env processes)."""
    if name == "Collector":
        from seal.learner.collection import Collector

        return Collector
    raise AttributeError(f"module 'seal.learner' has no attribute {name!r}")
