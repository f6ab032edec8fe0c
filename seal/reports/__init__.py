"""Read run directories and lay them out as the paper's tables and figures (`seal report`).

A run directory is `reports/<protocol>/<group-id>/seed-<n>/` with `config.toml`,
`provenance.json`, `metrics.csv` (one row per evaluation and task) and `train.csv` (training
curves, long format). A group directory holds several `seed-<n>/` runs. This module reads those
files only, never live objects, so a report can be rebuilt from any copy of the directories.

`report` lays groups out as Table 1 (Task x {Single Env, 50/50, High FK, High MW}) and Tables 6-7
("Pre-train on X" / "Fine-tune on Y"), with the update-count metric of `seal.metrics`, and draws
the success curves of Figs. 2-4 and the critic-loss curves of Fig. 7.
"""

from __future__ import annotations

import json
import math
import os
import re
import tomllib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from seal.errors import SealError
from seal.metrics import (
    DEFAULT_THRESHOLD,
    NEVER_REACHED,
    REQUIRED_METRICS_COLUMNS,
    add_percent_change,
    aggregate_seeds,
    env_totals,
    first_reach,
    format_count,
    format_number,
)
from seal.protocols.rundir import METRICS_COLUMNS, TRAIN_COLUMNS  # defined once, by the writer

BASELINE_COLUMN = "Single Env"
"""The column every other column's percent change is measured against (Table 1)."""

# Short labels the paper uses for its environments, by adapter name.
ADAPTER_LABELS: dict[str, str] = {"metaworld": "MW", "franka_kitchen_dense": "FK"}

# Rows list Meta-World's tasks first, then the kitchen's, as Table 1 does.
_ENV_RANK = {"MW": 0, "FK": 1}

# The paper's column order (Table 1, then Tables 6-7); other columns follow in the order given.
_PRESET_COLUMNS = {"high_fk": "High FK", "high_mw": "High MW"}
_COLUMN_ORDER = (BASELINE_COLUMN, "50/50", "High FK", "High MW")
# Fig. 4's colours: equal ratio green, high MW blue, high FK orange; the baseline is black.
_COLUMN_COLOURS = {
    BASELINE_COLUMN: "black",
    "50/50": "tab:green",
    "High FK": "tab:orange",
    "High MW": "tab:blue",
}
_OTHER_COLOURS = (
    "tab:red",
    "tab:purple",
    "tab:brown",
    "tab:pink",
    "tab:olive",
    "tab:cyan",
    "tab:gray",
)

# Scheduler kinds under which a `baseline` protocol is still the plain MTMHSAC baseline.
_PLAIN_SCHEDULERS = ("", "uniform", "none")

XAxis = Literal["grad_steps", "epoch"]

_EXPECTED = (
    "expected a run directory (seed-<n>/ holding metrics.csv and config.toml) "
    "or a group directory (reports/<protocol>/<group-id>/ holding seed-<n>/ run directories)"
)


# --------------------------------------------------------------------------- reading runs


@dataclass(frozen=True)
class RunData:
    """One run directory, read: its metrics and training logs as DataFrames, config and provenance."""

    path: Path
    """The run directory (`.../<protocol>/<group-id>/seed-<n>`)."""
    metrics: pd.DataFrame
    """metrics.csv: one row per evaluation and task (columns `seal.protocols.rundir.METRICS_COLUMNS`)."""
    train: pd.DataFrame
    """train.csv: seed, phase, epoch, grad_steps, env, key, value (empty if the file is absent)."""
    config: dict[str, Any]
    """The resolved protocol config (config.toml) as a dict."""
    provenance: dict[str, Any] = field(default_factory=dict)
    """provenance.json (empty if the file is absent)."""

    @property
    def protocol(self) -> str:
        """Protocol name: [protocol].name, else provenance, else the grandparent directory's name."""
        name = self.config.get("protocol", {}).get("name") or self.provenance.get("protocol")
        return str(name or self.path.parent.parent.name)

    @property
    def kind(self) -> str:
        """Protocol kind: baseline, finetune, joint (or a kind added later)."""
        return str(
            self.config.get("protocol", {}).get("kind") or self.provenance.get("kind") or "baseline"
        )

    @property
    def group(self) -> str:
        """Group id: provenance's, else the parent directory's name."""
        return str(self.provenance.get("group") or self.path.parent.name)

    @property
    def seed(self) -> int:
        """The run's seed: provenance's, else metrics.csv's, else the `seed-<n>` directory name."""
        if self.provenance.get("seed") is not None:
            return int(self.provenance["seed"])
        if len(self.metrics):
            return int(self.metrics["seed"].iloc[0])
        match = re.fullmatch(r"seed-(\d+)", self.path.name)
        return int(match.group(1)) if match else 0

    def env_label(self, env: str) -> str:
        """Short label of an environment ("MW", "FK"), from its adapter in [envs.<env>]; else its name."""
        env_table = self.config.get("envs", {}).get(env, {})
        adapter = env_table.get("adapter") if isinstance(env_table, dict) else None
        return ADAPTER_LABELS.get(adapter or env, env)

    def scheduler(self) -> dict[str, Any]:
        """The data-ratio / task scheduler table ([scheduler], or [schedule] in older configs)."""
        table = self.config.get("scheduler") or self.config.get("schedule") or {}
        return table if isinstance(table, dict) else {}


