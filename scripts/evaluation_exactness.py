"""Issue 60's exactness check: the same first crossings with cheaper evaluation as without.

Runs each seed of a protocol twice, as shipped and with `evaluation.decide_early = true` and
`evaluation.end_on_success = true` (or the --set overrides given), and compares every task's first
evaluation >= its threshold (`seal.metrics.first_reach`: reached, epoch, gradient steps and
millions of updates) and the training rows of train.csv that do not come from evaluation. Prints one line per seed and a verdict; exits 1 on a
difference. A finished pair under --out is read back, not run again.

    python scripts/evaluation_exactness.py protocols/testbed/alone.toml --seeds 0 1 2 \
        --out results/evaluation_exactness
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

from seal import load_run
from seal.metrics import first_reach
from seal.protocols import load_protocol
from seal.run.runner import run_seed

CHEAP = ["evaluation.decide_early=true", "evaluation.end_on_success=true"]
# Rows that evaluation writes to train.csv (the critic probe, the decisions); the rest are
# training's own and must be equal row for row.
EVAL_PREFIXES = ("eval_",)


def run_or_read(protocol: Path, seed: int, out: Path, overrides: list[str], side: str) -> Path:
    """The run directory of (protocol, seed, overrides) under out/<side>, run if not finished."""
    config = load_protocol(protocol, overrides)
    group = out / side / config.name
    run_dir = group / f"seed-{seed}"
    if not (run_dir / "provenance.json").is_file() or not load_run(run_dir).provenance.get(
        "end_time"
    ):
        run_seed(config, seed, group, quiet=True)
    return run_dir


def crossings(run_dir: Path, threshold: float) -> pd.DataFrame:
    metrics = load_run(run_dir).metrics
    keys = ["env", "task", "reached", "epoch", "grad_steps", "updates"]
    return first_reach(metrics, threshold)[keys].reset_index(drop=True)


def training_rows(run_dir: Path) -> pd.DataFrame:
    train = pd.read_csv(run_dir / "train.csv")
    train = train[~train["key"].astype(str).str.startswith(EVAL_PREFIXES)]
    keep = [c for c in train.columns if c not in ("wall_s",)]
    return train[keep].reset_index(drop=True)


def timing(run_dir: Path) -> tuple[float, float, float]:
    """The run's wall seconds, its loop's evaluation seconds and its asynchronous evaluation
    workers' CPU seconds (provenance's time_shares)."""
    shares = load_run(run_dir).provenance.get("time_shares") or {}
    return (
        float(shares.get("wall_s", 0.0)),
        float(shares.get("parts_s", {}).get("evaluate", 0.0)),
        float(shares.get("evaluate_worker_cpu_s", 0.0)),
    )


def _seconds(times: list[float] | tuple[float, float, float]) -> str:
    wall, evaluate, workers = times
    return (
        f"wall {wall:,.1f} s, evaluation {evaluate:,.1f} s in the loop, "
        f"{workers:,.1f} s of evaluation workers' CPU"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("protocol", type=Path)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--out", type=Path, default=Path("results/evaluation_exactness"))
    parser.add_argument("--set", dest="overrides", action="append", default=None)
    parser.add_argument("--base", action="append", default=[], help="overrides of both sides")
    args = parser.parse_args(argv)
    cheap = args.overrides or CHEAP
    threshold = load_protocol(args.protocol, args.base).evaluation.threshold
    same = True
    seconds = {"full": [0.0, 0.0, 0.0], "cheap": [0.0, 0.0, 0.0]}
    for seed in args.seeds:
        full = run_or_read(args.protocol, seed, args.out, list(args.base), "full")
        fast = run_or_read(args.protocol, seed, args.out, list(args.base) + cheap, "cheap")
        a, b = crossings(full, threshold), crossings(fast, threshold)
        equal_cross = a.equals(b)
        ta, tb = training_rows(full), training_rows(fast)
        equal_train = ta.equals(tb)
        same = same and equal_cross and equal_train
        reached = ", ".join(
            f"{r.env}/{r.task} "
            + (f"epoch {r.epoch} ({r.updates:.4f} M updates)" if r.reached else "never")
            for r in a.itertuples()
        )
        print(
            f"seed {seed}: crossings {'identical' if equal_cross else 'DIFFER'}, training rows "
            f"{'identical' if equal_train else 'DIFFER'} ({len(ta)} rows); full: {reached}"
        )
        for side, run_dir in (("full", full), ("cheap", fast)):
            times = timing(run_dir)
            seconds[side] = [a + b for a, b in zip(seconds[side], times, strict=True)]
            print(f"  {side}: {_seconds(times)} ({run_dir})")
        if not equal_cross:
            print(pd.concat({"full": a, "cheap": b}, axis=1).to_string())
    for side, times in seconds.items():
        print(f"{side}, seeds {args.seeds}: {_seconds(times)}")
    print(f"{args.protocol} with {' '.join(cheap)}: {'exact' if same else 'NOT EXACT'}")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
