"""Load, override, validate and scale protocol TOML files (reading and writing the TOML text:
`toml_io`; `seal protocol explain`: `explain`).

`load_protocol(path, overrides, scale)` is the one entry point: it reads the file, applies
`--set table.key=value` overrides, checks every key and value against the schema in
`seal.protocols.config` (and `seal.learner.AgentConfig` / `seal.schedulers` for their tables),
resolves adapters and task lists, applies `--scale`, and returns a frozen `ProtocolConfig`.
Every user mistake raises `ConfigError` naming the file, `table.key`, the value and what is valid.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import math
import re
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from seal import typed_config
from seal.errors import ConfigError, SealError
from seal.protocols import scheduling
from seal.protocols.config import (
    ALL_TABLES,
    SIMPLE_TABLES,
    EnvConfig,
    FinetuneConfig,
    ProtocolConfig,
    ProtocolTable,
    TransferConfig,
)
from seal.protocols.toml_io import apply_overrides, check_nesting, read_toml, toml_value
from seal.sweep import config_tables as sweep_tables  # a leaf module: no Ray, no run code
from seal.typed_config import shown_key

ENV_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]*")
"""What an [envs.<name>] may be called: it labels the env in metrics.csv and train.csv's columns."""

if TYPE_CHECKING:
    from seal.learner.config import AgentConfig
    from seal.schedulers.base import SchedulerConfig

# ---------------------------------------------------------------- scaling


def scale_config(config: ProtocolConfig, factor: float) -> ProtocolConfig:
    """`config` with total epochs and every schedule duration multiplied by `factor` (floor 1).

    Per-epoch quantities (batch, gradient steps per epoch, episode length, evaluation episodes,
    warm-up) are unchanged.
    """
    if not (isinstance(factor, (int, float)) and math.isfinite(factor) and factor > 0):
        raise ConfigError(f"{config.path}: --scale {factor!r} must be a positive number")
    rep = dataclasses.replace
    from seal.schedulers.base import scale_duration

    s = functools.partial(scale_duration, factor=factor)
    finetune = config.finetune
    if finetune is not None:
        finetune = rep(
            finetune,
            pretrain_epochs=s(finetune.pretrain_epochs),
            finetune_epochs=s(finetune.finetune_epochs),
        )
    scheduler = config.scheduler.scale(factor) if config.scheduler is not None else None
    return rep(
        config,
        protocol=rep(config.protocol, epochs=s(config.protocol.epochs)),
        evaluation=rep(
            config.evaluation,
            interval=s(config.evaluation.interval),
            every_grad_steps=s(config.evaluation.every_grad_steps)
            if config.evaluation.every_grad_steps
            else 0,
        ),
        checkpoint=rep(config.checkpoint, interval=s(config.checkpoint.interval)),
        logging=rep(config.logging, train_interval=s(config.logging.train_interval)),
        finetune=finetune,
        scheduler=scheduler,
    )


# ---------------------------------------------------------------- the protocol


def _build_envs(raw: object, file: str) -> dict[str, EnvConfig]:
    from seal.envs import adapter_class
    from seal.envs.registry import check_options

    if not isinstance(raw, dict) or not raw:
        raise ConfigError(
            f'{file}: envs must have at least one [envs.<name>] table, e.g. [envs.mw] adapter = "metaworld"'
        )
    envs: dict[str, EnvConfig] = {}
    for name, table in raw.items():
        where = f"{file}: envs.{shown_key(name)}"
        # The name labels the env in metrics.csv, train.csv's columns and every table.
        if not ENV_NAME.fullmatch(name):
            raise ConfigError(
                f"{where}: the env name {name!r} is not valid; valid: letters, digits, '_' and "
                "'-', starting with a letter or digit (e.g. [envs.mw])"
            )
        if not isinstance(table, dict):
            raise ConfigError(
                f"{where} must be a table with keys adapter, tasks, episode_length, options, demo_episodes"
            )
        if isinstance(table.get("tasks"), str):  # one task or set name: a one-element list
            table = {**table, "tasks": [table["tasks"]]}
        env = typed_config.build(EnvConfig, table, where)
        adapter_name = env.adapter or name
        try:
            cls = adapter_class(adapter_name)
        except SealError as exc:
            raise ConfigError(f"{where}.adapter: {exc}") from None
        try:
            check_options(env.options)
            adapter = cls(
                tasks=list(env.tasks) or None,
                episode_length=env.episode_length or None,
                **env.options,
            )
        except SealError as exc:
            message = str(exc)  # which key the adapter refused, for the error's location
            key = "tasks"
            if "option" in message:
                key = "options"
            elif "episode_length" in message:
                key = "episode_length"
            raise ConfigError(f"{where}.{key}: {exc}") from None
        # Resolved: set names expanded and the adapter's default episode length filled in.
        envs[name] = dataclasses.replace(
            env,
            adapter=adapter_name,
            tasks=tuple(adapter.tasks),
            episode_length=adapter.episode_length,
            options=dict(env.options),
        )
    return envs


