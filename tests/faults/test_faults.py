"""Fault injection on `point`: kills, a full disk, corrupt files and a second writer.

Every case ends by comparing the run directory with an uninterrupted run of the same protocol:
metrics.csv (wall-clock column aside) and train.csv equal, one row per (phase, epoch, env, task).
"""

from __future__ import annotations

import errno
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pandas as pd
import pytest
import torch

from seal.cli.main import main
from seal.learner.checkpoint import read_checkpoint
from seal.protocols import load_protocol
from seal.run.dirlock import DirLock
from seal.run.runner import run_seed
from tests.faults.point_protocol import point_protocol
from tests.waiting import wait_until

# The children here are whole seal runs; on a loaded machine one takes minutes. Every wait is for an
# event (a file, a row, the child's exit), never a duration: this limit only catches a hang.
pytestmark = pytest.mark.timeout(900)

EPOCHS = 12
PROTOCOL = point_protocol("faults", EPOCHS)
CHILD = Path(__file__).with_name("pausing_child.py")
KILL_MOMENTS = 10


@pytest.fixture(scope="module")
def protocol(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("protocol") / "faults.toml"
    path.write_text(PROTOCOL)
    return path


@pytest.fixture(scope="module")
def reference(protocol: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, float]:
    """The uninterrupted run's directory and its wall seconds."""
    start = time.perf_counter()
    run = run_seed(load_protocol(protocol), 0, tmp_path_factory.mktemp("ref") / "g").run_dir
    return run, time.perf_counter() - start


def _assert_same_rows(run_dir: Path, reference: Path) -> None:
    got, want = pd.read_csv(run_dir / "metrics.csv"), pd.read_csv(reference / "metrics.csv")
    assert not got.duplicated(["phase", "epoch", "env", "task"]).any()
    assert len(got) == EPOCHS * 2
    pd.testing.assert_frame_equal(got.drop(columns="wall_s"), want.drop(columns="wall_s"))
    pd.testing.assert_frame_equal(
        pd.read_csv(run_dir / "train.csv"), pd.read_csv(reference / "train.csv")
    )
    assert json.loads((run_dir / "provenance.json").read_text())["end_time"]


def _start_child(protocol: Path, out: Path, pause_at: int) -> subprocess.Popen[bytes]:
    args = ["run", str(protocol), "--out", str(out), "--quiet", "--no-report"]
    return subprocess.Popen(
        [sys.executable, str(CHILD), str(out / "paused"), str(pause_at), *args],
        env={**os.environ, "OMP_NUM_THREADS": "1"},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )


def _wait_for(child: subprocess.Popen[bytes], ready: Callable[[], bool]) -> None:
    wait_until(ready, "the moment to kill", child=child, poll_s=0.01)


def _resume(protocol: Path, run_dir: Path, capsys: pytest.CaptureFixture[str]) -> str:
    """`seal run --resume` in this process; its stderr."""
    capsys.readouterr()
    code = main(["run", str(protocol), "--resume", str(run_dir), "--quiet", "--no-report"])
    err = capsys.readouterr().err
    assert code == 0, err
    return err


# ---------------------------------------------------------------- kill -9


@pytest.mark.parametrize("moment", range(KILL_MOMENTS))
def test_sigkill_at_a_seeded_moment_then_resume_matches_the_uninterrupted_run(
    moment: int,
    protocol: Path,
    reference: tuple[Path, float],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Moments 0-6: a seeded delay after the run directory appears; 7-9: inside the atomic write
    of a seeded epoch checkpoint (full temporary file, rename not yet done)."""
    ref_dir, ref_seconds = reference
    rng = random.Random(moment)
    pause_at = rng.randint(1, EPOCHS // 2) if moment >= 7 else 0
    out = tmp_path / "out"
    child = _start_child(protocol, out, pause_at)
    try:
        if pause_at:
            _wait_for(child, (out / "paused").exists)
        else:
            _wait_for(child, lambda: any(out.glob("faults/*/seed-0/metrics.csv")))
            delay = rng.uniform(0.0, 0.8 * ref_seconds)  # the child needs about ref_seconds
            print(f"moment {moment}: SIGKILL {delay:.3f} s after the run directory appeared")
            time.sleep(delay)
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait()
    assert child.returncode == -signal.SIGKILL, "the child finished before the kill"
    (run_dir,) = out.glob("faults/*/seed-0")
    if pause_at:
        # Killed inside the write: the temporary file is there, the checkpoint is not.
        torn = list((run_dir / "checkpoints").glob(".ckpt-*.tmp"))
        assert len(torn) == 1
        assert not (run_dir / "checkpoints" / Path((out / "paused").read_text()).name).exists()
    _resume(protocol, run_dir, capsys)
    _assert_same_rows(run_dir, ref_dir)
    assert not list((run_dir / "checkpoints").glob(".*"))


# ---------------------------------------------------------------- a full disk


def test_disk_full_during_a_checkpoint_is_one_line_and_keeps_the_last_checkpoint(
    protocol: Path,
    reference: tuple[Path, float],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    real_save = torch.save

    def full_disk(obj: object, f: object, *args: object, **kwargs: object) -> None:
        if isinstance(obj, dict) and obj.get("runner") and obj["epoch"] == 6:
            f.write(b"\0" * 4096)  # type: ignore[attr-defined]
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real_save(obj, f, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(torch, "save", full_disk)
    out = tmp_path / "out"
    code = main(["run", str(protocol), "--out", str(out), "--quiet", "--no-report"])
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and "No space left on device" in err
    assert "ckpt-0000006.pt" in err and "--resume" in err
    (run_dir,) = out.glob("faults/*/seed-0")
    folder = run_dir / "checkpoints"
    assert sorted(p.name for p in folder.iterdir()) == [
        "best.pt",
        "ckpt-0000002.pt",
        "ckpt-0000004.pt",
    ]
    last = read_checkpoint(folder / "ckpt-0000004.pt")  # intact
    rows = len(pd.read_csv(run_dir / "metrics.csv"))
    assert rows >= last["runner"]["rows"]["metrics.csv"] == 4 * 2
    monkeypatch.setattr(torch, "save", real_save)
    _resume(protocol, run_dir, capsys)
    _assert_same_rows(run_dir, reference[0])


def test_disk_full_during_a_csv_append_is_one_line(
    protocol: Path,
    reference: tuple[Path, float],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    from seal.run import rundir

    real_fsync, calls = os.fsync, {"metrics": 0}

    def full_disk(fd: int) -> None:
        if os.readlink(f"/proc/self/fd/{fd}").endswith("metrics.csv"):
            calls["metrics"] += 1
            if calls["metrics"] == 7:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real_fsync(fd)

    if not Path("/proc/self/fd").is_dir():
        pytest.skip("needs /proc/self/fd")
    monkeypatch.setattr(rundir.os, "fsync", full_disk)
    out = tmp_path / "out"
    code = main(["run", str(protocol), "--out", str(out), "--quiet", "--no-report"])
    err = capsys.readouterr().err
    monkeypatch.setattr(rundir.os, "fsync", real_fsync)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "metrics.csv" in err and "No space left on device" in err
    (run_dir,) = out.glob("faults/*/seed-0")
    _resume(protocol, run_dir, capsys)
    _assert_same_rows(run_dir, reference[0])


def test_disk_full_while_creating_the_run_directory_is_one_line_and_leaves_nothing(
    protocol: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    from seal.run import rundir

    def full_disk(text_path: Path, text: str) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(text_path))

    monkeypatch.setattr(rundir, "atomic_write_text", full_disk)
    out = tmp_path / "out"
    code = main(["run", str(protocol), "--out", str(out), "--quiet", "--no-report"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "config.toml failed: No space left on device" in err[0]
    assert not out.exists()


# ---------------------------------------------------------------- corrupt files


def test_a_zero_byte_newest_checkpoint_and_a_torn_csv_line_resume_from_the_one_before(
    protocol: Path,
    reference: tuple[Path, float],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    run_dir = shutil.copytree(reference[0], tmp_path / "faults" / "g" / "seed-0")
    folder = run_dir / "checkpoints"
    (folder / "ckpt-0000012.pt").write_bytes(b"")
    with open(run_dir / "metrics.csv", "a") as fh:
        fh.write("0,train,13,pt,ea")  # a row cut short
    err = _resume(protocol, run_dir, capsys)
    assert f"skipping {folder / 'ckpt-0000012.pt'}: " in err and "not a seal checkpoint" in err
    assert f"resuming from {folder / 'ckpt-0000010.pt'}" in err
    _assert_same_rows(run_dir, reference[0])
    read_checkpoint(folder / "ckpt-0000012.pt")  # written again by the resumed run
    (record,) = json.loads((run_dir / "provenance.json").read_text())["resumes"]
    assert record["from"] == "ckpt-0000010.pt"
    assert [s["file"] for s in record["skipped"]] == ["ckpt-0000012.pt"]


def test_a_checkpoint_whose_csv_rows_are_gone_is_skipped(
    protocol: Path,
    reference: tuple[Path, float],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    run_dir = shutil.copytree(reference[0], tmp_path / "faults" / "g" / "seed-0")
    lines = (run_dir / "metrics.csv").read_text().splitlines(keepends=True)
    (run_dir / "metrics.csv").write_text("".join(lines[: 1 + 11 * 2]))  # epoch 12's rows lost
    err = _resume(protocol, run_dir, capsys)
    assert "fewer than the 24 the checkpoint recorded" in err
    _assert_same_rows(run_dir, reference[0])


def test_no_intact_checkpoint_refuses_in_one_line(
    protocol: Path,
    reference: tuple[Path, float],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    run_dir = shutil.copytree(reference[0], tmp_path / "faults" / "g" / "seed-0")
    for ckpt in (run_dir / "checkpoints").glob("ckpt-*.pt"):
        ckpt.write_bytes(b"")
    before = (run_dir / "metrics.csv").read_bytes()
    capsys.readouterr()
    code = main(["run", str(protocol), "--resume", str(run_dir), "--quiet", "--no-report"])
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert code == 2 and "no intact checkpoint" in last and str(run_dir) in last
    assert (run_dir / "metrics.csv").read_bytes() == before


# ---------------------------------------------------------------- two writers


def test_a_second_writer_is_refused_and_no_row_is_duplicated(
    protocol: Path,
    reference: tuple[Path, float],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    out = tmp_path / "out"
    child = _start_child(protocol, out, pause_at=2)  # holds the lock, paused mid-checkpoint
    try:
        _wait_for(child, (out / "paused").exists)
        (run_dir,) = out.glob("faults/*/seed-0")
        before = (run_dir / "metrics.csv").read_bytes()
        capsys.readouterr()
        code = main(["run", str(protocol), "--resume", str(run_dir), "--quiet", "--no-report"])
        err = capsys.readouterr().err
        assert code == 2 and len(err.strip().splitlines()) == 1
        assert str(run_dir) in err and f"pid {child.pid}" in err
        capsys.readouterr()
        assert main(["report", str(run_dir)]) == 2  # a report would write there too
        assert f"pid {child.pid}" in capsys.readouterr().err
        assert (run_dir / "metrics.csv").read_bytes() == before
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait()
    _resume(protocol, run_dir, capsys)  # the killed holder's lock is gone with it
    _assert_same_rows(run_dir, reference[0])


def test_the_lock_is_exclusive_within_one_process_too(tmp_path: Path) -> None:
    from seal.errors import SealError

    held = f"{tmp_path} is being written .*pid {os.getpid()}"
    with DirLock(tmp_path), pytest.raises(SealError, match=held):
        DirLock(tmp_path).acquire()
    DirLock(tmp_path).acquire().release()  # free again once released
