"""The one checkpoint format: an atomic `torch.save` of plain data, read as data only.

A checkpoint is a dict of tensors, containers and plain Python values (str, int, float, bool,
None), written to a temporary file in the same directory, fsynced, then renamed over the
destination (`os.replace`), so a crash leaves either the old or the new file, never a torn one.
An agent with a NaN/inf parameter is never saved, so a diverged run cannot overwrite its last good
checkpoint.

Checkpoints are files researchers share, so they are data: every reader goes through
`read_checkpoint`, which opens only a regular file (`seal.files`: no FIFO, device or directory,
and none in a run directory's checkpoints/ that leads out of that run directory), uses
`torch.load(weights_only=True)` (no code runs while loading) and refuses, with one message, a
file of another format version or not made by seal. What the fields must hold is the caller's
to check (`seal.run.checkpoint_fields` for `seal run`'s).

Fields: `seal_checkpoint` (the format version), `agent` (`Agent.state_dict()`), `replay`
(`MultiTaskReplay.state_dict()` or None) and any fields of the caller (the runner adds its
counters, config and RNG states). Readers take optional fields with `.get`, so a new field (new
agent state, a device-resident replay) needs no new loader; the version changes only when an
existing field changes meaning.
"""

from __future__ import annotations

import contextlib
import errno
import os
import tempfile
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch

from seal.errors import SealError, TrainingDivergedError
from seal.files import MIB, open_data_file
from seal.learner.replay import MultiTaskReplay
from seal.learner.sac import Agent

FORMAT_KEY = "seal_checkpoint"
FORMAT_VERSION = 2
"""Version 2: one container for `seal run`, `--resume`, `[transfer]` and `seal eval` (version 1
was two formats, one of them read with pickle)."""
RESERVED = (FORMAT_KEY, "agent", "replay")


class NotACheckpointError(SealError):
    """A file that is not a seal checkpoint of this version (or not readable as data only)."""


