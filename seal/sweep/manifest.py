"""A sweep directory on disk: sweep.json, the resolved configs it runs, and what a sweep or search returns.

`sweep.json` (`MANIFEST`) records what was asked and every trial's status; `configs/<name>.toml`
holds each protocol's resolved config, so that `--resume` runs exactly what was asked even if the
protocol file changed. `SweepResult` names what a sweep or search wrote.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import json
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from seal.errors import SealError
from seal.protocols.config import ProtocolConfig
from seal.protocols.loader import config_to_dict, load_protocol
from seal.protocols.toml_io import dumps_toml
from seal.run.rundir import atomic_write_text
from seal.sweep.ray_session import parse_resources
from seal.sweep.trials import TrialRecord

MANIFEST = "sweep.json"
"""The file in a sweep directory that records what was asked and every trial's status."""


@dataclass
class SweepResult:
    """What a sweep or search wrote."""

    sweep_dir: Path
    """Holds sweep.json, trials.{csv,md} (search: search.{csv,md}, best.toml) and tables/."""
    trials: list[TrialRecord]
    table: Path | None
    """The aggregated table in `seal report`'s format (tables/update_counts.md), else the trials table."""
    trials_table: Path
    """trials.md (a sweep) or search.md (a search, ranked)."""
    best_config: Path | None = None
    """A search's best resolved config (best.toml), ready for `seal run`."""
    notes: list[str] = field(default_factory=list)

    @property
    def failed(self) -> list[TrialRecord]:
        """Trials that raised."""
        return [t for t in self.trials if t.status == "failed"]

    def to_json(self) -> dict[str, Any]:
        """The one-line JSON `seal sweep --json` ends with."""
        data: dict[str, Any] = {
            "run_dirs": [t.run_dir for t in self.trials if t.status == "finished"],
            "table": str(self.table) if self.table else None,
            "sweep_dir": str(self.sweep_dir),
            "trials_table": str(self.trials_table),
            "failed": [
                {"trial": t.trial, "run_dir": t.run_dir, "error": t.error} for t in self.failed
            ],
        }
        if self.best_config is not None:
            data["best_config"] = str(self.best_config)
        return data


def _command(command: Sequence[str] | None) -> list[str]:
    return list(command) if command is not None else [Path(sys.argv[0]).name, *sys.argv[1:]]


def _saved_config_path(sweep_dir: Path, name: str) -> Path:
    return sweep_dir / "configs" / f"{name}.toml"


def _save_configs(sweep_dir: Path, configs: Sequence[ProtocolConfig]) -> None:
    """Each protocol's resolved config, so a resume runs exactly what was asked even if the file changed."""
    (sweep_dir / "configs").mkdir(parents=True, exist_ok=True)
    for config in configs:
        atomic_write_text(
            _saved_config_path(sweep_dir, config.name), dumps_toml(config_to_dict(config))
        )


def _write_manifest(
    sweep_dir: Path, kind: str, trials: Sequence[TrialRecord], extra: Mapping[str, Any]
) -> None:
    data = {"kind": kind, **extra, "trials": [dataclasses.asdict(t) for t in trials]}
    atomic_write_text(sweep_dir / MANIFEST, json.dumps(data, indent=2) + "\n")


def read_manifest(sweep_dir: str | Path) -> dict[str, Any]:
    """A sweep directory's sweep.json, or SealError saying what a sweep directory is."""
    path = Path(sweep_dir)
    manifest = path / MANIFEST
    if not manifest.is_file():
        hint = ""
        if path.is_dir() and (path.parent / MANIFEST).is_file():
            hint = f"; did you mean its sweep directory {path.parent}?"
        raise SealError(
            f"--resume {path}: not a sweep directory (no {MANIFEST}); pass the directory `seal sweep` printed as sweep_dir{hint}"
        )
    try:
        data = json.loads(manifest.read_text())
        data["trials"] = [TrialRecord(**t) for t in data["trials"]]
    except (json.JSONDecodeError, KeyError, TypeError) as exc:
        raise SealError(f"{manifest}: not a readable sweep manifest ({exc})") from None
    return data


def _load_configs(
    paths: Sequence[str | Path],
    overrides: Sequence[str],
    scale: float | None,
    *,
    search: bool = False,
    local: bool = True,
) -> list[ProtocolConfig]:
    if not paths:
        raise SealError("seal sweep: give at least one protocol FILE (or --resume SWEEP_DIR)")
    configs = [load_protocol(p, overrides, scale) for p in paths]
    names = [c.name for c in configs]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise SealError(
            f"protocols {[str(p) for p in paths]}: several have the name {dupes[0]!r}; each protocol of a sweep needs its own [protocol].name"
        )
    for config in configs:
        parse_resources(config)  # a bad [resources] table fails before Ray starts
        # So does a [transfer] checkpoint that is missing or does not fit, before any directory;
        # a search whose draws change what it must fit leaves that to each trial's own check.
        drawn = config.search if search else {}
        if config.transfer is not None and not any(k.startswith(FITTED) for k in drawn):
            from seal.run.setup import check_transfer_source

            check_transfer_source(config)
        if local:  # the trials run on this machine; a cluster's nodes check their own
            _check_memory(config, search)
    return configs


def _check_memory(config: ProtocolConfig, search: bool) -> None:
    """`seal run`'s memory refusal before a local Ray starts (it came as each trial's failure): for the
    protocol, or with `search` for each end of each [search] value set alone (`Distribution.ends`;
    values that are too big only together are left to each trial's own check). A protocol whose
    device this machine lacks (a GPU protocol on a CPU head node) is left to its trials."""
    from seal.errors import ConfigError
    from seal.provenance import resolve_device
    from seal.run import resources
    from seal.run.phase_model import build_adapters
    from seal.sweep.samples import parse_search, sample_overrides, with_overrides

    try:
        device = resolve_device(config.protocol.device)
    except SealError:
        return
    adapters = build_adapters(config)
    if not search:
        resources.check_resources(config, adapters, device)
        return
    for param in parse_search(config).params:
        for value in param.ends():
            trial = with_overrides(config, sample_overrides({param.key: value}))
            own = build_adapters(trial) if param.key.startswith("envs.") else adapters
            try:
                resources.check_resources(trial, own, device)
            except ConfigError as exc:
                raise ConfigError(
                    f"{exc} (with the [search] value {param.key} = {value!r}; every draw of "
                    "[search] must fit: lower that value)"
                ) from None


FITTED = ("transfer.", "agent.", "envs.")
"""The [search] keys that change whether a [transfer] checkpoint fits a trial's agent."""


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
