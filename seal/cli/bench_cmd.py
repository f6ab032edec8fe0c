"""`seal bench [--json] [--quick] [--learn [transfer|kitchen|table1|quickstart|reach_sb3|mtrl|learner] [--full | --fpr | --ladder] [--seeds-until-mde T --max-seeds N]]`: learner and collection speed as ratios, learning evidence."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from typing import Any

DESCRIPTION = """\
Speed as ratios against a reference timed side by side in one run, and learning evidence.

Speed (the default run; a table, or one JSON object with --json):
  sac_vs_sb3, mt10_update_flops_fraction, small_update_flops_fraction, collect_mt10_speedup,
  collect_fk_speedup, ratio_lever, paco_update_speedup
  --only paper_update_rate  the paper-scale SEAL update (MT10 + 10 kitchens, batch 2,560), eager
                            and compiled, CUDA graphs on a GPU (slow on a CPU, so not in the
                            default run)
  --only e2e_vs_sb3         the same learning work under stable-baselines3's SAC.learn and seal
                            run's loop on reach-v3 and slide-cabinet (--e2e-steps env steps each)
  --protocol FILE           --epochs epochs of a protocol measured, its wall time a seed projected

Learning evidence (--learn; slow, not for CI; docs/benchmarks.md):
  (no name)   the speed benches, then MTMHSAC learning point (with and without one-hot) and
              reach-v3
  transfer    the cross-environment transfer testbed (protocols/testbed, docs/transfer_testbed.md):
              every arm against its alone arm, steps_saved and transfer_updates_saved with 95% t
              CIs; --full, --ladder, --fpr and --seeds-until-mde choose other arms or rules
  kitchen     the kitchen runs (protocols/kitchen_learn): per run the first crossing, final
              success, held_90 and the end ratio of the critic's Q to what was earned; the goals,
              collapse_test, reward_test[_critic_ln] and learner_test[_bronet[_vs_critic_ln]]
              (docs/hyperparameters.md)
  table1      paper Table 1 at laptop scale (protocols/table1_small): `seal report`'s table
  quickstart  README command 1's protocol, seeds 0-9: the README's table, curve and k-of-10 (docs/)
  reach_sb3   reach-v3 under seal run and under SB3's SAC.learn, seeds 0-2, k of 3 a side
  mtrl        SMT Table 1's learners (protocols/mtrl_learn) on two easy MT10 tasks: k of 3, each
              task's first crossing, updates/s against MTMHSAC's timed side by side
  learner     with --set agent.KEY=VALUE: whether a learner change is no slower on Meta-World
              (issue 54's rule: the quickstart, table1's single_mw and reach, seed-paired)

