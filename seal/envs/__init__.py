"""Layer 1: environments. The adapter interface, built-in adapters and observation alignment."""

from seal.envs.base import EnvAdapter, ObsLayout
from seal.envs.registry import BUILTIN_ADAPTERS, adapter_class, make_adapter

__all__ = ["BUILTIN_ADAPTERS", "EnvAdapter", "ObsLayout", "adapter_class", "make_adapter"]
