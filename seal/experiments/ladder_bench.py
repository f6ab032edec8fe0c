"""`seal bench --learn transfer --ladder`: the ladder's eight arms, their 2^3 factorial, and
whether each mapped piece was kept or relearned (docs/transfer_testbed.md, "Ladder").

The arms are `LADDER_ARMS` (oracle_translator, the six `ladder_*` cells, oracle_policy), each
against the alone arm of the same seed and started from the pre-training of that seed, as every
oracle rung is: `run_transfer_bench(only=LADDER_ARMS)` runs them (or, with `reuse`, takes
finished runs; without `run`, only reads them) and writes its usual tables and plots under
<out>/transfer/. On top of its result, `ladder`:

- `arms`: each arm's mapped pieces (read from its protocol's `transfer.map_modules`), target AUC
  (primary: over the alone arm's budget) and gradient steps to 90% (secondary), and against the
  alone arm the AUC gain and steps_saved, each with its 95% CI and MDE (`summarise`'s);
- `effects`: per statistic, the seven contrasts of `seal.experiments.ladder` seed by seed, with
  paired t CI and MDE: `auc` of the arms' target AUC, `steps` of their steps_saved (a fraction of
  the alone arm's steps; positive = mapping the piece saves steps);
- `drift`: each piece's ||W - W0|| / ||W0|| at the run's last evaluation (train.csv's
  `drift/<piece>` of the target, `seal.learner.drift`): per arm, mean over seeds; per piece, over
  the arms that map it, the arms that leave it fresh, and the alone arm (its own init). Runs
  made before `logging.drift` have no such rows: their drift is None.

It writes <out>/transfer/ladder.json, tables/ladder.{md,tex} and plots/ladder.png.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from seal.experiments.arms import LADDER_ARMS, TARGET_ENV, arms
from seal.experiments.ladder import FACTORS, design, factorial
from seal.experiments.statistics import AUC_GAIN_BOUNDS
from seal.experiments.transfer import format_result, run_transfer_bench
from seal.pieces import PIECES

STATISTICS = {
    "auc": ("auc_per_seed", "target AUC", AUC_GAIN_BOUNDS),
    "steps": ("steps_saved_per_seed", "steps_saved", (-math.inf, math.inf)),
}
"""Per statistic of the factorial: the arms' per-seed key in `summarise`, its name, the range of
its effects (an AUC effect is a difference of mean AUCs in [0, 1]; a steps_saved one has none)."""


def levels() -> dict[str, tuple[str, ...]]:
    """Each ladder arm's mapped pieces on top of the translator, from its protocol file."""
    from seal.protocols import load_protocol

    out = {}
    for arm in arms(only=LADDER_ARMS):
        if arm.name in LADDER_ARMS:
            transfer = load_protocol(arm.protocol).transfer
            assert transfer is not None
            out[arm.name] = tuple(p for p in transfer.pieces if p in FACTORS)
    return {name: out[name] for name in LADDER_ARMS}


def run_ladder_bench(
    seeds: int = 5,
    out: str | os.PathLike[str] = "reports/bench_transfer",
    parallel: int = 2,
    log: Callable[[str], None] = lambda _: None,
    reuse: bool = False,
    address: str | None = None,
    run: bool = True,
    overrides: Sequence[str] = (),
) -> dict[str, Any]:
    """`run_transfer_bench` of the ladder's arms, with `ladder` added and its files written
    (`overrides`: `--set` values for every arm, as `run_transfer_bench`'s, for tests)."""
    cells = levels()
    design(cells)  # the protocols must make the full factorial before anything runs
    result = run_transfer_bench(
        seeds=seeds,
        out=out,
        parallel=parallel,
        log=log,
        only=LADDER_ARMS,
        reuse=reuse,
        address=address,
        run=run,
        overrides=overrides,
    )
    ladder = ladder_result(result["arms"], cells, _drift_rows(result["run_dirs"]))
    ladder["files"] = write_ladder(Path(result["report_dir"]), ladder)
    return {**result, "ladder": ladder}


# ---------------------------------------------------------------- the figures


def _drift_rows(run_dirs: Mapping[str, str]) -> dict[str, dict[int, dict[str, float]]]:
    """Arm -> seed -> piece -> the target's drift at the run's last evaluation ({} without rows)."""
    out: dict[str, dict[int, dict[str, float]]] = {}
    for key, path in run_dirs.items():
        arm, _, seed = key.rpartition("/seed-")
        train = pd.read_csv(Path(path) / "train.csv")
        rows = train[(train["env"] == TARGET_ENV) & train["key"].str.startswith("drift/")]
        last = rows[rows["epoch"] == rows["epoch"].max()] if len(rows) else rows
        out.setdefault(arm, {})[int(seed)] = {
            str(k).removeprefix("drift/"): float(v)
            for k, v in zip(last["key"], last["value"], strict=True)
        }
    return out


