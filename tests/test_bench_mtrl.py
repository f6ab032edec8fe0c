"""`seal bench --learn mtrl` (issue 57): SMT Table 1's learners at laptop scale, with their speed."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from seal.errors import SealError
from seal.experiments.mtrl import ARMS, arms, crossings, format_result, run_mtrl_bench
from seal.experiments.records import finished_runs
from seal.protocols import load_protocol
from tests.report_groups import HEADER

TINY = [
    "protocol.epochs=2",
    "envs.mw.episode_length=10",
    "training.warmup_steps=0",
    "training.batch_per_task=4",
    "evaluation.interval=1",
    "evaluation.episodes=1",
    "agent.hidden=[8]",
]


def test_every_arm_differs_from_the_reference_only_in_its_learner() -> None:
    ref = load_protocol(ARMS[0].protocol)
    for arm in ARMS:
        config = load_protocol(arm.protocol)
        assert config.envs == ref.envs and config.training == ref.training
        # 300 epochs x 150 env steps a task: the 45,000 a task of docs/smt_table1.md, one update
        # per env step (2 tasks x 150)
        assert config.evaluation == ref.evaluation and config.protocol.epochs == 300
        assert config.training.grad_steps_per_epoch == 300
        assert config.protocol.column == arm.label  # its column in the report
    assert [a.name for a in arms(["paco"])] == ["sac_mt_mh", "paco"]  # the reference comes too
    with pytest.raises(SealError, match="unknown mtrl arm 'nope'"):
        arms(["nope"])


def test_crossings_are_each_tasks_env_steps_at_its_first_evaluation_at_90(tmp_path: Path) -> None:
    run = tmp_path / "seed-0"
    run.mkdir()
    (run / "config.toml").write_text('[protocol]\nname = "p"\n')
    (run / "provenance.json").write_text(json.dumps({"seed": 0}))
    (run / "metrics.csv").write_text(
        HEADER
        + "0,train,1,mw,reach-v3,0.95,1,150,1500,0.001,1\n"
        + "0,train,1,mw,drawer-close-v3,0.5,1,150,1500,0.001,1\n"
        + "0,train,2,mw,reach-v3,0.5,1,300,3000,0.002,2\n"
        + "0,train,2,mw,drawer-close-v3,0.9,1,300,3000,0.002,2\n"
    )
    assert crossings({0: run}) == {0: {"reach-v3": 1500, "drawer-close-v3": 3000}}


@pytest.mark.slow
def test_tiny_end_to_end(tmp_path: Path) -> None:
    # One seed of PaCo and the reference, 2 epochs at 8 wide: the plumbing only.
    result = run_mtrl_bench(seeds=1, out=tmp_path, parallel=2, overrides=TINY, only=["paco"])
    assert list(result["learners"]) == ["sac_mt_mh", "paco"]
    for learner in result["learners"].values():
        assert learner["seeds"] == 1 and learner["every_task_90"] in (0, 1)
        assert set(learner["first_crossing_env_steps"]["0"]) == {
            "drawer-close-v3",
            "handle-press-v3",
        }
        assert learner["updates_per_s"] > 0
    assert result["learners"]["sac_mt_mh"]["speed_vs_reference"] == 1.0
    assert "| SAC-MT-MH" in result["by_task_table"] and "| PaCo" in result["by_task_table"]
    text = format_result(result)
    assert "PaCo" in text and "updates/s (x SAC-MT-MH)" in text
    assert result["missing"] == [] and "not run" not in text

    # --no-run over two seeds takes the finished seed 0 and names seed 1 of both arms.
    read = run_mtrl_bench(seeds=2, out=tmp_path, overrides=TINY, only=["paco"], run=False)
    assert read["missing"] == ["sac_mt_mh/seed-1", "paco/seed-1"]
    for name, learner in read["learners"].items():
        ran = result["learners"][name]
        assert learner["seeds"] == 1 and learner["run_dirs"] == ran["run_dirs"]
        assert learner["first_crossing_env_steps"] == ran["first_crossing_env_steps"]
    assert "not run (--no-run found no finished run): sac_mt_mh/seed-1, paco/seed-1" in (
        format_result(read)
    )


def test_no_run_without_a_finished_run_says_so_and_writes_nothing(tmp_path: Path) -> None:
    with pytest.raises(SealError, match=r"holds no finished run of these arms \(seeds 0-2\)"):
        run_mtrl_bench(seeds=3, out=tmp_path, only=["paco"], run=False)
    assert list(tmp_path.iterdir()) == []


RECORDS = Path(__file__).resolve().parents[1] / "results" / "mtrl_learn"
"""The committed records of `seal bench --learn mtrl` (docs/smt_table1.md)."""


def test_every_committed_record_is_read_as_a_finished_run_of_todays_protocol() -> None:
    """A record that today's code would not take (a default changed under it, a file missing) is
    silently left out of `--no-run`'s table: this names it instead."""
    by_protocol = {load_protocol(a.protocol).name: a for a in ARMS}
    records = sorted(RECORDS.glob("*/*/seed-*"))
    assert records, f"no run records under {RECORDS}"
    for record in records:
        arm = by_protocol[record.parents[1].name]
        seed = int(record.name.removeprefix("seed-"))
        taken = finished_runs([(arm, seed)], RECORDS)
        assert taken == {(arm.name, seed): record}, f"{record}: not taken as {arm.name} seed {seed}"
