"""One trial of a sweep or search: its record, running it in this process, and reading its run directory.

A trial is one run directory (`seal.run.runner.run_seed`'s). `execute_trial` is what a sweep's Ray
task executes: it runs the trial (keeping a finished run, continuing a started one), never raises
for a failing run (the error goes into the `TrialRecord` and error.txt), and re-reads the run's
last evaluation from its metrics.csv (`read_evaluations`).
"""

from __future__ import annotations

import csv
import json
import secrets
import time
import traceback
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from seal.protocols.config import ProtocolConfig
from seal.run.rundir import atomic_write_text

Status = Literal["finished", "failed", "stopped", "pending", "preempted"]


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


@dataclass
class TrialRecord:
    """One trial of a sweep or search: where it ran, how it ended, and its last evaluation."""

    trial: str
    """Name: "<protocol>/seed-<n>" in a sweep, "sample-<k>" in a search."""
    protocol: str
    seed: int
    run_dir: str
    status: Status = "pending"
    """finished, failed, stopped (ASHA stopped it early), pending (not run yet) or preempted (a
    SIGTERM or SIGINT stopped it after saving its last finished epoch; --resume continues it)."""
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
    note: str = ""
    """A preempted trial: what it did at the signal and what it saved, one line."""

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

    `threads` is the trial's whole CPUs (`Resources.threads`): torch's thread count here, and the
    cores its run's protocol.threads is resolved on and capped at, so the trials that share a
    machine start no more intra-op threads than the cores Ray reserved for them.
    Never raises for a failing run: the error is stored in the record and in error.txt.
    """
    from seal.run.preemption import Preempted, hearing_cancel
    from seal.run.runner import run_seed

    run_dir = Path(record.run_dir)
    started = time.monotonic()
    if is_finished(run_dir):
        record.start, record.status = "kept", "finished"
        record.refresh()
        return record
    if not config.checkpoint.save_replay and any(run_dir.glob("checkpoints/ckpt-*.pt")):
        set_aside(
            run_dir
        )  # a checkpoint it cannot continue from exactly; without one it starts over in place
    record.start = "continued" if is_started(run_dir) else "new"
    (run_dir / "error.txt").unlink(missing_ok=True)
    try:
        _set_threads(threads)
        with hearing_cancel():  # the sweep's or bench's gentle cancel, however the worker started
            run_seed(
                config,
                record.seed,
                run_dir.parent,
                quiet=True,
                resume=record.start == "continued",
                command=list(command) if command else None,
                cores=threads,
            )
        record.status, record.error = "finished", ""
    except Preempted as stop:  # a SIGTERM or SIGINT here, or the sweep's gentle ray.cancel
        record.status = "finished" if is_finished(run_dir) else "preempted"
        record.error, record.note = "", stop.what
    except Exception as exc:  # noqa: BLE001 - any failure is this trial's, recorded, never the sweep's
        record.status, record.error = "failed", _write_error(run_dir, exc)
    record.wall_s = round(time.monotonic() - started, 3)
    record.refresh()
    return record


def set_aside(run_dir: Path) -> Path:
    """Move a started run whose checkpoints hold no replay (checkpoint.save_replay = false) to
    <group>/.lost/<seed-n>-<hex>: it cannot continue exactly, so its trial runs afresh, as seeded
    as the first, and what it had made stays readable there. Returns the new place."""
    lost = run_dir.parent / ".lost"
    lost.mkdir(exist_ok=True)
    return run_dir.rename(lost / f"{run_dir.name}-{secrets.token_hex(4)}")


def last_preemption(run_dir: str | Path) -> str:
    """What the run's last stop on a signal saved (provenance.json's "preemptions"), else ""."""
    try:
        data = json.loads((Path(run_dir) / "provenance.json").read_text())
        return str(data.get("preemptions", [{}])[-1].get("what", ""))
    except (OSError, json.JSONDecodeError, AttributeError, IndexError, TypeError):
        return ""


def _outcome(record: TrialRecord) -> str:
    if record.status == "failed":
        return f"FAILED ({record.error})"
    if record.status == "preempted":
        return f"preempted ({record.note or 'stopped before it saved anything new'})"
    score = (
        f"mean success {record.mean_success:.2f}"
        if record.mean_success is not None
        else "no evaluation"
    )
    how = {"kept": "already finished, kept", "continued": "continued", "new": ""}[record.start]
    return f"{record.status} ({', '.join(p for p in (score, how, f'{record.wall_s:.0f} s' if record.wall_s else '') if p)})"
