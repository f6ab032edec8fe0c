"""`seal protocol explain`: every resolved value of a protocol with its documentation."""

from __future__ import annotations

import dataclasses
from typing import Any

from seal import typed_config
from seal.protocols.config import EnvConfig, FinetuneConfig, ProtocolConfig, TransferConfig
from seal.protocols.toml_io import toml_value


def explain(config: ProtocolConfig) -> str:
    """Every resolved value of `config` with its documentation, table by table."""
    out: list[str] = [f"# {config.path}: protocol {config.name!r} (kind {config.kind})", ""]

    def section(title: str, obj: Any, cls: type | None) -> None:
        out.append(f"[{title}]")
        docs = typed_config.field_docs(cls) if cls is not None else {}
        values = (
            {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)}
            if dataclasses.is_dataclass(obj)
            else dict(obj)
        )
        for key, value in values.items():
            shown = toml_value(value) if value is not None else "(none)"
            doc = docs.get(key, "").splitlines()[0] if docs.get(key) else ""
            out.append(f"{key} = {shown}" + (f"    # {doc}" if doc else ""))
        out.append("")

    section("protocol", config.protocol, type(config.protocol))
    for name, env in config.envs.items():
        section(f"envs.{name}", env, EnvConfig)
    agent = config.agent
    section("agent", agent, type(agent))
    if agent.preset:
        from seal.learner.presets import PRESETS

        out.pop()  # the section's blank line: the preset's lines belong to [agent]
        out.append(f"# agent.preset = {agent.preset!r} sets:")
        for key, value in PRESETS[agent.preset].items():
            shown = toml_value(value)
            if toml_value(getattr(agent, key)) == shown:
                out.append(f"#   {key} = {shown}")
            else:
                out.append(
                    f"#   {key} = {shown}, overridden: the explicit {key} = "
                    f"{toml_value(getattr(agent, key))} wins"
                )
        out.append("")
    for name in ("replay", "training", "evaluation"):
        obj = getattr(config, name)
        section(name, obj, type(obj))
    from seal.protocols.evaluation_cost import explain_lines

    out[-1:] = [*explain_lines(config), ""]  # what its options save, below [evaluation]'s keys
    if config.scheduler is not None:
        section("scheduler", config.scheduler.to_table(), type(config.scheduler))
    if config.finetune is not None:
        section("finetune", config.finetune, FinetuneConfig)
    if config.transfer is not None:
        section("transfer", config.transfer, TransferConfig)
    section("checkpoint", config.checkpoint, type(config.checkpoint))
    section("logging", config.logging, type(config.logging))
    for name in ("search", "resources"):
        if getattr(config, name):
            section(name, getattr(config, name), None)
    return "\n".join(out).rstrip() + "\n"