def _mean(values: Sequence[float | None]) -> float | None:
    known = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.mean(known)) if known else None


def drift_summary(
    drift: Mapping[str, Mapping[int, Mapping[str, float]]], cells: Mapping[str, Sequence[str]]
) -> dict[str, Any]:
    """Per arm (the ladder's and the alone arm), per piece: the end drift per seed and its mean;
    per piece: the mean over (arm, seed) of the arms that map it, of those that leave it fresh
    (the translator: none), and of the alone arm."""
    per_arm: dict[str, dict[str, Any]] = {}
    for arm, seeds in drift.items():
        if arm not in cells and arm != "alone":
            continue  # the pre-training: no target
        per_arm[arm] = {}
        for piece in PIECES:
            values = [seeds[s].get(piece) for s in sorted(seeds)]
            per_arm[arm][piece] = {"per_seed": values, "mean": _mean(values)}

    def pooled(names: Sequence[str], piece: str) -> float | None:
        return _mean([v for n in names if n in per_arm for v in per_arm[n][piece]["per_seed"]])

    per_piece = {}
    for piece in PIECES:
        mapped = [a for a, p in cells.items() if piece == "translator" or piece in p]
        fresh = [a for a in cells if a not in mapped]
        per_piece[piece] = {
            "mapped": pooled(mapped, piece),
            "fresh": pooled(fresh, piece),
            "alone": pooled(["alone"], piece),
        }
    return {"per_arm": per_arm, "per_piece": per_piece}


def ladder_result(
    summary: Mapping[str, Mapping[str, Any]],
    cells: Mapping[str, Sequence[str]],
    drift: Mapping[str, Mapping[int, Mapping[str, float]]],
) -> dict[str, Any]:
    """The ladder's figures from `summarise`'s arms, the arms' mapped pieces and their end drift."""
    keep = (
        "label",
        "auc_per_seed",
        "auc_mean",
        "auc_gain_per_seed",
        "auc_gain",
        "auc_gain_ci95",
        "mde_auc",
        "grad_steps_to_90_per_seed",
        "grad_steps_to_90_mean",
        "steps_saved_per_seed",
        "steps_saved",
        "ci95",
        "mde_steps",
        "censored",
        "task_runs",
    )
    arm_rows = {
        name: {"pieces": list(cells[name]), **{k: summary[name].get(k) for k in keep}}
        for name in cells
    }
    effects = {
        stat: factorial({a: summary[a][key] for a in cells}, cells, bounds)
        for stat, (key, _, bounds) in STATISTICS.items()
    }
    return {
        "against": "alone",
        "arms": arm_rows,
        "effects": effects,
        "drift": drift_summary(drift, cells),
    }


# ---------------------------------------------------------------- output


def _ci(value: float | None, ci: Sequence[float] | None) -> str:
    if value is None or not math.isfinite(value):
        return "n/a"
    if ci is None or not all(math.isfinite(c) for c in ci):
        return f"{value:+.3f} [no CI]"
    return f"{value:+.3f} [{ci[0]:+.3f}, {ci[1]:+.3f}]"


def _number(value: float | None, digits: int = 3) -> str:
    return "n/a" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def _seeds(values: Sequence[float]) -> str:
    return " ".join("n/a" if not math.isfinite(v) else f"{v:+.3f}" for v in values)


def _drift(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.3g}"


