"""Adapters by name (built-ins) or by import path ("package.module:Class", third-party), and the
env maps that positive controls start from (`env_map`)."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Mapping, Sequence
from typing import Any

from seal.envs.base import EnvAdapter, EnvMap
from seal.errors import SealError, UnknownNameError

BUILTIN_ADAPTERS: dict[str, str] = {
    "metaworld": "seal.envs.metaworld:MetaWorldAdapter",
    "franka_kitchen_dense": "franka_kitchen_dense.adapter:FrankaKitchenDenseAdapter",
    "point": "seal.envs.point:PointAdapter",
    # The transfer testbed (docs/transfer_testbed.md): point behind other spaces, point on diagonals.
    "point_view": "seal.envs.testbed:PointViewAdapter",
    "point_diagonal": "seal.envs.testbed:PointDiagonalAdapter",
}


def adapter_class(name_or_path: str) -> type[EnvAdapter]:
    """The adapter class for a built-in name or an import path "package.module:Class"."""
    cls = _resolve("adapter", name_or_path, BUILTIN_ADAPTERS, "Class")
    if not (isinstance(cls, type) and issubclass(cls, EnvAdapter)):
        raise SealError(
            f"adapter {name_or_path!r}: {_path(name_or_path, BUILTIN_ADAPTERS)} is not a "
            f"seal.envs.EnvAdapter subclass; built-in adapters: {', '.join(BUILTIN_ADAPTERS)}"
        )
    return cls


def make_adapter(
    name_or_path: str, tasks: Sequence[str] | str | None = None, **options: Any
) -> EnvAdapter:
    """Build an adapter by name or import path, with its task list and options."""
    return adapter_class(name_or_path)(tasks=tasks, **options)


def check_options(options: Mapping[str, Any]) -> None:
    """SealError for an adapter option that repeats one of every adapter's own arguments (tasks,
    episode_length), which the env sets by its own keys; Python would raise a bare TypeError."""
    repeated = sorted(set(options) & {"tasks", "episode_length"})
    if repeated:
        key = repeated[0]
        raise SealError(
            f"option {key!r} is not an adapter option: it is the env's own key, "
            f"[envs.<name>] {key} = ... in a protocol"
            + ("; --tasks in seal envs check" if key == "tasks" else "")
        )


BUILTIN_ENV_MAPS: dict[str, str] = {
    # The transfer testbed's oracle (docs/transfer_testbed.md, round 5): point -> point_view.
    "testbed_oracle": "seal.envs.testbed:ORACLE_MAP",
}


def env_map(name_or_path: str) -> EnvMap:
    """The `EnvMap` of a built-in name or an import path "package.module:NAME"."""
    found = _resolve("env map", name_or_path, BUILTIN_ENV_MAPS, "NAME")
    if not isinstance(found, EnvMap):
        raise SealError(
            f"env map {name_or_path!r}: {_path(name_or_path, BUILTIN_ENV_MAPS)} is not a "
            f"seal.envs.base.EnvMap; built-in env maps: {', '.join(BUILTIN_ENV_MAPS)}"
        )
    return found


def _path(name_or_path: str, builtins: Mapping[str, str]) -> str:
    """ "package.module.ATTR" of a built-in name or an import path."""
    return builtins.get(name_or_path, name_or_path).replace(":", ".")


def _resolve(kind: str, name_or_path: str, builtins: Mapping[str, str], attr_word: str) -> object:
    """The object a built-in name or an absolute import path "package.module:ATTR" names (None
    when the module lacks ATTR); SealError naming `name_or_path` and the valid names otherwise."""
    path = builtins.get(name_or_path, name_or_path)
    placeholder = f"package.module:{attr_word}"
    if ":" not in path:
        raise UnknownNameError(kind, name_or_path, [*builtins, placeholder])
    module_name, _, attr = path.partition(":")
    valid = f"valid: {', '.join(builtins)} or an absolute import path {placeholder}"
    if not all(part.isidentifier() for part in module_name.split(".")):
        # importlib would raise TypeError (".x": a relative import) or ValueError (""), not ImportError.
        raise SealError(
            f"{kind} {name_or_path!r}: module {module_name!r} is not an absolute import path; {valid}"
        )
    if not attr.isidentifier():
        raise SealError(
            f"{kind} {name_or_path!r}: {attr!r} after the ':' is not a Python name; {valid}"
        )
    if module_name.partition(".")[0] in sys.stdlib_module_names:
        # Holds no adapter or map, and some of it acts on import (antigravity opens a web
        # browser): a protocol or checkpoint from elsewhere must not make `seal` import it.
        raise SealError(
            f"{kind} {name_or_path!r}: module {module_name!r} is in Python's standard library, "
            f"which holds no {kind}; {valid}"
        )
    if "__main__" in module_name.split("."):
        # A package's __main__ is its command line: importing it runs it (PIL prints a report,
        # certifi parses seal's arguments), and it holds no adapter or map.
        raise SealError(
            f"{kind} {name_or_path!r}: module {module_name!r} is a package's command line "
            f"(__main__), which runs when imported; {valid}"
        )
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        top = module_name.partition(".")[0]
        hint = (
            f"; is {top} installed, or the folder that holds {top} on PYTHONPATH?"
            if isinstance(exc, ModuleNotFoundError) and exc.name == top
            else ""
        )
        raise SealError(
            f"{kind} {name_or_path!r}: cannot import module {module_name!r} ({exc}{hint}); {valid}"
        ) from None
    return getattr(module, attr, None)
