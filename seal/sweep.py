"""Scale-out on Ray: every (protocol, seed) as its own Ray task, and random search with Ray Tune.

`seal sweep FILE... [--seeds 0-4]` sends each (protocol, seed) pair to Ray as one task that calls
`seal.protocols.run_seed`, so every trial writes exactly the run directory `seal run` writes, all
seeds of a protocol under one group. `seal sweep FILE --search` gives Ray Tune the protocol's
`[search]` table as its param_space: Tune draws the configs (a searcher seeded by [search].seed,
so the same table always tries the same configs) and runs them (optionally stopping weak ones
early with ASHA); its ResultGrid is ranked and the best resolved config written as a TOML file
ready for `seal run`.

Ray is optional (the `ray` extra): it is imported inside the functions that need it, never at
module import, so `seal run` and the protocol layer never load it.

On disk, a sweep is a directory holding `sweep.json` (what was asked, every trial and its status),
`trials.{csv,md}` and `tables/` (the `seal report` tables of the finished runs)::

    one protocol:      <out>/<protocol>/<group-id>/        sweep.json, seed-<n>/, tables/
    several:           <out>/sweeps/<sweep-id>/            sweep.json, tables/ (groups as above)
    search:            <out>/<protocol>/search-<id>/       sweep.json, sample-<k>/seed-<n>/,
                                                           search.{csv,md}, best.toml

Fault tolerance: a trial that raises (e.g. training diverged) is recorded with its error and the
others go on. `--resume SWEEP_DIR` re-reads sweep.json: trials whose run directory is finished
(provenance.json has an end_time) are kept as they are, started ones continue from their last
checkpoint, and the rest start afresh. A search's resume lets Tune draw the same samples again;
the kept ones only report their evaluations.
"""

from __future__ import annotations

import csv
import dataclasses
import datetime as _dt
import itertools
import json
import math
import os
import sys
import time
import traceback
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from seal.errors import ConfigError, SealError
from seal.protocols import sweep_tables
from seal.protocols.config import ProtocolConfig
from seal.protocols.loader import (
    apply_overrides,
    config_from_dict,
    config_to_dict,
    dumps_toml,
    load_protocol,
    toml_value,
)
from seal.protocols.phase import LoopCallback, PhaseLoop
from seal.protocols.rundir import atomic_write_text, new_group_id, seed_dir
from seal.protocols.sweep_tables import (
    SEARCH_OPTIONS,
    Distribution,
    Resources,
    SearchSpec,
)

if TYPE_CHECKING:  # Ray is imported only where it is used (see the module docstring)
    from ray.tune import Callback, ResultGrid
    from ray.tune.experiment import Trial
    from ray.tune.schedulers import ASHAScheduler
    from ray.tune.search.basic_variant import BasicVariantGenerator

MANIFEST = "sweep.json"
"""The file in a sweep directory that records what was asked and every trial's status."""

Status = Literal["finished", "failed", "stopped", "pending"]


# ---------------------------------------------------------------- [resources] and [search]


def parse_resources(config: ProtocolConfig) -> Resources:
    """The protocol's [resources] table (already checked when it loaded)."""
    return sweep_tables.parse_resources(config.resources, config.path)


def parse_search(config: ProtocolConfig, num_samples: int | None = None) -> SearchSpec:
    """The protocol's [search] table as a SearchSpec; `num_samples` (from --samples) wins over the file's."""
    if not any(k not in SEARCH_OPTIONS for k in sweep_tables.flatten(config.search or {})):
        raise ConfigError(
            f"{config.path}: --search needs a [search] table naming at least one config value, e.g. "
            f'[search] "agent.actor_lr" = {{dist = "loguniform", low = 1e-5, high = 1e-3}}'
        )
    return sweep_tables.parse_search(config.search, config.path, num_samples)


def _plain(value: Any) -> Any:
    """numpy scalars -> Python numbers (so they print and serialise as TOML/JSON)."""
    item = getattr(value, "item", None)
    return item() if callable(item) and not isinstance(value, list | tuple | dict | str) else value


def sample_overrides(sample: Mapping[str, Any]) -> list[str]:
    """A sample as --set strings, e.g. {"agent.actor_lr": 1e-4} -> ["agent.actor_lr=0.0001"]."""
    return [f"{key}={toml_value(value)}" for key, value in sample.items()]


def with_overrides(
    config: ProtocolConfig, overrides: Sequence[str], where: str | None = None
) -> ProtocolConfig:
    """`config` with --set style overrides applied and everything validated again.

    The overrides are applied to the resolved config (after --scale), so a sampled
    `protocol.epochs` is used as given.
    """
    raw = apply_overrides(config_to_dict(config), overrides, where or config.path)
    return config_from_dict(raw, where or config.path)


def describe_sample(sample: Mapping[str, Any]) -> str:
    """A short one-line form of a sample, e.g. "agent.actor_lr=0.000123, agent.tau=0.01"."""
    parts = []
    for key, value in sample.items():
        shown = f"{value:.3g}" if isinstance(value, float) else toml_value(value)
        parts.append(f"{key}={shown}")
    return ", ".join(parts)


# ---------------------------------------------------------------- run directories


def is_finished(run_dir: str | Path) -> bool:
    """True when a run directory completed: its provenance.json has an end_time."""
    path = Path(run_dir) / "provenance.json"
    try:
        return bool(json.loads(path.read_text()).get("end_time"))
    except (OSError, json.JSONDecodeError):
        return False


