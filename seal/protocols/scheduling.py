"""The protocol side of `[scheduler]`: parse a table into its typed config, and build a scheduler.

The schedulers layer owns the configs (`seal.schedulers.registry`); this module only calls it. No
table means the default: every task collects every epoch and the batch is uniform over tasks.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

from seal.errors import ConfigError, SealError

if TYPE_CHECKING:
    from seal.schedulers.base import Scheduler, SchedulerConfig


def parse(table: Mapping[str, Any], where: str) -> SchedulerConfig | None:
    """The SchedulerConfig of a [scheduler] table (None for no table: uniform); ConfigError names
    the file and key."""
    from seal.schedulers.registry import config_from_table

    if not table:
        return None
    try:
        return config_from_table(dict(table), where)
    except ConfigError:
        raise
    except (SealError, TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: scheduler: {exc}") from None


def build(
    config: SchedulerConfig | None,
    env_tasks: Mapping[str, Sequence[str]],
    adapters: Mapping[str, str],
    where: str,
    *,
    seed: int = 0,
    episode_lengths: Mapping[str, int] | None = None,
) -> Scheduler:
    """The Scheduler of a protocol's scheduler config over `env_tasks`; `adapters` maps env ->
    adapter name. Errors name the file (`where`) and the `scheduler.key`."""
    from seal.schedulers.ratio import UniformConfig

    return (config or UniformConfig()).build(
        env_tasks, seed=seed, adapters=adapters, episode_lengths=episode_lengths, source=where
    )