def _check_demos(config: ProtocolConfig, file: str) -> None:
    """An env with demonstrations (`demo_episodes` > 0) needs a scripted expert for every task."""
    from seal.envs import adapter_class

    for name, env in config.envs.items():
        episodes = config.demo_episodes(name)
        if episodes == 0:
            continue
        adapter = adapter_class(env.adapter)(
            tasks=list(env.tasks), episode_length=env.episode_length, **env.options
        )
        missing = [t for t in adapter.tasks if adapter.expert(t) is None]
        if missing:
            key = (
                "training.demo_episodes"
                if env.demo_episodes is None
                else f"envs.{shown_key(name)}.demo_episodes"
            )
            raise ConfigError(
                f"{file}: {key} = {episodes} needs a scripted expert for every task, and adapter "
                f"{env.adapter!r} (envs.{shown_key(name)}) has none for {', '.join(missing)}; "
                "set demo_episodes = 0 or drop those tasks"
            )


def _check_discount(config: ProtocolConfig, file: str) -> None:
    """An env whose reward has a potential-based shaping term must shape with the learner's discount."""
    from seal.envs import adapter_class

    for name, env in config.envs.items():
        adapter = adapter_class(env.adapter)(
            tasks=list(env.tasks), episode_length=env.episode_length, **env.options
        )
        discount = adapter.shaping_discount
        if discount is not None and discount != config.agent.gamma:
            raise ConfigError(
                f"{file}: envs.{shown_key(name)}: adapter {env.adapter!r} shapes its reward with "
                f"discount {discount} (options.gamma) but agent.gamma = {config.agent.gamma}; "
                f"potential-based shaping keeps the optimal policy only when they are equal: "
                f"set envs.{shown_key(name)}.options.gamma = {config.agent.gamma}"
            )


def _check_replay(config: ProtocolConfig, file: str) -> None:
    """Each env's replay holds at least one transition per task (it is split evenly by task)."""
    capacity = config.replay.capacity_per_env
    for name, env in config.envs.items():
        if capacity < len(env.tasks):
            raise ConfigError(
                f"{file}: replay.capacity_per_env = {capacity} is below the {len(env.tasks)} "
                f"tasks of envs.{shown_key(name)}; the replay holds capacity_per_env / tasks "
                "transitions of each task: give at least one a task"
            )


def _check_kind(config: ProtocolConfig, file: str) -> None:
    kind, envs = config.kind, [shown_key(e) for e in config.envs]
    if kind == "baseline" and len(envs) != 1:
        raise ConfigError(
            f'{file}: envs has {len(envs)} environments ({", ".join(envs)}); kind = "baseline" trains on exactly one'
        )
    if kind == "joint" and len(envs) < 2:
        raise ConfigError(
            f'{file}: envs has {len(envs)} environment(s); kind = "joint" needs at least two'
        )
    if kind == "finetune":
        ft = config.finetune
        if ft is None:
            raise ConfigError(
                f'{file}: kind = "finetune" needs a [finetune] table with source and target'
            )
        for key in ("source", "target"):
            if getattr(ft, key) not in config.envs:
                raise ConfigError(
                    f"{file}: finetune.{key} = {getattr(ft, key)!r} is not one of the [envs] tables; valid: {', '.join(envs)}"
                )
        if ft.source == ft.target:
            raise ConfigError(
                f"{file}: finetune.target = {ft.target!r} must differ from finetune.source"
            )
        if len(envs) != 2:
            raise ConfigError(
                f'{file}: kind = "finetune" uses exactly two [envs] tables (source and target), got {", ".join(envs)}'
            )
        if config.agent.task_encoder == "smt_gru":
            # Its task encoding is of one env's episodes; the aligned observation is of both.
            raise ConfigError(
                f'{file}: agent.task_encoder = "smt_gru" does not run through a pad-and-fine-tune '
                'alignment (kind = "finetune"); use "one_hot" or "none"'
            )
    elif config.finetune is not None:
        raise ConfigError(
            f'{file}: finetune is only valid with kind = "finetune" (this protocol\'s kind is {kind!r})'
        )


