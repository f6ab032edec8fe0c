"""The protocol side of `[scheduler]`: parse, validate, scale and build a scheduler from the table.

The schedulers layer owns the configs (`seal.schedulers.registry`); this module only calls it. An
empty table means the default: every task collects every epoch and the batch is uniform over tasks.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from seal.errors import ConfigError, SealError


def parse_scheduler(table: Mapping[str, Any], where: str) -> Any:
    """The SchedulerConfig of a [scheduler] table ({} = uniform); ConfigError names the file and key."""
    from seal.schedulers.registry import config_from_table

    try:
        return config_from_table(dict(table), where)
    except ConfigError:
        raise
    except (SealError, TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: scheduler: {exc}") from None


def resolve_table(
    table: Mapping[str, Any], where: str, scale: float | None = None
) -> dict[str, Any]:
    """The [scheduler] table with every field resolved (and durations scaled); {} stays {}."""
    if not table:
        return {}
    config = parse_scheduler(table, where)
    if scale is not None:
        config = config.scale(scale)
    return config.to_table()


def build(
    table: Mapping[str, Any],
    env_tasks: Mapping[str, Sequence[str]],
    adapters: Mapping[str, str],
    where: str,
    *,
    seed: int = 0,
    episode_lengths: Mapping[str, int] | None = None,
) -> Any:
    """The Scheduler of a [scheduler] table over `env_tasks`; `adapters` maps env -> adapter name."""
    from seal.schedulers.registry import build_scheduler

    config = parse_scheduler(table, where)
    try:
        return build_scheduler(
            config,
            env_tasks,
            seed=seed,
            adapters=adapters,
            episode_lengths=episode_lengths,
            source=where,
        )
    except ConfigError:
        raise
    except (SealError, TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: scheduler: {exc}") from None
