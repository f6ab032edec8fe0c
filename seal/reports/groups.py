"""Report columns and gathering: which column a run's rows go to, and the groups they come from.

`column_label` names a run's phase and environment as the paper's columns ("Single Env", "50/50",
"High FK", "Pre-train on X", ...) and `_column_rank` orders them as Table 1 and Tables 6-7 do;
`_gather` resolves run and group paths into `_Group`s of runs, `_labelled` stacks their rows with
the column added, and `_disambiguate` tells apart columns that several groups give.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from seal.errors import SealError
from seal.metrics import format_number
from seal.reports.load import _EXPECTED, RunData, decided_early, load_run, run_dirs

BASELINE_COLUMN = "Single Env"
"""The column every other column's percent change is measured against (Table 1)."""

# Rows list Meta-World's tasks first, then the kitchen's, as Table 1 does.
_ENV_RANK = {"MW": 0, "FK": 1}

# The paper's column order (Table 1, then Tables 6-7); other columns follow in the order given.
_PRESET_COLUMNS = {"high_fk": "High FK", "high_mw": "High MW"}
_COLUMN_ORDER = (BASELINE_COLUMN, "50/50", "High FK", "High MW")

# Scheduler kinds under which a `baseline` protocol is still the plain MTMHSAC baseline.
_PLAIN_SCHEDULERS = ("", "uniform", "none")


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


def column_label(
    run: RunData, phase: str, env: str, others: Mapping[str, str] | None = None
) -> str:
    """The report column of one run's phase and environment, as the paper names them.

    A protocol's own [protocol].column wins; otherwise:

    baseline -> "Single Env"; joint with a constant ratio -> "50/50" (or its ratio); joint with the
    `high_fk` / `high_mw` presets -> "High FK" / "High MW"; finetune -> "Pre-train on X" for its
    pretrain phase and "Fine-tune on Y" for its finetune phase (Tables 6-7); a baseline whose
    scheduler has a non-empty `absent` table (a batch-matched alone arm) -> "Single Env (<the joint
    column> batch)", e.g. "Single Env (High FK batch)"; anything else, such as a baseline under an
    SMT or curriculum scheduler, -> its protocol name. `others` labels envs this run lacks (a
    matched arm's absent env) by the [envs.<env>] adapters of the other runs in the report.
    """
    named = run.config.get("protocol", {}).get("column")
    if (
        named and run.kind != "finetune"
    ):  # [protocol].column: the protocol names its own column (SMT Table 1's learners)
        return str(named)
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
    envs = list(run.config.get("envs", {})) or list(dict.fromkeys(run.metrics["env"]))
    absent = scheduler.get("absent")
    if run.kind == "baseline" and isinstance(absent, dict) and absent:
        # Batch-matched alone: the joint run's schedule with the absent envs' share not drawn.
        joint = _joint_label(run, scheduler, sched_kind, [*envs, *absent], others or {})
        return matched_label(joint or run.protocol)
    if run.kind == "joint":
        label = _joint_label(run, scheduler, sched_kind, envs, others or {})
        if label:
            return label
    return run.protocol


def matched_label(joint: str) -> str:
    """The column of the batch-matched alone arm of joint column `joint`: "Single Env (High FK batch)"."""
    return f"{BASELINE_COLUMN} ({joint} batch)"


def _joint_label(
    run: RunData,
    scheduler: dict[str, Any],
    sched_kind: str,
    envs: Sequence[str],
    others: Mapping[str, str],
) -> str | None:
    """The column a joint schedule over `envs` gets ("High FK", "50/50"), or None."""
    # `kind = "high_fk"` is seal.schedulers' shorthand for `kind = "stepped", preset = "high_fk"`.
    preset = str(scheduler.get("preset", "") or sched_kind).lower()
    if preset in _PRESET_COLUMNS:
        return _PRESET_COLUMNS[preset]
    start = scheduler.get("start")
    if sched_kind == "stepped" and isinstance(start, dict) and start:
        # A stepped schedule without a preset is named for the env it starts high on.
        high = max(start, key=lambda e: float(start[e]))
        own = high in run.config.get("envs", {})
        return f"High {run.env_label(high) if own else others.get(high, run.env_label(high))}"
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
    return None


def _column_rank(label: str) -> tuple[int, int, int, str]:
    """Table 1's columns first, then fine-tune columns by environment (MW, FK, others), then SMT
    Table 1's learners in its order, then the rest."""
    if label in _COLUMN_ORDER:
        return (_COLUMN_ORDER.index(label), 0, 0, "")
    if label.startswith(f"{BASELINE_COLUMN} ("):
        return (0, 1, 0, label)  # batch-matched alone arms next to Single Env
    for step, prefix in enumerate(("Pre-train on ", "Fine-tune on ")):
        if label.startswith(prefix):
            env = label.removeprefix(prefix)
            # Pre-train on X next to Fine-tune on X: the two columns that fill X's rows (Tables 6-7).
            return (len(_COLUMN_ORDER), _ENV_RANK.get(env, len(_ENV_RANK)), step, env)
    if label in SMT_TABLE1_ORDER:  # SMT Table 1's rows in its order, MOORE and CARE after
        return (len(_COLUMN_ORDER) + 1, SMT_TABLE1_ORDER.index(label), 0, "")
    return (len(_COLUMN_ORDER) + 2, 0, 0, label)


