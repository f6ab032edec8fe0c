"""Two leftovers of the fault work: a full disk that torch.save reports as a RuntimeError, and
`seal report` of several runs without --out, which takes no lock (docs/faults.md says why)."""

from __future__ import annotations

import errno
import os
import shutil
from pathlib import Path
from typing import Any

import pandas as pd
import pytest
import torch

from seal.cli.main import main
from seal.learner import checkpoint
from seal.learner.checkpoint import atomic_save, read_checkpoint
from seal.protocols import load_protocol
from seal.run.dirlock import DirLock
from seal.run.runner import run_seed
from tests.faults.point_protocol import point_protocol

PROTOCOL = point_protocol("disk", 6, keep_last=3, train_interval=None)
STREAM_WRITER = (
    "[enforce fail at inline_container.cc:672] . PytorchStreamWriter failed writing file "
    "data/0: file write failed"
)


class _FullAfter:
    """A file object that takes `room` bytes, then fails every write with ENOSPC, as a full disk."""

    def __init__(self, f: Any, room: int) -> None:
        self.f, self.room = f, room

    def write(self, data: bytes) -> int:
        if len(data) > self.room:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self.room -= len(data)
        return self.f.write(data)

    def flush(self) -> None:
        self.f.flush()


@pytest.fixture
def protocol(tmp_path: Path) -> Path:
    path = tmp_path / "disk.toml"
    path.write_text(PROTOCOL)
    return path


@pytest.mark.parametrize("how", ["the OSError torch swallowed", "little space left"])
def test_a_full_disk_that_torch_reports_as_runtime_error_is_the_one_line_disk_error(
    how: str,
    protocol: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """torch.save's zip writer turns a failed write into "unexpected pos ..." or "PytorchStreamWriter
    failed writing file ...": the first case runs the real writer on a file that fills up (its
    RuntimeError carries the OSError as context), the second raises the bare RuntimeError on a
    file system with no space left."""
    real_save, raised = torch.save, []

    def full_disk(obj: object, f: Any, *args: object, **kwargs: object) -> None:
        if not (isinstance(obj, dict) and obj.get("runner") and obj["epoch"] == 4):
            return real_save(obj, f, *args, **kwargs)  # type: ignore[arg-type]
        try:
            if how == "little space left":
                raise RuntimeError(STREAM_WRITER)
            real_save(obj, _FullAfter(f, room=4096), *args, **kwargs)  # type: ignore[arg-type]
        except RuntimeError as exc:
            raised.append(exc)
            raise

    class _NoSpace:
        f_bavail, f_frsize = 3, 4096

    monkeypatch.setattr(torch, "save", full_disk)
    if how == "little space left":
        monkeypatch.setattr(checkpoint.os, "statvfs", lambda path: _NoSpace())
    out = tmp_path / "out"
    code = main(["run", str(protocol), "--out", str(out), "--quiet", "--no-report"])
    err = capsys.readouterr().err.strip().splitlines()
    assert raised and isinstance(raised[0], RuntimeError)  # torch's own error, not an OSError
    assert code == 2 and len(err) == 1, err
    assert "ckpt-0000004.pt failed: No space left on device" in err[0] and "--resume" in err[0]
    (run,) = out.glob("disk/*/seed-0")
    folder = run / "checkpoints"
    assert not list(folder.glob(".*.tmp"))  # the temporary file is gone
    assert sorted(p.name for p in folder.glob("ckpt-*")) == ["ckpt-0000002.pt"]
    read_checkpoint(folder / "ckpt-0000002.pt")  # the last checkpoint is intact
    monkeypatch.undo()
    assert main(["run", str(protocol), "--resume", str(run), "--quiet", "--no-report"]) == 0
    metrics = pd.read_csv(run / "metrics.csv")
    assert len(metrics) == 6 * 2 and not metrics.duplicated(["epoch", "env", "task"]).any()


def test_a_stream_writer_error_with_space_left_is_not_called_a_full_disk(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def broken(obj: object, f: object, *args: object, **kwargs: object) -> None:
        raise RuntimeError(STREAM_WRITER)

    monkeypatch.setattr(torch, "save", broken)
    with pytest.raises(RuntimeError, match="PytorchStreamWriter"):
        atomic_save({"a": 1}, tmp_path / "x.pt")
    assert list(tmp_path.iterdir()) == []


def test_report_of_several_runs_without_out_takes_no_lock_and_makes_a_new_directory(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Every directory the report reads is held by another writer (as by a run that resumes):
    the report still goes ahead, into a directory of its own, new each time, which no other
    process can be writing: why it takes no lock (docs/faults.md)."""
    protocol = tmp_path / "disk.toml"
    protocol.write_text(PROTOCOL.replace("epochs = 6", "epochs = 2"))
    group = tmp_path / "reports" / "disk" / "g"
    run_seed(load_protocol(protocol), 0, group)
    shutil.copytree(group / "seed-0", group / "seed-1")
    (group / "seed-1" / "provenance.json").write_text('{"seed": 1}')
    runs = [group / "seed-0", group / "seed-1"]
    held = [DirLock(p).acquire() for p in (*runs, group)]
    try:
        assert main(["report", *map(str, runs)]) == 0, capsys.readouterr().err
        first = capsys.readouterr()
        assert main(["report", *map(str, runs)]) == 0, capsys.readouterr().err
        second = capsys.readouterr()
    finally:
        for lock in held:
            lock.release()
    made = sorted((tmp_path / "reports" / "comparison" / "disk").iterdir())
    assert len(made) == 2 and all((d / "tables" / "update_counts.md").is_file() for d in made)
    assert f"tables: {made[0] / 'tables'}" in first.out + second.out
    assert not (group / "tables").exists()  # nothing went into the locked group
    capsys.readouterr()
    assert main(["report", str(runs[0])]) == 0  # one run: written into it, under its lock
    with DirLock(runs[0]):
        assert main(["report", str(runs[0])]) == 2
    assert "is being written by another seal process" in capsys.readouterr().err