def default_architecture(kind: str) -> str:
    """The network each kind trains: SEAL for joint training, MTMHSAC otherwise (SEAL §3)."""
    return "seal" if kind == "joint" else "mtmhsac"


def _build_agent(raw: Mapping[str, Any] | None, kind: str, device: str, file: str) -> AgentConfig:
    from seal.learner.config import MTRL_ARCHITECTURES, RENAMED_KEYS, AgentConfig
    from seal.learner.presets import preset_values

    table = dict(raw or {})
    renamed = sorted(set(table) & set(RENAMED_KEYS))
    if renamed:
        old = renamed[0]
        raise ConfigError(f"{file}: agent.{old} no longer exists; use {RENAMED_KEYS[old]}")
    # [protocol].device is the one place a user sets the device; [agent].device may still override it.
    defaults: dict[str, Any] = {"architecture": default_architecture(kind), "device": device}
    if kind == "finetune":
        # The aligned observation already carries the aligned one-hot id at a fixed index
        # (Appendix D), so by default the agent appends no second one.
        defaults["task_encoder"] = "none"
    # A preset's keys fill what the table leaves out; the table's own keys win (seal.learner.presets).
    defaults.update(preset_values(table.get("preset", ""), file))
    if kind == "finetune" and {**defaults, **table}["architecture"] in MTRL_ARCHITECTURES:
        # A task-conditioned network takes the task id as its own input: "one_hot" is the only
        # task_encoder it runs with, so it is the default here too.
        defaults["task_encoder"] = "one_hot"
    agent = typed_config.build(AgentConfig, table, f"{file}: agent", defaults)
    _check_device_name(agent.device, "agent.device", file)
    return agent


def _check_device_name(name: str, key: str, file: str) -> None:
    """A device name is checked when the protocol loads (`seal protocol check` included); whether
    this machine has the device is checked when a run starts (`seal.device.resolve_device`)."""
    from seal.device import DEVICE_NAMES, is_device_name

    if not is_device_name(name):
        raise ConfigError(f"{file}: {key} = {name!r} is not a device name; valid: {DEVICE_NAMES}")


def _validate_scheduler(
    scheduler: SchedulerConfig | None, envs: dict[str, EnvConfig], file: str
) -> None:
    if scheduler is not None:
        scheduling.build(
            scheduler,
            {n: e.tasks for n, e in envs.items()},
            {n: e.adapter for n, e in envs.items()},
            file,
            episode_lengths={n: e.episode_length for n, e in envs.items()},
        )


def _validate_search(raw: dict[str, Any], spec: sweep_tables.SearchSpec, file: str) -> None:
    """Every searched `table.key` names a config value, valid at each end of its distribution."""
    base = {k: v for k, v in raw.items() if k != "search"}
    for param in spec.params:
        for value in param.ends():
            override = f"{param.key}={toml_value(value)}"
            trial = apply_overrides(copy.deepcopy(base), [override], f"{file}: search")
            config_from_dict(trial, f"{file} (search.{param.key} = {value!r})")


def _check_tables(raw: Mapping[str, Any], file: str) -> None:
    """Only known tables, each a table."""
    unknown = [t for t in raw if t not in ALL_TABLES]
    if unknown:
        raise ConfigError(
            f"{file}: [{shown_key(unknown[0])}] is not a valid table; valid tables: {', '.join(ALL_TABLES)}"
        )
    for table in ALL_TABLES:
        if table in raw and not isinstance(raw[table], dict):
            raise ConfigError(f"{file}: {table} must be a table ([{table}]), got {raw[table]!r}")


def _build_protocol_table(raw: Mapping[str, Any], file: str) -> ProtocolTable:
    table = dict(raw.get("protocol", {}))
    named = "name" in table
    table.setdefault("name", Path(file).stem if file != "<memory>" else "protocol")
    protocol = typed_config.build(ProtocolTable, table, f"{file}: protocol")
    _check_device_name(protocol.device, "protocol.device", file)
    name = protocol.name
    if not name or "/" in name or "\0" in name or name.startswith(".") or len(name.encode()) > 255:
        given = "" if named else " (from the file's name: set [protocol] name)"
        raise ConfigError(
            f"{file}: protocol.name = {name!r}{given} must be a folder name: not empty, without "
            "'/' or NUL, not starting with '.', at most 255 bytes"
        )
    return protocol