SMT_TABLE1_ORDER = (
    "SAC-MT",
    "SAC-MT-MH",
    "Soft Modular",
    "PCGrad",
    "PaCo",
    "SMT",
    "MOORE",
    "CARE",
)
"""The learners' columns (protocols/smt_table1, protocols/mtrl_learn) in SMT Table 1's order."""


# --------------------------------------------------------------------------- gathering


@dataclass(frozen=True)
class _Group:
    """The runs of one group directory."""

    path: Path
    runs: list[RunData]

    @property
    def name(self) -> str:
        return f"{self.runs[0].protocol}/{self.runs[0].group}"


# Keys that differ between the seeds of one experiment run one seed at a time (`seal bench`,
# sweeps): the seed range, and a checkpoint each seed starts from (a positive control's pre-training).
_PER_SEED_KEYS = {"protocol": ("seeds", "first_seed"), "transfer": ("checkpoint",)}
# Tables of what a run saves and logs, not what it learns (resume is exact: docs/faults.md), so
# seeds made with another checkpoint interval or replay saving are still seeds of one experiment.
_RECORD_KEEPING_TABLES = ("checkpoint", "logging")


def _experiment(run: RunData) -> str:
    """What makes two runs seeds of one experiment: the protocol name and the resolved config,
    per-seed keys and the record-keeping tables aside."""
    config = {
        table: dict(values)
        for table, values in run.config.items()
        if isinstance(values, dict) and table not in _RECORD_KEEPING_TABLES
    }
    for table, keys in _PER_SEED_KEYS.items():
        for key in keys:
            config.get(table, {}).pop(key, None)
    return f"{run.protocol}\n{json.dumps(config, sort_keys=True, default=str)}"


def _gather(paths: Iterable[str | os.PathLike[str]]) -> list[_Group]:
    """Resolve run and group paths into groups (runs given one by one join their group).

    Group directories of one experiment (same protocol and config but the per-seed keys and
    [checkpoint] and [logging], e.g. one `seal run --seeds <s>` per seed) whose seeds do not
    overlap merge into one group, so
    that their seeds make one column; otherwise every group directory is its own.
    """
    by_group: dict[Path, dict[Path, RunData]] = {}
    for given in paths:
        for run_path in run_dirs(given):
            resolved = run_path.resolve()
            by_group.setdefault(resolved.parent, {})
            if resolved not in by_group[resolved.parent]:
                by_group[resolved.parent][resolved] = load_run(run_path)
    if not by_group:
        raise SealError(f"no run or group directories given; {_EXPECTED}")
    groups: list[_Group] = []
    for group_path, runs in by_group.items():
        ordered = sorted(runs.values(), key=lambda r: r.seed)
        seeds = [r.seed for r in ordered]
        if len(set(seeds)) != len(seeds):
            raise SealError(
                f"{group_path}: several runs claim the same seed {seeds}; each seed-<n>/ must hold its own seed"
            )
        key = {_experiment(r) for r in ordered}
        merge = next(
            (
                g
                for g in groups
                if len(key) == 1
                and {_experiment(r) for r in g.runs} == key
                and not {r.seed for r in g.runs} & set(seeds)
            ),
            None,
        )
        if merge is None:
            groups.append(_Group(path=group_path, runs=ordered))
        else:
            groups[groups.index(merge)] = _Group(
                path=merge.path, runs=sorted([*merge.runs, *ordered], key=lambda r: r.seed)
            )
    return groups


def _labelled(groups: Sequence[_Group], frame_of: str) -> pd.DataFrame:
    """All runs' metrics (or train) rows with `column`, `env_label` and `source` (group) added."""
    # Each env name's label from the runs that have it, for matched arms whose joint env is absent.
    env_labels = {
        env: run.env_label(env)
        for group in groups
        for run in group.runs
        for env in run.config.get("envs", {})
    }
    frames = []
    for group in groups:
        for run in group.runs:
            frame = getattr(run, frame_of)
            if frame.empty:
                continue
            frame = frame.copy()
            frame["seed"] = run.seed  # the run's identity within the group, whatever the CSV says
            labels = {
                (phase, env): column_label(run, phase, env, env_labels)
                for phase, env in frame[["phase", "env"]].drop_duplicates().itertuples(index=False)
            }
            frame["column"] = [
                labels[(p, e)] for p, e in zip(frame["phase"], frame["env"], strict=True)
            ]
            frame["env_label"] = [
                run.env_label(e) if isinstance(e, str) else "" for e in frame["env"]
            ]
            frame["source"] = group.name
            # A run that ended once every task had reached the threshold (its curves hold there).
            frame["stops_when_reached"] = bool(
                run.config.get("evaluation", {}).get("stop_when_reached", False)
            )
            if frame_of == "metrics":  # rows whose success is over fewer episodes (decide_early)
                frame["decided_early"] = decided_early(frame, run.train)
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