def _read_csv(path: Path, required: Sequence[str], text_columns: Sequence[str]) -> pd.DataFrame:
    try:
        frame = pd.read_csv(path, dtype={c: str for c in text_columns}, keep_default_na=True)
    except pd.errors.EmptyDataError:
        raise SealError(
            f"{path}: file is empty; expected a CSV header with columns {list(required)}"
        ) from None
    except (pd.errors.ParserError, UnicodeDecodeError) as exc:
        raise SealError(f"{path}: not a readable CSV ({exc})") from None
    missing = [c for c in required if c not in frame.columns]
    if missing:
        raise SealError(f"{path}: missing column(s) {missing}; expected columns {list(required)}")
    for column in required:
        if column in text_columns:
            continue
        try:
            frame[column] = pd.to_numeric(frame[column])
        except (ValueError, TypeError):
            raise SealError(
                f"{path}: column {column!r} has non-numeric values; expected numbers"
            ) from None
    return frame


def load_run(path: str | os.PathLike[str]) -> RunData:
    """Read a run directory: metrics.csv and train.csv as DataFrames, config.toml and provenance.json.

    Raises SealError naming the path when it is not a run directory or a file is malformed.
    `train.csv` and `provenance.json` may be absent (a run stopped before its first log).
    """
    run = Path(path)
    if not run.is_dir():
        what = "does not exist" if not run.exists() else "is not a directory"
        raise SealError(f"{run} {what}; {_EXPECTED}")
    metrics_path, config_path = run / "metrics.csv", run / "config.toml"
    for needed in (metrics_path, config_path):
        if not needed.is_file():
            raise SealError(f"{run}: no {needed.name}; {_EXPECTED}")
    metrics = _read_csv(
        metrics_path, REQUIRED_METRICS_COLUMNS, text_columns=("phase", "env", "task")
    )
    train_path = run / "train.csv"
    if train_path.is_file():
        train = _read_csv(train_path, TRAIN_COLUMNS, text_columns=("phase", "env", "key"))
    else:
        train = pd.DataFrame(
            {
                c: pd.Series(dtype=object if c in ("phase", "env", "key") else float)
                for c in TRAIN_COLUMNS
            }
        )
    try:
        config = tomllib.loads(config_path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise SealError(f"{config_path}: not valid TOML ({exc})") from None
    provenance: dict[str, Any] = {}
    provenance_path = run / "provenance.json"
    if provenance_path.is_file():
        try:
            provenance = json.loads(provenance_path.read_text())
        except json.JSONDecodeError as exc:
            raise SealError(f"{provenance_path}: not valid JSON ({exc})") from None
    return RunData(path=run, metrics=metrics, train=train, config=config, provenance=provenance)


def _is_run_dir(path: Path) -> bool:
    return (path / "metrics.csv").is_file()


def run_dirs(path: str | os.PathLike[str]) -> list[Path]:
    """The run directories a path names: itself if it is a run, else its `seed-<n>/` runs, by seed.

    Seed directories without a metrics.csv yet (a run that has not evaluated) are left out.
    Raises SealError naming the path when it is neither a run nor a group directory.
    """
    where = Path(path)
    if not where.exists():
        raise SealError(f"{where} does not exist; {_EXPECTED}")
    if not where.is_dir():
        raise SealError(f"{where} is a file, not a directory; {_EXPECTED}")
    if _is_run_dir(where):
        return [where]
    seeds = [d for d in where.iterdir() if d.is_dir() and re.fullmatch(r"seed-\d+", d.name)]
    runs = sorted((d for d in seeds if _is_run_dir(d)), key=lambda d: int(d.name.split("-")[1]))
    if runs:
        return runs
    if seeds:
        raise SealError(
            f"{where}: none of its seed directories {sorted(d.name for d in seeds)} has a metrics.csv yet"
        )
    groups = sorted(
        str(d) for d in where.iterdir() if d.is_dir() and any(d.glob("seed-*/metrics.csv"))
    )
    hint = f"; it holds the group directories {groups[:5]}, pass those" if groups else ""
    raise SealError(f"{where}: neither a run nor a group directory; {_EXPECTED}{hint}")


# --------------------------------------------------------------------------- columns


def _ratio_label(scheduler: dict[str, Any], envs: Sequence[str]) -> str | None:
    """ "50/50" from a constant scheduler's ratio (a fraction, a list, or {env: weight}), else None."""
    ratio = next((scheduler[k] for k in ("ratios", "ratio", "weights") if k in scheduler), None)
    if isinstance(ratio, dict):
        weights = [float(ratio[e]) for e in envs if e in ratio] or [
            float(v) for v in ratio.values()
        ]
    elif isinstance(ratio, list | tuple):
        weights = [float(v) for v in ratio]
    elif isinstance(ratio, int | float) and 0 <= ratio <= 1:
        weights = [float(ratio), 1.0 - float(ratio)]
    elif not ratio and len(envs) >= 2:
        weights = [1.0] * len(envs)  # seal.schedulers: an empty `ratios` means equal shares
    else:
        return None
    total = sum(weights)
    if total <= 0:
        return None
    return "/".join(format_number(100.0 * w / total) for w in weights)


def column_label(run: RunData, phase: str, env: str) -> str:
    """The report column of one run's phase and environment, as the paper names them.

    baseline -> "Single Env"; joint with a constant ratio -> "50/50" (or its ratio); joint with the
    `high_fk` / `high_mw` presets -> "High FK" / "High MW"; finetune -> "Pre-train on X" for its
    pretrain phase and "Fine-tune on Y" for its finetune phase (Tables 6-7); anything else, such as
    a baseline under an SMT or curriculum scheduler, -> its protocol name.
    """
    scheduler = run.scheduler()
    sched_kind = str(scheduler.get("kind", "") or "").lower()
    if run.kind == "baseline" and sched_kind in _PLAIN_SCHEDULERS:
        return BASELINE_COLUMN
    if run.kind == "finetune":
        if phase == "pretrain":
            return f"Pre-train on {run.env_label(env)}"
        if phase == "finetune":
            return f"Fine-tune on {run.env_label(env)}"
        return f"{run.protocol} ({phase})"
    if run.kind == "joint":
        # `kind = "high_fk"` is seal.schedulers' shorthand for `kind = "stepped", preset = "high_fk"`.
        preset = str(scheduler.get("preset", "") or sched_kind).lower()
        if preset in _PRESET_COLUMNS:
            return _PRESET_COLUMNS[preset]
        envs = list(run.config.get("envs", {})) or list(dict.fromkeys(run.metrics["env"]))
        start = scheduler.get("start")
        if sched_kind == "stepped" and isinstance(start, dict) and start:
            # A stepped schedule without a preset is named for the env it starts high on.
            return f"High {run.env_label(max(start, key=lambda e: float(start[e])))}"
        if sched_kind == "constant":
            label = _ratio_label(scheduler, envs)
            if label:
                return label
        if sched_kind in _PLAIN_SCHEDULERS:
            # A uniform batch over all tasks: each env's share is its share of the tasks.
            tasks = run.metrics.groupby("env", sort=False)["task"].nunique()
            label = _ratio_label({"ratios": {e: int(tasks.get(e, 0)) for e in envs}}, envs)
            if label:
                return label
    return run.protocol


def _column_rank(label: str) -> tuple[int, int, int, str]:
    """Table 1's columns first, then fine-tune columns by environment (MW, FK, others), then the rest."""
    if label in _COLUMN_ORDER:
        return (_COLUMN_ORDER.index(label), 0, 0, "")
    for step, prefix in enumerate(("Pre-train on ", "Fine-tune on ")):
        if label.startswith(prefix):
            env = label.removeprefix(prefix)
            # Pre-train on X next to Fine-tune on X: the two columns that fill X's rows (Tables 6-7).
            return (len(_COLUMN_ORDER), _ENV_RANK.get(env, len(_ENV_RANK)), step, env)
    return (len(_COLUMN_ORDER) + 1, 0, 0, label)


# --------------------------------------------------------------------------- gathering


@dataclass(frozen=True)
class _Group:
    """The runs of one group directory."""

    path: Path
    runs: list[RunData]

    @property
    def name(self) -> str:
        return f"{self.runs[0].protocol}/{self.runs[0].group}"


def _gather(paths: Iterable[str | os.PathLike[str]]) -> list[_Group]:
    """Resolve run and group paths into groups (runs given one by one join their group)."""
    by_group: dict[Path, dict[Path, RunData]] = {}
    for given in paths:
        for run_path in run_dirs(given):
            resolved = run_path.resolve()
            by_group.setdefault(resolved.parent, {})
            if resolved not in by_group[resolved.parent]:
                by_group[resolved.parent][resolved] = load_run(run_path)
    if not by_group:
        raise SealError(f"no run or group directories given; {_EXPECTED}")
    groups = []
    for group_path, runs in by_group.items():
        ordered = sorted(runs.values(), key=lambda r: r.seed)
        seeds = [r.seed for r in ordered]
        if len(set(seeds)) != len(seeds):
            raise SealError(
                f"{group_path}: several runs claim the same seed {seeds}; each seed-<n>/ must hold its own seed"
            )
        groups.append(_Group(path=group_path, runs=ordered))
    return groups


def _labelled(groups: Sequence[_Group], frame_of: str) -> pd.DataFrame:
    """All runs' metrics (or train) rows with `column`, `env_label` and `source` (group) added."""
    frames = []
    for group in groups:
        for run in group.runs:
            frame = getattr(run, frame_of)
            if frame.empty:
                continue
            frame = frame.copy()
            frame["seed"] = run.seed  # the run's identity within the group, whatever the CSV says
            labels = {
                (phase, env): column_label(run, phase, env)
                for phase, env in frame[["phase", "env"]].drop_duplicates().itertuples(index=False)
            }
            frame["column"] = [
                labels[(p, e)] for p, e in zip(frame["phase"], frame["env"], strict=True)
            ]
            frame["env_label"] = [
                run.env_label(e) if isinstance(e, str) else "" for e in frame["env"]
            ]
            frame["source"] = group.name
            frames.append(frame)
    if not frames:
        return pd.DataFrame()
    return pd.concat(frames, ignore_index=True)


def _disambiguate(metrics: pd.DataFrame) -> pd.DataFrame:
    """Columns given by two groups for the same environment get the group appended to their label.

    Two baselines for one environment cannot be told apart as "the" baseline, so that is an error.
    """
    owners = metrics.groupby(["column", "env"], sort=False)["source"].unique()
    clashing = {
        (column, env): list(srcs) for (column, env), srcs in owners.items() if len(srcs) > 1
    }
    for (column, env), sources in clashing.items():
        if column == BASELINE_COLUMN:
            raise SealError(
                f"several baseline groups for environment {env!r}: {sources}; pass one of them "
                f"so the percent change has a single baseline"
            )
    if not clashing:
        return metrics
    out = metrics.copy()
    clash_columns = {column for column, _ in clashing}
    mask = out["column"].isin(clash_columns)
    out.loc[mask, "column"] = out.loc[mask, "column"] + " [" + out.loc[mask, "source"] + "]"
    return out


# --------------------------------------------------------------------------- tables


@dataclass
class ReportResult:
    """What `report` wrote and the numbers behind it."""

    out_dir: Path
    """Where tables/ and plots/ were written."""
    threshold: float
    """Success threshold used for the update-count metric."""
    tables: dict[str, Path]
    """Table files by name, e.g. "update_counts.md"."""
    plots: list[Path]
    """PNG files written."""
    update_counts: pd.DataFrame
    """Per (column, env, task): updates_mean/std (millions), grad/env steps, reached, seeds, pct_change."""
    per_seed: pd.DataFrame
    """Per (column, env, task, seed): the first evaluation reaching the threshold (seal.metrics.first_reach)."""
    totals: pd.DataFrame
    """Per (column, env): updates_total, tasks_reached, tasks."""
    groups: list[Path]
    """The group directories reported on."""
    skipped: list[str] = field(default_factory=list)
    """Notes on what could not be drawn (e.g. no critic_loss rows in train.csv)."""
    warnings: list[str] = field(default_factory=list)
    """Settings that differ between the groups compared (agent.shared_update, critic_sharing, reward versions)."""

    def to_json(self) -> dict[str, Any]:
        """Paths and update-count numbers as plain JSON values (NaN -> null)."""

        def num(value: Any) -> Any:
            return (
                None
                if value is None or (isinstance(value, float) and not math.isfinite(value))
                else value
            )

        counts: dict[str, dict[str, dict[str, dict[str, Any]]]] = {}
        for row in self.update_counts.itertuples(index=False):
            counts.setdefault(row.column, {}).setdefault(row.env, {})[row.task] = {
                "mean": num(float(row.updates_mean)),
                "std": num(float(row.updates_std)),
                "reached": int(row.reached),
                "seeds": int(row.seeds),
                "grad_steps": num(float(row.grad_steps_mean)),
                "env_steps": num(float(row.env_steps_mean)),
                "pct_change": num(float(row.pct_change)),
                "paper_updates": num(float(row.paper_updates_mean)),
            }
        totals: dict[str, dict[str, float]] = {}
        for row in self.totals.itertuples(index=False):
            totals.setdefault(row.column, {})[row.env] = float(row.updates_total)
        return {
            "out_dir": str(self.out_dir),
            "threshold": self.threshold,
            "groups": [str(g) for g in self.groups],
            "tables": {name: str(p) for name, p in self.tables.items()},
            "plots": [str(p) for p in self.plots],
            "update_counts": counts,
            "update_count_totals": totals,
            "skipped": self.skipped,
            "warnings": self.warnings,
        }


def _row_order(frame: pd.DataFrame) -> list[tuple[str, str]]:
    """(env, task) rows: Meta-World first, then the kitchen, then others; tasks in logged order."""
    env_labels = dict(zip(frame["env"], frame["env_label"], strict=False))
    envs = list(dict.fromkeys(frame["env"]))
    envs.sort(key=lambda e: _ENV_RANK.get(env_labels[e], len(_ENV_RANK)))
    rows = []
    for env in envs:
        tasks = dict.fromkeys(frame.loc[frame["env"] == env, "task"])
        rows.extend((env, task) for task in tasks)
    return rows


def _escape_latex(text: str) -> str:
    return re.sub(r"([_&%#$])", r"\\\1", text)


def _update_count_table(
    counts: pd.DataFrame,
    totals: pd.DataFrame,
    columns: list[str],
    rows: list[tuple[str, str]],
    labels: dict[str, str],
    style: str,
) -> pd.DataFrame:
    """The display table: Task x columns, cells from seal.metrics.format_count, total rows per env."""
    has_baseline = set(counts.loc[counts["column"] == BASELINE_COLUMN, "env"])
    cells = {(r.column, r.env, r.task): r for r in counts.itertuples(index=False)}
    esc = _escape_latex if style == "latex" else (lambda s: s)
    records = []
    for env, task in rows:
        record = {"Task": esc(f"{task} ({labels[env]})")}
        for column in columns:
            row = cells.get((column, env, task))
            if row is None:
                record[esc(column)] = ""
                continue
            show_pct = column != BASELINE_COLUMN and env in has_baseline
            pct = None if math.isnan(row.pct_change) else float(row.pct_change)
            record[esc(column)] = format_count(
                row.updates_mean,
                row.updates_std,
                int(row.reached),
                int(row.seeds),
                pct,
                show_pct,
                style,
            ) + _paper_suffix(row.updates_mean, row.paper_updates_mean, int(row.reached), style)
        records.append(record)
    for env in dict.fromkeys(env for env, _ in rows):
        record = {"Task": esc(f"Total ({labels[env]})")}
        for column in columns:
            total = totals[(totals["column"] == column) & (totals["env"] == env)]
            record[esc(column)] = (
                ""
                if total.empty
                else f"{format_number(float(total['updates_total'].iloc[0]))} "
                f"({int(total['tasks_reached'].iloc[0])}/{int(total['tasks'].iloc[0])} tasks)"
            )
        records.append(record)
    return pd.DataFrame.from_records(records)


PAPER_GAP = 0.005
"""Show C x GS x BS beside the exact count when they differ by more than this fraction."""


def _paper_suffix(exact: float, paper: float, reached: int, style: str) -> str:
    """ " {C×GS×BS: x}" when the paper's product differs from the exact count (changing batches)."""
    if (
        reached == 0
        or not math.isfinite(paper)
        or abs(paper - exact) <= PAPER_GAP * max(exact, 1e-12)
    ):
        return ""
    times = r"$\times$" if style == "latex" else "×"
    open_, close = (r"\{", r"\}") if style == "latex" else ("{", "}")
    return f" {open_}C{times}GS{times}BS: {format_number(paper)}{close}"


# Settings that change what an update count measures: a report comparing groups that differ in
# them compares different experiments, and says so.
COMPARABILITY_KEYS: tuple[tuple[str, str], ...] = (
    ("agent", "shared_update"),
    ("agent", "critic_sharing"),
)


def _comparability_warnings(groups: Sequence[_Group]) -> list[str]:
    """One line per setting (agent.shared_update, agent.critic_sharing, reward versions) that differs between groups."""
    seen: dict[str, dict[str, list[str]]] = {}
    for group in groups:
        run = group.runs[0]
        for table, key in COMPARABILITY_KEYS:
            value = run.config.get(table, {}).get(key)
            if value is not None:
                seen.setdefault(f"{table}.{key}", {}).setdefault(str(value), []).append(group.name)
        versions = run.provenance.get("reward_versions") or {}
        for env, version in versions.items() if isinstance(versions, dict) else ():
            seen.setdefault(f"reward version of {env}", {}).setdefault(str(version), []).append(
                group.name
            )
    return [
        f"groups differ in {what}: "
        + "; ".join(f"{value} in {', '.join(names)}" for value, names in values.items())
        for what, values in seen.items()
        if len(values) > 1
    ]


def _notes(threshold: float, with_change: bool) -> list[str]:
    pct = f"{threshold:.0%}"
    notes = [
        f"Millions of each task's transitions consumed by gradient updates until its first evaluation "
        f"with success >= {pct} (Appendix B). Mean ± sample std over the seeds that reached it; "
        f"[k/n] = seeds that reached it / seeds run.",
        f"{NEVER_REACHED} = never reached {pct} in any seed; counted as 0 in the totals and in update_counts.csv.",
        "Total = sum of the per-task means (never-reached tasks count 0); (k/N tasks) = tasks reached by any seed.",
    ]
    if with_change:
        notes.insert(
            2,
            f"(±x%) = change against {BASELINE_COLUMN} for the same task; bold = fewer updates; "
            f"n/a = the baseline or this column never reached it.",
        )
    return notes


def _success_tables(
    metrics: pd.DataFrame, columns: list[str], rows: list[tuple[str, str]], labels: dict[str, str]
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Final success per (column, env, task): numbers (long) and display (Task x columns)."""
    last_epoch = metrics.groupby(["column", "env", "seed"])["epoch"].transform("max")
    final = metrics[metrics["epoch"] == last_epoch]
    long = (
        final.groupby(["column", "env", "task"], sort=False)["success"]
        .agg(success_mean="mean", success_std="std", seeds="count")
        .reset_index()
    )
    cells = {(r.column, r.env, r.task): r for r in long.itertuples(index=False)}
    records = []
    for env, task in rows:
        record = {"Task": f"{task} ({labels[env]})"}
        for column in columns:
            row = cells.get((column, env, task))
            if row is None:
                record[column] = ""
                continue
            text = f"{row.success_mean:.2f}"
            if math.isfinite(row.success_std):
                text += f" ± {row.success_std:.2f}"
            record[column] = text
        records.append(record)
    for env in dict.fromkeys(env for env, _ in rows):
        record = {"Task": f"Mean ({labels[env]})"}
        for column in columns:
            env_rows = long[(long["column"] == column) & (long["env"] == env)]
            record[column] = (
                "" if env_rows.empty else f"{float(env_rows['success_mean'].mean()):.2f}"
            )
        records.append(record)
    return long, pd.DataFrame.from_records(records)


def _write_table(
    display: pd.DataFrame,
    stem: Path,
    title: str,
    notes: list[str],
    latex: pd.DataFrame | None = None,
) -> dict[str, Path]:
    """Markdown (with notes) and LaTeX (notes in the caption) versions of a display table."""
    md = stem.with_suffix(".md")
    md.write_text(
        f"# {title}\n\n{display.to_markdown(index=False, disable_numparse=True)}\n\n"
        + "".join(f"- {n}\n" for n in notes)
    )
    tex = stem.with_suffix(".tex")
    latex_frame = (
        latex if latex is not None else display.map(_escape_latex).rename(columns=_escape_latex)
    )
    caption = (
        _escape_latex(title + ". " + " ".join(notes))
        .replace("±", r"$\pm$")
        .replace(">=", r"$\geq$")
    )
    caption = caption.replace(NEVER_REACHED, "---")
    tex.write_text(
        latex_frame.to_latex(
            index=False,
            escape=False,
            caption=caption,
            column_format="l" + "r" * (latex_frame.shape[1] - 1),
        )
    )
    return {md.name: md, tex.name: tex}


# --------------------------------------------------------------------------- plots


def _colours(columns: Sequence[str]) -> dict[str, str]:
    others = iter(_OTHER_COLOURS * (1 + len(columns) // len(_OTHER_COLOURS)))
    return {c: _COLUMN_COLOURS.get(c) or next(others) for c in columns}


def _markers(points: int) -> dict[str, Any]:
    # Short curves (a few evaluations, or a single one) need markers to be visible at all.
    return {"marker": "o", "markersize": 3} if points <= 20 else {}


def _save(fig: Figure, path: Path) -> Path:
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    return path


def _mean_std_over_seeds(frame: pd.DataFrame, x: str, value: str) -> pd.DataFrame:
    """Per (column, env, step): x position, mean and sample std over seeds of `value`."""
    # Seeds are aligned on the epoch (evaluations happen at the same epochs), x is their mean there.
    grouped = frame.groupby(["column", "env", "epoch"], sort=True)
    return grouped.agg(
        x=(x, "mean"), mean=(value, "mean"), std=(value, "std"), seeds=("seed", "nunique")
    ).reset_index()


def _plot_success(
    metrics: pd.DataFrame,
    x: XAxis,
    colours: dict[str, str],
    labels: dict[str, str],
    plots: Path,
    threshold: float,
) -> list[Path]:
    """Figs. 2-4: per environment, success averaged over its tasks, mean ± std over seeds, per column."""
    per_eval = metrics.groupby(["column", "env", "seed", "epoch"], sort=False).agg(
        success=("success", "mean"), grad_steps=("grad_steps", "mean")
    )
    curves = _mean_std_over_seeds(per_eval.reset_index(), x, "success")
    written = []
    for env in dict.fromkeys(metrics["env"]):
        fig = Figure(figsize=(6.4, 4.0))
        ax = fig.add_subplot()
        env_curves = curves[curves["env"] == env]
        for column in sorted(env_curves["column"].unique(), key=_column_rank):
            curve = env_curves[env_curves["column"] == column].sort_values("x")
            std = curve["std"].fillna(0.0)
            seeds = int(curve["seeds"].max())
            ax.plot(
                curve["x"],
                curve["mean"],
                color=colours[column],
                label=f"{column} ({seeds} seed{'s' * (seeds > 1)})",
                **_markers(len(curve)),
            )
            ax.fill_between(
                curve["x"],
                (curve["mean"] - std).clip(0, 1),
                (curve["mean"] + std).clip(0, 1),
                color=colours[column],
                alpha=0.2,
                linewidth=0,
            )
        ax.axhline(
            threshold, color="grey", linestyle=":", linewidth=1, label=f"threshold {threshold:g}"
        )
        ax.set_ylim(-0.02, 1.02)
        ax.set_xlabel("gradient steps" if x == "grad_steps" else "epoch")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_ylabel("success rate (mean over tasks)")
        ax.set_title(f"{labels[env]}: success, mean ± std over seeds")
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize="small")
        written.append(_save(fig, plots / f"success_{_safe(env)}.png"))
    return written


def _plot_critic_loss(
    train: pd.DataFrame, x: XAxis, colours: dict[str, str], labels: dict[str, str], plots: Path
) -> Path | None:
    """Fig. 7: the value-function (critic) loss per environment, mean ± std over seeds, per column."""
    if train.empty or "critic_loss" not in set(train["key"]):
        return None
    loss = train[train["key"] == "critic_loss"].copy()
    loss["env"] = loss["env"].fillna("all")
    loss = (
        loss.groupby(["column", "env", "seed", "epoch"], sort=False)
        .agg(value=("value", "mean"), grad_steps=("grad_steps", "mean"))
        .reset_index()
    )
    curves = _mean_std_over_seeds(loss, x, "value")
    envs = list(dict.fromkeys(loss["env"]))
    fig = Figure(figsize=(6.0 * len(envs), 4.0))
    axes = fig.subplots(1, len(envs), squeeze=False)[0]
    positive = bool((curves["mean"] > 0).all())
    for ax, env in zip(axes, envs, strict=True):
        env_curves = curves[curves["env"] == env]
        for column in sorted(env_curves["column"].unique(), key=_column_rank):
            curve = env_curves[env_curves["column"] == column].sort_values("x")
            std = curve["std"].fillna(0.0)
            lower = (
                (curve["mean"] - std).clip(lower=curve["mean"] * 0.01)
                if positive
                else curve["mean"] - std
            )
            ax.plot(
                curve["x"],
                curve["mean"],
                color=colours[column],
                label=column,
                **_markers(len(curve)),
            )
            ax.fill_between(
                curve["x"],
                lower,
                curve["mean"] + std,
                color=colours[column],
                alpha=0.2,
                linewidth=0,
            )
        if positive:
            ax.set_yscale("log")  # losses span orders of magnitude as Q-values grow
        ax.set_xlabel("gradient steps" if x == "grad_steps" else "epoch")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_ylabel("critic loss")
        ax.set_title(f"{labels.get(env, env)}: value-function loss")
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize="small")
    return _save(fig, plots / "critic_loss.png")


def _plot_schedulers(groups: Sequence[_Group], plots: Path, skipped: list[str]) -> list[Path]:
    """plots/scheduler_membership.png (and scheduler_budget.png for SMT) of runs with a scheduler.csv.

    One run: those names; several: `scheduler_<protocol>_<group>_seed-<n>_<kind>.png`. A timeline
    of one snapshot with every task alike (the default uniform scheduler) is not drawn; one
    that cannot be plotted (empty, or written by an older runner) is reported in `skipped`.
    """
    from seal.schedulers.plots import plot_budget_usage, plot_membership

    runs = [r for g in groups for r in g.runs if (r.path / "scheduler.csv").is_file()]
    out: list[Path] = []
    for run in runs:
        tag = "" if len(runs) == 1 else "_" + _safe(f"{run.protocol}_{run.group}_seed-{run.seed}")
        try:
            timeline = pd.read_csv(run.path / "scheduler.csv")
            if timeline["status"].nunique() <= 1 and timeline["epoch"].nunique() <= 1:
                continue  # one snapshot, every task alike (the default uniform scheduler): nothing to draw
            out.append(plot_membership(timeline, plots / f"scheduler{tag}_membership.png"))
            if "used" in timeline:  # SMT's budget usage (Fig. 6); curricula have no budgets
                out.append(plot_budget_usage(timeline, plots / f"scheduler{tag}_budget.png"))
        except (ValueError, KeyError, pd.errors.EmptyDataError) as exc:
            skipped.append(f"scheduler{tag}_*.png: {run.path / 'scheduler.csv'}: {exc}")
    return out


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.+-]+", "_", name)


# --------------------------------------------------------------------------- report


def _resolve_threshold(groups: Sequence[_Group], threshold: float | None) -> float:
    if threshold is None:
        configured = {
            float(run.config.get("evaluation", {}).get("threshold", DEFAULT_THRESHOLD))
            for g in groups
            for run in g.runs
        }
        # One protocol-configured threshold is honoured; mixed ones fall back to the paper's 0.9.
        threshold = configured.pop() if len(configured) == 1 else DEFAULT_THRESHOLD
    if not (isinstance(threshold, int | float) and 0.0 < threshold <= 1.0):
        raise SealError(
            f"threshold {threshold!r} is not a success rate; expected 0 < threshold <= 1 (default 0.9)"
        )
    return float(threshold)


def _default_out(paths: Sequence[str | os.PathLike[str]], groups: Sequence[_Group]) -> Path:
    """One run -> the run; one group -> the group; several -> <reports root>/comparison/<protocols>."""
    if len(groups) == 1:
        group = groups[0]
        if len(paths) == 1 and _is_run_dir(Path(paths[0])):
            return Path(paths[0])
        return group.path
    root = Path(os.path.commonpath([str(g.path.parent.parent) for g in groups]))
    names = "+".join(dict.fromkeys(g.runs[0].protocol for g in groups))
    return root / "comparison" / _safe(names)[:150]


def report(
    paths: Sequence[str | os.PathLike[str]],
    out: str | os.PathLike[str] | None = None,
    threshold: float | None = None,
    x: XAxis = "grad_steps",
) -> ReportResult:
    """Merge runs and groups into the paper's tables and plots; write them under `out`.

    `paths` are run directories and/or group directories (e.g. the baseline groups and the joint
    groups). Writes `tables/update_counts.{md,csv,tex}`, `tables/update_counts_per_seed.csv`,
    `tables/success.{md,csv,tex}`, `plots/success_<env>.png` and `plots/critic_loss.png` under
    `out` (default: the run or group directory when there is one, else
    `<reports root>/comparison/<protocols>/`). `threshold` defaults to the runs' configured
    [evaluation].threshold when they agree, else 0.9. `x` is the plots' x axis.
    """
    if isinstance(paths, str | os.PathLike):
        paths = [paths]
    if x not in ("grad_steps", "epoch"):
        raise SealError(f"x axis {x!r} is not valid; expected 'grad_steps' or 'epoch'")
    groups = _gather(paths)
    threshold = _resolve_threshold(groups, threshold)
    metrics = _labelled(groups, "metrics")
    if metrics.empty:
        raise SealError(
            f"{[str(g.path) for g in groups]}: the metrics.csv files have no evaluation rows yet"
        )
    metrics = _disambiguate(metrics)
    train = _labelled(groups, "train")
    if not train.empty:
        # Training rows take their evaluation rows' column (disambiguated labels included).
        column_of = metrics.drop_duplicates(["source", "phase", "env"]).set_index(
            ["source", "phase", "env"]
        )["column"]
        keys = list(zip(train["source"], train["phase"], train["env"], strict=True))
        train["column"] = [column_of.get(k, c) for k, c in zip(keys, train["column"], strict=True)]

    out_dir = Path(out) if out is not None else _default_out(paths, groups)
    tables_dir, plots_dir = out_dir / "tables", out_dir / "plots"
    try:
        tables_dir.mkdir(parents=True, exist_ok=True)
        plots_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SealError(
            f"cannot write the report to {out_dir}: {exc.strerror}; pass --out DIR"
        ) from None

    # ---- update-count metric: per seed, across seeds, totals, % change against Single Env
    per_seed = []
    for (column, source), frame in metrics.groupby(["column", "source"], sort=False):
        reach = first_reach(frame, threshold)
        reach.insert(0, "column", column)
        reach.insert(1, "source", source)
        per_seed.append(reach)
    per_seed_frame = pd.concat(per_seed, ignore_index=True)
    counts = aggregate_seeds(per_seed_frame, keys=("column", "env", "task"))
    counts = add_percent_change(counts, BASELINE_COLUMN, column_key="column", on=("env", "task"))
    totals = env_totals(counts, keys=("column", "env"))

    columns = sorted(dict.fromkeys(metrics["column"]), key=_column_rank)
    rows = _row_order(metrics)
    labels = dict(zip(metrics["env"], metrics["env_label"], strict=False))
    notes = _notes(
        threshold,
        with_change=bool((counts["column"] == BASELINE_COLUMN).any() and len(columns) > 1),
    )
    if (counts["reached"] > 0).any() and any(
        _paper_suffix(r.updates_mean, r.paper_updates_mean, int(r.reached), "plain")
        for r in counts.itertuples(index=False)
    ):
        notes.append(
            "{C×GS×BS: x} = Appendix B's product (gradient steps × the task's batch in force at that "
            "evaluation), shown where the batch changed during the run and it differs from the exact count."
        )
    warnings = _comparability_warnings(groups)
    notes.extend(f"WARNING: {w}; these columns are not the same experiment." for w in warnings)
    title = f"Millions of updates to reach {threshold:.0%} success"

    tables: dict[str, Path] = {}
    counts_csv = tables_dir / "update_counts.csv"
    counts.to_csv(counts_csv, index=False)
    per_seed_csv = tables_dir / "update_counts_per_seed.csv"
    per_seed_frame.to_csv(per_seed_csv, index=False)
    tables[counts_csv.name], tables[per_seed_csv.name] = counts_csv, per_seed_csv
    display_md = _update_count_table(counts, totals, columns, rows, labels, "markdown")
    display_tex = _update_count_table(counts, totals, columns, rows, labels, "latex")
    tables.update(
        _write_table(display_md, tables_dir / "update_counts", title, notes, latex=display_tex)
    )

    success_long, success_display = _success_tables(metrics, columns, rows, labels)
    success_csv = tables_dir / "success.csv"
    success_long.to_csv(success_csv, index=False)
    tables[success_csv.name] = success_csv
    success_notes = ["Success rate at each run's last evaluation; mean ± sample std over seeds."]
    tables.update(
        _write_table(success_display, tables_dir / "success", "Final success rate", success_notes)
    )

    # ---- plots
    colours = _colours(columns)
    skipped: list[str] = []
    plots = _plot_success(metrics, x, colours, labels, plots_dir, threshold)
    loss_plot = _plot_critic_loss(train, x, colours, labels, plots_dir)
    if loss_plot is None:
        skipped.append("critic_loss.png: no critic_loss rows in the runs' train.csv")
    else:
        plots.append(loss_plot)
    plots.extend(_plot_schedulers(groups, plots_dir, skipped))

    return ReportResult(
        out_dir=out_dir,
        threshold=threshold,
        tables=tables,
        plots=plots,
        update_counts=counts,
        per_seed=per_seed_frame,
        totals=totals,
        groups=[g.path for g in groups],
        skipped=skipped,
        warnings=warnings,
    )


__all__ = [
    "METRICS_COLUMNS",
    "TRAIN_COLUMNS",
    "ReportResult",
    "RunData",
    "column_label",
    "load_run",
    "report",
    "run_dirs",
]
