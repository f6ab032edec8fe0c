"""`seal` entry point: dispatches to one subcommand module; user errors print one line and exit 2."""

from __future__ import annotations

import argparse
import importlib
import sys
import warnings
from typing import NoReturn

# Each module defines `register(subparsers)`, which adds its parser with `set_defaults(func=...)`.
# A module that does not exist yet is skipped, so the CLI grows with the package.
SUBCOMMAND_MODULES = (
    "seal.cli.envs_cmd",
    "seal.cli.run_cmd",
    "seal.cli.report_cmd",
    "seal.cli.eval_cmd",
    "seal.cli.protocol_cmd",
    "seal.cli.bench_cmd",
    "seal.cli.sweep_cmd",
)


class _OneLineParser(argparse.ArgumentParser):
    """argparse with a one-line error (no usage block), like every other `seal` error; exit 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see `{self.prog} --help`)\n")


def build_parser() -> argparse.ArgumentParser:
    """The full `seal` argument parser."""
    parser = _OneLineParser(prog="seal", description="SEAL: cross-environment multi-task RL.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:
                continue
            raise
        module.register(sub)
    return parser


def _show_seal_warnings() -> None:
    """Print SEAL's own warnings as one line each, "seal: warning: ...", not Python's two-line
    "file:line: SealWarning" form; every other warning is shown as Python shows it."""
    from seal.errors import SealWarning

    show = warnings.showwarning
    if getattr(show, "seal_one_line", False):
        return

    def one_line(message, category, filename, lineno, file=None, line=None):  # type: ignore[no-untyped-def]
        if issubclass(category, SealWarning):
            print(f"seal: warning: {message}", file=sys.stderr if file is None else file)
            return
        show(message, category, filename, lineno, file, line)

    one_line.seal_one_line = True  # type: ignore[attr-defined]
    warnings.showwarning = one_line


def main(argv: list[str] | None = None) -> int:
    """Run one `seal` command and return its exit code."""
    from seal.errors import SealError
    from seal.run.preemption import Preempted

    _show_seal_warnings()
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except SealError as exc:
        # One line whatever the message holds (a user's key or value with a newline in it).
        message = str(exc).strip().replace("\r", "\\r").replace("\n", "\\n")
        print(f"seal {args.command}: error: {message}", file=sys.stderr)
        return 2
    except Preempted as stop:  # SIGTERM or SIGINT: saved at a safe point (checkpoint.on_signal)
        print(f"seal {args.command}: {stop}", file=sys.stderr, flush=True)
        return stop.exit_code
    except KeyboardInterrupt:
        print(f"seal {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
