"""`seal bench --learn kitchen`: the arms, reading a run's first crossing, and a tiny end-to-end run."""

from __future__ import annotations

import dataclasses
import json
import shutil
import warnings
from pathlib import Path

import pandas as pd
import pytest

from seal import load_run
from seal.errors import SealError, SealWarning
from seal.experiments.kitchen import (
    ARMS,
    arm_config,
    arms,
    end_mean_q,
    end_q_ratio,
    format_result,
    pinned_version,
    run_figures,
    run_kitchen_bench,
)
from seal.protocols import load_protocol


def _metrics(success: list[float]) -> pd.DataFrame:
    """One task evaluated every 10 epochs of 280 steps (2,800 env steps), one update per step at batch 256."""
    n = len(success)
    epochs = [10 * (i + 1) for i in range(n)]
    return pd.DataFrame(
        {
            "seed": 0,
            "phase": "train",
            "env": "fk",
            "task": "slide-cabinet",
            "epoch": epochs,
            "success": success,
            "grad_steps": [280 * e - 4000 for e in epochs],
            "env_steps": [280 * e for e in epochs],
            "updates": [(280 * e - 4000) * 256 / 1e6 for e in epochs],
        }
    )


def test_run_figures_first_crossing_and_censored_total() -> None:
    # First >= 0.9 at the third evaluation: epoch 30, 8,400 env steps, 4,400 gradient steps,
    # 4,400 x 256 = 1.1264 M transitions; the later 0.8 does not undo it.
    reached = run_figures(_metrics([0.1, 0.5, 0.9, 0.8]))
    assert reached == {
        "reached": True,
        "env_steps": 8400,
        "grad_steps": 4400,
        "updates_m": pytest.approx(1.1264),
        "best_success": 0.9,
        "final_success": 0.8,
        "held_90": 0,
        "after_first": 1,
    }
    # Kept: two more evaluations at >= 90% of the three after the first crossing.
    kept = run_figures(_metrics([0.1, 0.9, 0.6, 1.0, 0.9]))
    assert (kept["held_90"], kept["after_first"]) == (2, 3)
    # Never reached: censored at the run's last evaluation (epoch 20: 5,600 steps, 1,600 updates).
    censored = run_figures(_metrics([0.3, 0.7]))
    assert (censored["reached"], censored["env_steps"], censored["grad_steps"]) == (
        False,
        5600,
        1600,
    )
    assert censored["updates_m"] == pytest.approx(0.4096)
    assert (censored["held_90"], censored["after_first"]) == (0, 0)


def test_end_mean_q_is_the_last_logged_mean_q() -> None:
    rows = [(280, "mean_q", 5.0), (560, "alpha/microwave", 0.1), (840, "mean_q", 7.5)]
    train = pd.DataFrame(rows[::-1], columns=["grad_steps", "key", "value"])  # out of order
    assert end_mean_q(train) == 7.5
    assert end_mean_q(train[train["key"] != "mean_q"]) is None


def test_end_q_ratio_is_the_last_evaluations_probe_ratio() -> None:
    rows = [(280, "eval_q_ratio/microwave", 4.0), (560, "mean_q", 9.0)]
    rows += [(840, "eval_q_ratio/microwave", 1.25), (840, "eval_q/microwave", 500.0)]
    train = pd.DataFrame(rows[::-1], columns=["grad_steps", "key", "value"])  # out of order
    assert end_q_ratio(train) == 1.25
    assert end_q_ratio(train[train["key"] == "mean_q"]) is None  # a run from before the probe


