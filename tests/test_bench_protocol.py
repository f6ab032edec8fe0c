"""`seal bench --protocol`: an N-epoch window of a real protocol, timed by the runner, projected."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from seal.bench.protocol import bench_protocol
from seal.cli.main import main

PROTOCOL = """
[protocol]
kind = "baseline"
epochs = 300
seeds = 2
device = "cpu"
threads = 1
[envs.pt]
adapter = "point"
tasks = ["east", "north"]
episode_length = 10
[agent]
hidden = [8, 8]
[training]
warmup_steps = 500
batch_per_task = 4
collector = "sync"
[evaluation]
every_grad_steps = 45
episodes = 2
[checkpoint]
interval = 100
[logging]
tensorboard = false
"""


def test_window_is_timed_and_projected_from_the_full_protocols_settings(tmp_path: Path) -> None:
    path = tmp_path / "p.toml"
    path.write_text(PROTOCOL)
    result = bench_protocol(path, epochs=3, out=tmp_path / "window")
    (train,) = result["phases"].values()
    # 10-step episodes: 10 gradient steps an epoch; the full run's 300 epochs make 3,000 steps,
    # so evaluations at 45, 90, ..., 2,970 (66) and at the end: 67. Checkpoints: 300 / 100 = 3.
    assert train["grad_steps_per_epoch"] == 10
    assert (train["epochs"], train["evaluations"], train["checkpoints"]) == (300, 67, 3)
    # Replay rows: window 3 x 20 = 60; full run's mean 300 x 20 / 2 = 3,000 (capacity 1e6): x50.
    expected = (
        300 * (train["collect_s_per_epoch"] + train["update_s_per_epoch"])
        + 67 * train["evaluate_s_each"]
        + 3 * train["checkpoint_s_each"] * 50
    )
    assert result["projected_s"] == pytest.approx(expected)
    assert all(
        train[k] > 0 for k in ("collect_s_per_epoch", "update_s_per_epoch", "evaluate_s_each")
    )
    # The window: 3 epochs, no warm-up, one evaluation and one checkpoint, at its end.
    run = tmp_path / "window" / "p" / "seed-0"
    rows = (run / "metrics.csv").read_text().splitlines()
    assert len(rows) == 1 + 2 and rows[1].split(",")[2] == "3"  # header + 2 tasks at epoch 3
    assert [p.name for p in (run / "checkpoints").glob("ckpt-*.pt")] == ["ckpt-0000003.pt"]


def test_cli_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "p.toml"
    path.write_text(PROTOCOL)
    assert main(["bench", "--protocol", str(path), "--epochs", "1", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["epochs"] == 1 and set(result["phases"]) == {"train"}
    assert main(["bench", "--protocol", str(path), "--epochs", "0"]) == 2
