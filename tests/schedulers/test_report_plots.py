"""`seal.reports.report` draws a run's scheduler timeline (pool membership, SMT budget usage)."""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import pandas as pd
from png_colours import colours_drawn

from seal.protocols import load_protocol
from seal.reports import report
from seal.run.runner import run_seed
from seal.schedulers.plots import STATUS_COLOURS

BODY = """
[protocol]
kind = "baseline"
epochs = {epochs}
seeds = 1
device = "cpu"
threads = 1
[envs.pt]
adapter = "point"
episode_length = 10
[agent]
hidden = [8, 8]
[training]
warmup_steps = 0
batch_per_task = 4
collector = "sync"
[evaluation]
interval = 5
episodes = 1
[logging]
tensorboard = false
"""
SMT = """
[scheduler]
kind = "smt"
budget_stage1 = 120
budget_stage2 = 20
slots = 2
reset_interval = 1000
score_interval = 1000
score_episodes = 1
"""


def test_report_plots_smt_membership_and_budget_usage(tmp_path: Path) -> None:
    path = tmp_path / "smt.toml"
    path.write_text(BODY.format(epochs=100) + SMT)
    run = run_seed(load_protocol(path), 0, tmp_path / "r" / "smt" / "g").run_dir
    assert (run / "scheduler.csv").is_file()
    result = report([run], out=tmp_path / "out")
    plots = tmp_path / "out" / "plots"
    assert plots / "scheduler_membership.png" in result.plots
    assert plots / "scheduler_budget.png" in result.plots
    # Each pool the timeline visited is drawn in its colour; one line per task in the budget plot.
    timeline = pd.read_csv(run / "scheduler.csv")
    pools = {STATUS_COLOURS[s.split(":")[-1]] for s in timeline["status"].astype(str)}
    assert len(pools) >= 2
    assert colours_drawn(plots / "scheduler_membership.png", sorted(pools)) == pools
    cycle = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    tasks = timeline.groupby(["env", "task"]).ngroups
    assert colours_drawn(plots / "scheduler_budget.png", cycle[:tasks]) == set(cycle[:tasks])


def test_report_without_a_scheduler_timeline_draws_no_scheduler_plot(tmp_path: Path) -> None:
    path = tmp_path / "plain.toml"
    path.write_text(BODY.format(epochs=2))
    run = run_seed(load_protocol(path), 0, tmp_path / "r" / "plain" / "g").run_dir
    # The default (uniform) scheduler logs one snapshot with every task at weight 1: nothing to draw.
    assert (run / "scheduler.csv").is_file()
    result = report([run], out=tmp_path / "out")
    assert not [p for p in result.plots if p.name.startswith("scheduler")]
    assert not list((tmp_path / "out" / "plots").glob("scheduler*"))