def is_started(run_dir: str | Path) -> bool:
    """True when a run directory exists (it has a config.toml), so it can be continued."""
    return (Path(run_dir) / "config.toml").is_file()


@dataclass(frozen=True)
class Evaluation:
    """One evaluation of a run: its phase, epoch and means over every (env, task) evaluated."""

    phase: str
    epoch: int
    grad_steps: int
    mean_success: float
    mean_return: float
    rows: int


def read_evaluations(run_dir: str | Path) -> list[Evaluation]:
    """The evaluations in a run's metrics.csv, in order (a torn last line is ignored)."""
    path = Path(run_dir) / "metrics.csv"
    try:
        text = path.read_text()
    except OSError:
        return []
    complete = text[: text.rfind("\n") + 1] if "\n" in text else ""
    groups: dict[tuple[str, int], list[dict[str, str]]] = {}
    for row in csv.DictReader(complete.splitlines()):
        try:
            groups.setdefault((row["phase"], int(row["epoch"])), []).append(row)
        except (KeyError, TypeError, ValueError):
            continue
    out = []
    for (phase, epoch), rows in groups.items():
        success = [float(r["success"]) for r in rows]
        returns = [float(r["return"]) for r in rows]
        out.append(
            Evaluation(
                phase=phase,
                epoch=epoch,
                grad_steps=int(float(rows[-1]["grad_steps"])),
                mean_success=sum(success) / len(success),
                mean_return=sum(returns) / len(returns),
                rows=len(rows),
            )
        )
    return out


def evaluations_per_run(config: ProtocolConfig) -> int:
    """How many evaluations a full run of `config` makes (every `interval` epochs and after the last)."""

    def count(epochs: int) -> int:
        interval = config.evaluation.interval
        return epochs // interval + (1 if epochs % interval else 0)

    if config.kind == "finetune" and config.finetune is not None:
        return count(config.finetune.pretrain_epochs) + count(config.finetune.finetune_epochs)
    return count(config.protocol.epochs)


# ---------------------------------------------------------------- trials


@dataclass
class TrialRecord:
    """One trial of a sweep or search: where it ran, how it ended, and its last evaluation."""

    trial: str
    """Name: "<protocol>/seed-<n>" in a sweep, "sample-<k>" in a search."""
    protocol: str
    seed: int
    run_dir: str
    status: Status = "pending"
    """finished, failed, stopped (ASHA stopped it early) or pending (not run yet)."""
    start: Literal["new", "continued", "kept"] = "new"
    """new: a fresh run; continued: resumed from its last checkpoint; kept: already finished, not run again."""
    error: str = ""
    """The exception, one line (the full traceback is in <run_dir>/error.txt)."""
    mean_success: float | None = None
    """Mean success over every (env, task) at the last evaluation."""
    mean_return: float | None = None
    """Mean return over every (env, task) at the last evaluation."""
    evaluations: int = 0
    wall_s: float = 0.0
    """Seconds this trial ran in this invocation (0 for kept trials)."""
    sample: dict[str, Any] = field(default_factory=dict)
    """A search trial's sampled config values (empty in a sweep)."""

    def refresh(self) -> None:
        """Re-read the last evaluation from the run directory."""
        evals = read_evaluations(self.run_dir)
        self.evaluations = len(evals)
        if evals:
            self.mean_success, self.mean_return = evals[-1].mean_success, evals[-1].mean_return


def _write_error(run_dir: Path, exc: BaseException) -> str:
    """Save the traceback next to the run (error.txt) and return the one-line error."""
    line = f"{type(exc).__name__}: {exc}".splitlines()[0] if str(exc) else type(exc).__name__
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
        atomic_write_text(run_dir / "error.txt", "".join(traceback.format_exception(exc)))
    except OSError:
        pass  # the one-line error still reaches the sweep's table
    return line


def _set_threads(threads: int) -> None:
    import torch

    torch.set_num_threads(threads)


def execute_trial(
    config: ProtocolConfig,
    record: TrialRecord,
    *,
    threads: int = 1,
    command: Sequence[str] | None = None,
) -> TrialRecord:
    """Run one trial in this process (what a Ray task executes) and return its updated record.

    Never raises for a failing run: the error is stored in the record and in error.txt.
    """
    from seal.protocols import run_seed

    run_dir = Path(record.run_dir)
    started = time.monotonic()
    if is_finished(run_dir):
        record.start, record.status = "kept", "finished"
        record.refresh()
        return record
    record.start = "continued" if is_started(run_dir) else "new"
    (run_dir / "error.txt").unlink(missing_ok=True)
    try:
        _set_threads(threads)
        run_seed(
            config,
            record.seed,
            run_dir.parent,
            quiet=True,
            resume=record.start == "continued",
            command=list(command) if command else None,
        )
        record.status, record.error = "finished", ""
    except Exception as exc:  # noqa: BLE001 - any failure is this trial's, recorded, never the sweep's
        record.status, record.error = "failed", _write_error(run_dir, exc)
    record.wall_s = round(time.monotonic() - started, 3)
    record.refresh()
    return record


# ---------------------------------------------------------------- ray session


