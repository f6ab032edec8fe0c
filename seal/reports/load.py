"""Reading run directories: `load_run` turns one `seed-<n>/` directory into a `RunData`.

`RunData` holds a run's metrics.csv and train.csv as DataFrames, its config.toml and
provenance.json as dicts, and names its protocol, kind, group, seed and environments' short
labels; `run_dirs` resolves a run or group path into run directories. Only the files are read,
as data (`seal.files`): each must be a regular file inside the run directory (config.toml at
most `CONFIG_LIMIT` bytes), and every malformed, missing or mistyped one, or a config value the
reports read that is of the wrong type, is a one-line SealError naming the file and the field.
"""

from __future__ import annotations

import io
import math
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from seal.errors import SealError
from seal.files import check_inside, check_regular_file
from seal.metrics import REQUIRED_METRICS_COLUMNS
from seal.protocols.evaluation_cost import DECIDED_KEY
from seal.protocols.toml_io import read_toml
from seal.run.rundir import (  # defined once, by the writer
    CONFIG_LIMIT,
    TRAIN_COLUMNS,
    read_provenance,
)
from seal.typed_config import shown_key

# Short labels the paper uses for its environments, by adapter name.
ADAPTER_LABELS: dict[str, str] = {"metaworld": "MW", "franka_kitchen_dense": "FK"}

_EXPECTED = (
    "expected a run directory (seed-<n>/ holding metrics.csv and config.toml) "
    "or a group directory (reports/<protocol>/<group-id>/ holding seed-<n>/ run directories)"
)


@dataclass(frozen=True)
class RunData:
    """One run directory, read: its metrics and training logs as DataFrames, config and provenance."""

    path: Path
    """The run directory (`.../<protocol>/<group-id>/seed-<n>`)."""
    metrics: pd.DataFrame
    """metrics.csv: one row per evaluation and task (columns `seal.run.rundir.METRICS_COLUMNS`)."""
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


def _read_csv(
    path: Path,
    required: Sequence[str],
    text_columns: Sequence[str],
    named: Sequence[str] = (),
    rates: Sequence[str] = (),
) -> pd.DataFrame:
    """The CSV with its required columns, numeric where not text, no blank `named` cell, and
    every `rates` cell a finite number in [0, 1] (a success rate)."""
    check_inside(path, path.parent, what=path.name)  # no symlink out of the run directory
    check_regular_file(path, what=path.name)  # a FIFO would block pandas forever
    try:
        data = path.read_bytes()
        # The writer ends every row with a newline, so text after the last one is a row being
        # written now or cut by a kill: left out, as `--resume` drops it (seal.run.rundir).
        complete = io.BytesIO(data[: data.rfind(b"\n") + 1])
        frame = pd.read_csv(complete, dtype={c: str for c in text_columns}, keep_default_na=True)
    except pd.errors.EmptyDataError:
        raise SealError(
            f"{path}: file is empty; expected a CSV header with columns {list(required)}"
        ) from None
    except (pd.errors.ParserError, UnicodeDecodeError) as exc:
        raise SealError(f"{path}: not a readable CSV ({exc})") from None
    missing = [c for c in required if c not in frame.columns]
    if missing:
        raise SealError(f"{path}: missing column(s) {missing}; expected columns {list(required)}")
    for column in named:
        blank = frame.index[frame[column].isna()]
        if len(blank):
            raise SealError(
                f"{path}: line {blank[0] + 2} has no {column!r}; every row names its {column}"
            )
    for column in required:
        if column in text_columns:
            continue
        try:
            frame[column] = pd.to_numeric(frame[column])
        except (ValueError, TypeError):
            raise SealError(
                f"{path}: column {column!r} has non-numeric values; expected numbers"
            ) from None
    for column in rates:
        values = frame[column]
        # NaN compares False, so a blank, nan or inf cell is refused with the out-of-range ones.
        bad = frame.index[~((values >= 0.0) & (values <= 1.0))]
        if len(bad):
            raise SealError(
                f"{path}: line {bad[0] + 2} has {column} = {float(values[bad[0]])!r}; expected a "
                f"{column} rate, a finite number in [0, 1]"
            )
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
        if not os.path.lexists(needed):
            raise SealError(f"{run}: no {needed.name}; {_EXPECTED}")
    metrics = _read_csv(
        metrics_path,
        REQUIRED_METRICS_COLUMNS,
        text_columns=("phase", "env", "task"),
        named=("env", "task"),
        rates=("success",),
    )
    train_path = run / "train.csv"
    if os.path.lexists(train_path):
        train = _read_csv(train_path, TRAIN_COLUMNS, text_columns=("phase", "env", "key"))
    else:
        train = pd.DataFrame(
            {
                c: pd.Series(dtype=object if c in ("phase", "env", "key") else float)
                for c in TRAIN_COLUMNS
            }
        )
    config = read_toml(config_path, what="run config", within=run, limit=CONFIG_LIMIT)
    _check_config(config, config_path)
    provenance = read_provenance(run)
    _check_provenance(provenance, run / "provenance.json")
    return RunData(path=run, metrics=metrics, train=train, config=config, provenance=provenance)


