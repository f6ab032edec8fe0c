"""`seal run FILE`: run a protocol's seeds into one group (or `seal run --resume RUN_DIR`: continue
one of them)."""

from __future__ import annotations

import argparse
import sys
import traceback
from pathlib import Path


def add_protocol_arguments(parser: argparse.ArgumentParser, *, file_help: str = "") -> None:
    """FILE, --set and --scale: shared by `seal run` (where FILE may be left out with --resume,
    said in `file_help`) and `seal protocol explain|check`."""
    parser.add_argument(
        "file",
        metavar="FILE",
        nargs="?" if file_help else None,
        help="protocol TOML file, e.g. protocols/quickstart.toml" + file_help,
    )
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="TABLE.KEY=VALUE",
        help="override one value (TOML syntax), e.g. --set protocol.epochs=200; repeatable",
    )
    parser.add_argument(
        "--scale",
        type=float,
        default=None,
        metavar="F",
        help="multiply total epochs and every schedule duration by F (floor 1; a 0 meaning off stays 0); per-epoch quantities are unchanged",
    )


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add `seal run`."""
    p = subparsers.add_parser(
        "run", help="run a protocol (all its seeds) and write run directories", description=__doc__
    )
    add_protocol_arguments(
        p,
        file_help="; optional with --resume, which then checks its name and warns where it differs",
    )
    p.add_argument(
        "--out",
        default=None,
        metavar="DIR",
        help="reports root; runs go to DIR/<protocol>/<group>/seed-<n> (default: reports)",
    )
    p.add_argument(
        "--seeds",
        default=None,
        metavar="N|A-B|A,B",
        help="run these seeds instead of the protocol's (e.g. 0-1 or 3)",
    )
    p.add_argument(
        "--resume",
        default=None,
        metavar="RUN_DIR",
        help="continue this seed directory from its last checkpoint, with the config saved in it (FILE, if given, must be the protocol it ran; --set, --scale, --seeds and --out do not apply)",
    )
    p.add_argument(
        "--quiet",
        action="store_true",
        help="no progress bar, and no final table or 'runs written to' line",
    )
    p.add_argument(
        "--json",
        action="store_true",
        help='end with one JSON line: {"run_dir", "update_counts", "final_success"[, "run_dirs"]}',
    )
    p.add_argument(
        "--no-report", action="store_true", help="do not make tables and plots at the end"
    )
    p.set_defaults(func=run)


def parse_seeds(text: str) -> list[int]:
    """ "3" -> [3], "0-2" -> [0, 1, 2], "1,4" -> [1, 4]."""
    from seal.errors import SealError

    seeds: list[int] = []
    try:
        for part in text.split(","):
            lo, sep, hi = part.strip().partition("-")
            seeds.extend(range(int(lo), int(hi) + 1) if sep else [int(lo)])
    except ValueError:
        raise SealError(
            f"--seeds {text!r}: expected N, A-B or A,B,... of non-negative ints"
        ) from None
    if not seeds or min(seeds) < 0:
        raise SealError(f"--seeds {text!r}: expected N, A-B or A,B,... of non-negative ints")
    twice = sorted({s for s in seeds if seeds.count(s) > 1})
    if twice:
        raise SealError(
            f"--seeds {text!r} lists seed {', '.join(map(str, twice))} more than once; "
            "a seed is one run directory"
        )
    return seeds


def run(args: argparse.Namespace) -> int:
    """Load (validating before anything is written), run every seed, report, print JSON."""
    from seal.errors import SealError
    from seal.protocols import load_protocol
    from seal.run.preemption import Preempted
    from seal.run.results import result_json
    from seal.run.runner import new_group_dir, resume_run, run_seed

    if args.resume:
        _check_resume_options(args)
        given = load_protocol(args.file) if args.file else None
        results = [resume_run(args.resume, quiet=args.quiet, protocol=given)]
        group = Path(args.resume).parent
    else:
        if args.file is None:
            raise SealError("give a protocol FILE (or --resume RUN_DIR)")
        config = load_protocol(args.file, args.overrides, args.scale)
        command = [Path(sys.argv[0]).name, *sys.argv[1:]]
        seeds = config.seeds if args.seeds is None else parse_seeds(args.seeds)
        group = new_group_dir(config, "reports" if args.out is None else args.out)
        results = []
        for i, s in enumerate(seeds):
            try:
                results.append(run_seed(config, s, group, quiet=args.quiet, command=command))
            except Preempted as stop:
                if i + 1 < len(seeds):
                    later = ", ".join(map(str, seeds[i + 1 :]))
                    raise Preempted(
                        stop.signum,
                        f"{stop}; seeds {later} of {group} did not start",
                        resumable=stop.resumable,
                    ) from None
                raise
    table = None if args.no_report else _report(group)
    if not args.quiet and not args.json:
        if table is not None:
            print(table.read_text())
        print(f"runs written to {group}")
    if args.json:
        print(result_json(results))
    return 0


def _check_resume_options(args: argparse.Namespace) -> None:
    """A resumed run keeps the config and directory it saved: options that would change them are
    refused, not silently dropped."""
    from seal.errors import SealError

    given = [
        flag
        for flag, value in (
            ("--set", args.overrides or None),
            ("--scale", args.scale),
            ("--seeds", args.seeds),
            ("--out", args.out),
        )
        if value is not None
    ]
    if given:
        raise SealError(
            f"--resume {args.resume}: {', '.join(given)} cannot change a resumed run "
            "(it goes on with the config and directory it saved); drop them, or start a new run"
        )


def _report(group: Path) -> Path | None:
    """Tables and plots for the group; the update-count table's Markdown file, or None if the
    report failed (a failure here never loses the run)."""
    from seal.errors import SealError
    from seal.reports import report
    from seal.run.dirlock import DirLock

    try:
        with DirLock(group):
            return report([group], out=group).tables["update_counts.md"]
    except SealError as exc:  # e.g. another process writes the group's report now
        print(f"seal run: warning: no tables and plots for {group}: {exc}", file=sys.stderr)
        return None
    except Exception:  # noqa: BLE001 - the runs are on disk; say what failed and go on
        print(
            f"seal run: warning: making tables and plots for {group} failed (the runs are complete; retry with `seal report {group}`):",
            file=sys.stderr,
        )
        traceback.print_exc(file=sys.stderr)
        return None
