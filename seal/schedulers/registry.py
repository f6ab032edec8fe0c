"""From a protocol's [scheduler] table to a config, and from a config to a scheduler.

`config_from_table` checks every key and type against the config dataclass of the table's `kind`
(`seal.typed_config.build`: unknown keys, wrong types and unknown kinds raise ConfigError naming
`scheduler.key`);
`build_scheduler` validates values against the protocol's envs and tasks and dispatches on the
config's type, ending in a clear error for anything else.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from seal.errors import ConfigError
from seal.schedulers.base import Scheduler, SchedulerConfig
from seal.schedulers.curriculum import (
    CurriculumPhase,
    CurriculumV1Config,
    CurriculumV2Config,
    ProgressivePhase,
)
from seal.schedulers.ratio import (
    ConstantRatioConfig,
    SteppedRatioConfig,
    UniformConfig,
)
from seal.schedulers.smt import SMTConfig
from seal.typed_config import build

SCHEDULER_CONFIGS: dict[str, type[SchedulerConfig]] = {
    cls.kind: cls
    for cls in (
        UniformConfig,
        ConstantRatioConfig,
        SteppedRatioConfig,
        SMTConfig,
        CurriculumV1Config,
        CurriculumV2Config,
    )
}
"""The [scheduler] kinds and their config dataclasses."""

# The shorthand kinds of issue 4: `kind = "high_fk"` is `kind = "stepped", preset = "high_fk"`.
KIND_ALIASES: dict[str, tuple[str, dict[str, Any]]] = {
    "high_fk": ("stepped", {"preset": "high_fk"}),
    "high_mw": ("stepped", {"preset": "high_mw"}),
}


def config_from_table(table: Mapping[str, Any] | None, source: str = "") -> SchedulerConfig:
    """The config of a [scheduler] table; empty or None means `uniform` (every task, uniform batch).

    `source` (the protocol file) prefixes error messages.
    """
    try:
        table = dict(table or {})
        if not table:
            return UniformConfig()
        kind = table.pop("kind", None)
        if kind is None:
            raise ConfigError(
                f"scheduler.kind: required; valid: {', '.join([*SCHEDULER_CONFIGS, *KIND_ALIASES])}"
            )
        if kind in KIND_ALIASES:
            kind, implied = KIND_ALIASES[kind]
            table = {**implied, **table}
        if kind not in SCHEDULER_CONFIGS:
            raise ConfigError(
                f"scheduler.kind = {kind!r}: unknown; valid: {', '.join([*SCHEDULER_CONFIGS, *KIND_ALIASES])}"
            )
        return build(SCHEDULER_CONFIGS[kind], table, "scheduler")
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}" if source else str(exc)) from None


def build_scheduler(
    config: SchedulerConfig | Mapping[str, Any] | None,
    env_tasks: Mapping[str, Sequence[str]],
    *,
    seed: int = 0,
    adapters: Mapping[str, str] | None = None,
    episode_lengths: Mapping[str, int] | None = None,
    source: str = "",
) -> Scheduler:
    """The scheduler of a config (or a raw [scheduler] table) over `env_tasks` (env -> task names, in order).

    `adapters` (env name -> adapter name) lets presets find the kitchen and Meta-World envs
    (default: the env names themselves); `episode_lengths` (env -> steps) gives SMT's default M
    and m per env; `seed` seeds SMT's initial random pick. Errors name `scheduler.key`.
    """
    if config is None or isinstance(config, Mapping):
        config = config_from_table(config, source)
    if type(config)._build is SchedulerConfig._build:
        raise ValueError(
            f"no scheduler for config type {type(config).__name__}; valid kinds: {', '.join(SCHEDULER_CONFIGS)}"
        )
    return config.make(
        env_tasks, seed=seed, adapters=adapters, episode_lengths=episode_lengths, source=source
    )


__all__ = [
    "KIND_ALIASES",
    "SCHEDULER_CONFIGS",
    "CurriculumPhase",
    "ProgressivePhase",
    "build_scheduler",
    "config_from_table",
]
