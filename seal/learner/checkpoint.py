"""Atomic checkpoints of an agent, its replay and any extra state of the caller.

A checkpoint is one `torch.save` file written to a temporary file in the same directory, fsynced,
then renamed over the destination (`os.replace`), so a crash leaves either the old or the new file,
never a torn one. An agent with a NaN/inf parameter is never saved, so a diverged run cannot
overwrite its last good checkpoint. Files are read with `torch.load(weights_only=True)`: `extra`
must be made of tensors, containers and plain Python values (numpy arrays: convert to tensors).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch

from seal.errors import SealError, TrainingDivergedError
from seal.learner.replay import MultiTaskReplay
from seal.learner.sac import Agent

CHECKPOINT_FORMAT = 1


def atomic_save(obj: Any, path: str | os.PathLike[str]) -> Path:
    """torch.save `obj` to `path` atomically: temp file in the same directory, fsync, os.replace."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            torch.save(obj, f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    # fsync the directory too, so the rename itself survives a power loss.
    with contextlib.suppress(OSError):
        dir_fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)
    return path


def save_checkpoint(
    path: str | os.PathLike[str],
    agent: Agent,
    replay: MultiTaskReplay | None = None,
    extra: Mapping[str, Any] | None = None,
    *,
    include_replay: bool = True,
) -> Path:
    """Write agent (+ replay unless include_replay=False, e.g. for export) + extra to `path` atomically.

    Raises TrainingDivergedError, writing nothing, if any agent parameter is NaN/inf. On success
    sets `agent.last_checkpoint`, which divergence errors name.
    """
    path = Path(path)
    if not agent.parameters_finite():
        raise TrainingDivergedError(
            f"refusing to write checkpoint {path}: the agent has NaN/inf parameters at update {agent.num_updates}; "
            f"last good checkpoint: {agent.last_checkpoint or 'none saved yet'}"
        )
    state = {
        "format": CHECKPOINT_FORMAT,
        "agent": agent.state_dict(),
        "replay": replay.state_dict() if replay is not None and include_replay else None,
        "extra": dict(extra or {}),
    }
    atomic_save(state, path)
    agent.last_checkpoint = str(path)
    return path


def read_checkpoint(
    path: str | os.PathLike[str], map_location: str | torch.device = "cpu"
) -> dict[str, Any]:
    """The raw checkpoint dict (format, agent, replay, extra); SealError if missing or unreadable."""
    path = Path(path)
    if not path.is_file():
        raise SealError(f"checkpoint {path} does not exist")
    try:
        state = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:
        raise SealError(f"checkpoint {path} cannot be read: {exc}") from exc
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        raise SealError(f"checkpoint {path} is not a seal checkpoint of format {CHECKPOINT_FORMAT}")
    return state


def load_checkpoint(
    path: str | os.PathLike[str], agent: Agent, replay: MultiTaskReplay | None = None
) -> dict[str, Any]:
    """Restore `agent` (and `replay` when given) from `path`; returns the caller's extra state.

    Asking for the replay of a checkpoint saved without one (an export) raises SealError.
    """
    state = read_checkpoint(path, map_location=agent.device)
    agent.load_state_dict(state["agent"])
    if replay is not None:
        if state["replay"] is None:
            raise SealError(
                f"checkpoint {path} was saved without its replay (export); resuming a run needs a checkpoint with replay"
            )
        replay.load_state_dict(state["replay"])
    agent.last_checkpoint = str(path)
    return state["extra"]
