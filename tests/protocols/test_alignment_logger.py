"""The alignment logger: a joint testbed run logs the translators' CKA at every evaluation, learning unchanged."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from seal.learner.probes import cka_from_checkpoints
from seal.protocols import load_protocol
from seal.run import loggers as loggers_module
from seal.run.loggers import ALIGNMENT_SEED, ALIGNMENT_STATES, alignment_envs
from seal.run.runner import run_seed

TESTBED = Path(__file__).resolve().parents[2] / "protocols" / "testbed"
TINY = [
    "protocol.epochs=3",
    "training.warmup_steps=0",
    "training.grad_steps_per_epoch=2",
    "evaluation.interval=1",
    "evaluation.episodes=1",
    "envs.source.episode_length=5",
    "envs.target.episode_length=5",
    "agent.translator_hidden=[8]",
    "agent.latent_dim=8",
    "agent.trunk_hidden=[8]",
    "agent.critic_hidden=[8]",
    "logging.tensorboard=true",
]
KEYS = ["alignment/cka_translator", "alignment/cka_trunk"]


def test_only_joint_seal_runs_of_the_testbed_pair_are_probed() -> None:
    assert alignment_envs(load_protocol(TESTBED / "high_source.toml")) == ("source", "target")
    assert alignment_envs(load_protocol(TESTBED / "no_correspondence.toml")) == ("source", "target")
    assert alignment_envs(load_protocol(TESTBED / "alone.toml")) is None  # one env
    mtmhsac = ["agent.architecture='mtmhsac'"]
    assert alignment_envs(load_protocol(TESTBED / "alone.toml", mtmhsac)) is None


def test_a_joint_testbed_run_logs_cka_rows_and_learns_as_without_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    config = load_protocol(TESTBED / "high_source.toml", TINY)
    run = run_seed(config, 0, tmp_path / "with").run_dir
    train = pd.read_csv(run / "train.csv")
    rows = train[train["key"].isin(KEYS)]
    metrics = pd.read_csv(run / "metrics.csv")
    # One row per key at every evaluation (epochs 1, 2, 3), under the point_view env.
    assert sorted(rows["epoch"].unique()) == sorted(metrics["epoch"].unique()) == [1, 2, 3]
    assert (rows.groupby("epoch")["key"].apply(sorted) == [KEYS] * 3).all()
    assert set(rows["env"]) == {"target"}
    assert list(rows["grad_steps"].unique()) == [2, 4, 6]
    assert rows["value"].between(0.0, 1.0).all()

    # TensorBoard mirrors them through the loggers' usual train-row path.
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(run / "tb" / "train"))
    events.Reload()
    logged = [(e.step, e.value) for e in events.Scalars("charts/target/alignment/cka_trunk")]
    trunk = rows[rows["key"] == "alignment/cka_trunk"]
    assert [s for s, _ in logged] == list(trunk["grad_steps"])
    assert [v for _, v in logged] == pytest.approx(list(trunk["value"]), rel=1e-6)

    # Post hoc from the final checkpoint: the last logged values.
    final = sorted((run / "checkpoints").glob("ckpt-*.pt"))[-1]
    post_hoc = cka_from_checkpoints(
        final, "source", final, "target", n=ALIGNMENT_STATES, seed=ALIGNMENT_SEED
    )
    last = rows[rows["epoch"] == 3].set_index("key")["value"]
    assert post_hoc == pytest.approx(
        {"translator": last[KEYS[0]], "trunk": last[KEYS[1]]}, abs=1e-9
    )

    # The same run without the logger: identical evaluations and training curves.
    monkeypatch.setattr(loggers_module, "alignment_envs", lambda config: None)
    plain = run_seed(config, 0, tmp_path / "without").run_dir
    without = pd.read_csv(plain / "metrics.csv")
    pd.testing.assert_frame_equal(metrics.drop(columns="wall_s"), without.drop(columns="wall_s"))
    pd.testing.assert_frame_equal(
        train[~train["key"].isin(KEYS)].reset_index(drop=True), pd.read_csv(plain / "train.csv")
    )
