"""`seal sweep FILE... [--seeds 0-4]`: every (protocol, seed) pair as its own Ray task.

`sweep` makes (or, with `--resume`, re-reads) the sweep directory, sends each unfinished trial to
Ray as one `execute_trial` task, records each trial in sweep.json as it ends, and then writes the
trials table and the aggregated `seal report` tables of the finished runs.

A SIGTERM or SIGINT to the driver cancels the trials gently (`ray.cancel(ref, force=False)`,
which runs the trial's SIGINT handler), so each saves its last finished epoch as `seal run`
does (`seal.run.preemption`); the driver waits up to the grace period, marks them
preempted in sweep.json and raises `Preempted` with the `seal sweep --resume` command.
"""

from __future__ import annotations

import json
import time
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

from seal.errors import SealError
from seal.protocols.config import ProtocolConfig
from seal.protocols.loader import config_to_dict, load_protocol
from seal.protocols.toml_io import dumps_toml
from seal.run.preemption import Preempted, SignalStop
from seal.run.rundir import new_group_id, seed_dir
from seal.sweep.manifest import (
    SweepResult,
    _command,
    _load_configs,
    _now,
    _save_configs,
    _saved_config_path,
    _write_manifest,
    read_manifest,
)
from seal.sweep.ray_session import RaySession, check_address, check_feasible, parse_resources
from seal.sweep.tables import _aggregate, _write_trials_table
from seal.sweep.trials import (
    TrialRecord,
    _outcome,
    _write_error,
    execute_trial,
    is_finished,
    is_started,
    last_preemption,
)

if TYPE_CHECKING:  # Ray is imported only where it is used (see the package docstring)
    from ray import ObjectRef


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
    local: bool,
) -> tuple[Path, dict[str, Any], list[TrialRecord], dict[str, ProtocolConfig]]:
    """(sweep directory, manifest, trials, configs by name) of a new sweep, its groups created;
    `local`: its trials run on this machine (a local Ray), so their memory is checked here."""
    from seal.run.runner import new_group_dir

    loaded = _load_configs(paths, overrides, scale, local=local)
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


DEFAULT_GRACE_S = 60.0
"""How long a stopped sweep waits for its trials to save (`seal sweep --grace-s`)."""


def _run_trials(
    ray: ModuleType,
    configs: Mapping[str, ProtocolConfig],
    trials: list[TrialRecord],
    save: Callable[[], None],
    command: Sequence[str],
    say: Callable[[str], None],
    grace_s: float = DEFAULT_GRACE_S,
) -> SignalStop | None:
    """Each unfinished trial as its own Ray task; `trials` updated and `save`d as they end.

    A SIGTERM or SIGINT stops the sweep (`_stop_trials`); then the stop is returned, else None.
    """
    remote = ray.remote(execute_trial)
    pending: dict[ObjectRef[TrialRecord], TrialRecord] = {}
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
    done = [len(trials) - len(pending)]

    def finish(ref: ObjectRef[TrialRecord], stopping: bool = False) -> None:
        record = pending.pop(ref)
        try:
            result: TrialRecord = ray.get(ref)
            trials[trials.index(record)] = result
            record = result
        except Exception as exc:  # noqa: BLE001 - a crashed worker is this trial's failure
            if stopping:  # cancelled: before it started, or while it saved
                _mark_stopped(record)
            else:
                record.status, record.error = "failed", _write_error(Path(record.run_dir), exc)
                record.refresh()
        done[0] += 1
        say(f"[{done[0]}/{len(trials)}] {record.trial}: {_outcome(record)}")
        save()

    stop = SignalStop()
    with stop.handling():
        try:
            while pending and not stop.requested:
                ready, _ = ray.wait(list(pending), num_returns=1, timeout=0.5)
                for ref in ready:
                    finish(ref)
        except KeyboardInterrupt:  # no handlers outside the main thread: Ctrl-C stops at once
            for ref in pending:
                ray.cancel(ref, force=True)
            save()
            raise
        if not stop.requested:
            return None
        _stop_trials(ray, pending, stop, grace_s, say, finish)
        save()
    return stop


