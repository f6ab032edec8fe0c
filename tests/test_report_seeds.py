"""`seal report` over groups of several seeds written by hand: the batch-matched alone column,
seeds run one at a time, censored totals, a cell's CI and the curves' plots."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pandas as pd
import pytest

from seal.cli.main import main
from seal.reports import report
from seal.stats import change_ci, stratified_change_ci
from tests.report_groups import (
    CONFIGS,
    HIGH_FK,
    md_rows_of,
    md_table,
    write_group,
)

# ---- three seeds a group, with a batch-matched alone arm (protocols/matched/*): FK only, two
# tasks, 500 gradient steps an epoch. Each seed reaches 90% at the epoch given and stays there.
#   a: Single Env 0.064/epoch, epochs 3, 3, 3 -> 0.192 each; High FK 0.02/epoch, epochs 1, 1, 2
#      -> 0.02, 0.02, 0.04; matched 0.02/epoch, epochs 2, 3, 3 -> 0.04, 0.06, 0.06. Every High FK
#      seed is below its Single Env and its matched seed, so every paired resample is a decrease:
#      resolved against both, bold.
#   b: Single Env epochs 1, 2, 3 -> 0.064, 0.128, 0.192; High FK 0.05/epoch, epochs 1, 2, 4 ->
#      0.05, 0.1, 0.2 (mean -8.9%), but seed 2 alone gives 0.2 / 0.192 = +4.2%: the CI includes 0,
#      so the decrease is not bold.
MATCHED_CONFIG = (
    '[protocol]\nname = "high_fk_fk_alone"\nkind = "baseline"\n\n[envs.fk]\n'
    'adapter = "franka_kitchen_dense"\n\n[scheduler]\nkind = "stepped"\n'
    "start = { fk = 0.9, mw = 0.1 }\nstep = 0.1\ninterval = 1000\nabsent = { mw = 10 }\n"
)
THREE_SEEDS = {  # protocol -> task -> (updates per epoch, epoch each seed reaches)
    "baseline_fk": {"a": (0.064, (3, 3, 3)), "b": (0.064, (1, 2, 3))},
    "high_fk": {"a": (0.02, (1, 1, 2)), "b": (0.05, (1, 2, 4))},
    "high_fk_fk_alone": {"a": (0.02, (3, 3, 4)), "b": (0.05, (2, 2, 2))},
}


def _three_seed_groups(root: Path) -> list[Path]:
    CONFIGS.setdefault("high_fk_fk_alone", MATCHED_CONFIG)
    paths = []
    for protocol, tasks in THREE_SEEDS.items():
        runs = {}
        for seed in range(3):
            lines = []
            for epoch in range(1, 5):
                for task, (rate, reach) in tasks.items():
                    success = 0.95 if epoch >= reach[seed] else 0.1
                    updates = round(rate * epoch, 6)
                    lines.append(
                        f"{seed},train,{epoch},fk,{task},{success},1,{500 * epoch},"
                        f"{280 * epoch},{updates},{epoch}\n"
                    )
            runs[seed] = "".join(lines)
        paths.append(write_group(root, protocol, runs))
    return paths


def test_matched_alone_column_and_the_not_bold_rule(tmp_path: Path) -> None:
    result = report(_three_seed_groups(tmp_path / "reports"), out=tmp_path / "out")
    md = (tmp_path / "out" / "tables" / "update_counts.md").read_text()
    header, rows = md_table(md)
    assert header == ["Task", "Single Env", "Single Env (High FK batch)", "High FK"]
    counts = result.update_counts.set_index(["column", "env", "task"])
    a = counts.loc[("High FK", "fk", "a")]
    assert a["reference"] == "Single Env" and a["matched_reference"] == "Single Env (High FK batch)"
    assert a["paired"] and a["matched_paired"]  # the same seeds 0, 1, 2 in every group
    # Mean 0.02667 against 0.192 (-86.1%) and against 0.06667 (-60.0%).
    assert a["pct_change"] == pytest.approx(100 * (0.08 / 3 / 0.192 - 1))
    assert a["matched_pct_change"] == pytest.approx(-60.0)
    assert (a["pct_ci_low"], a["pct_ci_high"]) == pytest.approx(
        tuple(100 * v for v in change_ci([0.02, 0.02, 0.04], [0.192] * 3, paired=True))
    )
    assert a["resolved"] and a["matched_resolved"]
    # Fewer updates than both references, each resolved: the count is bold; 500, 500, 1000 steps
    # -> 666.7 steps x 40 transitions a step = 26,667.
    assert rows["a (FK)"][2] == "**0.02667 ± 0.01155** [3/3]"
    assert md_table(md, "Gradient steps × per-step batch")[1]["a (FK)"][2] == "666.7 × 40"
    # Fieller's ends are the ratios c at which scipy's paired t-test of arm - c * reference sits
    # at p = 0.05, found apart by root-finding (scipy.optimize.brentq on ttest_1samp): against
    # Single Env (0.192 in every seed), the t CI of 0.02667 +- 4.303 * 0.00667 over 0.192; against
    # the matched arm (0.06, 0.06, 0.08), -105.3% to -42.0%. Both resolved: bold.
    changes = (tmp_path / "out" / "tables" / "update_changes.md").read_text()
    change_rows = md_table(changes, "a (FK)")[1]
    assert change_rows["Single Env (High FK batch)"] == [
        "Single Env",
        "**-65.3%**",
        "**[-80.2, -50.3]**",
        "3",
    ]
    assert md_rows_of(changes, "a (FK)", "High FK") == [
        ["Single Env", "**-86.1%**", "**[-101.1, -71.2]**", "3"],
        ["matched", "**-60.0%**", "**[-105.3, -42.0]**", "3"],
    ]
    b = counts.loc[("High FK", "fk", "b")]
    assert b["pct_change"] == pytest.approx(100 * (0.35 / 0.384 - 1))
    # Single Env's b (0.064, 0.128, 0.192) is within t(0.975, 2 df) = 4.3 standard errors of 0:
    # no ratio is excluded, so no CI and nothing resolved.
    assert math.isnan(b["pct_ci_low"]) and not b["resolved"]
    assert not rows["b (FK)"][2].startswith("**")
    assert md_rows_of(changes, "b (FK)", "High FK")[0] == ["Single Env", "-8.9%", "[n/a]", "3"]
    # The matched arm is set against Single Env only: the batch's effect without the other env.
    matched_a = counts.loc[("Single Env (High FK batch)", "fk", "a")]
    assert matched_a["reference"] == "Single Env" and matched_a["matched_reference"] == ""
    # Totals: a stratified CI over the tasks both reached, against both references.
    total = result.totals.set_index(["column", "env"]).loc[("High FK", "fk")]
    assert total["shared_tasks"] == 2 and total["matched_shared_tasks"] == 2
    assert total["pct_change"] == pytest.approx(100 * ((0.08 / 3 + 0.35 / 3) / (0.192 + 0.128) - 1))
    # Against the matched arm: (0.02667 + 0.11667) / (0.06667 + 0.1) - 1 = -14.0%, with the CI of
    # the two tasks' seeds as strata, paired by seed.
    low, high = stratified_change_ci(
        {"a": [0.02, 0.02, 0.04], "b": [0.05, 0.10, 0.20]},
        {"a": [0.06, 0.06, 0.08], "b": [0.10, 0.10, 0.10]},
        paired=True,
    )
    assert md_rows_of(changes, "Total (FK)", "High FK")[1] == [
        "matched",
        "-14.0%",
        f"[{100 * low:+.1f}, {100 * high:+.1f}]",
        "3",
        "2",
    ]
    assert rows["Total (FK)"][2] == "0.1433 (2/2 tasks)"  # the count alone
    assert "Fewer than 3 seeds" not in changes
    assert "vs matched = against the arm's batch-matched alone arm" in changes


def test_seeds_run_one_at_a_time_make_one_column(tmp_path: Path) -> None:
    # `seal bench` runs each seed as its own `seal run --seeds s`: one group directory per seed.
    # Groups of one protocol and config whose seeds do not overlap are seeds of one column.
    root = tmp_path / "reports"
    for path in _three_seed_groups(root):
        for seed in (1, 2):
            (path.parent / f"g-seed{seed}").mkdir()
            (path / f"seed-{seed}").rename(path.parent / f"g-seed{seed}" / f"seed-{seed}")
    runs = [p for p in root.glob("*/*/seed-*") if "baseline" not in str(p)]
    result = report(runs, out=tmp_path / "out")
    counts = result.update_counts.set_index(["column", "env", "task"])
    assert set(counts.index.get_level_values("column")) == {"Single Env (High FK batch)", "High FK"}
    a = counts.loc[("High FK", "fk", "a")]
    assert (a["reached"], a["seeds"], a["matched_paired"]) == (3, 3, True)
    # Without a Single Env column the change against the matched arm is still there, and bold.
    md = (tmp_path / "out" / "tables" / "update_counts.md").read_text()
    assert "**0.02667 ± 0.01155** [3/3]" in md
    changes = (tmp_path / "out" / "tables" / "update_changes.md").read_text()
    assert md_rows_of(changes, "a (FK)", "High FK") == [
        ["matched", "**-60.0%**", "**[-105.3, -42.0]**", "3"]
    ]


def test_seeds_that_differ_in_what_they_save_or_log_still_make_one_column(tmp_path: Path) -> None:
    # The mtrl bench's seed 0 saved no replay, its later seeds did (to resume across sessions):
    # [checkpoint] and [logging] say what a run keeps, not what it learns. [training] does not.
    root = tmp_path / "reports"
    write_group(root, "high_fk", {0: HIGH_FK[0]}, group="g1")
    extra = {
        1: "[checkpoint]\ninterval = 25\nsave_replay = false\n",
        2: "[logging]\ntensorboard = false\n",
    }
    for seed, table in extra.items():
        group = write_group(root, "high_fk", {seed: HIGH_FK[0]}, group=f"g{seed + 1}")
        config = group / f"seed-{seed}" / "config.toml"
        config.write_text(config.read_text() + "\n" + table)
    groups = sorted((root / "high_fk").iterdir())
    result = report(groups, out=tmp_path / "o")
    counts = result.update_counts
    assert set(counts["column"]) == {"High FK"}
    assert set(counts["seeds"]) == {3}

    config = root / "high_fk" / "g3" / "seed-2" / "config.toml"
    config.write_text(config.read_text() + "\n[training]\nbatch_per_task = 64\n")
    split = report(groups, out=tmp_path / "o2")
    assert set(split.update_counts["column"]) == {"High FK [high_fk/g1]", "High FK [high_fk/g3]"}


def test_a_cells_ci_is_of_the_change_it_shows_when_a_seed_never_reached() -> None:
    from seal.reports.changes import _cell_change

    # Seed 2 of the arm never reached the task. The cell shows mean(1.0, 1.2) / mean(1, 1, 2) - 1
    # = 1.1 / 1.333 - 1 = -17.5%; pairing seeds 0 and 1 alone would give the CI of another
    # change, which can exclude it (seal bench --learn table1 printed "+19.8% [+0.0, +10.2]" so).
    arm = pd.DataFrame({"t": [1.0, 1.2, float("nan")]}, index=[0, 1, 2])
    base = pd.DataFrame({"t": [1.0, 1.0, 2.0]}, index=[0, 1, 2])
    low, high, paired, enough = _cell_change(arm, base, "t")
    assert not paired and not enough  # 2 seeds reached in the arm: nothing resolved
    assert low <= 100 * (1.1 / (4 / 3) - 1) <= high
    # The CI is the unpaired one of the seeds shown, not a paired one of seeds 0 and 1.
    assert (low, high) == pytest.approx(
        tuple(100 * v for v in change_ci([1.0, 1.2], [1.0, 1.0, 2.0], paired=False))
    )
    # Both reached in the same seeds: paired, as before.
    assert _cell_change(arm.fillna(1.1), base, "t")[2]


# Censoring through `seal report`, by hand. One Meta-World group of two seeds, three tasks, 0.1 M
# of each task's transitions per epoch; seed 0 runs 5 epochs (run total 0.5 M), seed 1 runs 4 (0.4).
#   drawer-close: seed 0 reaches at epoch 2 (0.2), seed 1 at epoch 3 (0.3) -> 0.25 [2/2]
#   reach:        seed 0 never (its run total 0.5), seed 1 at epoch 4 (0.4) -> 0.4 [1/2], censored
#   push:         never (run totals 0.5, 0.4) -> "— [0/2]", censored
# Total = 0.25 + (0.5 + 0.4) / 2 + (0.5 + 0.4) / 2 = 1.15, a lower bound: "≥ 1.15 (2/3 tasks, 2
# censored)". --censored zero: 0.25 + 0.4 + 0 = 0.65, "0.65 (2/3 tasks)".
def _censored_rows(seed: int, epochs: int, reach: dict[str, int]) -> str:
    return "".join(
        f"{seed},train,{epoch},mw,{task}-v3,{0.95 if epoch >= reach.get(task, 99) else 0.5},0,"
        f"{100 * epoch},{100 * epoch},{0.1 * epoch:.1f},{epoch}\n"
        for epoch in range(1, epochs + 1)
        for task in ("drawer-close", "reach", "push")
    )


def test_a_total_with_a_censored_task_is_a_lower_bound(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    runs = {
        0: _censored_rows(0, 5, {"drawer-close": 2}),
        1: _censored_rows(1, 4, {"drawer-close": 3, "reach": 4}),
    }
    group = write_group(tmp_path / "reports", "baseline_mw", runs)
    result = report([group], out=tmp_path / "out")
    md = (tmp_path / "out" / "tables" / "update_counts.md").read_text()
    rows = _first_column(md)
    assert rows["drawer-close-v3 (MW)"].startswith("0.25 ± 0.07071 [2/2]")
    assert rows["reach-v3 (MW)"].startswith("0.4 [1/2]")
    assert rows["push-v3 (MW)"] == "— [0/2]"
    assert rows["Total (MW)"] == "≥ 1.15 (2/3 tasks, 2 censored)"
    assert "censored" in md and "lower bound" in md

    csv = pd.read_csv(tmp_path / "out" / "tables" / "update_counts.csv").set_index("task")
    assert csv.loc["Total", "updates_total"] == pytest.approx(1.15)
    assert csv.loc["Total", "censored_tasks"] == 2
    assert (csv.loc["Total", "tasks_reached"], csv.loc["Total", "tasks"]) == (2, 3)
    assert csv.loc["reach-v3", "updates_bound"] == pytest.approx(0.45)
    assert list(csv.loc[["drawer-close-v3", "reach-v3", "push-v3"], "censored_tasks"]) == [0, 1, 1]
    assert result.to_json()["update_count_censored_tasks"] == {"Single Env": {"mw": 2}}
    tex = (tmp_path / "out" / "tables" / "update_counts.tex").read_text()
    assert r"$\geq$ 1.15 (2/3 tasks, 2 censored)" in tex

    # The paper's rule, behind --censored zero: never-reached counts 0, no bound is claimed.
    out = tmp_path / "zero"
    assert main(["report", str(group), "--out", str(out), "--censored", "zero", "--json"]) == 0
    payload = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert payload["update_count_totals"]["Single Env"]["mw"] == pytest.approx(0.65)
    assert payload["censored_rule"] == "zero"
    zero_md = (out / "tables" / "update_counts.md").read_text()
    assert _first_column(zero_md)["Total (MW)"] == "0.65 (2/3 tasks)"
    assert "≥" not in zero_md


def _first_column(md: str) -> dict[str, str]:
    """The first Markdown table's rows: Task -> its first column's cell."""
    rows: dict[str, str] = {}
    for line in md.splitlines():
        if line.startswith("|"):
            cells = [c.strip() for c in line.strip("|").split("|")]
            rows[cells[0]] = cells[1]
        elif rows:
            break
    return rows


def test_the_interval_plot_cuts_wide_cis_at_its_limits(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from seal.reports import plots

    saved = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: saved.append(fig) or path)
    rows = [
        plots.Interval("narrow", -20.0, -30.0, -10.0, mde=15.0, resolved=True),
        plots.Interval("wide", 40.0, -250.0, 13_000.0, mde=900.0),
    ]
    plots.plot_intervals([("t", rows)], tmp_path / "p.png", "x", "title", limits=(-100, 300))
    ax = saved[0].axes[0]
    # The axis is the limits padded by 3% of their span, not the wide row's -250..13,000.
    assert ax.get_xlim() == pytest.approx((-112.0, 312.0))
    # The wide row's CI is cut at both edges, each cut marked by an arrowhead at the edge.
    cuts = {(line.get_marker(), tuple(line.get_xdata())) for line in ax.lines}
    assert ("<", (-100.0,)) in cuts and (">", (300.0,)) in cuts
    # Its MDE band (+-900%) is cut to the axis too: one bar from -100 to +300.
    bars = [(p.get_x(), p.get_width()) for p in ax.patches]
    assert (-100.0, 400.0) in bars and (-15.0, 30.0) in bars
    # Without limits nothing is cut.
    plots.plot_intervals([("t", rows)], tmp_path / "q.png", "x", "title")
    assert not any(line.get_marker() in "<>" for line in saved[1].axes[0].lines)


def test_a_run_that_stopped_once_learned_holds_its_last_value_in_the_curve(
    tmp_path: Path,
) -> None:
    """Seed 0 stopped at epoch 1 (every task reached); seed 1 ran on. Past epoch 1 the mean curve
    is (1.00 + seed 1's) / 2 when the runs stop when reached, and seed 1's alone when they don't
    (a run cut short for another reason is not imputed)."""
    from seal.reports.groups import _gather, _labelled
    from seal.reports.plots import success_curves

    rows = {
        0: "0,train,1,mw,drawer-close-v3,1.00,1,500,500,0.064,1\n",
        1: "1,train,1,mw,drawer-close-v3,0.00,1,500,500,0.064,1\n"
        "1,train,2,mw,drawer-close-v3,0.40,1,1000,1000,0.128,2\n"
        "1,train,3,mw,drawer-close-v3,0.95,1,1500,1500,0.192,3\n",
    }
    means = {}
    for stops in (True, False):
        CONFIGS["stopping"] = (
            CONFIGS["baseline_mw"] + f"\n[evaluation]\nstop_when_reached = {str(stops).lower()}\n"
        )
        try:
            group = write_group(tmp_path / str(stops), "stopping", rows)
        finally:
            del CONFIGS["stopping"]
        metrics = _labelled(_gather([group]), "metrics")
        curve = success_curves(metrics, "epoch").set_index("epoch")
        means[stops] = curve["mean"].round(6).tolist()
        assert curve["seeds"].tolist() == ([2, 2, 2] if stops else [2, 1, 1])
    assert means[True] == [0.5, 0.7, 0.975]
    assert means[False] == [0.5, 0.4, 0.95]