class RaySession:
    """`with RaySession(address):` a Ray connection; shut down on exit only if this opened it.

    address None starts a private local Ray in this process's machine (address="local", never an
    unrelated cluster found through RAY_ADDRESS); "auto" or "HOST:PORT" joins an existing cluster.
    If Ray is already initialised (e.g. by a test fixture or a notebook), that session is used.
    """

    def __init__(self, address: str | None = None, num_cpus: int | None = None) -> None:
        self.address = address
        self.num_cpus = num_cpus
        self.started = False

    def __enter__(self) -> Any:
        ray = import_ray()
        if ray.is_initialized():
            return ray
        kwargs: dict[str, Any] = {
            "include_dashboard": False,
            "log_to_driver": False,
            "logging_level": "warning",
        }
        if self.address is None:
            # Ray counts the machine's CPUs itself (cgroup limits included) unless told otherwise.
            kwargs.update(address="local", **({"num_cpus": self.num_cpus} if self.num_cpus else {}))
        else:
            kwargs["address"] = self.address
        try:
            ray.init(**kwargs)
        except (ConnectionError, RuntimeError, ValueError) as exc:
            where = (
                "a local Ray"
                if self.address is None
                else f"the Ray cluster at --address {self.address}"
            )
            hint = (
                ""
                if self.address is None
                else " (start it with `ray start --head` on the head node, or drop --address for a local Ray; "
                "if the cluster uses token authentication, set RAY_AUTH_MODE=token and RAY_AUTH_TOKEN to the "
                "token `ray get-auth-token` prints on the head node)"
            )
            raise SealError(f"cannot start or join {where}: {exc}{hint}") from None
        self.started = True
        return ray

    def __exit__(self, *exc: Any) -> None:
        if self.started:
            import_ray().shutdown()


def check_feasible(ray: Any, config: ProtocolConfig, res: Resources) -> None:
    """SealError when no node could ever hold one trial (Ray would otherwise wait forever)."""
    total = ray.cluster_resources()
    for key, name, asked in (("CPU", "cpus", res.cpus), ("GPU", "gpus", res.gpus)):
        have = float(total.get(key, 0.0))
        if asked > have:
            raise SealError(
                f"{config.path}: resources.{name} = {asked:g} per trial, but the Ray cluster has {have:g} {key}s in all; "
                f"lower resources.{name}, start the local Ray with more (--num-cpus), or join a bigger cluster (--address)"
            )


def check_address(address: str | None, timeout_s: float = 5.0) -> None:
    """SealError unless something listens at a HOST:PORT --address (Ray itself would retry for minutes).

    None (local Ray), "auto", "local" and "ray://" client addresses are left to Ray.
    """
    if address is None or address in ("auto", "local") or "://" in address:
        return
    host, sep, port = address.rpartition(":")
    if not sep or not host or not port.isdigit():
        raise SealError(
            f"--address {address!r}: expected auto or HOST:PORT, e.g. 10.0.0.1:6379 (the address `ray start --head` printed)"
        )
    import socket

    try:
        with socket.create_connection((host, int(port)), timeout=timeout_s):
            pass
    except OSError as exc:
        raise SealError(
            f"--address {address}: no Ray cluster answers there ({exc.strerror or exc}); start one with "
            f"`ray start --head --port={port}` on that node, or drop --address to use a local Ray"
        ) from None


def import_ray() -> Any:
    """The `ray` module, or SealError saying how to install it."""
    try:
        import ray
    except ImportError:
        raise SealError(
            "seal sweep needs Ray: pip install 'seal[ray]' (or pip install 'ray[tune]')"
        ) from None
    return ray


# ---------------------------------------------------------------- sweep


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
    paths: Sequence[str | Path], overrides: Sequence[str], scale: float | None
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
    return configs


def _resume_sweep(
    sweep_dir: Path,
) -> tuple[dict[str, Any], list[TrialRecord], dict[str, ProtocolConfig]]:
    """(manifest, trials, configs by name) of an earlier sweep directory."""
    manifest = read_manifest(sweep_dir)
    if manifest.get("kind") != "sweep":
        raise SealError(
            f"--resume {sweep_dir}: this is a {manifest.get('kind')!r} directory; resume it with --search"
        )
    trials = manifest["trials"]
    configs = {
        name: load_protocol(_saved_config_path(sweep_dir, name))
        for name in dict.fromkeys(t.protocol for t in trials)
    }
    for t in trials:
        t.wall_s = 0.0
    return manifest, trials, configs


def _new_sweep(
    paths: Sequence[str | Path],
    seeds: Sequence[int] | None,
    overrides: Sequence[str],
    scale: float | None,
    out: str | Path,
    command: Sequence[str],
) -> tuple[Path, dict[str, Any], list[TrialRecord], dict[str, ProtocolConfig]]:
    """(sweep directory, manifest, trials, configs by name) of a new sweep, its groups created."""
    from seal.protocols.runner import new_group_dir

    loaded = _load_configs(paths, overrides, scale)
    groups = {c.name: new_group_dir(c, out).resolve() for c in loaded}
    if len(loaded) == 1:
        sweep_dir = groups[loaded[0].name]
    else:
        stamp = new_group_id(json.dumps([dumps_toml(config_to_dict(c)) for c in loaded]))
        sweep_dir = Path(out).resolve() / "sweeps" / stamp
    trials = [
        TrialRecord(
            trial=f"{c.name}/seed-{s}",
            protocol=c.name,
            seed=s,
            run_dir=str(seed_dir(groups[c.name], s)),
        )
        for c in loaded
        for s in dict.fromkeys(seeds if seeds is not None else c.seeds)
    ]
    sweep_dir.mkdir(parents=True, exist_ok=True)
    for group in groups.values():
        group.mkdir(parents=True, exist_ok=True)
    _save_configs(sweep_dir, loaded)
    manifest = {
        "created": _now(),
        "command": " ".join(command),
        "protocols": [str(p) for p in paths],
        "groups": {n: str(g) for n, g in groups.items()},
    }
    return sweep_dir, manifest, trials, {c.name: c for c in loaded}


