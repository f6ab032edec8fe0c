"""`seal envs`: list adapters and their tasks; `seal envs check NAME`: check one adapter."""

from __future__ import annotations

import argparse
import json
import sys
import tomllib
from typing import Any


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add `seal envs [--json]` and `seal envs check NAME [--tasks ...] [--seed N] [--option K=V] [--json]`."""
    parser = subparsers.add_parser(
        "envs",
        help="list environment adapters, or check one",
        description="List the built-in environment adapters with their observation and action sizes, "
        "episode length and tasks (or check one: seal envs check NAME).",
    )
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")
    parser.set_defaults(func=list_adapters)
    sub = parser.add_subparsers(dest="envs_command", metavar="SUBCOMMAND")
    check = sub.add_parser(
        "check",
        help="check an adapter's API conformance and reward semantics",
        description="Check an adapter, in the style of stable-baselines3's check_env: the interface's "
        "promises on every task (spaces, seeding, episodes), then the adapter's own reward and "
        "success checks. Prints a line a task with its figures and ok or FAIL, then the verdict; "
        "exits 1 when a task fails.",
    )
    check.add_argument(
        "name", help="a built-in adapter name or an import path package.module:Class"
    )
    check.add_argument(
        "--tasks", nargs="+", help="task names or task-set names (default: the adapter's tasks)"
    )
    check.add_argument(
        "--seed", type=int, default=0, help="seed for envs and random actions (default: 0)"
    )
    check.add_argument(
        "--option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="an adapter option, value as TOML (e.g. gravity_compensation=true); repeatable",
    )
    # SUPPRESS keeps a --json given before `check` (seal envs --json check NAME) from being reset.
    check.add_argument(
        "--json", action="store_true", default=argparse.SUPPRESS, help="print the report as JSON"
    )
    check.set_defaults(func=check_command)


def list_adapters(args: argparse.Namespace) -> int:
    """Print every built-in adapter's tasks and sizes; an adapter that fails to load shows its error."""
    from seal.envs.registry import BUILTIN_ADAPTERS, make_adapter

    listing: dict[str, dict[str, Any]] = {}
    for name in BUILTIN_ADAPTERS:
        try:
            listing[name] = make_adapter(name).describe()
        except Exception as exc:  # noqa: BLE001 - one broken adapter must not hide the others
            listing[name] = {"error": f"{type(exc).__name__}: {exc}"}
    if args.json:
        print(json.dumps({"adapters": listing}, indent=2))
        return 0
    for name, info in listing.items():
        if "error" in info:
            print(f"{name}: unavailable ({info['error']})")
            continue
        print(
            f"{name}: obs_dim {info['obs_dim']}, act_dim {info['act_dim']}, episode_length {info['episode_length']}"
        )
        print(f"  tasks: {', '.join(info['tasks'])}")
    return 0


def check_command(args: argparse.Namespace) -> int:
    """Run `check_adapter`; exit 0 when every task is ok, 1 otherwise (bad names exit 2 via SealError)."""
    from seal.envs.check import check_adapter
    from seal.envs.registry import check_options, make_adapter
    from seal.errors import SealError

    if args.seed < 0:  # gymnasium's seeding refuses it, which would read as every task failing
        raise SealError(f"--seed {args.seed}: must be >= 0")
    options = _options(args.option)
    check_options(options)  # make_adapter takes episode_length as a keyword; --option may not
    adapter = make_adapter(args.name, tasks=args.tasks, **options)
    as_json = getattr(args, "json", False)
    progress = None if as_json else (lambda line: print(line, file=sys.stderr, flush=True))
    report = check_adapter(adapter, seed=args.seed, progress=progress)
    if as_json:
        print(json.dumps(report, indent=2))
    else:
        for task, result in report["tasks"].items():
            figures = ", ".join(
                f"{k} {_fmt(v)}"
                for k, v in result.items()
                if k not in ("ok", "errors", "api_ok", "semantic_ok")
            )
            print(f"{'ok  ' if result['ok'] else 'FAIL'} {task}: {figures}")
            for error in result["errors"]:
                print(f"     {error}")
        print(f"{report['adapter']}: {'ok' if report['ok'] else 'NOT ok'}")
    return 0 if report["ok"] else 1


def _options(pairs: list[str]) -> dict[str, Any]:
    """--option KEY=VALUE pairs as a dict; values parse as TOML, anything else stays a string."""
    from seal.errors import SealError

    options: dict[str, Any] = {}
    for pair in pairs:
        key, sep, raw = pair.partition("=")
        if not sep or not key.strip():
            raise SealError(
                f"--option {pair!r} must look like key=value (e.g. gravity_compensation=true)"
            )
        try:
            options[key.strip()] = tomllib.loads(f"v = {raw.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            options[key.strip()] = raw.strip()
    return options


def _fmt(value: object) -> str:
    return f"{value:.3g}" if isinstance(value, float) else str(value)