Every named --learn bench runs each run as a Ray task (the ray extra: pip install 'seal[ray]')
that runs its protocol as `seal run` does, on a private local Ray of --jobs CPUs or, with
--address, on a Ray cluster whose nodes all see --out at the same path (a shared filesystem).
"""


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `bench` subcommand."""
    parser = subparsers.add_parser(
        "bench",
        help="benchmark the learner and collection against references (ratios)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=DESCRIPTION,
    )
    parser.add_argument(
        "--json", action="store_true", help="print one JSON object instead of the table"
    )
    parser.add_argument(
        "--quick", action="store_true", help="few repeats and short episodes (noisier numbers)"
    )
    parser.add_argument(
        "--learn",
        nargs="?",
        const="evidence",
        default=None,
        metavar="transfer|kitchen|table1|quickstart|reach_sb3|mtrl|learner",
        help="a learning bench listed above, run instead of the speed benches; with no name, the speed benches and then the learning checks of point and reach-v3 (slow; not for CI)",
    )
    parser.add_argument(
        "--full",
        action="store_true",
        help="with --learn transfer: also the per_env, 50/50 and high-target arms, the shared-critic diagnostic, and their target-alone arms",
    )
    parser.add_argument(
        "--ladder",
        action="store_true",
        help="with --learn transfer: only the ladder (docs/transfer_testbed.md, \"Ladder\"): oracle_translator, the six ladder_* cells and oracle_policy (every subset of head, critic and temperatures mapped on top of the perfect translator) with their alone arm and pre-training; prints each arm's AUC and steps to 90%% and the 2^3 factorial's main effects and interactions with paired t CIs and MDEs beside each mapped piece's end drift, and writes <out>/transfer/ladder.json and plots/ladder.png",
    )
    parser.add_argument(
        "--fpr",
        action="store_true",
        help="with --learn transfer: only the false-positive rate: run the alone arm for --seeds seeds (default 10), draw 1,000 random 5/5 splits of them, pair the halves at random, and report the share of the arms' 95%% CIs that exclude 0, with its binomial 95%% CI",
    )
    parser.add_argument(
        "--seeds",
        type=int,
        default=None,
        metavar="N",
        help="with a --learn bench: seeds 0..N-1 per arm (default 5 for transfer, 2 for kitchen, 5 for table1, 10 for quickstart and learner, 3 for reach_sb3 and mtrl)",
    )
    parser.add_argument(
        "--seeds-until-mde",
        type=float,
        default=None,
        metavar="TARGET",
        help="with --learn transfer and --max-seeds, instead of --seeds: start at 5 seeds and add "
        "a batch at a time (as many runs as go at once) until every named statistic's MDE is "
        "<= TARGET, or --max-seeds is reached. The statistics: steps_saved and the AUC gain "
        "of high_source, pretrained_trunk, oracle_translator and no_correspondence. The MDE "
        "uses the one-sided 80%% chi-square upper limit on the paired SD. With --fpr: the CI's "
        "false-positive rate under this rule, on max(40, 2 x --max-seeds) alone seeds "
        "(docs/transfer_testbed.md)",
    )
    parser.add_argument(
        "--max-seeds",
        type=int,
        default=None,
        metavar="N",
        help="with --seeds-until-mde: the most seeds the rule runs (>= 5)",
    )
    parser.add_argument(
        "--arms",
        nargs="+",
        metavar="ARM",
        default=None,
        help="with --learn transfer|kitchen|table1|quickstart|reach_sb3|mtrl|learner: only these arms (protocols/testbed/<ARM>.toml and the alone arms and pre-trainings they need, positive_pretrained being round 4's name of pretrained_trunk; protocols/kitchen_learn/<ARM>.toml; protocols/table1_small/<ARM>.toml and its references; seal or sb3 for reach_sb3; protocols/mtrl_learn/<ARM>.toml and sac_mt_mh; quickstart, table1_single_mw or reach for learner)",
    )
    parser.add_argument(
        "--reuse",
        action="store_true",
        help="with a --learn bench: take finished runs under --out whose resolved config is today's instead of running them again, and (except reach_sb3) resume unfinished ones from their last checkpoint where it holds the replay (checkpoint.save_replay; the others run again)",
    )
    parser.add_argument(
        "--no-run",
        action="store_true",
        help="with --learn kitchen, learner, mtrl or transfer (not with --fpr or --seeds-until-mde): run and resume nothing; report the finished runs under --out that --reuse would take (run records, say) and name the ones not found (transfer: over the seeds 0..k-1 that have a run of every arm)",
    )
    parser.add_argument(
        "--jobs",
        "--num-cpus",  # `seal sweep`'s name for the same thing
        dest="jobs",
        type=int,
        default=None,
        metavar="N",
        help="with a --learn bench: CPUs of the private local Ray the runs share (default 2). A run reserves the CPUs its protocol.threads resolves to, one for every shipped bench protocol, so --jobs 2 runs two at a time; a quickstart run reserves them all, so its seeds run one at a time. Not with --address",
    )
    parser.add_argument(
        "--address",
        default=None,
        metavar="auto|HOST:PORT",
        help="with a --learn bench: run on the Ray cluster at this address (auto: the one `ray start` began on this machine) instead of a private local Ray; every node must see --out at the same path (a shared filesystem), which is checked before the first run",
    )
    parser.add_argument(
        "--out",
        default=None,
        metavar="DIR",
        help="with a --learn bench: reports root of the runs (default reports/bench_<bench>, e.g. reports/bench_kitchen)",
    )
    parser.add_argument(
        "--only", nargs="+", metavar="KEY", help="run only these keys, e.g. --only sac_vs_sb3"
    )
    parser.add_argument(
        "--threads",
        type=int,
        default=None,
        help="torch intra-op threads for both sides (default: torch's)",
    )
    parser.add_argument(
        "--repeats", type=int, default=None, help="timing repeats (best of N); overrides the preset"
    )
    parser.add_argument(
        "--e2e-steps",
        type=int,
        default=None,
        metavar="N",
        help="with --only e2e_vs_sb3: env steps with updates timed on each side, per env (default 20,000; whole episodes)",
    )
    parser.add_argument(
        "--protocol",
        default=None,
        metavar="FILE",
        help="measure --epochs epochs of this protocol (collection, updates, evaluation, checkpoint) and project its whole wall time per seed",
    )
    parser.add_argument(
        "--epochs",
        type=int,
        default=None,
        help="with --protocol: epochs per phase to measure (default 5)",
    )
    parser.add_argument(
        "--cores",
        type=int,
        default=None,
        help="with --protocol: project the env-stepping floor and the serial and overlapped wall times for this many cores (default: this machine's)",
    )
    parser.add_argument(
        "--update-rate",
        type=float,
        default=None,
        metavar="UPDATES_PER_S",
        help="with --protocol: project with this update rate instead of the window's (e.g. 1000, the one-GPU goal)",
    )
    parser.add_argument(
        "--floor-only",
        action="store_true",
        help="with --protocol: measure the env step costs only, no window (projections need --update-rate)",
    )
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="TABLE.KEY=VALUE",
        help="with --protocol or --learn transfer, table1, quickstart, reach_sb3, kitchen, mtrl or learner: override a protocol value (e.g. protocol.device=cuda, evaluation.stop_when_reached=false)",
    )
    parser.add_argument(
        "--baseline",
        action="append",
        default=[],
        metavar="TABLE.KEY=VALUE",
        help="with --learn learner: the old side's overrides (default: the protocols as shipped), e.g. --baseline agent.critic_layer_norm=false to compare against the learner before a default moved",
    )
    parser.set_defaults(func=run)


