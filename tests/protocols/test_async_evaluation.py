"""evaluation.mode = "async": the same rows as a synchronous evaluation of the same snapshots, and exact resume."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
import torch

from seal.learner.checkpoint import read_checkpoint
from seal.protocols import load_protocol
from seal.run.runner import resume_run, run_seed
from seal.run.workers import EvaluationWorker
from tests.crash import CrashAfter

# Evaluations every 2 epochs and checkpoints every 3: an evaluation is often in flight at a
# checkpoint; the stepped scheduler changes the batch mid-run, so rows carry changing counts.
PROTOCOL = """
[protocol]
name = "async_eval"
kind = "joint"
epochs = 9
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
warmup_steps = 10
batch_per_task = 8
collector = "sync"
[evaluation]
interval = 2
episodes = 3
[checkpoint]
interval = 3
keep_last = 5
[logging]
tensorboard = false
[scheduler]
kind = "stepped"
start = { a = 0.9, b = 0.1 }
interval = 4
"""


def _frames(run_dir: Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    metrics = pd.read_csv(run_dir / "metrics.csv").drop(columns="wall_s")
    # An asynchronous evaluation's critic-probe rows (eval_q/..., train.csv) are appended when its
    # results come in, so their place among the training rows depends on timing: the same rows,
    # compared in one order.
    train = pd.read_csv(run_dir / "train.csv")
    train = train.sort_values(["phase", "epoch", "grad_steps", "env", "key"], kind="stable")
    return metrics, train.reset_index(drop=True)


def _actor(path: Path) -> dict[str, torch.Tensor]:
    return read_checkpoint(path)["agent"]["actor"]


def _assert_same_runs(got: Path, want: Path) -> None:
    (gm, gt), (wm, wt) = _frames(got), _frames(want)
    pd.testing.assert_frame_equal(gm, wm)
    pd.testing.assert_frame_equal(gt, wt)
    best_got, best_want = _actor(got / "checkpoints/best.pt"), _actor(want / "checkpoints/best.pt")
    assert best_got.keys() == best_want.keys()
    assert all(torch.equal(best_got[k], best_want[k]) for k in best_want)


def _never_done(monkeypatch: pytest.MonkeyPatch) -> None:
    """Results are taken only when the loop must wait: every checkpoint holds one pending."""
    monkeypatch.setattr(EvaluationWorker, "done", lambda self: False)


@pytest.mark.slow
def test_async_rows_equal_sync_rows_on_point(tmp_path: Path) -> None:
    path = tmp_path / "async_eval.toml"
    path.write_text(PROTOCOL)
    sync = run_seed(load_protocol(path), 0, tmp_path / "sync")
    asyn = run_seed(load_protocol(path, ['evaluation.mode="async"']), 0, tmp_path / "async")
    _assert_same_runs(asyn.run_dir, sync.run_dir)
    assert len(pd.read_csv(asyn.run_dir / "metrics.csv")) == 5 * 3  # epochs 2, 4, 6, 8, 9
    assert asyn.update_counts == sync.update_counts
    assert asyn.final_success == sync.final_success


@pytest.mark.slow
def test_a_pending_evaluation_is_rerun_on_resume(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _never_done(monkeypatch)
    path = tmp_path / "async_eval.toml"
    path.write_text(PROTOCOL)
    config = load_protocol(path, ['evaluation.mode="async"'])
    reference = run_seed(load_protocol(path), 0, tmp_path / "sync").run_dir
    with pytest.raises(KeyboardInterrupt):
        run_seed(config, 0, tmp_path / "killed", callbacks=[CrashAfter(at=8)])
    (run_dir,) = (tmp_path / "killed").glob("seed-0")
    # The epoch-6 checkpoint holds the evaluation of epoch 6, not yet written when it was taken;
    # its rows came at epoch 8 (the next evaluation waits for it), before the crash. The resume
    # goes back to the checkpoint and re-runs it.
    ckpt = read_checkpoint(run_dir / "checkpoints/ckpt-0000006.pt")
    (pending,) = ckpt["runner"]["pending_evaluations"]
    assert (pending["epoch"], ckpt["runner"]["rows"]["metrics.csv"]) == (6, 2 * 3)
    assert len(pd.read_csv(run_dir / "metrics.csv")) == 3 * 3
    resume_run(run_dir)
    _assert_same_runs(run_dir, reference)


QUICKSTART = Path(__file__).resolve().parents[2] / "protocols" / "quickstart.toml"
# The quickstart's shape (its two real envs, networks, ratio, overlapped collection), in short
# episodes, evaluated synchronously unless a test says otherwise.
QUICKSTART_SMALL = [
    "protocol.epochs=3",
    'evaluation.mode="sync"',
    "protocol.threads=1",
    "envs.mw.episode_length=30",
    "envs.fk.episode_length=30",
    "training.warmup_steps=30",
    "training.demo_episodes=0",
    "evaluation.interval=1",
    "evaluation.episodes=2",
    "checkpoint.interval=2",
    "logging.tensorboard=false",
]


@pytest.mark.slow
def test_async_rows_equal_sync_rows_on_the_quickstart_shape(tmp_path: Path) -> None:
    sync = run_seed(load_protocol(QUICKSTART, QUICKSTART_SMALL), 0, tmp_path / "sync")
    asyn = run_seed(
        load_protocol(QUICKSTART, [*QUICKSTART_SMALL, 'evaluation.mode="async"']),
        0,
        tmp_path / "async",
    )
    _assert_same_runs(asyn.run_dir, sync.run_dir)
    assert len(pd.read_csv(asyn.run_dir / "metrics.csv")) == 3 * 2  # 3 epochs, 2 tasks