def _run_trials(
    ray: Any,
    configs: Mapping[str, ProtocolConfig],
    trials: list[TrialRecord],
    save: Callable[[], None],
    command: Sequence[str],
    say: Callable[[str], None],
) -> None:
    """Each unfinished trial as its own Ray task; `trials` updated and `save`d as they end."""
    remote = ray.remote(execute_trial)
    pending: dict[Any, TrialRecord] = {}
    for record in trials:
        if is_finished(record.run_dir):  # resume: a finished run is not sent to Ray at all
            record.start, record.status = "kept", "finished"
            record.refresh()
            continue
        res = parse_resources(configs[record.protocol])
        task = remote.options(
            num_cpus=res.cpus,
            num_gpus=res.gpus,
            max_retries=0,
            name=f"seal-sweep:{record.trial}",
        )
        pending[
            task.remote(configs[record.protocol], record, threads=res.threads, command=command)
        ] = record
    done_count, total = len(trials) - len(pending), len(trials)
    try:
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            ref = ready[0]
            record = pending.pop(ref)
            try:
                result: TrialRecord = ray.get(ref)
                trials[trials.index(record)] = result
                record = result
            except Exception as exc:  # noqa: BLE001 - a crashed worker is this trial's failure
                record.status, record.error = "failed", _write_error(Path(record.run_dir), exc)
                record.refresh()
            done_count += 1
            say(f"[{done_count}/{total}] {record.trial}: {_outcome(record)}")
            save()
    except KeyboardInterrupt:
        for ref in pending:
            ray.cancel(ref, force=True)
        save()
        raise


def sweep(
    paths: Sequence[str | Path] = (),
    *,
    seeds: Sequence[int] | None = None,
    overrides: Sequence[str] = (),
    scale: float | None = None,
    out: str | Path = "reports",
    address: str | None = None,
    num_cpus: int | None = None,
    resume: str | Path | None = None,
    command: Sequence[str] | None = None,
    progress: Callable[[str], None] | None = None,
) -> SweepResult:
    """Run every (protocol, seed) pair as its own Ray task; each writes the run directory `seal run` writes.

    `seeds` default to each protocol's own. All seeds of a protocol go into one new group
    `<out>/<protocol>/<group-id>/`. `resume` continues an earlier sweep directory instead (paths,
    seeds, overrides and scale are then taken from it). Failing trials are recorded, not raised.
    """
    command = _command(command)
    check_address(address)
    if resume is not None:
        sweep_dir = Path(resume)
        manifest, trials, configs = _resume_sweep(sweep_dir)
    else:
        sweep_dir, manifest, trials, configs = _new_sweep(
            paths, seeds, overrides, scale, out, command
        )
    extra = {k: v for k, v in manifest.items() if k not in ("kind", "trials")}
    say = progress or (lambda _msg: None)

    def save() -> None:
        _write_manifest(sweep_dir, "sweep", trials, extra)

    save()
    say(f"sweep directory: {sweep_dir}")
    with RaySession(address, num_cpus) as ray:
        for config in configs.values():
            check_feasible(ray, config, parse_resources(config))
        _run_trials(ray, configs, trials, save, command, say)

    notes: list[str] = []
    trials_table = _write_trials_table(sweep_dir / "trials", trials, ranked=False)
    table = _aggregate(sweep_dir, trials, notes) or trials_table
    save()
    return SweepResult(
        sweep_dir=sweep_dir, trials=trials, table=table, trials_table=trials_table, notes=notes
    )


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")


def _outcome(record: TrialRecord) -> str:
    if record.status == "failed":
        return f"FAILED ({record.error})"
    score = (
        f"mean success {record.mean_success:.2f}"
        if record.mean_success is not None
        else "no evaluation"
    )
    how = {"kept": "already finished, kept", "continued": "continued", "new": ""}[record.start]
    return f"{record.status} ({', '.join(p for p in (score, how, f'{record.wall_s:.0f} s' if record.wall_s else '') if p)})"


def _aggregate(sweep_dir: Path, trials: Sequence[TrialRecord], notes: list[str]) -> Path | None:
    """`seal report` tables of the finished runs under sweep_dir/tables; None (with a note) if impossible."""
    finished = [t.run_dir for t in trials if t.status == "finished"]
    if not finished:
        notes.append("no trial finished, so there is no aggregated table")
        return None
    from seal.reports import report

    try:
        result = report(finished, out=sweep_dir)
    except SealError as exc:
        notes.append(f"aggregated table not made: {exc}")
        return None
    return result.tables.get("update_counts.md")


_TABLE_COLUMNS = (
    "rank",
    "trial",
    "status",
    "mean_success",
    "mean_return",
    "evaluations",
    "seed",
    "start",
    "wall_s",
    "error",
    "run_dir",
)


