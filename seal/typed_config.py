"""One typed-config engine for every TOML table (protocol, agent, scheduler), on pydantic v2.

The tables are plain frozen dataclasses marked `@with_config(SCHEMA)`: their fields carry their
types, their bounds (`Annotated[int, Field(ge=1)]`) and a docstring each, which `field_docs`
returns for `seal protocol explain` and `--help`. `build(cls, table, where)` validates a TOML
table into one, or raises a one-line `ConfigError` naming `where.key`, the bad value and what is
valid. Pydantic over msgspec or cattrs: it validates stdlib dataclasses as they are (no second
class hierarchy), keeps bounds and docs at the field, and Ray already depends on it.

The rules, one place: types are strict (no string for a number, no number for a bool); an int
field takes an integral float (`capacity_per_env = 1e7`); lists fill tuples; floats are finite.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import types
import typing
from collections.abc import Mapping
from typing import Any, TypeVar

from pydantic import ConfigDict, JsonValue, TypeAdapter, ValidationError
from pydantic_core import ErrorDetails

from seal.errors import ConfigError, SealError

T = TypeVar("T")

SCHEMA = ConfigDict(extra="forbid", allow_inf_nan=False, use_attribute_docstrings=True)
"""The pydantic config of every table class: unknown keys and non-finite floats are errors;
field docstrings are the docs."""

_EXPECTED = {
    "int_type": "an integer",
    "int_from_float": "an integer",
    "float_type": "a number",
    "string_type": "a string",
    "bool_type": "true or false",
    "tuple_type": "a list",
    "list_type": "a list",
    "dict_type": "a table",
    "dataclass_type": "a table",
}
"""What a wrong-typed value should have been, by pydantic error type."""


@functools.cache
def _adapter(cls: type[T]) -> TypeAdapter[T]:
    return TypeAdapter(cls)


@functools.cache
def field_docs(cls: type) -> dict[str, str]:
    """Each field's docstring (the string literal under it), by field name; "" where it has none."""
    schema = _adapter(cls).json_schema(mode="validation")
    return {
        name: prop.get("description", "") for name, prop in schema.get("properties", {}).items()
    }


def shown_key(key: object) -> str:
    """A user's table or key name as messages show it: as written when it is printable text,
    else as a quoted TOML key ("east\\n"), so a message stays one readable line."""
    text = str(key)
    return text if text and text.isprintable() and text.strip() == text else json.dumps(text)


def _toml_to_json(value: object) -> JsonValue:
    """TOML values as JSON-ready ones: integral floats become ints (an int field takes them, a
    float field takes ints); dates and times become a table, which every typed field refuses."""
    if isinstance(value, Mapping):
        return {str(k): _toml_to_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_toml_to_json(v) for v in value]
    if isinstance(value, float) and math.isfinite(value) and value.is_integer():
        return int(value)
    if isinstance(value, (bool, int, float, str)) or value is None:
        return value
    return {"<toml>": str(value)}


def _field_type(tp: object, part: str | int) -> object:
    """The type one step down a validation error's location: a dataclass field or a sequence item.

    Type forms are `object`s here (3.11 has no TypeForm).
    """
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is typing.Annotated:
        return _field_type(args[0], part)
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        return _field_type(inner[0], part) if len(inner) == 1 else Any
    if isinstance(part, int):
        return args[0] if origin in (list, tuple) and args else Any
    if dataclasses.is_dataclass(tp):
        return typing.get_type_hints(tp, include_extras=True).get(part, Any)
    if origin is dict and len(args) == 2:
        return args[1]
    return Any