def test_arms_are_single_kitchen_protocols_differing_only_in_demonstrations() -> None:
    with warnings.catch_warnings():  # the v4 arms' candidate-reward warning (once per process)
        warnings.simplefilter("ignore", SealWarning)
        configs = {arm.name: load_protocol(arm.protocol) for arm in ARMS}
    for name, config in configs.items():
        assert config.evaluation.mode == "async", name  # off the loop's critical path
        assert config.kind == "baseline" and config.envs["fk"].adapter == "franka_kitchen_dense"
        v4 = "_v4" in name
        # v4 arms and the learner tests run all epochs
        runs_on = v4 or name.endswith(("_critic_ln", "_bronet"))
        assert config.evaluation.stop_when_reached is not runs_on, name
        assert config.envs["fk"].options == {"reward_version": "v4" if v4 else "v3"}, name
        # 535 epochs x 280 steps = 149,800 env steps: within the 150k budget.
        assert config.protocol.epochs * config.envs["fk"].episode_length == 149_800
    for task in ("slide_cabinet", "light_switch", "bottom_left_burner"):
        plain, demos = configs[task], configs[f"{task}_demos"]
        assert plain.training.demo_episodes == 0 and demos.training.demo_episodes == 10
        assert dataclasses.replace(demos.training, demo_episodes=0) == plain.training
        assert (demos.agent, demos.envs, demos.evaluation) == (
            plain.agent,
            plain.envs,
            plain.evaluation,
        )
    for task in (
        "slide_cabinet",
        "light_switch",
        "bottom_left_burner",
        "microwave",
        "bottom_right_burner",
    ):
        v3, v4 = configs[task], configs[f"{task}_v4"]  # only the reward and stopping differ
        assert dataclasses.replace(v4.evaluation, stop_when_reached=True) == v3.evaluation
        assert (v4.agent, v4.training, v4.envs["fk"].tasks) == (
            v3.agent,
            v3.training,
            v3.envs["fk"].tasks,
        )
        assert v4.protocol.seeds == 3
        # The learner tests (issue 54; issue 37's collapse test on v4): one change to the arm,
        # with the v3 arm's stopping turned off as its records were made.
        for base in (task, f"{task}_v4"):
            plain, changed = configs[base], configs[f"{base}_critic_ln"]
            assert changed.agent == dataclasses.replace(plain.agent, critic_layer_norm=True)
            assert not plain.agent.critic_layer_norm
            assert (changed.training, changed.envs, changed.protocol.seeds) == (
                plain.training,
                plain.envs,
                3,
            )
            assert changed.evaluation == dataclasses.replace(
                plain.evaluation, stop_when_reached=False
            )
        # BroNet's learner test (issue 54 rule 3), on v3 only: the critic block is the one change.
        plain, bronet = configs[task], configs[f"{task}_bronet"]
        assert bronet.agent == dataclasses.replace(plain.agent, critic_block="bronet")
        assert (bronet.training, bronet.envs, bronet.protocol.seeds) == (
            plain.training,
            plain.envs,
            3,
        )
        assert bronet.evaluation == dataclasses.replace(plain.evaluation, stop_when_reached=False)
    with pytest.raises(SealError, match="unknown kitchen arm 'nope'"):
        arms(["nope"])


TINY = [
    "envs.fk.episode_length=5",
    "training.warmup_steps=0",
    "training.demo_episodes=1",
    "training.batch_per_task=4",
    "training.grad_steps_per_epoch=2",
    "evaluation.interval=1",
    "evaluation.episodes=1",
    "agent.hidden=[8]",
]
"""A kitchen arm shrunk to seconds: the plumbing only (epochs are each test's)."""


@pytest.mark.slow
def test_tiny_end_to_end(tmp_path, capsys) -> None:
    tiny = ["protocol.epochs=1", *TINY]
    result = run_kitchen_bench(seeds=1, out=tmp_path, overrides=tiny, only=["slide_cabinet_demos"])
    arm = result["arms"]["slide_cabinet_demos"]
    (figures,) = arm["per_seed"]
    # One epoch of 5 env steps and 2 updates of batch 4: 8 transitions; 5 demonstration steps aside.
    assert (figures["env_steps"], figures["grad_steps"]) == (5, 2)
    assert figures["updates_m"] == pytest.approx(8e-6)
    assert arm["demos"] == [{"episodes": 1, "env_steps": 5, "expert_success": 0.0}]
    assert not arm["learned_within_budget"] and result["goal"]["met"] is False
    assert result["goal"]["rewards_alone"]["met"] is None  # one arm of five run
    assert result["goal"]["v4"]["met"] is None
    # Its protocol stops at the first crossing; no v4 arm ran, so the reward test has nothing.
    assert arm["stop_when_reached"] is True
    assert result["reward_test"]["tasks"] == {} and result["reward_test"]["default"] is None
    assert "slide-cabinet + demos" in format_result(result)
    assert "reward test" not in format_result(result)
    # A second call, through the CLI with the same --set values, takes the finished run instead of
    # running it again.
    from seal.cli.main import main

    args = ["bench", "--learn", "kitchen", "--arms", "slide_cabinet_demos", "--seeds", "1"]
    args += ["--out", str(tmp_path), "--reuse", "--json"]
    assert main(args + [a for value in tiny for a in ("--set", value)]) == 0
    again = json.loads(capsys.readouterr().out)
    assert again["reused"] == ["slide_cabinet_demos/seed-0"] and again["overrides"] == tiny
    # A run record (the run without checkpoints/ and tb/, as results/ keeps one) is read by
    # --no-run, which runs nothing and names the seed it did not find.
    run = Path(result["run_dirs"]["slide_cabinet_demos/seed-0"])
    record = tmp_path / "records" / run.relative_to(tmp_path)
    shutil.copytree(run, record, ignore=shutil.ignore_patterns("checkpoints", "tb"))
    args[args.index("--out") + 1] = str(tmp_path / "records")
    args[args.index("--seeds") + 1] = "2"
    args[args.index("--reuse")] = "--no-run"
    assert main(args + [a for value in tiny for a in ("--set", value)]) == 0
    read = json.loads(capsys.readouterr().out)
    assert read["missing"] == ["slide_cabinet_demos/seed-1"]
    assert read["run_dirs"] == {"slide_cabinet_demos/seed-0": str(record)}
    assert read["arms"]["slide_cabinet_demos"]["per_seed"] == [{"seed": 0, **figures}]
    assert read["arms"]["slide_cabinet_demos"]["reached"] == "0/1"
    assert read["goal"]["met"] is False  # seed 0 already missed it
    assert sorted(p.name for p in record.parent.parent.rglob("seed-*")) == ["seed-0"]
    text = format_result(read)
    assert "s0 5+ (0.00)" in text
    assert "not run (--no-run found no finished run): slide_cabinet_demos/seed-1" in text
    assert main(["bench", "--learn", "table1", "--no-run"]) == 2
    assert "error: --no-run only applies to --learn kitchen" in capsys.readouterr().err