def _write_trials_table(stem: Path, trials: Sequence[TrialRecord], *, ranked: bool) -> Path:
    """<stem>.csv and <stem>.md: one row per trial (search: ranked, sampled values as columns)."""
    import pandas as pd

    keys = list(dict.fromkeys(k for t in trials for k in t.sample))
    rows = []
    for i, t in enumerate(trials, start=1):
        row = {c: getattr(t, c, None) for c in _TABLE_COLUMNS if c != "rank"}
        row["rank"] = i if ranked else None
        row.update({k: t.sample.get(k) for k in keys})
        rows.append(row)
    columns = [c for c in _TABLE_COLUMNS if ranked or c != "rank"]
    columns = columns[:3] + keys + columns[3:]
    frame = pd.DataFrame(rows, columns=columns)
    frame.to_csv(stem.with_suffix(".csv"), index=False)
    shown = frame.drop(columns=["run_dir"]).copy()
    for key in keys:
        shown[key] = [
            f"{v:.4g}" if isinstance(v, float) else toml_value(v) if v is not None else ""
            for v in shown[key]
        ]
    for column in ("mean_success", "mean_return"):
        shown[column] = [("" if v is None or v != v else f"{v:.3f}") for v in shown[column]]
    shown["error"] = [str(e)[:120] for e in shown["error"]]
    title = "Search trials, best first" if ranked else "Sweep trials"
    note = (
        "Ranked by mean success at the last evaluation, then mean return; trials stopped early by ASHA "
        "rank after finished ones, failed trials last."
        if ranked
        else "mean_success / mean_return: means over every (env, task) at the run's last evaluation."
    )
    atomic_write_text(
        stem.with_suffix(".md"),
        f"# {title}\n\n{shown.to_markdown(index=False, disable_numparse=True)}\n\n{note}\n",
    )
    return stem.with_suffix(".md")


# ---------------------------------------------------------------- search


def rank_trials(trials: Iterable[TrialRecord]) -> list[TrialRecord]:
    """Best first: finished before stopped early before failed; within each, by mean success then mean return.

    Short searches often leave every trial at 0 success, so mean return breaks ties; a trial that
    ASHA stopped saw less training, so it never ranks above one that ran to the end.
    """
    order = {"finished": 0, "stopped": 1, "pending": 2, "failed": 3}

    def key(t: TrialRecord) -> tuple[float, float, float]:
        success = t.mean_success if t.mean_success is not None else -math.inf
        ret = t.mean_return if t.mean_return is not None else -math.inf
        return (order[t.status], -success, -ret)

    return sorted(trials, key=key)


def search_space(spec: SearchSpec) -> dict[str, Any]:
    """The [search] table as Tune's param_space: each "table.key" to its Tune distribution."""
    return {p.key: p.tune_domain() for p in spec.params}


def search_algorithm(spec: SearchSpec) -> BasicVariantGenerator:
    """Tune's random sampler seeded by [search].seed, so a search (and its resume) draws the same configs.

    It numbers its trials in the order it draws them, which is the sample index (`trial_index`).
    """
    from ray.tune.search.basic_variant import BasicVariantGenerator

    # Tune ignores TuneConfig.max_concurrent_trials when given a search algorithm: set it here.
    return BasicVariantGenerator(max_concurrent=spec.max_concurrent or 0, random_state=spec.seed)


def count_trials(spec: SearchSpec) -> int:
    """Trials of a search: `num_samples` draws for every point of the grid entries (Tune's semantics)."""
    return spec.num_samples * math.prod(len(p.values) for p in spec.params if p.dist == "grid")


def trial_name(index: int) -> str:
    """The name (and directory) of the sample drawn `index`-th, e.g. "sample-003"."""
    return f"sample-{index:03d}"


def trial_index(trial_id: str) -> int:
    """The sample index of a Tune trial id: BasicVariantGenerator ids end in the draw's number ("1a2b3_00003")."""
    return int(trial_id.rsplit("_", 1)[1])


def plain_sample(config: Mapping[str, Any]) -> dict[str, Any]:
    """A Tune trial's config (its sampled values) with plain Python numbers, in [search] order."""
    return {key: _plain(value) for key, value in config.items()}


def evaluation_horizon(base: ProtocolConfig, spec: SearchSpec) -> int:
    """The most evaluations any sample can make (ASHA's max_t; Tune draws the samples, so it is a bound).

    Evaluations grow with epochs and shrink with the interval, so the bound tries every combination
    of the ends (choice and grid: the values) of the searched values that change the count alone.
    """

    def ends(p: Distribution) -> tuple[Any, ...]:
        if p.dist in ("choice", "grid"):
            return p.values
        return (int(p.low), int(p.high)) if p.dist == "int" else (p.low, p.high)

    def count(sample: Mapping[str, Any]) -> int:
        try:
            return evaluations_per_run(with_overrides(base, sample_overrides(sample)))
        except SealError:
            return 0  # a value the schema refuses fails its trial before any evaluation

    plain = evaluations_per_run(base)
    varying = [p for p in spec.params if any(count({p.key: v}) != plain for v in ends(p))]
    keys = [p.key for p in varying]
    combos = itertools.product(*(ends(p) for p in varying))
    return max(plain, *(count(dict(zip(keys, c, strict=True))) for c in combos))


