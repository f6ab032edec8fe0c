"""protocols/table1_small and `seal bench --learn table1`: the arms, their batches, and the plumbing end to end."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pandas as pd
import pytest

from seal.errors import SealError
from seal.experiments.table1 import ARMS, REFERENCES, TABLE1, arms, format_result, run_table1_bench
from seal.protocols import load_protocol
from seal.schedulers import Progress
from seal.schedulers.registry import build_scheduler

ADAPTERS = {"mw": "metaworld", "fk": "franka_kitchen_dense"}
TASKS = {"mw": ("drawer-close-v3",), "fk": ("slide-cabinet",)}


def _counts(name: str, epoch: int) -> dict[str, list[int]]:
    """The per-task batch of one update of arm `name` at `epoch`, as the runner draws it."""
    config = load_protocol(TABLE1 / f"{name}.toml")
    envs = list(config.envs)
    scheduler = build_scheduler(
        config.scheduler, {e: TASKS[e] for e in envs}, adapters={e: ADAPTERS[e] for e in envs}
    )
    total = config.training.batch_per_task * len(envs)  # the runner's: batch_per_task x its tasks
    plan = scheduler.plan(Progress(epoch=epoch))
    return {e: c.tolist() for e, c in plan.batch_counts(total).items()}


def test_every_arm_resolves_with_one_network_budget_and_evaluation() -> None:
    tables = {}
    for arm in ARMS:
        config = load_protocol(arm.protocol)
        raw = tomllib.loads(arm.protocol.read_text())
        assert config.agent.architecture == "seal", arm.name
        assert config.protocol.epochs == 150 and config.training.grad_steps_per_epoch == 100
        assert {e: tuple(c.tasks) for e, c in config.envs.items()} == {
            e: TASKS[e] for e in config.envs
        }
        tables[arm.name] = {k: raw[k] for k in ("agent", "training", "evaluation")}
        # Demonstrations for the kitchen only: 30 episodes; drawer-close learns from none.
        assert {e: config.demo_episodes(e) for e in config.envs} == {
            e: {"mw": 0, "fk": 30}[e] for e in config.envs
        }
        # Every kitchen gets the same reward version.
        if "fk" in config.envs:
            assert raw["envs"]["fk"]["options"] == tables.get("_fk", raw["envs"]["fk"]["options"])
            tables["_fk"] = raw["envs"]["fk"]["options"]
    first = tables["single_mw"]
    assert all(t == first for n, t in tables.items() if n != "_fk")


@pytest.mark.parametrize("joint", ["high_fk", "high_mw"])
@pytest.mark.parametrize("env", ["mw", "fk"])
def test_matched_alone_draws_the_joint_runs_batch_every_epoch(joint: str, env: str) -> None:
    alone = f"{joint}_{env}_alone"
    assert list(load_protocol(TABLE1 / f"{alone}.toml").envs) == [env]
    for epoch in range(150):
        assert _counts(alone, epoch) == {env: _counts(joint, epoch)[env]}, epoch
    # By hand, epoch 0 (90/10 of 256): 230.4 and 25.6 floor to 230 + 25; the one left over goes
    # to the larger remainder, .6: the low env draws 26. From epoch 60 on (4 steps of 10 points
    # every 15 epochs) both draw 128.
    high, low = ("fk", "mw") if joint == "high_fk" else ("mw", "fk")
    assert _counts(joint, 0) == {high: [230], low: [26]} or _counts(joint, 0) == {
        low: [26],
        high: [230],
    }
    assert _counts(joint, 15)[low] == [51]  # 20% of 256 = 51.2
    assert _counts(joint, 60) == {"mw": [128], "fk": [128]}
    assert _counts(alone, 149) == {env: [128]}


def test_single_env_is_50_50s_batch_matched_arm() -> None:
    for epoch in (0, 75, 149):
        joint = _counts("joint_50_50", epoch)
        assert _counts("single_mw", epoch) == {"mw": joint["mw"]} == {"mw": [128]}
        assert _counts("single_fk", epoch) == {"fk": joint["fk"]} == {"fk": [128]}


def test_arms_adds_the_arms_a_column_is_set_against() -> None:
    assert [a.name for a in arms(["high_fk"])] == [
        "single_mw",
        "single_fk",
        "high_fk",
        "high_fk_mw_alone",
        "high_fk_fk_alone",
    ]
    assert len(arms()) == len(ARMS) == 9
    assert set(REFERENCES) == {"joint_50_50", "high_fk", "high_mw"}
    with pytest.raises(SealError, match="unknown table1 arm 'nope'"):
        arms(["nope"])


TINY = [
    "protocol.epochs=2",
    "training.warmup_steps=0",
    "training.grad_steps_per_epoch=2",
    "training.demo_episodes=1",
    "evaluation.interval=1",
    "evaluation.episodes=1",
    "agent.translator_hidden=[8]",
    "agent.latent_dim=8",
    "agent.trunk_hidden=[8]",
    "agent.critic_hidden=[8]",
]


@pytest.mark.slow
def test_tiny_end_to_end(tmp_path: Path) -> None:
    # One seed of High FK and its references, 2 epochs of 2 updates, 8-wide: the plumbing only.
    result = run_table1_bench(seeds=1, out=tmp_path, parallel=2, overrides=TINY, only=["high_fk"])
    assert len(result["run_dirs"]) == 5 and result["reused"] == []
    metrics = {
        key: pd.read_csv(Path(path) / "metrics.csv") for key, path in result["run_dirs"].items()
    }
    joint = metrics["high_fk/seed-0"].set_index(["epoch", "env"])
    matched = metrics["high_fk_mw_alone/seed-0"].set_index(["epoch", "env"])
    # 4 updates of 26 drawer-close transitions (10% of 256, rounded up by the larger remainder):
    # 104 transitions, in the joint run and in its batch-matched alone arm alike.
    assert joint.loc[(2, "mw"), "batch"] == matched.loc[(2, "mw"), "batch"] == 26
    assert joint.loc[(2, "mw"), "updates"] == matched.loc[(2, "mw"), "updates"] == 104e-6
    assert joint.loc[(2, "fk"), "updates"] == pytest.approx(4 * 230e-6)
    single = metrics["single_mw/seed-0"].set_index("epoch")
    assert single.loc[2, "updates"] == pytest.approx(4 * 128e-6)
    # The table is `seal report`'s, with the paper's columns and the batch-matched ones.
    for column in ("Single Env", "High FK", "Single Env (High FK batch)"):
        assert column in result["table"], column
    assert {c["column"] for c in result["cells"]} == {
        "Single Env",
        "High FK",
        "Single Env (High FK batch)",
    }
    # Beside it, the changes table and the report's plots (changes with their MDE, success).
    assert "# Changes against the reference columns" in result["table"]
    assert {Path(p).name for p in result["plots"]} >= {"changes_mw.png", "success_mw.png"}
    text = format_result(result)
    assert "1 seeds of 5 arms" in text and "budget 5400 s with >= 5 seeds: not met" in text
    assert result["budget"]["met"] is False  # one seed is fewer than the budget's five


def test_cli_rejects_set_outside_protocol_and_the_learning_sets(capsys) -> None:
    from seal.cli.main import main

    # The speed benches (no --protocol, no --learn set) take no protocol overrides.
    for args in (["bench"], ["bench", "--learn"]):
        assert main([*args, "--set", "protocol.epochs=2"]) == 2
        assert (
            "--set only applies to --protocol and to --learn transfer, table1, quickstart, "
            "reach_sb3, kitchen, mtrl and learner" in capsys.readouterr().err
        )


def _run_metrics(env: str, task: str, points: list[tuple[int, float]]) -> pd.DataFrame:
    """A run's evaluation rows: (gradient steps, success) of one task."""
    return pd.DataFrame(
        {
            "epoch": range(1, len(points) + 1),
            "env": env,
            "task": task,
            "grad_steps": [g for g, _ in points],
            "success": [s for _, s in points],
        }
    )


