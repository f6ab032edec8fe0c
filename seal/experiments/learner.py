"""`seal bench --learn learner --set agent.KEY=VALUE`: is a learner change no slower on Meta-World?

Issue 54's second rule (docs/hyperparameters.md, "The learner's default"): a learner change (the
`--set` overrides, e.g. `agent.critic_layer_norm=true`) may become the default only if, on
Meta-World, it is no slower than the learner it replaces. Three checks, each a shipped protocol
run seed for seed as shipped ("old") and with the overrides ("new"):

| check | protocol | seeds | task |
|---|---|---|---|
| quickstart | `protocols/quickstart.toml`, kitchen reward v3 (`Check.pins`) | 0-9 | drawer-close-v3 |
| table1_single_mw | `protocols/table1_small/single_mw.toml` | 0-4 | drawer-close-v3 |
| reach | `protocols/learn/reach.toml` (reach_sb3's SEAL side) | 0-2 | reach-v3 |

Per seed: the task's env steps at its first evaluation >= 90% (`seal.metrics.first_reach`); a
seed that never got there counts at its run's total, a lower bound, marked "+". Per check: the
paired change new - old, its mean and 95% Student's t CI (`seal.stats.t_ci`). The change is no
slower when the CI includes 0 or lies below it; the learner passes when all three checks are.

`--baseline` gives the old side overrides of its own: once a default has moved, `--baseline
agent.critic_layer_norm=false --set agent.critic_layer_norm=true` still reads the runs that moved it.
Both learners' runs share `out`: `--reuse` tells them apart by their saved agent table
(`seal.experiments.records.finished_run`). The quickstart's runs reserve a whole node each, as
`seal bench --learn quickstart`'s do; the others one CPU.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from seal.errors import SealError, UnknownNameError
from seal.experiments.arms import Arm
from seal.experiments.launcher import bench_context, run_or_reuse
from seal.experiments.quickstart import ARM as QUICKSTART
from seal.experiments.reach_sb3 import REACH
from seal.experiments.records import code_versions, finished_run, versions_note
from seal.experiments.table1 import TABLE1
from seal.metrics import DEFAULT_THRESHOLD, first_reach

if TYPE_CHECKING:
    import pandas as pd


@dataclass(frozen=True)
class Check:
    """One Meta-World check of the rule: an arm, the seeds it runs, the task whose crossing counts."""

    name: str
    arm: Arm
    seeds: int
    env: str
    task: str
    whole_node: bool = False
    pins: tuple[str, ...] = ()
    """Overrides both sides of the check run with: what the check measures that the shipped
    protocol has since moved."""


CHECKS: tuple[Check, ...] = (
    # The quickstart on kitchen reward v3, on which rule 2 was measured (its records are v3's); the
    # shipped quickstart follows the default reward, v4 since rule 4.
    Check(
        "quickstart",
        QUICKSTART,
        10,
        "mw",
        "drawer-close-v3",
        whole_node=True,
        pins=("envs.fk.options={reward_version='v3'}",),
    ),
    Check(
        "table1_single_mw",
        Arm("single_mw", "Single Env (MW)", None, directory=TABLE1),
        5,
        "mw",
        "drawer-close-v3",
    ),
    Check("reach", REACH, 3, "mw", "reach-v3"),
)
"""The rule's checks, with the seeds it names (docs/hyperparameters.md)."""


def arms(only: Sequence[str] | None = None) -> list[Check]:
    """The checks named in `only`, in that order (all without it)."""
    if not only:
        return list(CHECKS)
    names = [c.name for c in CHECKS]
    for name in only:
        if name not in names:
            raise UnknownNameError("--arms check", name, names)
    return [next(c for c in CHECKS if c.name == name) for name in dict.fromkeys(only)]


def crossing(
    metrics: pd.DataFrame, env: str, task: str, threshold: float = DEFAULT_THRESHOLD
) -> dict[str, Any]:
    """{"env_steps", "reached"}: the task's env steps at its first evaluation >= threshold in a
    run's metrics, else at its last evaluation (a lower bound on what reaching would have cost)."""
    mine = metrics[(metrics["env"] == env) & (metrics["task"] == task)]
    if mine.empty:
        raise SealError(f"metrics.csv: no evaluation of {env}/{task}")
    (row,) = first_reach(mine, threshold).itertuples(index=False)
    steps = row.env_steps if row.reached else mine["env_steps"].max()
    return {"env_steps": int(steps), "reached": bool(row.reached)}


def paired_change(old: Sequence[float], new: Sequence[float]) -> dict[str, Any]:
    """The seed-paired change new - old: per seed, mean, 95% t CI, and whether it is no slower
    (the CI includes 0 or lies below it; None below two seeds, where there is no CI)."""
    from seal.stats import t_ci

    if len(old) != len(new):
        raise SealError(f"paired change: {len(old)} old seeds against {len(new)} new ones")
    diffs = [float(b) - float(a) for a, b in zip(old, new, strict=True)]
    low, high = t_ci(diffs)
    return {
        "differences": diffs,
        "mean": float(sum(diffs) / len(diffs)) if diffs else math.nan,
        "ci95": [low, high],
        "no_slower": None if math.isnan(low) else bool(low <= 0.0),
    }