@dataclass(frozen=True)
class SearchPlan:
    """What every search trial needs (shipped once to Ray's object store)."""

    base: ProtocolConfig
    """The resolved config a sample's values are set on."""
    search_dir: Path
    seed: int
    """The run seed of every sample."""
    threads: int
    command: tuple[str, ...]
    recorded: Mapping[int, Mapping[str, Any]]
    """Samples sweep.json already holds, by index: what their run directories were started with."""
    kept: frozenset[int]
    """Samples not run again (finished, or stopped by ASHA before): their evaluations are only reported."""

    def run_dir(self, index: int) -> Path:
        """The run directory of sample `index`."""
        return seed_dir(self.search_dir / trial_name(index), self.seed)


def search_trainable(tune_config: Mapping[str, Any], plan: SearchPlan) -> None:
    """The Ray Tune function trainable of one sample: run it, reporting mean success per evaluation.

    `tune_config` holds the values Tune drew. The run reports from its phase loop (`TuneReporter`,
    a `LoopCallback`), so each evaluation reaches Tune as it is made (`training_iteration` counts
    evaluations, which ASHA's grace period uses) and ASHA stops the trial at its report. A
    continued run first reports the evaluations it kept; a kept one only reports them.
    """
    from ray import tune

    from seal.protocols import run_seed

    index = trial_index(tune.get_context().get_trial_id())
    sample, run_dir = plain_sample(tune_config), plan.run_dir(index)
    reporter = TuneReporter(run_dir)
    if index in plan.kept:
        reporter.report_kept()
        return
    (run_dir / "error.txt").unlink(missing_ok=True)
    try:
        recorded = plan.recorded.get(index)
        if recorded is not None and dict(recorded) != sample:
            raise SealError(
                f"{trial_name(index)}: Tune drew {describe_sample(sample)}, but this search recorded "
                f"{describe_sample(recorded)} (was it started with another Ray version?); start a new search"
            )
        where = f"{plan.base.path} [{trial_name(index)}]"
        config = with_overrides(plan.base, sample_overrides(sample), where)
        _set_threads(plan.threads)
        run_seed(
            config,
            plan.seed,
            run_dir.parent,
            quiet=True,
            resume=is_started(run_dir),
            command=list(plan.command),
            callbacks=[reporter],
        )
    except Exception as exc:
        _write_error(run_dir, exc)
        raise


class TuneReporter(LoopCallback):
    """Reports each evaluation's means to Ray Tune from the phase loop (`tune.report`)."""

    def __init__(self, run_dir: Path) -> None:
        self.run_dir = run_dir
        self.kept_reported = False

    def report_kept(self) -> None:
        """The evaluations metrics.csv already holds (a finished or continued run), once."""
        if not self.kept_reported:
            self.kept_reported = True
            for e in read_evaluations(self.run_dir):
                self._report(e.mean_success, e.mean_return, e.epoch, e.grad_steps, e.phase)

    def on_phase_start(self, loop: PhaseLoop) -> None:
        # Run.run has cut metrics.csv back to the checkpoint it continues from.
        self.report_kept()

    def on_evaluation(self, loop: PhaseLoop) -> None:
        rows = loop.last_rows
        self._report(
            sum(float(r["success"]) for r in rows) / len(rows),
            sum(float(r["return"]) for r in rows) / len(rows),
            loop.state.epoch,
            loop.state.grad_steps,
            loop.phase.name,
        )

    @staticmethod
    def _report(success: float, ret: float, epoch: int, grad_steps: int, phase: str) -> None:
        from ray import tune

        tune.report(
            {
                "mean_success": success,
                "mean_return": ret,
                "epoch": epoch,
                "grad_steps": grad_steps,
                "phase": phase,
            }
        )


@dataclass
class TuneLog:
    """What the driver learns from Tune's callbacks while a search runs."""

    samples: dict[int, dict[str, Any]] = field(default_factory=dict)
    """Each started trial's drawn values, by index (a ResultGrid has no config for a trial that never reported)."""
    completed: set[int] = field(default_factory=set)
    """Trials Tune completed (ran out or stopped by the scheduler); an interrupted search leaves its
    running trials out, so they stay pending, not "stopped"."""

    def callback(self) -> Callback:
        """A Tune callback that fills this log."""
        from ray import tune

        log = self

        class _Log(tune.Callback):
            def on_trial_start(
                self, iteration: int, trials: list[Trial], trial: Trial, **info: object
            ) -> None:
                log.samples[trial_index(trial.trial_id)] = plain_sample(trial.config)

            def on_trial_complete(
                self, iteration: int, trials: list[Trial], trial: Trial, **info: object
            ) -> None:
                log.completed.add(trial_index(trial.trial_id))

        return _Log()


def _resume_search(search_dir: Path) -> tuple[dict[str, Any], list[TrialRecord], ProtocolConfig]:
    """(manifest, its trials as recorded, base config) of an earlier search directory.

    Tune's own resume (`Tuner.restore`) unpickles its experiment state, so a resume reads sweep.json.
    """
    manifest = read_manifest(search_dir)
    if manifest.get("kind") != "search":
        raise SealError(
            f"--resume {search_dir}: this is a {manifest.get('kind')!r} directory; resume it without --search"
        )
    records = manifest["trials"]
    base = load_protocol(_saved_config_path(search_dir, manifest["protocol"]))
    manifest.setdefault("seed", records[0].seed if records else base.protocol.first_seed)
    return manifest, records, base


