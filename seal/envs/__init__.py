"""Layer 1: environments. The adapter interface, built-in adapters and observation alignment."""

from seal.envs.base import EnvAdapter, EnvMap, ObsLayout
from seal.envs.registry import (
    BUILTIN_ADAPTERS,
    BUILTIN_ENV_MAPS,
    adapter_class,
    env_map,
    make_adapter,
)

__all__ = [
    "BUILTIN_ADAPTERS",
    "BUILTIN_ENV_MAPS",
    "EnvAdapter",
    "EnvMap",
    "ObsLayout",
    "adapter_class",
    "env_map",
    "make_adapter",
]