def atomic_save(obj: object, path: str | os.PathLike[str]) -> Path:
    """torch.save `obj` to `path` atomically: temp file in the same directory, fsync, os.replace."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            try:
                torch.save(obj, f)
            except RuntimeError as exc:
                raise _write_error(exc, path) from exc
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        if isinstance(exc, OSError) and exc.filename is None and exc.errno is not None:
            # A full disk's error then names the checkpoint; an OSError made of a bare message
            # would print "[Errno None] None" with a filename, so it is left as it is.
            exc.filename = str(path)
        raise
    # fsync the directory too, so the rename itself survives a power loss.
    with contextlib.suppress(OSError):
        dir_fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)
    return path


LOW_SPACE = 64 * MIB
"""Free space below which a write that torch reports without an OS error counts as a full disk."""


def _write_error(exc: RuntimeError, path: Path) -> BaseException:
    """The OSError behind a RuntimeError from torch.save's zip writer, else the RuntimeError.

    torch's writer wraps a failed write of the file object in a RuntimeError ("unexpected pos",
    "PytorchStreamWriter failed writing file ..."); the OSError it swallowed (ENOSPC, EDQUOT)
    is its context. Without one, a stream-writer failure on a file system with less than
    LOW_SPACE free is reported as ENOSPC: the runner then stops in one line, as for any full disk.
    """
    seen: BaseException | None = exc
    while seen is not None:
        if isinstance(seen, OSError) and seen.errno is not None:
            return seen
        seen = seen.__cause__ or seen.__context__
    message = str(exc)
    if "PytorchStreamWriter" in message or "unexpected pos" in message:
        with contextlib.suppress(OSError):
            fs = os.statvfs(path.parent)
            if fs.f_bavail * fs.f_frsize < LOW_SPACE:
                first = message.strip().splitlines()[0][:200] if message.strip() else ""
                return OSError(
                    errno.ENOSPC, f"{os.strerror(errno.ENOSPC)} (torch.save: {first})", str(path)
                )
    return exc


def save_checkpoint(
    path: str | os.PathLike[str],
    agent: Agent,
    replay: MultiTaskReplay | None = None,
    fields: Mapping[str, object] | None = None,
) -> Path:
    """Write `agent` (+ `replay`, + the caller's `fields`) to `path` atomically.

    Raises TrainingDivergedError, writing nothing, if any agent parameter is NaN/inf. On success
    sets `agent.last_checkpoint`, which divergence errors name.
    """
    path = Path(path)
    if not agent.parameters_finite():
        raise TrainingDivergedError(
            f"refusing to write checkpoint {path}: the agent has NaN/inf parameters at update {agent.num_updates}",
            agent.last_checkpoint,
        )
    clash = sorted(set(fields or {}) & set(RESERVED))
    if clash:
        raise ValueError(f"checkpoint field {clash[0]!r} is reserved")
    state = {
        FORMAT_KEY: FORMAT_VERSION,
        "agent": agent.state_dict(),
        "replay": replay.state_dict() if replay is not None else None,
        **dict(fields or {}),
    }
    atomic_save(state, path)
    agent.last_checkpoint = str(path)
    return path


def run_dir_of(path: str | os.PathLike[str]) -> Path | None:
    """The run directory a checkpoint path lies in (`<run>/checkpoints/<file>`, with the run's
    config.toml beside checkpoints/), else None."""
    folder = Path(path).parent
    run = folder.parent
    is_run = folder.name == "checkpoints" and os.path.lexists(run / "config.toml")
    return run if is_run else None


def read_checkpoint(
    path: str | os.PathLike[str], within: str | os.PathLike[str] | None = None
) -> dict[str, Any]:
    """The checkpoint's fields, loaded on the CPU as data only (no code runs).

    SealError if the file is missing, not a regular file (a FIFO, a device, a directory) or, in
    the `within` directory (default: the run directory it lies in, `run_dir_of`), a symlink
    leading out of it; NotACheckpointError if it is not a seal checkpoint of FORMAT_VERSION
    (another version, a torn file, or a pickle that would run code).
    """
    path = Path(path)
    if not os.path.lexists(path):
        raise SealError(f"checkpoint {path}: no such file")
    within = within if within is not None else run_dir_of(path)
    try:
        fh = open_data_file(path, what="checkpoint", within=within)
    except SealError as exc:
        raise SealError(f"checkpoint {exc}") from None

    def refuse(found: object, why: str) -> NotACheckpointError:
        return NotACheckpointError(
            f"checkpoint {path}: not a seal checkpoint (format {found}, expected {FORMAT_VERSION}): {why}"
        )

    try:
        with fh, warnings.catch_warnings():
            # torch's note on a pickle protocol it does not write: the refusal below says more
            warnings.simplefilter("ignore", UserWarning)
            state = torch.load(fh, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - damaged bytes fail anywhere in torch's unpickler
        # (KeyError, IndexError, TypeError, AttributeError on a flipped bit); nothing ran either way.
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        if "Weights only load failed" in first:  # torch's advice there is to load it unsafely
            why = (
                "it holds Python objects other than tensors and plain data, which seal never writes"
            )
        else:
            why = f"it cannot be read as plain data ({first[:200]})"
        raise refuse(
            "unknown",
            f"{why}; nothing in it was run. Expected a checkpoint seal run wrote "
            "(<run>/checkpoints/best.pt or ckpt-<epoch>.pt)",
        ) from None
    if not isinstance(state, dict) or FORMAT_KEY not in state:
        raise refuse("unknown", f"no {FORMAT_KEY!r} field; it was not written by seal")
    version = state[FORMAT_KEY]
    if type(version) is not int or version != FORMAT_VERSION:  # a tensor would compare elementwise
        raise refuse(
            repr(version)[:40] if type(version) is not int else version,
            "written by another seal version; rerun the run that made it",
        )
    if not isinstance(state.get("agent"), dict):
        raise refuse(FORMAT_VERSION, "it holds no agent state")
    return state