def decided_early(metrics: pd.DataFrame, train: pd.DataFrame) -> pd.Series:
    """Per metrics.csv row: whether its task stopped before running all its episodes
    (`evaluation.decide_early`: train.csv's `eval_decided_early/<task>` is 1 at that evaluation),
    so its success is over its first episodes only; False for a run without the option."""
    prefix = f"{DECIDED_KEY}/"
    keys = ["phase", "env", "epoch", "grad_steps", "task"]
    flags = train[train["key"].astype(str).str.startswith(prefix) & (train["value"] > 0.5)]
    if flags.empty:
        return pd.Series(False, index=metrics.index)
    hits = flags.assign(task=flags["key"].str[len(prefix) :])[keys].drop_duplicates()
    merged = metrics[keys].merge(hits.assign(hit=True), on=keys, how="left")
    return pd.Series(merged["hit"].eq(True).to_numpy(), index=metrics.index)


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _ratio_ok(value: object) -> bool:
    """A constant schedule's ratio as the reports read it: a number, a list or table of numbers."""
    if isinstance(value, Mapping):
        return all(_is_number(v) for v in value.values())
    if isinstance(value, list):
        return all(_is_number(v) for v in value)
    return _is_number(value)


def _check_config(config: Mapping[str, Any], path: Path) -> None:
    """SealError naming `path` and the field if a value the reports read has the wrong type.

    Only what `seal report` reads is held here, so run directories of older seal versions,
    whose configs the protocol schema no longer takes, still report.
    """

    def refuse(field: str, value: object, expected: str) -> SealError:
        shown = repr(value) if len(repr(value)) <= 60 else repr(value)[:57] + "..."
        return SealError(f"{path}: {field} = {shown}; expected {expected}")

    for table, value in config.items():
        if not isinstance(value, Mapping) and table in (
            "protocol",
            "envs",
            "agent",
            "evaluation",
            "scheduler",
            "schedule",
        ):
            raise refuse(table, value, "a table")
    protocol = config.get("protocol", {})
    for key in ("name", "kind"):
        if not isinstance(protocol.get(key, ""), str):
            raise refuse(f"protocol.{key}", protocol[key], "a string")
    for name, env in config.get("envs", {}).items():
        where = f"envs.{shown_key(name)}"
        if not isinstance(env, Mapping):
            raise refuse(where, env, "a table")
        if not isinstance(env.get("adapter", ""), str):
            raise refuse(f"{where}.adapter", env["adapter"], "an adapter name (a string)")
    threshold = config.get("evaluation", {}).get("threshold", 0.9)
    if not (_is_number(threshold) and 0 < threshold <= 1):
        raise refuse("evaluation.threshold", threshold, "a success rate, 0 < threshold <= 1")
    for table in ("scheduler", "schedule"):
        scheduler = config.get(table, {})
        for key in ("kind", "preset"):
            if not isinstance(scheduler.get(key, ""), str):
                raise refuse(f"{table}.{key}", scheduler[key], "a string")
        for key in ("start", "absent"):
            value = scheduler.get(key, {})
            if not (isinstance(value, Mapping) and all(_is_number(v) for v in value.values())):
                raise refuse(f"{table}.{key}", value, "a table of numbers by env")
        for key in ("ratios", "ratio", "weights"):
            if key in scheduler and not _ratio_ok(scheduler[key]):
                raise refuse(f"{table}.{key}", scheduler[key], "a number, or numbers by env")


def _check_provenance(provenance: Mapping[str, Any], path: Path) -> None:
    """SealError naming `path` and the field if a value the reports read has the wrong type."""
    for key, ok, expected in (
        (
            "seed",
            lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 0,
            "a seed >= 0",
        ),
        ("group", lambda v: isinstance(v, str), "a string"),
        ("protocol", lambda v: isinstance(v, str), "a string"),
        ("kind", lambda v: isinstance(v, str), "a string"),
        ("reward_versions", lambda v: isinstance(v, Mapping), "a table of versions by adapter"),
    ):
        if provenance.get(key) is not None and not ok(provenance[key]):
            raise SealError(f"{path}: field {key} = {provenance[key]!r}; expected {expected}")


def _is_run_dir(path: Path) -> bool:
    # lexists: a damaged metrics.csv (a FIFO, a link out) still marks a run, which load_run refuses
    return os.path.lexists(path / "metrics.csv")


def _seed_order(name: str) -> tuple[bool, int, str]:
    """seed-2 before seed-10; a name whose suffix is no number after those."""
    suffix = name.removeprefix("seed-")
    return (not suffix.isdigit(), int(suffix) if suffix.isdigit() else 0, name)


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
        names = ", ".join(sorted((d.name for d in seeds), key=_seed_order))
        raise SealError(
            f"{where}: none of its seed directories ({names}) has a metrics.csv; their runs "
            "stopped before their first evaluation or are still running (report them after it)"
        )
    groups = sorted(
        str(d) for d in where.iterdir() if d.is_dir() and any(d.glob("seed-*/metrics.csv"))
    )
    hint = f"; it holds the group directories {', '.join(groups[:5])}, pass those" if groups else ""
    raise SealError(f"{where}: neither a run nor a group directory; {_EXPECTED}{hint}")
