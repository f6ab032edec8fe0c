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


def test_floor_arithmetic_on_a_hand_worked_case() -> None:
    from seal.bench.protocol import floor_projection

    # Env a: 3,000 steps at 1 ms = 3 core-s; env b: 500 steps at 4 ms = 2 core-s; 5 core-s in all.
    # 2 cores at efficiency 0.5: a floor of 5 s. Updates 3 s, checkpoints 1 s:
    # serial 5 + 3 + 1 = 9 s; overlapped max(5, 3) + 1 = 6 s.
    f = floor_projection(
        env_steps={"a": 3000, "b": 500},
        step_s={"a": 1e-3, "b": 4e-3},
        cores=2,
        update_s=3.0,
        checkpoint_s=1.0,
        efficiency=0.5,
    )
    assert f["env_core_h"] == pytest.approx(5 / 3600)
    assert f["floor_h"] == pytest.approx(5 / 3600)
    assert f["serial_h"] == pytest.approx(9 / 3600)
    assert f["overlapped_h"] == pytest.approx(6 / 3600)
    # Updates longer than the stepping: the overlapped run waits on them.
    slow = floor_projection(
        env_steps={"a": 3000}, step_s={"a": 1e-3}, cores=1, update_s=10.0, efficiency=1.0
    )
    assert (slow["floor_h"], slow["overlapped_h"]) == pytest.approx((3 / 3600, 10 / 3600))
    # No update rate: the floor alone.
    none = floor_projection(env_steps={"a": 1}, step_s={"a": 1.0}, cores=1, update_s=None)
    assert none["serial_h"] is None and none["overlapped_h"] is None


def test_floor_counts_the_protocols_env_steps(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from seal.bench import protocol

    monkeypatch.setattr(protocol, "measure_step_costs", lambda config, log=None: {"pt": 1e-3})
    path = tmp_path / "p.toml"
    path.write_text(PROTOCOL)
    result = bench_protocol(path, epochs=0, floor_only=True, cores=4, update_rate=100.0)
    f = result["floor"]
    (train,) = f["phases"].values()
    # 300 epochs x 2 tasks x 10 steps = 6,000 training steps; 67 evaluations x 2 episodes x 2
    # tasks x 10 steps = 2,680; 8,680 steps at 1 ms = 8.68 core-s over 4 x 0.8 cores.
    assert (train["train_env_steps"], train["eval_env_steps"]) == (6000, 2680)
    assert f["floor_h"] == pytest.approx(8.68 / 3.2 / 3600)
    # 3,000 gradient steps at 100 updates/s = 30 s, longer than the floor.
    assert f["serial_h"] == pytest.approx((8.68 / 3.2 + 30) / 3600)
    assert f["overlapped_h"] == pytest.approx(30 / 3600)
    assert f["label"] == "projections" and f["update_rate"] == "given"


def test_cli_floor_with_cores(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "p.toml"
    path.write_text(PROTOCOL)
    argv = ["bench", "--protocol", str(path), "--epochs", "1", "--cores", "16", "--json"]
    assert main(argv) == 0
    f = json.loads(capsys.readouterr().out)["floor"]
    assert f["cores"] == 16 and f["update_rate"] == "measured"
    assert 0 < f["floor_h"] <= f["overlapped_h"] <= f["serial_h"]
    assert main(["bench", "--protocol", str(path), "--floor-only", "--cores", "3"]) == 0
    assert "env-stepping floor" in capsys.readouterr().out