def run_learner_bench(
    seeds: int = 10,
    out: str = "reports/bench_learner",
    parallel: int = 2,
    overrides: Sequence[str] = (),
    log: Callable[[str], None] = lambda _: None,
    only: Sequence[str] | None = None,
    reuse: bool = False,
    address: str | None = None,
    run: bool = True,
    baseline: Sequence[str] = (),
) -> dict[str, Any]:
    """Run (or, with `run=False`, read) each check's seeds (at most `seeds`) as shipped (with
    `baseline`'s overrides, if any) and with `overrides`, and apply the rule."""
    from seal import load_run
    from seal.bench.timing import machine_load

    if not overrides:
        raise SealError(
            "--learn learner compares a learner change against the shipped learner: give the "
            "change as --set overrides, e.g. --set agent.critic_layer_norm=true"
        )
    if seeds < 2:
        raise SealError(f"--seeds must be >= 2 for a paired CI, got {seeds}")
    if sorted(baseline) == sorted(overrides):
        raise SealError(
            f"--baseline {' '.join(baseline)} is the change itself: both sides would be the same runs"
        )
    load_before = machine_load()
    started = time.monotonic()
    checks, shas = [], {}
    sides_of = ("old", tuple(baseline)), ("new", tuple(overrides))
    chosen = arms(only)
    dirs: dict[tuple[str, str, int], Path] = {}
    for check in chosen if run else ():
        n = min(seeds, check.seeds)
        # Seeds in chunks, each run as shipped and then with the change, so that a bench stopped
        # part-way (--reuse continues it) leaves pairs: one seed a chunk where a run takes a node.
        chunk = 1 if check.whole_node else max(1, parallel)
        for first in range(0, n, chunk):
            jobs = [(check.arm, s) for s in range(first, min(n, first + chunk))]
            for side, sets in sides_of:
                got, _ = run_or_reuse(
                    jobs, Path(out), (*check.pins, *sets), parallel, log, reuse,
                    address=address, whole_node=check.whole_node,
                )  # fmt: skip
                dirs.update({(check.name, side, s): d for (_, s), d in got.items()})
    for check in chosen:
        n = min(seeds, check.seeds)
        sides: dict[str, dict[int, dict[str, Any] | None]] = {}
        for side, sets in sides_of:
            sides[side] = {}
            for s in range(n):
                d = dirs.get((check.name, side, s)) or finished_run(
                    check.arm, s, Path(out), (*check.pins, *sets)
                )
                if d is None:
                    sides[side][s] = None
                    continue
                loaded = load_run(d)
                found = crossing(loaded.metrics, check.env, check.task)
                sides[side][s] = {**found, "run_dir": str(d)}
                shas[(f"{check.name}_{side}", s)] = loaded.provenance.get("git_sha")
        both = [s for s in range(n) if sides["old"][s] and sides["new"][s]]
        change = paired_change(
            [sides["old"][s]["env_steps"] for s in both],
            [sides["new"][s]["env_steps"] for s in both],
        )
        checks.append(
            {
                "check": check.name,
                "protocol": str(check.arm.protocol),
                "pins": list(check.pins),
                "task": f"{check.env}/{check.task}",
                "seeds": n,
                "paired_seeds": both,
                "old": {str(s): v for s, v in sides["old"].items()},
                "new": {str(s): v for s, v in sides["new"].items()},
                "change": change,
            }
        )
    verdicts = [c["change"]["no_slower"] for c in checks]
    # The rule is decided over all three checks at their own seeds, not over a subset (--arms, --seeds).
    complete = len(checks) == len(CHECKS) and all(
        len(c["paired_seeds"]) == c["seeds"] == check.seeds
        for c, check in zip(checks, chosen, strict=True)
    )
    versions = code_versions(shas)
    return {
        "overrides": list(overrides),
        "baseline": list(baseline),
        "checks": checks,
        "no_slower": (all(verdicts) if complete and None not in verdicts else None),
        "complete": complete,
        "code_versions": versions,
        "versions_note": versions_note(versions),
        **bench_context(time.monotonic() - started, parallel, address, load_before),
    }


def format_result(result: Mapping[str, Any]) -> str:
    """The human-readable output of `run_learner_bench`."""
    change = " ".join(result["overrides"])
    old = " ".join(result.get("baseline", ()))
    against = f"the protocols with {old}" if old else "the protocols as shipped"
    lines = [f"Meta-World, no slower: {change} (new) against {against} (old)"]
    for c in result["checks"]:

        def cell(v: Mapping[str, Any] | None) -> str:
            if v is None:
                return "not run"
            return f"{v['env_steps']:,}{'' if v['reached'] else '+'}"

        per_seed = ", ".join(
            f"s{s} {cell(c['old'][str(s)])} -> {cell(c['new'][str(s)])}" for s in range(c["seeds"])
        )
        ch = c["change"]
        low, high = ch["ci95"]
        verdict = {True: "no slower", False: "SLOWER", None: "no CI"}[ch["no_slower"]]
        pinned = "".join(f"; both sides {pin}" for pin in c.get("pins", ()))
        lines.append(f"{c['check']} ({c['task']}{pinned}), env steps to 90% old -> new: {per_seed}")
        lines.append(
            f"  change new - old over {len(c['paired_seeds'])} paired seeds: mean "
            f"{ch['mean']:+,.0f}, 95% t CI [{low:+,.0f}, {high:+,.0f}]: {verdict}"
        )
    overall = {
        True: "passes",
        False: "fails",
        None: "not decided (a check, or some of its seeds, not run)",
    }
    lines.append(f"rule (every check no slower): {overall[result['no_slower']]}")
    lines.append("+ = never reached 90%: the run's total env steps, a lower bound")
    if result["versions_note"]:
        lines.append(f"note, {result['versions_note']}")
    lines.append(f"{result['wall_s']:.0f} s wall on {result['ray']}")
    return "\n".join(lines)