def _check_kind_tables(config: ProtocolConfig, file: str) -> None:
    """[scheduler] and [transfer] do nothing under kind = "finetune": refused, not ignored."""
    if config.kind != "finetune":
        return
    if config.scheduler is not None:
        raise ConfigError(
            f'{file}: scheduler is not used by kind = "finetune" (each phase trains on one env with uniform batches); remove [scheduler]'
        )
    if config.transfer is not None:
        raise ConfigError(
            f'{file}: transfer is not used by kind = "finetune" (its [finetune] table transfers between phases); remove [transfer]'
        )


def upgrade_saved(raw: dict[str, Any]) -> dict[str, Any]:
    """A protocol a run saved (its config.toml, a checkpoint's copy), with [agent] keys renamed
    since then mapped to today's (`AgentConfig.upgrade`)."""
    from seal.learner.config import AgentConfig

    if not isinstance(raw.get("agent"), dict):
        return raw
    return {**raw, "agent": AgentConfig.upgrade(raw["agent"])}


def config_from_dict(raw: dict[str, Any], path: str = "<memory>") -> ProtocolConfig:
    """Validate a parsed protocol (tables as dicts) into a ProtocolConfig; `path` names it in errors."""
    file = str(path)
    _check_tables(raw, file)
    protocol = _build_protocol_table(raw, file)
    tables = {
        name: typed_config.build(cls, raw.get(name, {}), f"{file}: {name}")
        for name, cls in SIMPLE_TABLES.items()
        if name not in ("protocol", "finetune")
    }
    optional = {
        name: typed_config.build(cls, raw[name], f"{file}: {name}") if name in raw else None
        for name, cls in (("transfer", TransferConfig), ("finetune", FinetuneConfig))
    }
    envs = _build_envs(raw.get("envs"), file)
    config = ProtocolConfig(
        path=file,
        protocol=protocol,
        envs=envs,
        agent=_build_agent(raw.get("agent"), protocol.kind, protocol.device, file),
        scheduler=scheduling.parse(raw.get("scheduler", {}), file),
        search=dict(raw.get("search", {})),
        resources=dict(raw.get("resources", {})),
        **tables,
        **optional,
    )
    _check_kind(config, file)
    _check_demos(config, file)
    _check_discount(config, file)
    _check_replay(config, file)
    _check_kind_tables(config, file)
    _validate_scheduler(config.scheduler, envs, file)
    sweep_tables.parse_resources(config.resources, file)
    if config.search:
        _validate_search(raw, sweep_tables.parse_search(config.search, file), file)
    finetune = config.finetune
    if finetune is not None:  # 0 epochs means [protocol].epochs
        config = config.replace(
            finetune=dataclasses.replace(
                finetune,
                pretrain_epochs=finetune.pretrain_epochs or protocol.epochs,
                finetune_epochs=finetune.finetune_epochs or protocol.epochs,
            )
        )
    return config


def load_protocol(
    path: str | Path, overrides: Iterable[str] = (), scale: float | None = None
) -> ProtocolConfig:
    """Read, override, validate and scale a protocol file; nothing is written."""
    raw = apply_overrides(read_toml(path), overrides, str(path))
    check_nesting(raw, str(path))
    config = config_from_dict(raw, str(path))
    return scale_config(config, scale) if scale is not None else config


# ---------------------------------------------------------------- writing and explaining


def config_to_dict(config: ProtocolConfig) -> dict[str, Any]:
    """The resolved config as TOML-ready nested tables (it loads back to the same config)."""

    def plain(obj: Any) -> Any:
        if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
            return {f.name: plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
        if isinstance(obj, dict):
            return {str(k): plain(v) for k, v in obj.items()}
        if isinstance(obj, (list, tuple)):
            return [plain(v) for v in obj]
        return obj

    out: dict[str, Any] = {"protocol": plain(config.protocol), "envs": plain(config.envs)}
    out["agent"] = plain(config.agent)
    for name in ("replay", "training", "evaluation"):
        out[name] = plain(getattr(config, name))
    if config.scheduler is not None:
        out["scheduler"] = config.scheduler.to_table()
    if config.finetune is not None:
        out["finetune"] = plain(config.finetune)
    if config.transfer is not None:
        out["transfer"] = plain(config.transfer)
    out["checkpoint"] = plain(config.checkpoint)
    out["logging"] = plain(config.logging)
    if config.search:
        out["search"] = plain(config.search)
    if config.resources:
        out["resources"] = plain(config.resources)
    return out
