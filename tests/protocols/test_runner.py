"""Runners on the point env: run directory format, update counts, the three kinds, --json, seal eval."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

from seal.cli.main import main
from seal.protocols import load_protocol
from seal.run.rundir import METRICS_COLUMNS, TRAIN_COLUMNS
from seal.run.runner import run_seed

HERE = Path(__file__).resolve().parent

# Tiny and fast: 10-step episodes, 8-wide networks, one torch thread, no worker processes.
TINY = """
[protocol]
kind = "{kind}"
epochs = {epochs}
seeds = 1
device = "cpu"
threads = 1
[training]
warmup_steps = {warmup}
batch_per_task = {batch}
collector = "sync"
[evaluation]
interval = 1
episodes = 2
[checkpoint]
interval = 2
keep_last = 2
[logging]
train_interval = 1
"""


def protocol(
    tmp_path: Path,
    body: str,
    *,
    kind: str,
    epochs: int = 3,
    warmup: int = 0,
    batch: int = 4,
    name: str = "tiny",
) -> Path:
    path = tmp_path / f"{name}.toml"
    path.write_text(TINY.format(kind=kind, epochs=epochs, warmup=warmup, batch=batch) + body)
    return path


BASELINE_ENVS = """
[envs.pt]
adapter = "point"
tasks = ["east", "north"]
episode_length = 10
[agent]
hidden = [8, 8]
"""


def test_baseline_run_directory_and_hand_computed_counters(tmp_path: Path) -> None:
    config = load_protocol(
        protocol(tmp_path, BASELINE_ENVS, kind="baseline", epochs=3, warmup=20, batch=4)
    )
    result = run_seed(config, 0, tmp_path / "reports" / "tiny" / "g1")
    run = result.run_dir
    assert run == tmp_path / "reports" / "tiny" / "g1" / "seed-0"
    metrics = pd.read_csv(run / "metrics.csv")
    assert tuple(metrics.columns) == METRICS_COLUMNS
    # One row per evaluation (every epoch) and task: 3 epochs x 2 tasks.
    assert len(metrics) == 6 and set(metrics["phase"]) == {"train"}
    # Epoch 1: each task collects one 10-step episode at random (warm-up 20 env steps for the env:
    # 2 x 10 = 20, done), then 10 gradient steps (episode length) of 4 transitions per task.
    # So after epoch e: env_steps per task = 10 e, grad_steps = 10 e, updates = 4 x 10 e / 1e6.
    for epoch in (1, 2, 3):
        rows = metrics[metrics["epoch"] == epoch]
        assert list(rows["task"]) == ["east", "north"]
        assert set(rows["env_steps"]) == {10 * epoch}
        assert set(rows["grad_steps"]) == {10 * epoch}
        assert rows["updates"].tolist() == pytest.approx([40 * epoch / 1e6] * 2)
    train = pd.read_csv(run / "train.csv")
    assert tuple(train.columns) == TRAIN_COLUMNS
    assert {"critic_loss", "actor_loss", "mean_q", "alpha/east", "alpha/north"} <= set(train["key"])
    assert set(train["env"]) == {"pt"}
    provenance = json.loads((run / "provenance.json").read_text())
    assert {
        "git_sha",
        "packages",
        "command",
        "device",
        "seed",
        "start_time",
        "end_time",
        "protocol",
        "kind",
        "group",
        "phase_names",
    } <= set(provenance)
    assert (
        provenance["phase_names"] == ["train"]
        and provenance["group"] == "g1"
        and provenance["end_time"]
    )
    assert provenance["packages"]["torch"].startswith("2.13")
    # Checkpoints every 2 epochs and at the end (2, 3), the last 2 kept, and the best.
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == [
        "best.pt",
        "ckpt-0000002.pt",
        "ckpt-0000003.pt",
    ]
    assert (run / "config.toml").is_file() and any((run / "tb").iterdir())
    assert load_protocol(run / "config.toml") == config.replace(path=str(run / "config.toml"))
    assert set(result.update_counts["pt"]) == {"east", "north"}
    assert result.final_success["pt"]["east"] == metrics.iloc[-2]["success"]
    # A task never at the threshold has no count (JSON null), not 0; a reached one its updates.
    for task, count in result.update_counts["pt"].items():
        rows = metrics[(metrics["task"] == task) & (metrics["success"] >= 0.9)]
        assert count == (None if rows.empty else rows.iloc[0]["updates"]), task


JOINT_ENVS = """
[envs.a]
adapter = "point"
tasks = ["east"]
episode_length = 10
[envs.b]
adapter = "point"
tasks = ["west", "south"]
episode_length = 6
[agent]
translator_hidden = [8]
latent_dim = 8
trunk_hidden = [8]
[scheduler]
kind = "stepped"
start = { a = 0.9, b = 0.1 }
interval = 1
"""


def test_joint_stepped_ratio_counts_and_mixed_episode_lengths(tmp_path: Path) -> None:
    config = load_protocol(protocol(tmp_path, JOINT_ENVS, kind="joint", epochs=2, batch=10))
    run = run_seed(config, 0, tmp_path / "g").run_dir
    m = pd.read_csv(run / "metrics.csv").set_index(["epoch", "env", "task"])
    # grad_steps_per_epoch = -1 with episodes of 10 (a) and 6 (b) steps: the longest, 10 per epoch.
    assert (
        m.loc[(1, "a", "east"), "grad_steps"] == 10 and m.loc[(2, "b", "west"), "grad_steps"] == 20
    )
    assert (
        m.loc[(2, "a", "east"), "env_steps"] == 20 and m.loc[(2, "b", "south"), "env_steps"] == 12
    )
    # Batch = 10 per task x 3 tasks = 30. Epoch 1 at 90/10: a's task 27; b's 3 split 1.5/1.5 ->
    # largest remainder, ties to the first: west 2, south 1. Epoch 2 at 80/20: a 24, b 3/3.
    # Consumed after epoch 1 = 10 steps x those counts; after epoch 2 add 10 x the new counts.
    assert m.loc[(1, "a", "east"), "updates"] == pytest.approx(270e-6)
    assert m.loc[(1, "b", "west"), "updates"] == pytest.approx(20e-6)
    assert m.loc[(1, "b", "south"), "updates"] == pytest.approx(10e-6)
    assert m.loc[(2, "a", "east"), "updates"] == pytest.approx(510e-6)
    assert m.loc[(2, "b", "west"), "updates"] == pytest.approx(50e-6)
    assert m.loc[(2, "b", "south"), "updates"] == pytest.approx(40e-6)
    assert (run / "scheduler.csv").is_file()
    train = pd.read_csv(run / "train.csv")
    assert {"a", "b"} <= set(train["env"])


FINETUNE_ENVS = """
[envs.a]
adapter = "point"
tasks = ["east", "north"]
episode_length = 10
[envs.b]
adapter = "point_variants:PointWideAdapter"
tasks = ["west"]
episode_length = 8
[agent]
hidden = [8, 8]
[finetune]
source = "a"
target = "b"
pretrain_epochs = 3
finetune_epochs = 2
"""


def test_finetune_runs_both_phases_and_restarts_counters(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.syspath_prepend(str(HERE))  # the second adapter lives beside this test
    config = load_protocol(protocol(tmp_path, FINETUNE_ENVS, kind="finetune", batch=4))
    result = run_seed(config, 0, tmp_path / "g")
    run = result.run_dir
    m = pd.read_csv(run / "metrics.csv")
    assert m.groupby("phase").size().to_dict() == {"pretrain": 3 * 2, "finetune": 2 * 1}
    assert set(m[m.phase == "pretrain"]["env"]) == {"a"} and set(
        m[m.phase == "finetune"]["env"]
    ) == {"b"}
    first = m[m.phase == "finetune"].iloc[0]
    # Counters restart: after fine-tuning epoch 1, 8 env steps, 8 grad steps, 4 x 8 transitions.
    assert (first["epoch"], first["env_steps"], first["grad_steps"]) == (1, 8, 8)
    assert first["updates"] == pytest.approx(32e-6)
    names = {p.name for p in (run / "checkpoints").iterdir()}
    assert {"best-pretrain.pt", "best-finetune.pt", "ckpt-finetune-0000002.pt"} <= names
    assert json.loads((run / "provenance.json").read_text())["phase_names"] == [
        "pretrain",
        "finetune",
    ]
    assert set(result.update_counts) == {"a", "b"}
    # The fine-tuned policy evaluates through the CLI with the saved config.
    assert (
        main(["eval", str(run / "checkpoints" / "best-finetune.pt"), "--episodes", "1", "--json"])
        == 0
    )


def test_cli_json_line_for_two_seeds(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = protocol(tmp_path, BASELINE_ENVS, kind="baseline", epochs=2)
    code = main(
        [
            "run",
            str(path),
            "--out",
            str(tmp_path / "out"),
            "--seeds",
            "0-1",
            "--quiet",
            "--json",
            "--set",
            "evaluation.interval=2",
        ]
    )
    assert code == 0
    line = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert set(line) == {"run_dir", "update_counts", "final_success", "run_dirs"}
    assert [Path(p).name for p in line["run_dirs"]] == ["seed-0", "seed-1"]
    assert Path(line["run_dirs"][0]).parent == Path(line["run_dirs"][1]).parent  # one group
    assert set(line["final_success"]["pt"]) == {"east", "north"}
    for run in line["run_dirs"]:
        assert (
            len(pd.read_csv(Path(run) / "metrics.csv")) == 2
        )  # one evaluation (epoch 2) x 2 tasks


def test_cli_ends_with_the_update_count_table(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = protocol(tmp_path, BASELINE_ENVS, kind="baseline", epochs=1)
    assert main(["run", str(path), "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    (table,) = (tmp_path / "out").glob("tiny/*/tables/update_counts.md")
    assert out.startswith(table.read_text())  # the table the report wrote, then where runs went
    assert "| east (pt)" in out and "| north (pt)" in out
    assert out.rstrip().endswith(f"runs written to {table.parents[1]}")


def test_eval_video_says_why_it_cannot(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = load_protocol(protocol(tmp_path, BASELINE_ENVS, kind="baseline", epochs=1))
    run = run_seed(config, 0, tmp_path / "g").run_dir
    # The point env has no renderer: either rendering or the env refuses, as one SealError line.
    assert main(["eval", str(run / "checkpoints" / "best.pt"), "--video", str(tmp_path / "v")]) == 2
    assert "--video" in capsys.readouterr().err
    assert main(["eval", str(tmp_path / "nope.pt")]) == 2
    capsys.readouterr()
    assert main(["eval", str(run / "checkpoints" / "best.pt"), "--seed", "-5"]) == 2
    assert capsys.readouterr().err == "seal eval: error: --seed -5: must be >= 0\n"
    # An evaluation whose results cannot fit (it was a 149 GiB numpy error once under way).
    assert main(["eval", str(run / "checkpoints" / "best.pt"), "--episodes", "10000000000"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("seal eval: error: --episodes 10000000000: ")
    assert "lower --episodes" in err[0]


SMT_ENVS = """
[envs.pt]
adapter = "point"
episode_length = 10
[agent]
hidden = [8, 8]
[scheduler]
kind = "smt"
budget_stage1 = 300
budget_stage2 = 60
slots = 2
reset_interval = 100
score_interval = 100
score_episodes = 2
solved_return = { pt = -3.0 }
unsolvable_return = { pt = -8.0 }
"""


def test_scheduler_that_ends_early_stops_the_run_with_a_final_evaluation(tmp_path: Path) -> None:
    config = load_protocol(protocol(tmp_path, SMT_ENVS, kind="baseline", epochs=500))
    run = run_seed(config, 0, tmp_path / "g").run_dir
    metrics = pd.read_csv(run / "metrics.csv")
    timeline = pd.read_csv(run / "scheduler.csv")
    # SMT spends B1 + B2 = 360 env steps: with 10-step episodes and at most 2 tasks collecting per
    # epoch that is over within 500 epochs, and the run stops there instead of idling on.
    last = int(metrics["epoch"].max())
    assert last < 500
    assert int(metrics[metrics["epoch"] == last]["env_steps"].sum()) >= 360
    assert {"epoch", "env", "task", "status"} <= set(timeline.columns)
    assert set(timeline["status"]) & {"main", "training"}
    assert (run / "checkpoints" / f"ckpt-{last:07d}.pt").is_file()


def test_a_divergence_while_fine_tuning_names_one_last_good_checkpoint(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The fine-tune phase's new agent has saved nothing yet: the run's newest checkpoint (the
    pre-training's) is the last good one, named once (it said "none saved yet" beside it)."""
    monkeypatch.syspath_prepend(str(HERE))
    path = protocol(tmp_path, FINETUNE_ENVS, kind="finetune", batch=4)
    out = tmp_path / "out"
    # A learning rate of 1e300 x the pre-training's makes the first fine-tune update non-finite.
    argv = ["run", str(path), "--out", str(out), "--quiet", "--set", "finetune.lr_factor=1e300"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "training diverged in phase 'finetune'" in err, err
    assert err.count("last good checkpoint") == 1 and "none saved yet" not in err
    assert err.rstrip().endswith("ckpt-pretrain-0000003.pt"), err


def test_a_device_this_machine_lacks_is_named_with_its_file_and_key(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = protocol(tmp_path, BASELINE_ENVS, kind="baseline", epochs=1)  # no machine has 100 GPUs
    out = tmp_path / "out"
    argv = ["run", str(path), "--out", str(out), "--quiet", "--set", 'protocol.device="cuda:99"']
    assert main(argv) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and f"{path}: protocol.device = 'cuda:99': " in err[0], err
    assert not out.exists()
