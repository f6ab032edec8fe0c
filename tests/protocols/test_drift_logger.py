"""[logging] drift through the runner: rows at every evaluation, 0 before any update, the same
after a resume, and learning unchanged."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from seal.learner.checkpoint import read_checkpoint
from seal.learner.drift import relative_drift
from seal.learner.probes import agent_from_state
from seal.pieces import PIECES
from seal.protocols import load_protocol
from seal.run.loop import LoopCallback, PhaseLoop
from seal.run.runner import run_seed

TESTBED = Path(__file__).resolve().parents[2] / "protocols" / "testbed"
# point_view alone (alone.toml has logging.drift on): 4 tasks x 5 steps = 20 env steps an
# epoch, so a warm-up of 30 leaves epoch 1's evaluation before any update.
TINY = [
    "protocol.epochs=4",
    "training.warmup_steps=30",
    "training.grad_steps_per_epoch=2",
    "evaluation.interval=1",
    "evaluation.episodes=1",
    "envs.target.episode_length=5",
    "agent.translator_hidden=[8]",
    "agent.latent_dim=8",
    "agent.trunk_hidden=[8]",
    "agent.critic_hidden=[8]",
    "checkpoint.interval=2",
    "checkpoint.save_replay=true",  # resume needs it
]
KEYS = sorted(f"drift/{p}" for p in PIECES)


def _drift(run: Path) -> pd.DataFrame:
    train = pd.read_csv(run / "train.csv")
    return train[train["key"].str.startswith("drift/")].reset_index(drop=True)


def test_drift_rows_start_at_0_and_end_at_the_checkpoints_distance(tmp_path: Path) -> None:
    config = load_protocol(TESTBED / "alone.toml", TINY)
    assert config.logging.drift
    run = run_seed(config, 0, tmp_path / "with").run_dir
    rows, metrics = _drift(run), pd.read_csv(run / "metrics.csv")
    assert sorted(rows["epoch"].unique()) == sorted(metrics["epoch"].unique()) == [1, 2, 3, 4]
    assert (rows.groupby("epoch")["key"].apply(sorted) == [KEYS] * 4).all()
    assert set(rows["env"]) == {"target"}
    first = rows[rows["epoch"] == 1]
    assert (first["grad_steps"] == 0).all() and (first["value"] == 0.0).all()
    assert (rows[rows["epoch"] == 4]["value"] > 0).all()
    # The last rows are the final checkpoint's agent against the W0 it holds.
    final = read_checkpoint(run / "checkpoints" / "ckpt-0000004.pt")
    agent = agent_from_state(final["agent"])
    envs = {"target": "target"}
    expected = relative_drift(agent, final["runner"]["drift_start"], envs)
    last = rows[rows["epoch"] == 4].set_index("key")["value"]
    assert last.to_dict() == pytest.approx(
        {f"drift/{p}": v for (_, p), v in expected.items()}, rel=1e-6
    )

    # The same run without drift: identical evaluations and training curves.
    plain = run_seed(
        load_protocol(TESTBED / "alone.toml", [*TINY, "logging.drift=false"]), 0, tmp_path / "off"
    ).run_dir
    assert _drift(plain).empty
    assert "drift_start" not in read_checkpoint(plain / "checkpoints" / "ckpt-0000004.pt")["runner"]
    for table in ("metrics.csv", "train.csv"):
        left, right = pd.read_csv(run / table), pd.read_csv(plain / table)
        left = left[~left["key"].str.startswith("drift/")] if "key" in left else left
        cols = [c for c in left.columns if c != "wall_s"]
        pd.testing.assert_frame_equal(left[cols].reset_index(drop=True), right[cols])


class _Crash(LoopCallback):
    """Stops the run with an error once epoch 3 is done (after the checkpoint of epoch 2)."""

    def on_epoch_end(self, loop: PhaseLoop) -> None:
        if loop.state.epoch == 3:
            raise RuntimeError("crash")


def test_a_resumed_run_measures_from_the_same_start(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    config = load_protocol(TESTBED / "alone.toml", TINY)
    reference = _drift(run_seed(config, 0, tmp_path / "ref").run_dir)
    with pytest.raises(RuntimeError, match="crash"):
        run_seed(config, 0, tmp_path / "g", callbacks=[_Crash()])

    def no_new_start(*_: object) -> None:
        raise AssertionError("a resumed phase takes W0 from its checkpoint")

    monkeypatch.setattr("seal.learner.drift.start_weights", no_new_start)
    resumed = _drift(run_seed(config, 0, tmp_path / "g", resume=True).run_dir)
    # Epochs 3 and 4 come from the resumed process: W0 from the checkpoint, not its own agent.
    assert sorted(resumed["epoch"].unique()) == [1, 2, 3, 4]
    pd.testing.assert_frame_equal(resumed, reference)


def test_an_asynchronous_evaluation_logs_its_snapshots_drift(tmp_path: Path) -> None:
    config = load_protocol(TESTBED / "alone.toml", TINY)
    sync = _drift(run_seed(config, 0, tmp_path / "sync").run_dir)
    config = load_protocol(TESTBED / "alone.toml", [*TINY, 'evaluation.mode="async"'])
    rows = _drift(run_seed(config, 0, tmp_path / "async").run_dir)
    order = ["epoch", "key"]
    pd.testing.assert_frame_equal(
        rows.sort_values(order).reset_index(drop=True),
        sync.sort_values(order).reset_index(drop=True),
    )