def _documents(ladder: Mapping[str, Any]) -> tuple[str, list[Any], list[str]]:
    """(title, sections, notes) of the ladder's tables (`seal.reports.tables` documents)."""
    arm_rows = [
        {
            "arm": name,
            "mapped on the translator": " + ".join(a["pieces"]) or "-",
            "AUC": _number(a["auc_mean"]),
            "AUC gain [95% CI]": _ci(a["auc_gain"], a["auc_gain_ci95"]),
            "MDE": _number(a["mde_auc"]),
            "steps to 90%": _number(a["grad_steps_to_90_mean"], 0),
            "steps_saved [95% CI]": _ci(a["steps_saved"], a["ci95"]),
            "MDE ": _number(a["mde_steps"]),
        }
        for name, a in ladder["arms"].items()
    ]
    effect_rows = [
        {
            "effect": name,
            "AUC [95% CI]": _ci(auc["mean"], auc["ci95"]),
            "MDE": _number(auc["mde"]),
            "steps_saved [95% CI]": _ci(steps["mean"], steps["ci95"]),
            "MDE ": _number(steps["mde"]),
        }
        for (name, auc), steps in zip(
            ladder["effects"]["auc"].items(), ladder["effects"]["steps"].values(), strict=True
        )
    ]
    per_seed_rows = [
        {
            "effect": name,
            "AUC per seed": _seeds(auc["per_seed"]),
            "steps_saved per seed": _seeds(steps["per_seed"]),
        }
        for (name, auc), steps in zip(
            ladder["effects"]["auc"].items(), ladder["effects"]["steps"].values(), strict=True
        )
    ]
    drift_rows = [
        {
            "piece": piece,
            "mapped": _drift(d["mapped"]),
            "fresh": _drift(d["fresh"]),
            "alone": _drift(d["alone"]),
        }
        for piece, d in ladder["drift"]["per_piece"].items()
    ]
    notes = [
        "Arms: the target's AUC (mean success over gradient steps 0..the alone arm's budget, "
        "mean over tasks and seeds) and gradient steps to first >= 90% on every task; gain and "
        "steps_saved against Single Env (alone.toml) seed for seed, 95% CI = Student's t, MDE at "
        "the seeds run (two-sided 5%, power 0.8).",
        "Effects: 2^3 contrasts per seed (a main effect = mean over the 4 arms mapping the piece - "
        "mean over the 4 leaving it fresh; an interaction = the mean over the arms whose signs "
        "multiply to +1 - the others'), then mean, paired t CI and MDE over seeds; positive = "
        "mapping helps (more AUC, fewer steps).",
        "Drift = ||W - W0|| / ||W0|| of the target's piece (its parameters concatenated; "
        "temperatures as alpha) at the run's last evaluation, mean over seeds and over the arms "
        "that map it (mapped), that start it fresh (fresh: none for the translator), and of the "
        "alone arm (against its own init); n/a: no drift rows (runs without logging.drift).",
    ]
    sections = [
        ("Arms", pd.DataFrame(arm_rows), None),
        ("Effects", pd.DataFrame(effect_rows), None),
        ("Effects per seed", pd.DataFrame(per_seed_rows), None),
        ("Drift at the last evaluation: kept or relearned", pd.DataFrame(drift_rows), None),
    ]
    return "Ladder: which mapped piece carries transfer", sections, notes


def format_ladder(ladder: Mapping[str, Any]) -> str:
    """The ladder's tables as Markdown (no line over 100 characters)."""
    from seal.reports.tables import markdown_document

    return markdown_document(*_documents(ladder))


def write_ladder(directory: Path, ladder: Mapping[str, Any]) -> dict[str, Any]:
    """ladder.json, tables/ladder.{md,tex} and plots/ladder.png (each arm's gains and each
    effect, 95% CI and ±MDE) under `directory`; their paths."""
    from seal.reports.plots import Interval, plot_intervals
    from seal.reports.tables import write_document
    from seal.stats import MIN_SEEDS_RESOLVED, resolved

    (directory / "tables").mkdir(parents=True, exist_ok=True)
    (directory / "plots").mkdir(parents=True, exist_ok=True)
    files: dict[str, Any] = {"json": str(directory / "ladder.json")}
    Path(files["json"]).write_text(json.dumps(ladder, indent=2, default=float) + "\n")
    tables = write_document(directory / "tables" / "ladder", *_documents(ladder))
    files["tables"] = [str(p) for p in tables.values()]

    def row(label: str, value: Any, ci: Any, mde: Any, n: int) -> Interval:
        value = math.nan if value is None else float(value)
        low, high = (math.nan, math.nan) if ci is None else (float(ci[0]), float(ci[1]))
        enough = n >= MIN_SEEDS_RESOLVED and math.isfinite(low)
        return Interval(
            label,
            value,
            low,
            high,
            math.nan if mde is None else float(mde),
            enough and resolved((low, high)),
        )

    panels = []
    for stat, (value_key, ci_key, mde_key, what) in {
        "auc": ("auc_gain", "auc_gain_ci95", "mde_auc", "AUC gain vs Single Env"),
        "steps": ("steps_saved", "ci95", "mde_steps", "steps_saved vs Single Env"),
    }.items():
        arm_rows = [
            row(name, a[value_key], a[ci_key], a[mde_key], len(a["auc_per_seed"]))
            for name, a in ladder["arms"].items()
        ]
        effect_rows = [
            row(name, e["mean"], e["ci95"], e["mde"], len(e["per_seed"]))
            for name, e in ladder["effects"][stat].items()
        ]
        panels += [
            (f"{what}: the eight arms", arm_rows),
            (f"{STATISTICS[stat][1]}: effects (main, 2-way, 3-way)", effect_rows),
        ]
    path = plot_intervals(
        panels,
        directory / "plots" / "ladder.png",
        "paired statistic (positive = mapping helps: more AUC, fewer steps)",
        "Ladder: the eight arms and the factorial's effects, mean over seeds, 95% CI, ±MDE",
    )
    files["plot"] = str(path)
    return files


def format_ladder_result(result: Mapping[str, Any]) -> str:
    """The human-readable output of `run_ladder_bench`: the transfer bench's, then the ladder's."""
    files = result["ladder"]["files"]
    return (
        f"{format_result(result)}\n\n{format_ladder(result['ladder'])}\n\n"
        f"Ladder figures: {files['json']}\nLadder plot: {files['plot']}"
    )