def test_auc_changes_pair_by_seed_and_keep_a_censored_seed() -> None:
    from seal.experiments.table1 import auc_changes, format_auc

    fk, task = "fk", "slide-cabinet"
    runs = {
        # Budget 400 (the longest run). Single Env seed 0: 0, 0 at 200, 1 at 400 -> area 100/400.
        ("single_fk", 0): _run_metrics(fk, task, [(0, 0.0), (200, 0.0), (400, 1.0)]),
        # seed 1 never reaches: 0, 0.5 at 200, 0.5 at 400 -> (50 + 100) / 400 = 0.375.
        ("single_fk", 1): _run_metrics(fk, task, [(0, 0.0), (200, 0.5), (400, 0.5)]),
        # High FK seed 0 stops at 200 on 1.0, held to 400: (100 + 200) / 400 = 0.75.
        ("high_fk", 0): _run_metrics(fk, task, [(0, 0.0), (200, 1.0)]),
        # seed 1: 0, 1.0 at 100 (stops), held: (50 + 300) / 400 = 0.875.
        ("high_fk", 1): _run_metrics(fk, task, [(0, 0.0), (100, 1.0)]),
        # seed 2 has no Single Env run to pair with: left out.
        ("high_fk", 2): _run_metrics(fk, task, [(0, 0.0), (100, 1.0)]),
    }
    (row,) = auc_changes(runs)
    assert (row["arm"], row["vs"], row["task"], row["seeds"]) == (
        "high_fk",
        "single_fk",
        task,
        [0, 1],
    )
    assert row["auc_arm"] == pytest.approx((0.75 + 0.875) / 2)
    assert row["auc_vs"] == pytest.approx((0.25 + 0.375) / 2)
    assert row["auc_diff_per_seed"] == pytest.approx([0.5, 0.5])
    # Two equal differences: SD 0, so the CI is the point and the MDE 0.
    assert row["auc_diff_ci95"] == pytest.approx([0.5, 0.5]) and row["sd_paired_auc"] == 0.0
    text = format_auc([row])
    assert (
        "| slide-cabinet | High FK | Single Env | 0.812 | 0.312 | +0.500 | [+0.500, +0.500] | 2 |"
        in text
    )
    assert max(len(line) for line in text.splitlines()) <= 100