LEARN_SETS: dict[str, tuple[str, int, str]] = {
    "transfer": ("seal.experiments.transfer", 5, "reports/bench_transfer"),
    "kitchen": ("seal.experiments.kitchen", 2, "reports/bench_kitchen"),
    "table1": ("seal.experiments.table1", 5, "reports/bench_table1"),
    "quickstart": ("seal.experiments.quickstart", 10, "reports/bench_quickstart"),
    "reach_sb3": ("seal.experiments.reach_sb3", 3, "reports/bench_reach_sb3"),
    "mtrl": ("seal.experiments.mtrl", 3, "reports/bench_mtrl"),
    "learner": ("seal.experiments.learner", 10, "reports/bench_learner"),
}
"""`--learn <set>`: the module (with run_<set>_bench and format_result), default seeds and reports root."""
OVERRIDE_SETS = ("transfer", "table1", "quickstart", "reach_sb3", "kitchen", "mtrl", "learner")
"""The `--learn` sets that take `--set` overrides of their protocols."""


def run(args: argparse.Namespace) -> int:
    """Run the benchmark and print the result."""
    import dataclasses

    import torch

    from seal.bench.suite import BenchSettings, format_table, run_bench
    from seal.errors import SealError

    def log(msg: str) -> None:
        print(f"[bench] {msg}", file=sys.stderr, flush=True)

    if args.learn not in (None, "evidence", *LEARN_SETS):
        raise SealError(
            f"--learn {args.learn!r}: unknown; valid: --learn, "
            + ", ".join(f"--learn {name}" for name in LEARN_SETS)
        )
    if args.full and args.learn != "transfer":
        raise SealError("--full only applies to --learn transfer")
    if args.fpr and (args.learn != "transfer" or args.full or args.arms):
        raise SealError("--fpr only applies to --learn transfer, without --full and --arms")
    until_mde = args.seeds_until_mde is not None
    if (until_mde or args.max_seeds is not None) and args.learn != "transfer":
        raise SealError("--seeds-until-mde and --max-seeds only apply to --learn transfer")
    if until_mde != (args.max_seeds is not None):
        raise SealError("--seeds-until-mde TARGET and --max-seeds N go together")
    if until_mde and args.seeds is not None:
        raise SealError(
            "--seeds N runs N seeds; --seeds-until-mde runs seeds until the MDE target "
            "(up to --max-seeds): give one of them"
        )
    if until_mde:
        from seal.experiments.until_mde import check_rule

        check_rule(args.seeds_until_mde, args.max_seeds)
    if args.overrides and args.learn == "transfer" and (args.fpr or until_mde):
        raise SealError(
            "--set applies to --learn transfer's arms (a testbed variant: every arm, alone arms "
            "included, runs with it), not to --fpr or --seeds-until-mde"
        )
    if args.ladder and (
        args.learn != "transfer" or args.full or args.fpr or args.arms or until_mde
    ):
        raise SealError(
            "--ladder only applies to --learn transfer, without --full, --fpr, --arms and "
            "--seeds-until-mde (it runs the ladder's own arms)"
        )
    if args.no_run and (
        args.learn not in ("kitchen", "learner", "mtrl", "transfer") or args.fpr or until_mde
    ):
        raise SealError(
            "--no-run only applies to --learn kitchen, learner, mtrl and transfer, without --fpr "
            "and --seeds-until-mde"
        )
    named = ", ".join(LEARN_SETS)
    for flag, given in (
        ("--jobs", args.jobs is not None),
        ("--address", args.address is not None),
        ("--seeds", args.seeds is not None),
        ("--reuse", args.reuse),
        ("--out", args.out is not None),
    ):
        if given and args.learn not in LEARN_SETS:
            raise SealError(f"{flag} only applies to a named --learn bench ({named})")
    speed_only = {
        "--quick": args.quick,
        "--only": bool(args.only),
        "--repeats": args.repeats is not None,
        "--e2e-steps": args.e2e_steps is not None,
    }
    for flag, given in speed_only.items():
        if given and (args.learn in LEARN_SETS or args.protocol is not None):
            raise SealError(
                f"{flag} only applies to the speed benches, not to --learn NAME or --protocol"
            )
    protocol_only = {
        "--epochs": args.epochs is not None,
        "--cores": args.cores is not None,
        "--update-rate": args.update_rate is not None,
        "--floor-only": args.floor_only,
    }
    for flag, given in protocol_only.items():
        if given and args.protocol is None:
            raise SealError(f"{flag} only applies to --protocol FILE")
    if args.arms and args.learn not in LEARN_SETS:
        raise SealError(
            "--arms only applies to --learn transfer, kitchen, table1, quickstart, reach_sb3, mtrl and learner"
        )
    if args.overrides and args.protocol is None and args.learn not in OVERRIDE_SETS:
        raise SealError(
            "--set only applies to --protocol and to --learn "
            + ", ".join(OVERRIDE_SETS[:-1])
            + f" and {OVERRIDE_SETS[-1]}"
        )
    if args.baseline and args.learn != "learner":
        raise SealError("--baseline only applies to --learn learner (its old side)")
    if args.learn in LEARN_SETS:
        import importlib

        module, default_seeds, default_out = LEARN_SETS[args.learn]
        if args.jobs is not None and args.address is not None:
            raise SealError(
                "--jobs sets the CPUs of a local Ray; with --address the cluster's nodes decide"
            )
        jobs = 2 if args.jobs is None else args.jobs
        if jobs < 1:
            raise SealError(f"--jobs must be >= 1, got {jobs}")
        bench = importlib.import_module(module)
        if until_mde:
            bench = importlib.import_module("seal.experiments.until_mde")
            rule = {"target": args.seeds_until_mde, "max_seeds": args.max_seeds}
            common = {"out": args.out or default_out, "parallel": jobs, "log": log}
            common.update(reuse=args.reuse, address=args.address)
            if args.fpr:
                result = bench.run_fpr_until_mde(**rule, **common)
                text = bench.format_fpr_until_mde
            else:
                result = bench.run_transfer_until_mde(
                    **rule, **common, full=args.full, only=args.arms
                )
                text = bench.format_result
            _emit(result, text, args.json)
            return 0
        if args.fpr:
            result = bench.run_fpr_bench(
                seeds=bench.FPR_SEEDS if args.seeds is None else args.seeds,
                out=args.out or default_out,
                parallel=jobs,
                log=log,
                reuse=args.reuse,
                address=args.address,
            )
            _emit(result, bench.format_fpr, args.json)
            return 0
        if args.ladder:
            from seal.experiments.ladder_bench import format_ladder_result, run_ladder_bench

            result = run_ladder_bench(
                seeds=default_seeds if args.seeds is None else args.seeds,
                out=args.out or default_out,
                parallel=jobs,
                log=log,
                reuse=args.reuse,
                address=args.address,
                run=not args.no_run,
                overrides=args.overrides,
            )
            _emit(result, format_ladder_result, args.json)
            return 0
        extra: dict[str, object] = {}
        if args.learn == "transfer":
            extra["full"] = args.full
        if args.learn in OVERRIDE_SETS:
            extra["overrides"] = args.overrides
        if args.no_run:
            extra["run"] = False
        if args.baseline:
            extra["baseline"] = args.baseline
        result = getattr(bench, f"run_{args.learn}_bench")(
            seeds=default_seeds if args.seeds is None else args.seeds,
            out=args.out or default_out,
            parallel=jobs,
            log=log,
            only=args.arms,
            reuse=args.reuse,
            address=args.address,
            **extra,
        )
        _emit(result, bench.format_result, args.json)
        return 0
    if args.protocol is not None:
        from seal.bench.protocol import bench_protocol, format_protocol_bench

        if args.threads is not None:
            torch.set_num_threads(max(1, args.threads))
        result = bench_protocol(
            args.protocol,
            5 if args.epochs is None else args.epochs,
            args.overrides,
            log=log,
            cores=args.cores,
            update_rate=args.update_rate,
            floor_only=args.floor_only,
        )
        _emit(result, format_protocol_bench, args.json)
        return 0

    if args.threads is not None:
        if args.threads < 1:
            raise SealError(f"--threads must be >= 1, got {args.threads}")
        torch.set_num_threads(args.threads)
    settings = BenchSettings.quick() if args.quick else BenchSettings()
    if args.repeats is not None:
        if args.repeats < 1:
            raise SealError(f"--repeats must be >= 1, got {args.repeats}")
        settings = dataclasses.replace(settings, repeats=args.repeats)
    if args.e2e_steps is not None:
        if args.e2e_steps < 1:
            raise SealError(f"--e2e-steps must be >= 1, got {args.e2e_steps}")
        settings = dataclasses.replace(settings, e2e_steps=args.e2e_steps)
    result = run_bench(
        settings,
        only=args.only,
        learn=args.learn == "evidence",
        log=log,
    )
    _emit(result, format_table, args.json)
    return 0


def _emit(result: Any, text: Callable[[Any], str], as_json: bool) -> None:
    """Print a bench's result: one JSON object (numpy floats as floats) or its text table."""
    print(json.dumps(result, indent=2, default=float) if as_json else text(result))
