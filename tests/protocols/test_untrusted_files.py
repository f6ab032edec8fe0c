"""Files from elsewhere are data: a checkpoint whose unpickling would run code is refused everywhere.

The crafted file's payload calls `Path.touch` on a target file when unpickled, the shape of a
shared `.pt` that runs a shell command. `seal eval`, `seal run --resume` and `[transfer]` must all
refuse it with exit 2 and one line, and the target must not exist afterwards.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from seal.cli.main import main

PROTOCOL = """
[protocol]
kind = "baseline"
epochs = 1
seeds = 1
device = "cpu"
threads = 1
[envs.pt]
adapter = "point"
tasks = ["east"]
episode_length = 10
[agent]
hidden = [8, 8]
[training]
warmup_steps = 0
batch_per_task = 4
collector = "sync"
[evaluation]
interval = 1
episodes = 1
[logging]
tensorboard = false
"""


def _refused(capsys: pytest.CaptureFixture[str], code: int, target: Path) -> None:
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and "not a seal checkpoint (format unknown, expected 2)" in err[0], err
    assert "Traceback" not in err[0]
    assert not target.exists()


def test_seal_eval_refuses_a_checkpoint_that_would_run_code(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], code_running_checkpoint
) -> None:
    target = tmp_path / "created-by-unpickling"
    evil = code_running_checkpoint(tmp_path / "shared.pt", target)
    code = main(["eval", str(evil), "--episodes", "1"])
    _refused(capsys, code, target)


def test_transfer_refuses_it_before_any_run_directory_exists(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], code_running_checkpoint
) -> None:
    target = tmp_path / "created-by-unpickling"
    evil = code_running_checkpoint(tmp_path / "shared.pt", target)
    (tmp_path / "p.toml").write_text(PROTOCOL + f'[transfer]\ncheckpoint = "{evil}"\n')
    out = tmp_path / "reports"
    code = main(["run", str(tmp_path / "p.toml"), "--out", str(out), "--quiet"])
    _refused(capsys, code, target)
    assert not out.exists()


def test_resume_refuses_it_and_leaves_the_run_as_it_was(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], code_running_checkpoint
) -> None:
    (tmp_path / "p.toml").write_text(PROTOCOL)
    out = tmp_path / "reports"
    assert main(["run", str(tmp_path / "p.toml"), "--out", str(out), "--quiet", "--no-report"]) == 0
    (run,) = out.glob("p/*/seed-0")
    (latest,) = (run / "checkpoints").glob("ckpt-*.pt")
    target = tmp_path / "created-by-unpickling"
    code_running_checkpoint(latest, target)  # someone handed us this run directory
    before = (run / "metrics.csv").read_bytes()
    capsys.readouterr()
    code = main(["run", str(tmp_path / "p.toml"), "--resume", str(run), "--quiet", "--no-report"])
    _refused(capsys, code, target)
    assert (run / "metrics.csv").read_bytes() == before