def _literal(tp: object) -> object:
    """The Literal inside an Annotated or optional annotation."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is typing.Annotated:
        return _literal(args[0])
    if origin in (typing.Union, types.UnionType):
        return next(
            (_literal(a) for a in args if typing.get_origin(_literal(a)) is typing.Literal), tp
        )
    return tp


def _message(error: ErrorDetails, data: Mapping[str, object], cls: type, where: str) -> str:
    """One pydantic error as the one line the user reads."""
    loc = [p for p in error["loc"] if isinstance(p, (str, int))]
    value: object = data
    for part in loc:
        value = _item(value, part)
    owner: object = cls  # the table class that holds the bad key
    for part in loc[:-1]:
        owner = _field_type(owner, part)
    path = where + "".join(f"[{p}]" if isinstance(p, int) else f".{shown_key(p)}" for p in loc)
    kind, ctx = error["type"], error.get("ctx") or {}
    if kind == "unexpected_keyword_argument":
        valid = (
            [f.name for f in dataclasses.fields(owner)] if dataclasses.is_dataclass(owner) else []
        )
        if not valid:  # e.g. scheduler.kind = "uniform", which has no settings
            return f"{path} is not a valid key; this table takes no other keys"
        return f"{path} is not a valid key; valid keys: {', '.join(valid)}"
    counted = _count_message(kind, loc, data, cls, where, ctx)
    if counted is not None:
        return counted
    if kind.startswith("missing"):
        return f"{path}: required key is missing"
    shown = f"{path} = {value!r}"
    if kind == "literal_error":
        options = typing.get_args(_literal(_field_type(owner, loc[-1]))) if loc else ()
        return f"{shown} is not valid; valid: {', '.join(repr(o) for o in options)}"
    if kind == "finite_number":
        return f"{shown} is not valid; expected a finite number"
    bounds = {
        "greater_than_equal": f">= {ctx.get('ge')}",
        "greater_than": f"> {ctx.get('gt')}",
        "less_than_equal": f"<= {ctx.get('le')}",
        "less_than": f"< {ctx.get('lt')}",
    }
    if kind in bounds:
        return f"{shown} is out of range; valid: {bounds[kind]}"
    if kind in _EXPECTED:
        return f"{shown} has the wrong type; expected {_EXPECTED[kind]}"
    return f"{shown} is not valid: {error['msg']}"


def _count_message(
    kind: str,
    loc: list[str | int],
    data: Mapping[str, object],
    cls: type,
    where: str,
    ctx: Mapping[str, object],
) -> str | None:
    """One line for a list of the wrong length: pydantic reports too few items of a fixed-length
    tuple as its first missing item ("decoder_weights[1]: missing"), too many as "too_long"."""
    if kind.startswith("missing") and loc and isinstance(loc[-1], int):
        field_loc = loc[:-1]
    elif kind == "too_long" and loc:
        field_loc = loc
    else:
        return None
    given: object = data
    owner: object = cls
    for part in field_loc:
        given = _item(given, part)
    for part in field_loc[:-1]:
        owner = _field_type(owner, part)
    if not isinstance(given, list) or not isinstance(field_loc[-1], str):
        return None
    args = typing.get_args(_field_type(owner, field_loc[-1]))
    expected = len(args) if args and Ellipsis not in args else f"at most {ctx.get('max_length')}"
    path = where + "".join(
        f"[{p}]" if isinstance(p, int) else f".{shown_key(p)}" for p in field_loc
    )
    return f"{path} = {given!r} has {len(given)} items; expected {expected}"


def _union_message(
    errors: list[ErrorDetails], data: Mapping[str, object], where: str
) -> str | None:
    """One line for a value that no member of a union field takes ("an integer or 'auto'"), or
    None when the first error is not of a union: pydantic then reports one error per member, each
    at the field's location plus the member's tag."""
    *field_loc, tag = errors[0]["loc"]
    value: object = data
    for part in field_loc:
        value = _item(value, part)
    if not field_loc or not isinstance(tag, str) or isinstance(value, (Mapping, list, tuple)):
        return None
    members = [e for e in errors if list(e["loc"][:-1]) == field_loc]
    if len(members) < 2:
        return None
    expected = []
    for error in members:
        kind, ctx = error["type"], error.get("ctx") or {}
        if kind == "literal_error":
            expected.append(str(ctx.get("expected")))
        elif kind == "greater_than_equal":
            expected.append(f"a number >= {ctx.get('ge')}")
        elif kind == "greater_than":
            expected.append(f"a number > {ctx.get('gt')}")
        else:
            expected.append(_EXPECTED.get(kind, error["msg"]))
    path = where + "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in field_loc)
    return f"{path} = {value!r} is not valid; expected {' or '.join(dict.fromkeys(expected))}"


def _item(container: object, part: str | int) -> object:
    """container[part] for a table key or a list index it has, else None."""
    if isinstance(container, Mapping):
        return container.get(part)
    if (
        isinstance(container, (list, tuple))
        and isinstance(part, int)
        and 0 <= part < len(container)
    ):
        return container[part]
    return None


def build(
    cls: type[T],
    table: Mapping[str, object],
    where: str,
    defaults: Mapping[str, object] | None = None,
) -> T:
    """An instance of the table class `cls` from a TOML table, every key and value checked.

    `where` ("file: table") starts every message; `defaults` replace the class defaults for keys
    the table leaves out. A `__post_init__` check that raises SealError, ValueError or TypeError
    becomes a ConfigError at `where`.
    """
    if not isinstance(table, Mapping):
        raise ConfigError(f"{where} must be a table, got {table!r}")
    data = {**(defaults or {}), **table}
    try:
        return _adapter(cls).validate_json(json.dumps(_toml_to_json(data)), strict=True)
    except ValidationError as exc:
        errors = exc.errors()
        if errors and errors[0]["type"] != "value_error":
            message = _union_message(errors, data, where) or _message(errors[0], data, cls, where)
            raise ConfigError(message) from None
        cause = errors[0].get("ctx", {}).get("error") if errors else exc
        raise ConfigError(_at(where, cause)) from None
    except (SealError, TypeError) as exc:
        raise ConfigError(_at(where, exc)) from None


def _at(where: str, cause: object) -> str:
    """`cause` after `where` ("file: table"), without the table twice when the cause already
    starts with it ("agent.hidden: ...", not "agent: agent.hidden: ...")."""
    file, _, table = where.rpartition(": ")
    text = str(cause)
    if file and table and text.startswith(f"{table}."):
        return f"{file}: {text}"
    return f"{where}: {text}"
