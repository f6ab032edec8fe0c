"""`seal run`'s time shares: the loop's wall by part (LOOP_PARTS), other, and start-up apart."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from seal.protocols import load_protocol
from seal.run.runner import run_seed
from seal.run.state import LOOP_PARTS

PROTOCOL = """
[protocol]
name = "time_shares"
kind = "baseline"
epochs = 3
seeds = 1
device = "cpu"
threads = 1
[envs.pt]
adapter = "point"
tasks = ["east", "north"]
episode_length = 50
[agent]
hidden = [32, 32]
[training]
warmup_steps = 50
batch_per_task = 32
collector = "sync"
[evaluation]
interval = 1
episodes = 2
mode = "{mode}"
[checkpoint]
interval = 2
[logging]
train_interval = 1
tensorboard = true
"""


def _run(tmp_path: Path, mode: str) -> dict:
    path = tmp_path / f"{mode}.toml"
    path.write_text(PROTOCOL.format(mode=mode))
    result = run_seed(load_protocol(path), 0, tmp_path / mode)
    provenance = json.loads((result.run_dir / "provenance.json").read_text())
    assert provenance["time_shares"] == result.time_shares
    return provenance["time_shares"]


def test_synchronous_run_other_is_small_and_startup_apart(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    shares = _run(tmp_path, "sync")
    parts, loop = shares["parts_s"], shares["loop_s"]
    assert set(parts) == set(LOOP_PARTS) and all(parts[p] > 0 for p in LOOP_PARTS)
    # The parts never overlap (the rows an evaluation writes are log, not evaluate) ...
    assert shares["other_s"] == pytest.approx(loop - sum(parts.values()))
    assert shares["other_s"] >= -1e-9
    # ... and cover the loop but for the epoch's bookkeeping (the 5%).
    assert shares["other_s"] <= 0.05 * loop
    assert shares["startup_s"] > 0
    assert shares["wall_s"] == pytest.approx(shares["startup_s"] + loop)
    assert shares["evaluate_worker_cpu_s"] == 0.0
    line = capsys.readouterr().err
    assert "time: wall" in line and "start-up" in line and "other" in line


def test_asynchronous_run_reports_the_worker_cpu_apart(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    shares = _run(tmp_path, "async")
    assert shares["evaluate_worker_cpu_s"] > 0
    assert shares["other_s"] >= -1e-9
    err = capsys.readouterr().err
    assert "evaluate (waiting)" in err and "evaluation worker CPU" in err
