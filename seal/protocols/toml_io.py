"""Protocol TOML as text: reading it safely (size, nesting, UTF-8), `--set table.key=value`
overrides, and writing configs back (`dumps_toml`, `toml_value`). The schema is `loader`'s."""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from seal.errors import ConfigError, SealError
from seal.files import read_data_file
from seal.typed_config import shown_key


def parse_override(text: str, path: str = "--set") -> tuple[list[str], Any]:
    """Split "table.key=value" into (["table", "key"], value); the value is parsed as TOML.

    A value that is not valid TOML is taken as a plain string, so `--set protocol.device=cpu` works.
    """
    key, sep, raw = text.partition("=")
    parts = [p.strip() for p in key.strip().split(".")]
    if not sep or len(parts) < 2 or not all(parts):
        raise ConfigError(
            f"{path}: override {text!r} must look like table.key=value (e.g. protocol.epochs=100)"
        )
    try:
        value = tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    except RecursionError:
        raise ConfigError(
            f"{path}: override {key.strip()}: the value nests arrays or inline tables more than "
            f"{MAX_NESTING} levels deep; at most {MAX_NESTING} are valid"
        ) from None
    return parts, value


def apply_overrides(raw: dict[str, Any], overrides: Iterable[str], path: str) -> dict[str, Any]:
    """`raw` with each "table.key=value" override set (tables created as needed)."""
    for text in overrides:
        parts, value = parse_override(text, path)
        node = raw
        for part in parts[:-1]:
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                raise ConfigError(f"{path}: override {text!r}: {part!r} is a value, not a table")
            node = child
        node[parts[-1]] = value
    return raw


MAX_NESTING = 32
"""The deepest nesting of tables and arrays a protocol or run config may have (the shipped ones
use 5): deeper input is refused in one line before anything recurses through it."""


def _nesting(value: object) -> tuple[int, list[str]]:
    """(how deep tables and arrays nest in `value`, the key path to the deepest), without recursion."""
    deepest: tuple[int, list[str]] = (0, [])
    stack: list[tuple[object, int, list[str]]] = [(value, 0, [])]
    while stack:
        node, depth, where = stack.pop()
        if isinstance(node, dict):
            items: Iterable[tuple[str, object]] = ((str(k), v) for k, v in node.items())
        elif isinstance(node, list):
            items = ((f"[{i}]", v) for i, v in enumerate(node))
        else:
            continue
        if depth + 1 > deepest[0]:
            deepest = (depth + 1, where)
        if depth + 1 > MAX_NESTING:
            break
        stack.extend((v, depth + 1, [*where, k]) for k, v in items)
    return deepest


def check_nesting(raw: Mapping[str, Any], where: str) -> None:
    """ConfigError if tables and arrays in `raw` nest deeper than MAX_NESTING."""
    depth, path = _nesting(dict(raw))
    if depth > MAX_NESTING:
        key = "".join(p if p.startswith("[") else f".{shown_key(p)}" for p in path[:4])
        key = key.removeprefix(".") + ("…" if len(path) > 4 else "")
        raise ConfigError(
            f"{where}: {key or 'the document'} nests tables or arrays more than {MAX_NESTING} levels "
            f"deep; at most {MAX_NESTING} are valid"
        )


def parse_toml(text: str, where: str) -> dict[str, Any]:
    """`text` parsed as TOML, or ConfigError naming `where` and the syntax problem."""
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{where}: not valid TOML: {exc}") from None
    except RecursionError:  # tomllib recurses once per level of nested arrays and inline tables
        raise ConfigError(
            f"{where}: arrays or inline tables nest more than {MAX_NESTING} levels deep; at most "
            f"{MAX_NESTING} are valid"
        ) from None
    check_nesting(raw, where)
    return raw


def read_toml(
    path: str | Path,
    *,
    what: str = "protocol file",
    within: str | Path | None = None,
    limit: int | None = None,
) -> dict[str, Any]:
    """The parsed TOML file, or ConfigError naming the file and the problem.

    The file is read as data (`seal.files.read_data_file`): a regular file, inside `within` and
    at most `limit` bytes when they are given; `what` names it in messages.
    """
    p = Path(path)
    try:
        data = read_data_file(p, what=what, within=within, limit=limit)
    except ConfigError:
        raise
    except SealError as exc:
        raise ConfigError(str(exc)) from None
    try:
        # utf-8-sig: a byte-order mark, which some Windows editors write, is dropped (tomllib
        # rejects it as "Invalid statement at line 1, column 1").
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise ConfigError(
            f"{p}: not UTF-8 text (byte {exc.object[exc.start]:#04x} on line {line}); TOML files must be UTF-8"
        ) from None
    return parse_toml(text, str(p))


def _toml_key(key: str) -> str:
    return key if key and all(c.isalnum() or c in "-_" for c in key) else json.dumps(key)


def toml_value(value: object) -> str:
    """One value as inline TOML (`seal protocol explain`, a sweep sample's `--set` overrides).

    Documents are written by tomli-w (`dumps_toml`); it has no public inline-value writer.
    """
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        if isinstance(value, float) and not math.isfinite(value):
            return ("-inf" if value < 0 else "inf") if math.isinf(value) else "nan"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)  # a JSON string is a valid TOML basic string
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, Mapping):
        items = (
            f"{_toml_key(str(k))} = {toml_value(v)}" for k, v in value.items() if v is not None
        )
        return "{" + ", ".join(items) + "}"
    raise SealError(f"cannot write {value!r} ({type(value).__name__}) as TOML")


def dumps_toml(data: Mapping[str, Any]) -> str:
    """Nested dicts as a TOML document (tomli-w), dicts as [tables]; None values are omitted."""
    import tomli_w

    def without_none(node: Any) -> Any:
        if isinstance(node, Mapping):
            return {k: without_none(v) for k, v in node.items() if v is not None}
        return node

    return tomli_w.dumps(without_none(data))
