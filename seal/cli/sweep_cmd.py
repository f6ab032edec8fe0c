"""`seal sweep FILE... [--seeds 0-4] [--search] [--address auto|HOST:PORT] [--resume DIR] [--json]`.

Ray is imported only when the command runs (inside `seal.sweep`), never when the CLI starts.
"""

from __future__ import annotations

import argparse
import json
import sys


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `sweep` subcommand."""
    parser = subparsers.add_parser(
        "sweep",
        help="run seeds x protocols on Ray, or a random hyperparameter search with Ray Tune",
        description=(
            "Run every (protocol, seed) pair as its own Ray task; each writes the run directory "
            "`seal run` writes, all seeds of a protocol in one group, and the finished runs are "
            "aggregated into `seal report`'s tables. With --search, let Ray Tune draw --samples "
            "configs from the protocol's [search] table (seeded) and run them (ASHA early stopping with "
            'scheduler = "asha"), then write a ranked table and best.toml. A [resources] table '
            "(cpus, gpus) sets what each trial reserves. Without --address a local Ray starts "
            "inside this process; --address auto or HOST:PORT joins a running cluster. Exits 1 when a "
            "trial failed or is unfinished (the table says which)."
        ),
    )
    parser.add_argument(
        "files", nargs="*", metavar="FILE", help="protocol TOML files (one with --search)"
    )
    parser.add_argument(
        "--seeds",
        default=None,
        metavar="N|A-B|A,B",
        help="seeds of every protocol (default: each protocol's own); --search uses one seed, default the protocol's first",
    )
    parser.add_argument(
        "--scale",
        type=float,
        default=None,
        metavar="F",
        help="multiply total epochs and every schedule duration by F (as `seal run --scale`)",
    )
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="TABLE.KEY=VALUE",
        help="override one value of every protocol (TOML syntax); repeatable",
    )
    parser.add_argument(
        "--address",
        default=None,
        metavar="auto|HOST:PORT",
        help="join this Ray cluster (default: start a local Ray in this process)",
    )
    parser.add_argument(
        "--num-cpus",
        "--jobs",  # `seal bench --learn`'s name for the same thing
        dest="num_cpus",
        type=int,
        default=None,
        metavar="N",
        help="CPUs of the local Ray (default: all of this machine's); not with --address",
    )
    parser.add_argument(
        "--out",
        default="reports",
        metavar="DIR",
        help="reports root (default: reports): runs go to DIR/<protocol>/<group>/seed-<n>, the sweep's own files to that group for one protocol or to DIR/sweeps/<id> for several; with --search, DIR/<protocol>/search-<id>/sample-<k>/seed-<n>",
    )
    parser.add_argument(
        "--resume",
        default=None,
        metavar="SWEEP_DIR",
        help="continue an earlier sweep (or, with --search, search) directory: finished trials are kept, others continue or start",
    )
    parser.add_argument(
        "--grace-s",
        type=float,
        default=None,
        metavar="S",
        help="on SIGTERM or SIGINT, wait up to S seconds for the running trials to save their last finished epoch (default: 60); set it a little under the grace period the cluster gives (Slurm KillWait, Kubernetes terminationGracePeriodSeconds)",
    )
    parser.add_argument(
        "--search",
        action="store_true",
        help="random search over the protocol's [search] table with Ray Tune",
    )
    parser.add_argument(
        "--samples",
        type=int,
        default=None,
        metavar="N",
        help="--search: random draws (default: [search].num_samples, else 10)",
    )
    parser.add_argument(
        "--json",
        action="store_true",
        help='end with one JSON line: {"run_dirs": [...], "table": path, "sweep_dir", "failed", ...}',
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the sweep or search; exit 1 when a trial failed or did not finish (everything is still written)."""
    from seal.cli.run_cmd import parse_seeds
    from seal.errors import SealError
    from seal.sweep.grid import sweep
    from seal.sweep.search import search

    def say(message: str) -> None:
        print(f"seal sweep: {message}", file=sys.stderr, flush=True)

    seeds = None if args.seeds is None else parse_seeds(args.seeds)
    if args.resume and args.files:
        raise SealError(
            f"--resume {args.resume}: give either protocol FILEs or --resume, not both (a resume runs what the sweep directory recorded)"
        )
    if args.num_cpus is not None and args.num_cpus < 1:
        raise SealError(
            f"--num-cpus {args.num_cpus}: expected an integer >= 1 (default: all of this machine's)"
        )
    if args.num_cpus is not None and args.address is not None:
        raise SealError(
            f"--num-cpus {args.num_cpus} sets the CPUs of a local Ray; with --address "
            f"{args.address} the cluster's nodes decide (drop one of them)"
        )
    common = {
        "out": args.out,
        "address": args.address,
        "num_cpus": args.num_cpus,
        "resume": args.resume,
        "progress": say,
    }
    if args.search:
        if len(args.files) > 1:
            raise SealError(
                f"--search takes one protocol FILE, got {len(args.files)}: {' '.join(args.files)}"
            )
        if args.grace_s is not None:
            raise SealError(
                "--grace-s is for sweeps; a search stops its trials through Ray Tune, which keeps its own state"
            )
        if seeds is not None and len(seeds) != 1:
            raise SealError(
                f"--seeds {args.seeds}: a search runs one seed per sample; search with one seed, then run "
                f"the best config on many: seal sweep <search dir>/best.toml --seeds {args.seeds}"
            )
        result = search(
            args.files[0] if args.files else None,
            seed=seeds[0] if seeds else None,
            num_samples=args.samples,
            overrides=args.overrides,
            scale=args.scale,
            **common,
        )
    else:
        if args.samples is not None:
            raise SealError("--samples is only used with --search")
        if args.grace_s is not None and not args.grace_s >= 0:
            raise SealError(f"--grace-s {args.grace_s:g}: expected seconds >= 0")
        grace = {} if args.grace_s is None else {"grace_s": args.grace_s}
        result = sweep(
            args.files, seeds=seeds, overrides=args.overrides, scale=args.scale, **common, **grace
        )
    for note in result.notes:
        say(f"note: {note}")
    if args.json:
        print(json.dumps(result.to_json()))
    else:
        print(result.trials_table.read_text())
        if result.table is not None and result.table != result.trials_table:
            print(f"aggregated table: {result.table}")
        if result.best_config is not None:
            print(f"best config: {result.best_config}  (seal run {result.best_config})")
        print(f"sweep directory: {result.sweep_dir}")
    unfinished = any(t.status == "pending" for t in result.trials)
    return 1 if result.failed or unfinished else 0