def _new_search(
    path: str | Path,
    seed: int | None,
    num_samples: int | None,
    overrides: Sequence[str],
    scale: float | None,
    out: str | Path,
    command: Sequence[str],
) -> tuple[Path, dict[str, Any], ProtocolConfig]:
    """(search directory, manifest, base config) of a new search, its directory created."""
    (base,) = _load_configs([path], overrides, scale)
    spec = parse_search(base, num_samples)
    search_dir = (
        Path(out).resolve() / base.name / f"search-{new_group_id(dumps_toml(config_to_dict(base)))}"
    )
    search_dir.mkdir(parents=True, exist_ok=True)
    _save_configs(search_dir, [base])
    manifest = {
        "created": _now(),
        "command": " ".join(command),
        "protocol": base.name,
        "file": str(path),
        "seed": base.protocol.first_seed if seed is None else seed,
        "search": dataclasses.asdict(spec),
    }
    return search_dir, manifest, base


def _search_records(
    search_dir: Path,
    base: ProtocolConfig,
    spec: SearchSpec,
    seed: int,
    earlier: Sequence[TrialRecord],
) -> list[TrialRecord]:
    """One record per trial, by sample index; samples and ASHA stops recorded earlier are kept."""
    before = {t.trial: t for t in earlier}
    records = []
    for index in range(count_trials(spec)):
        name = trial_name(index)
        old = before.get(name)
        record = TrialRecord(
            trial=name,
            protocol=base.name,
            seed=seed,
            run_dir=str(seed_dir(search_dir / name, seed)),
            sample=dict(old.sample) if old else {},
        )
        if is_finished(record.run_dir):
            record.start, record.status = "kept", "finished"
        elif old is not None and old.status == "stopped":
            # A trial ASHA stopped was judged by the scheduler already: kept, not run again.
            record.start, record.status = "kept", "stopped"
        elif is_started(record.run_dir):
            record.start = "continued"
        records.append(record)
    return records


def search(
    path: str | Path | None = None,
    *,
    seed: int | None = None,
    num_samples: int | None = None,
    overrides: Sequence[str] = (),
    scale: float | None = None,
    out: str | Path = "reports",
    address: str | None = None,
    num_cpus: int | None = None,
    resume: str | Path | None = None,
    command: Sequence[str] | None = None,
    progress: Callable[[str], None] | None = None,
) -> SweepResult:
    """Random search over the protocol's [search] table with Ray Tune; returns the ranked trials.

    Each sample is one run (one seed: `seed`, default the protocol's first) of the protocol with
    the sampled values set, under `<out>/<protocol>/search-<id>/sample-<k>/seed-<n>/`. Writes
    search.{csv,md} (ranked) and best.toml (the best sample's resolved config, for `seal run`).
    """
    command = _command(command)
    check_address(address)
    say = progress or (lambda _msg: None)
    earlier: list[TrialRecord] = []
    if resume is not None:
        search_dir = Path(resume)
        manifest, earlier, base = _resume_search(search_dir)
    elif path is None:
        raise SealError("seal sweep --search: give one protocol FILE (or --resume SEARCH_DIR)")
    else:
        search_dir, manifest, base = _new_search(
            path, seed, num_samples, overrides, scale, out, command
        )
    spec = parse_search(base, manifest["search"]["num_samples"])
    records = _search_records(search_dir, base, spec, manifest["seed"], earlier)
    extra = {k: v for k, v in manifest.items() if k not in ("kind", "trials")}
    _write_manifest(search_dir, "search", records, extra)
    say(f"search directory: {search_dir} ({len(records)} samples)")
    res = parse_resources(base)
    plan = SearchPlan(
        base=base,
        search_dir=search_dir.resolve(),
        seed=manifest["seed"],
        threads=res.threads,
        command=tuple(command),
        recorded={i: r.sample for i, r in enumerate(records) if r.sample},
        kept=frozenset(i for i, r in enumerate(records) if r.start == "kept"),
    )
    if len(plan.kept) < len(records):
        with RaySession(address, num_cpus) as ray:
            check_feasible(ray, base, res)
            results, log = _run_tune(plan, spec, res)
        _record_results(records, results, log, say)
    else:
        for record in records:
            record.refresh()  # a search with every trial kept runs nothing: no Ray
    return _finish_search(search_dir, records, base, extra)


def _finish_search(
    search_dir: Path, records: list[TrialRecord], base: ProtocolConfig, extra: Mapping[str, Any]
) -> SweepResult:
    """Rank the trials; write search.{csv,md}, best.toml and sweep.json."""
    ranked = rank_trials(records)
    trials_table = _write_trials_table(search_dir / "search", ranked, ranked=True)
    best = _write_best(search_dir, ranked, base)
    notes: list[str] = []
    if best is None:
        notes.append("no trial finished, so there is no best config")
    unfinished = [t.trial for t in ranked if t.status == "pending"]
    if unfinished:
        notes.append(
            f"{len(unfinished)} trial(s) did not finish; continue them with: seal sweep --search --resume {search_dir}"
        )
    _write_manifest(search_dir, "search", ranked, extra)
    return SweepResult(
        sweep_dir=search_dir,
        trials=ranked,
        table=trials_table,
        trials_table=trials_table,
        best_config=best,
        notes=notes,
    )


