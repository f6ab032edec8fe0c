"""`seal report RUN_OR_GROUP... [--json] [--out DIR] [--threshold T] [--consecutive K] [--censored run-total|zero] [--x grad_steps|epoch]`."""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `report` subcommand."""
    parser = subparsers.add_parser(
        "report",
        help="tables (update counts, success) and plots from run or group directories",
        description=(
            "Merge the seeds of one or more groups (reports/<protocol>/<group-id>/) or single runs "
            "(.../seed-<n>/) into the paper's update-count table (Task x {Single Env, 50/50, High FK, "
            "High MW, Pre-train on X, Fine-tune on Y}) with the percent change against Single Env and its "
            "95% CI (Fieller's, t quantiles), gradient steps x per-step batch beside each count, "
            "a final-success table, success curves per environment and critic-loss curves. "
            "Writes <out>/tables/ (Markdown, CSV, LaTeX) and <out>/plots/ (PNG)."
        ),
    )
    parser.add_argument(
        "paths", nargs="+", metavar="RUN_OR_GROUP", help="run directories and/or group directories"
    )
    parser.add_argument(
        "--out",
        metavar="DIR",
        default=None,
        help="output directory (default: the run or group when there is one, else a new directory <reports root>/comparison/<protocols>/<time>-<random>)",
    )
    parser.add_argument(
        "--threshold",
        type=float,
        default=None,
        help="success rate a task must reach for the update-count metric (default: the runs' [evaluation].threshold when they all agree, else 0.9)",
        metavar="T",
    )
    parser.add_argument(
        "--consecutive",
        type=int,
        default=1,
        metavar="K",
        help="a task has reached when K successive evaluations are >= the threshold; counted at the first of them (default: 1, the paper's criterion)",
    )
    parser.add_argument(
        "--censored",
        choices=("run-total", "zero"),
        default="run-total",
        help="how a total counts a task some seed never brought to the threshold: at that seed's run "
        'total, the total then printed as a lower bound "≥ x" (default), or as 0 (the paper\'s rule, '
        "which makes a failed arm look cheap)",
    )
    parser.add_argument(
        "--x",
        choices=("grad_steps", "epoch"),
        default="grad_steps",
        help="x axis of the plots (default: grad_steps)",
    )
    parser.add_argument(
        "--json",
        action="store_true",
        help="print one JSON line with the paths and update-count numbers",
    )
    parser.set_defaults(func=run)


def _entries(target: str | None) -> set[str] | None:
    """The names in the report's target directory, or None when it does not exist yet."""
    path = Path(target) if target is not None else None
    return None if path is None or not path.is_dir() else {p.name for p in path.iterdir()}


def _remove_new(target: str | None, before: set[str] | None) -> None:
    """Remove what a failed report made in `target`: all of it when it made the directory,
    else its lock file and the folders (plots/, tables/) that were not there before. The lock
    kept any other writer out meanwhile, so what is new is the report's."""
    if target is None:
        return
    path = Path(target)
    if before is None:
        shutil.rmtree(path, ignore_errors=True)
        return
    for entry in path.iterdir():
        if entry.name in before:
            continue
        if entry.name == ".seal.lock" and entry.is_file():
            entry.unlink()
        elif entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry, ignore_errors=True)


def run(args: argparse.Namespace) -> int:
    """Build the report and print where it went (or one JSON line)."""
    from seal.reports import check_report_inputs, report
    from seal.run.dirlock import DirLock

    # Refused before the lock is taken, so a mistake leaves no directory and no lock file.
    check_report_inputs(args.paths, args.out, args.threshold, args.consecutive)

    # One writer per directory: lock the run or group the tables and plots go into. A comparison
    # of several without --out takes no lock: its directory is made new and unique, so no
    # other process writes there (seal.reports._default_out).
    single = args.paths[0] if len(args.paths) == 1 and Path(args.paths[0]).is_dir() else None
    target = args.out or single
    lock = DirLock(Path(target)) if target is not None else None
    before = _entries(target)
    if lock is not None:
        lock.acquire()
    try:
        try:
            result = report(
                args.paths,
                out=args.out,
                threshold=args.threshold,
                x=args.x,
                consecutive=args.consecutive,
                censored=args.censored,
            )
        finally:
            if lock is not None:
                lock.release()
    except BaseException:  # refused while reading the runs, a bug or Ctrl-C: leave the target
        _remove_new(target, before)  # as it was (a new --out goes whole)
        raise
    for note in result.skipped:
        print(f"seal report: note: {note}", file=sys.stderr)
    for warning in result.warnings:
        print(f"seal report: warning: {warning}", file=sys.stderr)
    if args.json:
        print(json.dumps(result.to_json()))
        return 0
    print((result.tables["update_counts.md"]).read_text())
    if "update_changes.md" in result.tables:
        print(result.tables["update_changes.md"].read_text())
    print(f"tables: {result.out_dir / 'tables'}")
    for path in result.plots:
        print(f"plot:   {path}")
    return 0
