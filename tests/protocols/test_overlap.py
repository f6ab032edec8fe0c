"""training.overlap (actor-learner): deterministic across processes, exact resume, one epoch of policy lag."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import torch

from seal.learner.checkpoint import read_checkpoint
from seal.protocols import load_protocol
from seal.run.runner import resume_run, run_seed
from tests.crash import CrashAfter

PROTOCOL = """
[protocol]
name = "overlap"
kind = "joint"
epochs = 8
seeds = 1
device = "cpu"
threads = 1
[envs.a]
adapter = "point"
tasks = ["east", "north"]
episode_length = 10
[envs.b]
adapter = "point"
tasks = ["west"]
episode_length = 8
[agent]
translator_hidden = [8]
latent_dim = 8
trunk_hidden = [8]
[training]
warmup_steps = 20
batch_per_task = 8
collector = "sync"
overlap = true
[evaluation]
interval = 2
episodes = 2
[checkpoint]
interval = 3
keep_last = 5
[logging]
tensorboard = false
train_interval = 2
[scheduler]
kind = "stepped"
start = { a = 0.9, b = 0.1 }
interval = 4
"""


def _same_files(got: Path, want: Path) -> None:
    pd.testing.assert_frame_equal(
        pd.read_csv(got / "metrics.csv").drop(columns="wall_s"),
        pd.read_csv(want / "metrics.csv").drop(columns="wall_s"),
    )
    pd.testing.assert_frame_equal(pd.read_csv(got / "train.csv"), pd.read_csv(want / "train.csv"))


def _same_agent(got: Path, want: Path) -> None:
    a, b = read_checkpoint(got)["agent"], read_checkpoint(want)["agent"]
    for part in ("actor", "critic", "critic_target"):
        assert all(torch.equal(a[part][k], b[part][k]) for k in b[part]), part
    assert a["num_updates"] == b["num_updates"]


@pytest.fixture
def protocol(tmp_path: Path) -> Path:
    path = tmp_path / "overlap.toml"
    path.write_text(PROTOCOL)
    return path


@pytest.mark.slow
def test_overlap_is_deterministic_across_processes(protocol: Path, tmp_path: Path) -> None:
    here = run_seed(load_protocol(protocol), 0, tmp_path / "here").run_dir
    child = subprocess.run(
        [
            sys.executable,
            "-m",
            "seal.cli.main",
            "run",
            str(protocol),
            "--out",
            str(tmp_path / "child"),
        ]
        + ["--quiet", "--no-report"],
        env={**os.environ, "OMP_NUM_THREADS": "1"},
        capture_output=True,
        text=True,
    )
    assert child.returncode == 0, child.stderr
    (there,) = (tmp_path / "child").glob("overlap/*/seed-0")
    _same_files(there, here)
    _same_agent(there / "checkpoints/ckpt-0000008.pt", here / "checkpoints/ckpt-0000008.pt")


@pytest.mark.slow
def test_overlap_resumes_bitwise_after_a_checkpoint(protocol: Path, tmp_path: Path) -> None:
    config = load_protocol(protocol)
    reference = run_seed(config, 0, tmp_path / "ref").run_dir
    with pytest.raises(KeyboardInterrupt):
        run_seed(config, 0, tmp_path / "killed", callbacks=[CrashAfter(at=5)])
    (run_dir,) = (tmp_path / "killed").glob("seed-0")
    assert (run_dir / "checkpoints/ckpt-0000003.pt").is_file()
    resume_run(run_dir)  # from epoch 3
    _same_files(run_dir, reference)
    _same_agent(run_dir / "checkpoints/ckpt-0000008.pt", reference / "checkpoints/ckpt-0000008.pt")


def test_overlap_lags_the_serial_loop_by_one_epoch(protocol: Path, tmp_path: Path) -> None:
    serial = run_seed(load_protocol(protocol, ["training.overlap=false"]), 0, tmp_path / "s")
    overlap = run_seed(load_protocol(protocol), 0, tmp_path / "o")
    s = pd.read_csv(serial.run_dir / "metrics.csv").groupby("epoch")
    o = pd.read_csv(overlap.run_dir / "metrics.csv").groupby("epoch")
    # Warm-up ends with epoch 2's collection (20 env steps of a and 16 of b after 2 epochs, b's
    # 20 after epoch 3). Serial trains in epoch 3 on what epoch 3 collected; overlapped trains
    # first in epoch 4, on epoch 3's episodes, so it is one epoch (10 steps) behind throughout.
    assert s["grad_steps"].first()[4] == 20 and o["grad_steps"].first()[4] == 10
    assert s["env_steps"].sum().equals(o["env_steps"].sum())  # the same episodes collected