@pytest.mark.slow
def test_a_run_a_session_left_unfinished_is_resumed_not_restarted(tmp_path) -> None:
    """`--reuse` continues an unfinished run from its last checkpoint (`seal run --resume`) in
    its own directory, where it used to start the seed again from epoch 1."""
    tiny = ["protocol.epochs=2", "checkpoint.interval=1", *TINY]
    only = ["slide_cabinet_demos"]
    first = run_kitchen_bench(seeds=1, out=tmp_path, overrides=tiny, only=only)
    run = Path(first["run_dirs"]["slide_cabinet_demos/seed-0"])
    full = pd.read_csv(run / "metrics.csv")
    # As a session that ended during epoch 2 leaves it: no epoch-2 checkpoint, rows or end time.
    (run / "checkpoints" / "ckpt-0000002.pt").unlink()
    full[full["epoch"] < 2].to_csv(run / "metrics.csv", index=False)
    provenance = json.loads((run / "provenance.json").read_text())
    provenance["end_time"] = None
    (run / "provenance.json").write_text(json.dumps(provenance))
    logs: list[str] = []
    again = run_kitchen_bench(
        seeds=1, out=tmp_path, overrides=tiny, only=only, reuse=True, log=logs.append
    )
    assert any(line.startswith("resume slide_cabinet_demos seed 0") for line in logs), logs
    assert again["reused"] == [] and Path(again["run_dirs"]["slide_cabinet_demos/seed-0"]) == run
    resumed = pd.read_csv(run / "metrics.csv")
    assert resumed["epoch"].tolist() == full["epoch"].tolist()  # epoch 2 run again, once
    assert json.loads((run / "provenance.json").read_text())["end_time"]


RECORDS = Path(__file__).resolve().parents[1] / "results" / "kitchen_learn"
"""The committed records of the kitchen learning runs (results/README.md)."""


def test_every_committed_run_record_is_read_as_a_finished_run_of_todays_protocol() -> None:
    """A record that today's code would not take (a default changed under it, a file missing) is
    silently left out of `--no-run`'s table: this names it instead. The v3 arms ran with
    `evaluation.stop_when_reached=false`, as the issue-37 table sets them beside v4."""
    by_protocol = {arm_config(a).name: a for a in ARMS}
    records = sorted(RECORDS.glob("*/*/seed-*"))
    assert records, f"no run records under {RECORDS}"
    with warnings.catch_warnings():  # the v4 records' candidate-reward warning, expected here
        warnings.simplefilter("ignore", SealWarning)
        taken = {r: _taken(r, by_protocol) for r in records}
    for record, (arm, found) in taken.items():
        seed = int(record.name.removeprefix("seed-"))
        assert found == record, f"{record}: not taken as the finished run of {arm.name} seed {seed}"
        run = load_run(record)
        assert run.metrics["epoch"].max() == arm_config(arm).protocol.epochs  # stopping off
        assert run.provenance["reward_versions"] == {"franka_kitchen_dense": pinned_version(arm)}


def _taken(record: Path, by_protocol: dict) -> tuple:
    """(the record's arm, the run `--no-run` takes for its arm and seed)."""
    from seal.experiments.records import finished_run

    arm = by_protocol[record.parents[1].name]
    seed = int(record.name.removeprefix("seed-"))
    return arm, finished_run(arm, seed, RECORDS, ["evaluation.stop_when_reached=false"])
