"""Layer 2: the learner. Networks, multi-task SAC, replay, checkpoints and collection."""

from seal.learner.config import AgentConfig, Batch, EnvSpec
from seal.learner.replay import MultiTaskReplay, counts_from_ratio
from seal.learner.sac import Agent

__all__ = ["Agent", "AgentConfig", "Batch", "EnvSpec", "MultiTaskReplay", "counts_from_ratio"]