def _stop_trials(
    ray: ModuleType,
    pending: Mapping[ObjectRef[TrialRecord], TrialRecord],
    stop: SignalStop,
    grace_s: float,
    say: Callable[[str], None],
    finish: Callable[[ObjectRef[TrialRecord], bool], None],
) -> None:
    """Cancel the running trials gently, so each saves as `seal run` does on SIGINT, and wait up
    to `grace_s` for them (until a second signal); force-cancel the rest."""
    say(
        f"{stop.name}: stopping {len(pending)} running or waiting trials; each saves its last "
        f"finished epoch (waiting up to {grace_s:g} s; a second signal stops waiting)"
    )
    for ref in pending:
        ray.cancel(ref, force=False)  # a KeyboardInterrupt there: the run's SIGINT handler
    deadline = time.monotonic() + grace_s
    while pending and stop.count < 2 and (left := deadline - time.monotonic()) > 0:
        ready, _ = ray.wait(list(pending), num_returns=1, timeout=min(0.5, left))
        for ref in ready:
            finish(ref, True)
    for ref, record in list(pending.items()):
        ray.cancel(ref, force=True)
        _mark_stopped(record)
        record.note = f"still running after {grace_s:g} s: cut off, its newest checkpoint stays"
        say(f"{record.trial}: {_outcome(record)}")


def _mark_stopped(record: TrialRecord) -> None:
    """A trial whose task was cancelled: finished, preempted (it has a run directory to continue), or pending."""
    if is_finished(record.run_dir):
        record.status = "finished"
    elif is_started(record.run_dir):
        record.status, record.note = "preempted", last_preemption(record.run_dir)
    else:
        record.status = "pending"
    record.refresh()


def _stopped_line(stop: SignalStop, trials: Sequence[TrialRecord], sweep_dir: Path) -> str:
    """The line a stopped sweep ends with: how its trials ended and the command that resumes them."""
    counts = Counter(t.status for t in trials)
    parts = [
        f"{counts[s]} {s}" for s in ("preempted", "finished", "failed", "pending") if counts[s]
    ]
    return f"{stop.name}: stopped the sweep ({', '.join(parts)}); resume with: seal sweep --resume {sweep_dir}"


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
    grace_s: float = DEFAULT_GRACE_S,
) -> SweepResult:
    """Run every (protocol, seed) pair as its own Ray task; each writes the run directory `seal run` writes.

    `seeds` default to each protocol's own. All seeds of a protocol go into one new group
    `<out>/<protocol>/<group-id>/`. `resume` continues an earlier sweep directory instead (paths,
    seeds, overrides and scale are then taken from it). Failing trials are recorded, not raised.

    On SIGTERM or SIGINT the running trials are cancelled gently and save their last finished
    epoch (waiting up to `grace_s`); sweep.json marks them preempted and `Preempted` is raised
    with the command that resumes them.
    """
    command = _command(command)
    check_address(address)
    if resume is not None:
        sweep_dir = Path(resume)
        manifest, trials, configs = _resume_sweep(sweep_dir)
    else:
        sweep_dir, manifest, trials, configs = _new_sweep(
            paths, seeds, overrides, scale, out, command, local=address in (None, "local")
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
        stop = _run_trials(ray, configs, trials, save, command, say, grace_s)

    notes: list[str] = []
    trials_table = _write_trials_table(sweep_dir / "trials", trials, ranked=False)
    if stop is not None:
        assert stop.signum is not None
        raise Preempted(stop.signum, _stopped_line(stop, trials, sweep_dir))
    table = _aggregate(sweep_dir, trials, notes) or trials_table
    save()
    return SweepResult(
        sweep_dir=sweep_dir, trials=trials, table=table, trials_table=trials_table, notes=notes
    )
