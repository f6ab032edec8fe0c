"""Whether two source trees run the same protocols to the same CSV rows (issue 61: a refactor of
the run loop must change no row).

    python scripts/loop_identity.py BEFORE_TREE AFTER_TREE [--out DIR] [--set K=V ...]
                                    [--protocol FILE ...]

For each protocol (default: protocols/quickstart.toml, protocols/testbed/alone.toml and
protocols/testbed/high_source.toml) it runs `seal run PROTOCOL --seeds 0 --out DIR --quiet
[--set K=V ...]` with each tree's code (PYTHONPATH=tree, this same python, from that tree's
root, the BEFORE tree first, one after the other), then compares each run's metrics.csv and
train.csv line by line, byte for byte, after dropping the time-dependent columns: those whose
header names wall clock or rate (contains "wall", "seconds", "time", "per_s", or ends in "_s").
In metrics.csv that is `wall_s`; train.csv (seed, phase, epoch, grad_steps, env, key, value)
has none, and its rows whose key names time the same way are dropped too (there are none).

Prints, per protocol and file, the lines compared, the columns left out and the differing lines
(the first few of them); a file that differs only in the order of its rows is said so. Exits 1
on any difference (or a run that fails), 0 when every file matches.
"""

from __future__ import annotations

import argparse
import csv
import io
import os
import re
import subprocess
import sys
import tempfile
from collections import Counter
from pathlib import Path

PROTOCOLS = (
    "protocols/quickstart.toml",
    "protocols/testbed/alone.toml",
    "protocols/testbed/high_source.toml",
)
FILES = ("metrics.csv", "train.csv")
TIMED = re.compile(r"wall|seconds|time|per_s|_s$", re.IGNORECASE)
"""A column (or train.csv key) whose values depend on the wall clock."""
SHOWN = 5


def run(tree: Path, protocol: str, out: Path, sets: list[str]) -> Path:
    """Run seed 0 of `protocol` with `tree`'s code; its run directory."""
    command = [
        sys.executable,
        "-c",
        "import sys; from seal.cli.main import main; sys.exit(main(sys.argv[1:]))",
        "run",
        protocol,
        "--seeds",
        "0",
        "--out",
        str(out),
        "--quiet",
        *(a for s in sets for a in ("--set", s)),
    ]
    env = {**os.environ, "PYTHONPATH": str(tree)}
    print(f"[{tree}] seal run {protocol} --seeds 0 {' '.join(sets)}", flush=True)
    subprocess.run(command, cwd=tree, env=env, check=True, stdout=subprocess.DEVNULL)
    (seed_dir,) = out.glob("*/*/seed-0")
    return seed_dir


def kept_lines(path: Path) -> tuple[list[str], list[str]]:
    """The file's lines without its time-dependent columns (and train.csv's timed keys); the
    columns left out."""
    rows = list(csv.reader(io.StringIO(path.read_text())))
    header = rows[0]
    dropped = [c for c in header if TIMED.search(c)]
    keep = [i for i, c in enumerate(header) if c not in dropped]
    key = header.index("key") if "key" in header else None
    lines = []
    for row in rows:
        if key is not None and row is not header and TIMED.search(row[key].split("/")[0]):
            continue
        lines.append(",".join(row[i] for i in keep))
    return lines, dropped


def compare(before: Path, after: Path, name: str) -> bool:
    """Print the comparison of one file; whether it matches."""
    old, dropped = kept_lines(before / name)
    new, _ = kept_lines(after / name)
    differing = [
        (i, a, b) for i, (a, b) in enumerate(zip(old, new, strict=False), start=1) if a != b
    ]
    extra = abs(len(old) - len(new))
    left_out = ", ".join(dropped) or "none"
    print(
        f"  {name}: {len(old)} lines before, {len(new)} after, {min(len(old), len(new))} compared; "
        f"left out: {left_out}; differing lines: {len(differing)}"
        + (f", {extra} lines in one file only" if extra else "")
    )
    for i, a, b in differing[:SHOWN]:
        print(f"    line {i}:\n      before {a}\n      after  {b}")
    same = not differing and not extra
    if not same and Counter(old) == Counter(new):
        print("    the same rows, in another order")
    return same


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("before", type=Path, help="source tree of the code before")
    parser.add_argument("after", type=Path, help="source tree of the code after")
    parser.add_argument("--out", type=Path, help="where the runs go (default: a temporary folder)")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="K=V")
    parser.add_argument("--protocol", dest="protocols", action="append", metavar="FILE")
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="loop-identity-"))
    ok = True
    for protocol in args.protocols or PROTOCOLS:
        stem = protocol.replace("/", "_").removesuffix(".toml")
        try:
            dirs = [
                run(tree.resolve(), protocol, out / stem / side, args.sets)
                for side, tree in (("before", args.before), ("after", args.after))
            ]
        except subprocess.CalledProcessError as exc:
            print(f"{protocol}: a run failed (exit {exc.returncode})")
            ok = False
            continue
        print(f"{protocol}: {dirs[0]} vs {dirs[1]}")
        for name in FILES:
            ok = compare(dirs[0], dirs[1], name) and ok
    print("identical" if ok else "DIFFERENT")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