def _scheduler(base: ProtocolConfig, spec: SearchSpec) -> ASHAScheduler | None:
    """ASHA over evaluations when [search].scheduler = "asha", else None (every trial runs to its end)."""
    if spec.scheduler != "asha":
        return None
    from ray.tune.schedulers import ASHAScheduler

    return ASHAScheduler(
        time_attr="training_iteration",
        # One beyond the last evaluation: ASHA stops a trial that reaches max_t at that report,
        # which would cut a run off before it writes its end (it would read as "stopped").
        max_t=max(evaluation_horizon(base, spec) + 1, spec.grace_period),
        grace_period=spec.grace_period,
        reduction_factor=spec.reduction_factor,
    )


def _run_tune(plan: SearchPlan, spec: SearchSpec, res: Resources) -> tuple[ResultGrid, TuneLog]:
    """Let Ray Tune draw every sample (seeded) and run it; its ResultGrid and what its callbacks saw."""
    from ray import tune

    # The legacy reporter honours verbose=0; the new one still draws a banner on stdout, which
    # would sit among `seal sweep`'s own output (the --json line must stay the last one).
    os.environ.setdefault("RAY_AIR_NEW_OUTPUT", "0")
    trainable = tune.with_resources(
        tune.with_parameters(search_trainable, plan=plan), {"cpu": res.cpus, "gpu": res.gpus}
    )
    scheduler = _scheduler(plan.base, spec)
    log = TuneLog()
    tuner = tune.Tuner(
        trainable,
        param_space=search_space(spec),
        tune_config=tune.TuneConfig(
            metric="mean_success",
            mode="max",
            num_samples=spec.num_samples,
            search_alg=search_algorithm(spec),
            scheduler=scheduler,
            trial_dirname_creator=lambda trial: trial_name(trial_index(trial.trial_id)),
            # Reusing actors saves a Python + torch start per trial; only safe when no trial is
            # stopped early, since a stopped trial's run (Tune's function thread) would live on in the reused actor.
            reuse_actors=scheduler is None,
        ),
        run_config=tune.RunConfig(
            name="tune",
            storage_path=str(plan.search_dir),
            verbose=0,
            failure_config=tune.FailureConfig(max_failures=0, fail_fast=False),
            callbacks=[log.callback()],
        ),
    )
    return tuner.fit(), log


def _record_results(
    records: Sequence[TrialRecord],
    results: ResultGrid,
    log: TuneLog,
    say: Callable[[str], None],
) -> None:
    """Each record's sample, scores, status and time from Tune's ResultGrid (its last report)."""
    by_index = {int(Path(r.path).name.removeprefix("sample-")): r for r in results}
    for index, record in enumerate(records):
        # A recorded sample is what its run directory was started with (a resume checks they match).
        record.sample = record.sample or log.samples.get(index, {})
        result = by_index.get(index)
        if result is None:  # never drawn: the search was interrupted first
            record.refresh()
            continue
        metrics = result.metrics or {}
        if "mean_success" in metrics:
            record.mean_success, record.mean_return = (
                metrics["mean_success"],
                metrics["mean_return"],
            )
            record.evaluations = int(metrics["training_iteration"])
        else:
            record.refresh()  # no report reached Tune (it failed first)
        if is_finished(record.run_dir):
            record.status = "finished"
        elif result.error is not None:
            record.status = "failed"
            record.error = _error_line(Path(record.run_dir) / "error.txt") or _last_line(
                result.error
            )
        elif index in log.completed:
            record.status = "stopped"  # Tune completed it before the run finished: ASHA stopped it
        else:
            record.status = "pending"  # interrupted (Ctrl-C): --resume continues it
        if record.start != "kept":
            record.wall_s = round(float(metrics.get("time_total_s") or 0.0), 3)
        say(f"{record.trial} [{describe_sample(record.sample)}]: {_outcome(record)}")


def _last_line(error: BaseException) -> str:
    """The last line of an exception's text (Tune wraps a trial's error in its own traceback)."""
    text = str(error).strip()
    return text.splitlines()[-1] if text else type(error).__name__


def _error_line(error_file: Path) -> str:
    """The last line of a saved traceback ("SealError: ..."), or ""."""
    try:
        lines = [ln for ln in error_file.read_text().splitlines() if ln.strip()]
    except OSError:
        return ""
    return lines[-1] if lines else ""


def _write_best(
    search_dir: Path, ranked: Sequence[TrialRecord], base: ProtocolConfig
) -> Path | None:
    """best.toml: the best finished sample's resolved config without [search], ready for `seal run`."""
    best = next((t for t in ranked if t.status == "finished"), None)
    if best is None:
        return None
    config = with_overrides(base, sample_overrides(best.sample), f"{base.path} [{best.trial}]")
    data = config_to_dict(config)
    data.pop("search", None)
    score = (
        f"mean success {best.mean_success:.3f}, mean return {best.mean_return:.3f}"
        if best.mean_success is not None
        else "no evaluation"
    )
    header = (
        f"# Best config of the random search in {search_dir}\n"
        f"# {best.trial} ({score} at its last evaluation): {describe_sample(best.sample)}\n"
        f"# Run it with: seal run {search_dir / 'best.toml'}\n\n"
    )
    path = search_dir / "best.toml"
    atomic_write_text(path, header + dumps_toml(data))
    return path


__all__ = [
    "Distribution",
    "Resources",
    "SearchSpec",
    "SweepResult",
    "TrialRecord",
    "execute_trial",
    "is_finished",
    "parse_resources",
    "parse_search",
    "rank_trials",
    "read_evaluations",
    "sample_overrides",
    "search",
    "sweep",
]
