"""`seal.load_run`, `seal.reports.report` and `seal report` on run directories written by hand."""

from __future__ import annotations

import json
import math
from pathlib import Path

import matplotlib.image
import numpy as np
import pandas as pd
import pytest

import seal
from seal.cli.main import main
from seal.errors import SealError
from seal.reports import RunData, column_label, load_run, report
from seal.stats import change_ci, mde, stratified_change_ci

HEADER = "seed,phase,epoch,env,task,success,return,grad_steps,env_steps,updates,wall_s\n"
TRAIN_HEADER = "seed,phase,epoch,grad_steps,env,key,value\n"

# ---- baseline_mw/g1: MTMHSAC on Meta-World, 2 seeds. Constant batch: 128 per task per step,
# 500 steps per epoch -> 0.064 M of each task's transitions per epoch.
#   drawer-close: seed 0 reaches 0.9 at epoch 2 (0.128), seed 1 at epoch 3 (0.192)
#                 -> mean 0.16, sample std 0.032 * sqrt(2) = 0.04525, [2/2]
#   reach:        seed 0 at epoch 3 (0.192), seed 1 never -> 0.192 [1/2]
#   Total (MW) = 0.16 + 0.192 = 0.352, 2/2 tasks.
BASELINE_MW = {
    0: """0,train,1,mw,drawer-close-v3,0.50,10,500,500,0.064,1
0,train,1,mw,reach-v3,0.10,5,500,500,0.064,1
0,train,2,mw,drawer-close-v3,0.92,20,1000,1000,0.128,2
0,train,2,mw,reach-v3,0.40,6,1000,1000,0.128,2
0,train,3,mw,drawer-close-v3,1.00,30,1500,1500,0.192,3
0,train,3,mw,reach-v3,0.90,7,1500,1500,0.192,3
""",
    1: """1,train,1,mw,drawer-close-v3,0.30,10,500,500,0.064,1
1,train,1,mw,reach-v3,0.10,5,500,500,0.064,1
1,train,2,mw,drawer-close-v3,0.60,20,1000,1000,0.128,2
1,train,2,mw,reach-v3,0.20,6,1000,1000,0.128,2
1,train,3,mw,drawer-close-v3,0.94,30,1500,1500,0.192,3
1,train,3,mw,reach-v3,0.50,7,1500,1500,0.192,3
""",
}

# ---- baseline_fk/g1: one seed. slide-cabinet reaches at epoch 3 (0.192); microwave never.
BASELINE_FK = {
    0: """0,train,1,fk,slide-cabinet,0.20,1,500,280,0.064,1
0,train,1,fk,microwave,0.00,1,500,280,0.064,1
0,train,2,fk,slide-cabinet,0.50,1,1000,560,0.128,2
0,train,2,fk,microwave,0.10,1,1000,560,0.128,2
0,train,3,fk,slide-cabinet,0.95,1,1500,840,0.192,3
0,train,3,fk,microwave,0.20,1,1500,840,0.192,3
""",
}

# ---- high_fk/g1: joint, 2 seeds, stepped ratio -> uneven `updates`:
# MW tasks 0.02, 0.05, 0.09 M; FK tasks 0.10, 0.18, 0.24 M after epochs 1, 2, 3.
#   drawer-close: seed 0 epoch 1 (0.02), seed 1 epoch 2 (0.05) -> mean 0.035, std 0.015*sqrt2
#                 = 0.02121; vs 0.16: (0.035 - 0.16) / 0.16 = -78.125% -> bold "-78.1%"
#   reach:        never -> "— [0/2]"
#   slide-cabinet: seed 0 epoch 2 (0.18), seed 1 epoch 1 (0.10) -> mean 0.14, std 0.04*sqrt2
#                 = 0.05657; vs 0.192: (0.14 - 0.192) / 0.192 = -27.083% -> "-27.1%"
#   microwave:    seed 0 epoch 3 (0.24), seed 1 never -> 0.24 [1/2]; baseline never -> "n/a"
#   Total (MW) = 0.035 (1/2 tasks), Total (FK) = 0.14 + 0.24 = 0.38 (2/2 tasks).
HIGH_FK = {
    0: """0,train,1,mw,drawer-close-v3,0.95,1,500,500,0.02,1
0,train,1,mw,reach-v3,0.10,1,500,500,0.02,1
0,train,1,fk,slide-cabinet,0.20,1,500,280,0.10,1
0,train,1,fk,microwave,0.10,1,500,280,0.10,1
0,train,2,mw,drawer-close-v3,1.00,1,1000,1000,0.05,2
0,train,2,mw,reach-v3,0.30,1,1000,1000,0.05,2
0,train,2,fk,slide-cabinet,0.91,1,1000,560,0.18,2
0,train,2,fk,microwave,0.50,1,1000,560,0.18,2
0,train,3,mw,drawer-close-v3,1.00,1,1500,1500,0.09,3
0,train,3,mw,reach-v3,0.50,1,1500,1500,0.09,3
0,train,3,fk,slide-cabinet,1.00,1,1500,840,0.24,3
0,train,3,fk,microwave,0.90,1,1500,840,0.24,3
""",
    1: """1,train,1,mw,drawer-close-v3,0.50,1,500,500,0.02,1
1,train,1,mw,reach-v3,0.10,1,500,500,0.02,1
1,train,1,fk,slide-cabinet,0.90,1,500,280,0.10,1
1,train,1,fk,microwave,0.00,1,500,280,0.10,1
1,train,2,mw,drawer-close-v3,0.90,1,1000,1000,0.05,2
1,train,2,mw,reach-v3,0.20,1,1000,1000,0.05,2
1,train,2,fk,slide-cabinet,1.00,1,1000,560,0.18,2
1,train,2,fk,microwave,0.10,1,1000,560,0.18,2
1,train,3,mw,drawer-close-v3,1.00,1,1500,1500,0.09,3
1,train,3,mw,reach-v3,0.40,1,1500,1500,0.09,3
1,train,3,fk,slide-cabinet,1.00,1,1500,840,0.24,3
1,train,3,fk,microwave,0.30,1,1500,840,0.24,3
""",
}

# ---- finetune_fk_to_mw/g1: one seed. Pre-train on FK, then fine-tune on MW; counts and
# gradient steps restart at the fine-tune phase.
#   Pre-train on FK: slide-cabinet at epoch 2 (0.128); vs 0.192 -> -33.3%. microwave never.
#   Fine-tune on MW: drawer-close at fine-tune epoch 1 (0.064, 500 grad steps); vs 0.16 -> -60.0%.
FINETUNE = {
    0: """0,pretrain,1,fk,slide-cabinet,0.40,1,500,280,0.064,1
0,pretrain,1,fk,microwave,0.00,1,500,280,0.064,1
0,pretrain,2,fk,slide-cabinet,0.95,1,1000,560,0.128,2
0,pretrain,2,fk,microwave,0.00,1,1000,560,0.128,2
0,finetune,1,mw,drawer-close-v3,0.91,1,500,500,0.064,3
0,finetune,1,mw,reach-v3,0.00,1,500,500,0.064,3
0,finetune,2,mw,drawer-close-v3,1.00,1,1000,1000,0.128,4
0,finetune,2,mw,reach-v3,0.20,1,1000,1000,0.128,4
""",
}

ENVS = '[envs.mw]\nadapter = "metaworld"\ntasks = ["drawer-close-v3", "reach-v3"]\n\n[envs.fk]\nadapter = "franka_kitchen_dense"\n'
CONFIGS = {
    "baseline_mw": '[protocol]\nname = "baseline_mw"\nkind = "baseline"\n\n[envs.mw]\nadapter = "metaworld"\n',
    "baseline_fk": '[protocol]\nname = "baseline_fk"\nkind = "baseline"\n\n[envs.fk]\nadapter = "franka_kitchen_dense"\n',
    "high_fk": f'[protocol]\nname = "high_fk"\nkind = "joint"\n\n{ENVS}\n[scheduler]\nkind = "stepped"\npreset = "high_fk"\n',
    "finetune_fk_to_mw": f'[protocol]\nname = "finetune_fk_to_mw"\nkind = "finetune"\n\n{ENVS}\n[finetune]\nsource = "fk"\ntarget = "mw"\n',
}

# Critic losses logged every epoch, per environment (Fig. 7).
TRAIN = {
    "baseline_mw": "{s},train,1,500,mw,critic_loss,{a}\n{s},train,2,1000,mw,critic_loss,{b}\n{s},train,2,1000,mw,actor_loss,-3.0\n"
    # The critic probe at each evaluation (issue 54): Q at the first states over what was earned.
    "{s},train,1,500,mw,eval_q_ratio/drawer-close-v3,{a}\n{s},train,2,1000,mw,eval_q_ratio/drawer-close-v3,{b}\n"
    "{s},train,1,500,mw,eval_q_ratio/reach-v3,{b}\n{s},train,2,1000,mw,eval_q_ratio/reach-v3,{a}\n",
    "high_fk": "{s},train,1,500,mw,critic_loss,{a}\n{s},train,1,500,fk,critic_loss,{b}\n{s},train,2,1000,mw,critic_loss,{b}\n{s},train,2,1000,fk,critic_loss,{a}\n",
}


def _write_group(root: Path, protocol: str, runs: dict[int, str], group: str = "g1") -> Path:
    group_dir = root / protocol / group
    for seed, rows in runs.items():
        run = group_dir / f"seed-{seed}"
        run.mkdir(parents=True)
        (run / "config.toml").write_text(CONFIGS[protocol])
        (run / "metrics.csv").write_text(HEADER + rows)
        provenance = {
            "git_sha": "abc",
            "seed": seed,
            "protocol": protocol,
            "group": group,
            "kind": "x",
        }
        (run / "provenance.json").write_text(json.dumps(provenance))
        if protocol in TRAIN:
            (run / "train.csv").write_text(
                TRAIN_HEADER + TRAIN[protocol].format(s=seed, a=2.0 + seed, b=1.0 + seed)
            )
    return group_dir


@pytest.fixture()
def groups(tmp_path: Path) -> dict[str, Path]:
    root = tmp_path / "reports"
    return {
        "baseline_mw": _write_group(root, "baseline_mw", BASELINE_MW),
        "baseline_fk": _write_group(root, "baseline_fk", BASELINE_FK),
        "high_fk": _write_group(root, "high_fk", HIGH_FK),
        "finetune": _write_group(root, "finetune_fk_to_mw", FINETUNE),
    }


def _assert_png(path: Path) -> None:
    assert path.is_file() and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    image = matplotlib.image.imread(path)
    assert image.shape[0] > 200 and image.shape[1] > 300
    assert image.std() > 0.01  # something was drawn, not a blank canvas


def test_load_run_reads_all_files(groups: dict[str, Path]) -> None:
    run = seal.load_run(groups["high_fk"] / "seed-1")
    assert isinstance(run, RunData)
    assert run.metrics.shape == (12, 11)
    assert run.metrics["success"].dtype.kind == "f"
    assert run.train["key"].tolist() == ["critic_loss"] * 4
    assert run.config["scheduler"]["preset"] == "high_fk"
    assert (run.protocol, run.kind, run.group, run.seed) == ("high_fk", "joint", "g1", 1)
    assert run.provenance["git_sha"] == "abc"
    assert run.env_label("mw") == "MW" and run.env_label("fk") == "FK"


def test_load_run_without_optional_files(groups: dict[str, Path]) -> None:
    run_dir = groups["baseline_fk"] / "seed-0"
    (run_dir / "provenance.json").unlink()
    run = load_run(run_dir)
    assert run.train.empty and list(run.train.columns) == [
        "seed",
        "phase",
        "epoch",
        "grad_steps",
        "env",
        "key",
        "value",
    ]
    assert run.provenance == {}
    assert (run.group, run.seed) == ("g1", 0)  # from the directory names and metrics.csv


def test_bad_paths_name_the_path(tmp_path: Path, groups: dict[str, Path]) -> None:
    with pytest.raises(SealError, match=r"nowhere does not exist; expected a run directory"):
        load_run(tmp_path / "nowhere")
    with pytest.raises(SealError, match=r"neither a run nor a group directory.*pass those"):
        report([groups["baseline_mw"].parent])  # the protocol directory, one level too high
    run = groups["baseline_mw"] / "seed-0"
    (run / "metrics.csv").write_text("seed,phase,epoch\n0,train,1\n")
    with pytest.raises(SealError, match=r"seed-0/metrics.csv: missing column\(s\) \['env', 'task'"):
        load_run(run)
    (run / "metrics.csv").write_text(HEADER + "0,train,1,mw,reach-v3,high,1,1,1,0.1,1\n")
    with pytest.raises(SealError, match=r"column 'success' has non-numeric values"):
        load_run(run)
    (run / "metrics.csv").write_text(HEADER + BASELINE_MW[0])
    (run / "config.toml").write_text("[protocol\n")
    with pytest.raises(SealError, match=r"config.toml: not valid TOML"):
        load_run(run)


def _md_table(md: str, section: str = "") -> tuple[list[str], dict[str, list[str]]]:
    """The table under **section** of a Markdown document (the first one for ""), its column
    chunks joined again: (header, {first cell: the other cells})."""
    header: list[str] = []
    rows: dict[str, list[str]] = {}
    heading = ""
    for block in md.split("\n\n"):
        lines = block.strip().splitlines()
        if len(lines) == 1 and lines[0].startswith("**") and lines[0].endswith("**"):
            heading = lines[0].strip("*")
            continue
        if heading != section or not lines or not lines[0].startswith("|"):
            continue
        cells = [[c.strip() for c in line.strip("|").split("|")] for line in lines]
        header = header + cells[0][1:] if header else cells[0]
        for row in cells[2:]:
            rows.setdefault(row[0], []).extend(row[1:])
    return header, rows


def _md_rows_of(md: str, section: str, arm: str) -> list[list[str]]:
    """Every row of the table under **section** whose first cell is `arm`, without that cell."""
    block = md.split(f"**{section}**\n\n", 1)[1].split("\n\n", 1)[0]
    cells = [[c.strip() for c in line.strip("|").split("|")] for line in block.splitlines()[2:]]
    return [row[1:] for row in cells if row[0] == arm]


def _longest_line(path: Path) -> int:
    return max(len(line) for line in path.read_text().splitlines())


def test_report_lays_out_the_papers_table(tmp_path: Path, groups: dict[str, Path]) -> None:
    out = tmp_path / "out"
    result = report(list(groups.values()), out=out)
    assert result.out_dir == out and result.threshold == 0.9

    counts = result.update_counts.set_index(["column", "env", "task"])
    assert counts.loc[("Single Env", "mw", "drawer-close-v3"), "updates_mean"] == pytest.approx(
        0.16
    )
    assert counts.loc[("High FK", "mw", "drawer-close-v3"), "pct_change"] == pytest.approx(-78.125)
    assert counts.loc[("High FK", "fk", "slide-cabinet"), "pct_change"] == pytest.approx(
        -27.0833333
    )
    assert math.isnan(
        counts.loc[("High FK", "fk", "microwave"), "pct_change"]
    )  # baseline never reached
    assert counts.loc[
        ("Fine-tune on MW", "mw", "drawer-close-v3"), "updates_mean"
    ] == pytest.approx(0.064)
    assert counts.loc[("Fine-tune on MW", "mw", "drawer-close-v3"), "grad_steps_mean"] == 500
    assert counts.loc[("Pre-train on FK", "fk", "slide-cabinet"), "pct_change"] == pytest.approx(
        -100 / 3
    )

    md = (out / "tables" / "update_counts.md").read_text()
    header, rows = _md_table(md)
    assert header == ["Task", "Single Env", "High FK", "Fine-tune on MW", "Pre-train on FK"]
    # Meta-World rows first, then the kitchen, then one total per environment. A cell holds the
    # count alone: its changes are rows of update_changes.md, its steps x batch a table below.
    assert list(rows) == [
        "drawer-close-v3 (MW)",
        "reach-v3 (MW)",
        "slide-cabinet (FK)",
        "microwave (FK)",
        "Total (MW)",
        "Total (FK)",
    ]
    assert rows["drawer-close-v3 (MW)"] == [
        "0.16 ± 0.04525 [2/2]",
        "0.035 ± 0.02121 [2/2]",
        "0.064 [1/1]",
        "",
    ]
    assert rows["reach-v3 (MW)"] == ["0.192 [1/2]", "— [0/2]", "— [0/1]", ""]
    assert rows["slide-cabinet (FK)"] == ["0.192 [1/1]", "0.14 ± 0.05657 [2/2]", "", "0.128 [1/1]"]
    assert rows["microwave (FK)"] == ["— [0/1]", "0.24 [1/2]", "", "— [0/1]"]
    # Every total holds a censored task, counted at its run total (the metrics' last `updates`):
    # Single Env MW 0.16 + reach (0.192 + seed 1's 0.192) / 2 = 0.352; FK 0.192 + microwave's 0.192;
    # High FK MW 0.035 + reach's 0.09; FK 0.14 + microwave (0.24 + seed 1's 0.24) / 2 = 0.38;
    # Fine-tune 0.064 + reach's 0.128; Pre-train 0.128 + microwave's 0.128.
    assert rows["Total (MW)"] == [
        "≥ 0.352 (2/2 tasks, 1 censored)",
        "≥ 0.125 (1/2 tasks, 1 censored)",
        "≥ 0.192 (1/2 tasks, 1 censored)",
        "",
    ]
    assert rows["Total (FK)"] == [
        "≥ 0.384 (1/2 tasks, 1 censored)",
        "≥ 0.38 (2/2 tasks, 1 censored)",
        "",
        "≥ 0.256 (1/2 tasks, 1 censored)",
    ]
    # Five columns do not fit 100 characters: the table is split, the Task column in each part.
    assert md.count("| Task ") == 3 and _longest_line(out / "tables" / "update_counts.md") <= 100
    # Gradient steps x per-step batch, e.g. 750 steps x 46.67 = 35,000 transitions.
    _, steps = _md_table(md, "Gradient steps × per-step batch")
    assert steps["drawer-close-v3 (MW)"] == ["1250 × 128", "750 × 46.67", "500 × 128", ""]
    assert steps["microwave (FK)"] == ["—", "1500 × 160", "", "—"]
    assert "— = never reached 90% in any seed" in md

    # The changes: one row per (task, arm, reference). Two seeds a group: nothing is bold,
    # whatever the CI (MIN_SEEDS_RESOLVED = 3). High FK and Single Env ran seeds 0 and 1 on MW, so
    # drawer-close is paired by seed: 0.035/0.16 - 1 = -78.1%. Its CI is [n/a]: Single Env's
    # 0.128 and 0.192 put its mean within t(0.975, 1 df) = 12.7 standard errors (0.032) of 0, so
    # Fieller's set of ratios is unbounded, as it should be from 2 seeds.
    changes = (out / "tables" / "update_changes.md").read_text()
    assert _longest_line(out / "tables" / "update_changes.md") <= 100
    header, rows = _md_table(changes, "drawer-close-v3 (MW)")
    assert header == ["Arm", "vs", "Change", "95% CI", "n"]
    assert rows["High FK"] == ["Single Env", "-78.1%", "[n/a]", "2"]
    assert rows["Fine-tune on MW"] == ["Single Env", "-60.0%", "[n/a]", "1 vs 2"]
    _, rows = _md_table(changes, "slide-cabinet (FK)")
    assert rows["High FK"] == ["Single Env", "-27.1%", "[n/a]", "2 vs 1"]  # one baseline seed
    assert rows["Pre-train on FK"] == ["Single Env", "-33.3%", "[n/a]", "1"]
    _, rows = _md_table(changes, "microwave (FK)")
    assert rows["High FK"] == ["Single Env", "n/a", "[n/a]", "1 vs 0"]
    header, rows = _md_table(changes, "Total (MW)")
    assert header[-1] == "tasks"
    assert rows["High FK"] == ["Single Env", "-78.1%", "[n/a]", "2", "1"]
    assert "| **" not in changes  # no change bold: too few seeds
    assert "Fewer than 3 seeds in" in changes and "against or of them is resolved" in changes
    # The pairing note lists comparisons with a CI; drawer-close's is [n/a], so its pairing shows
    # in its n alone ("2", one number: paired).
    assert "Paired by seed: High FK vs Single Env (MW)" not in changes
    frame = pd.read_csv(out / "tables" / "update_changes.csv")
    paired = frame.set_index(["task", "column"]).loc[("drawer-close-v3", "High FK")]
    # Per seed 0.02 / 0.128 - 1 = -84.375% and 0.05 / 0.192 - 1 = -73.958%: SD 7.366 points.
    assert paired["sd_paired_pct"] == pytest.approx(np.std([-84.375, -73.958333], ddof=1))
    assert paired["mde_pct"] == pytest.approx(mde(paired["sd_paired_pct"], 2))
    assert math.isnan(
        frame.set_index(["task", "column"]).loc[("slide-cabinet", "High FK")]["mde_pct"]
    )

    tex = (out / "tables" / "update_counts.tex").read_text()
    assert r"0.035 $\pm$ 0.02121 [2/2]" in tex and r"750 $\times$ 46.67" in tex
    assert r"\textbf" not in tex and r"\begin{tabular}" in tex
    assert "drawer-close-v3 (MW)" in tex and "--- [0/2]" in tex
    assert r"-78.1\%" in (out / "tables" / "update_changes.tex").read_text()

    csv = pd.read_csv(out / "tables" / "update_counts.csv")
    assert set(csv.columns) >= {
        "column",
        "env",
        "task",
        "updates_mean",
        "updates_std",
        "reached",
        "seeds",
        "pct_change",
    }
    # 4 Single Env + 4 High FK + 2 Pre-train + 2 Fine-tune task rows, then a Total per (column, env).
    assert len(csv) == 12 + 6
    assert sorted(csv.loc[csv["task"] == "Total", "censored_tasks"]) == [1] * 6
    per_seed = pd.read_csv(out / "tables" / "update_counts_per_seed.csv")
    assert len(per_seed) == 4 + 2 + 8 + 4  # (column, seed, env, task) rows

    # Final success: High FK slide-cabinet ends at 1.0 in both seeds; microwave (0.9 + 0.3) / 2 = 0.6.
    success = pd.read_csv(out / "tables" / "success.csv").set_index(["column", "env", "task"])
    assert success.loc[("High FK", "fk", "slide-cabinet"), "success_mean"] == pytest.approx(1.0)
    assert success.loc[("High FK", "fk", "microwave"), "success_mean"] == pytest.approx(0.6)
    assert (out / "tables" / "success.md").is_file() and (out / "tables" / "success.tex").is_file()

    assert sorted(p.name for p in result.plots) == [
        "changes_fk.png",
        "changes_mw.png",
        "critic_loss.png",
        "critic_overestimation.png",
        "success_fk.png",
        "success_mw.png",
    ]
    for plot in result.plots:
        _assert_png(plot)


def test_single_group_writes_into_the_group(groups: dict[str, Path]) -> None:
    result = report([groups["high_fk"]], x="epoch")
    assert result.out_dir == groups["high_fk"]
    assert (groups["high_fk"] / "tables" / "update_counts.md").is_file()
    _assert_png(groups["high_fk"] / "plots" / "success_mw.png")
    # Without a baseline there is no change: no changes table, and no interval plot.
    md = (groups["high_fk"] / "tables" / "update_counts.md").read_text()
    assert "0.035 ± 0.02121 [2/2]" in md and "%)" not in md
    assert not (groups["high_fk"] / "tables" / "update_changes.md").exists()
    assert not list((groups["high_fk"] / "plots").glob("changes_*"))


def test_single_run_writes_into_the_run(groups: dict[str, Path]) -> None:
    run = groups["baseline_fk"] / "seed-0"
    result = report([run])
    assert result.out_dir == run and (run / "tables" / "update_counts.csv").is_file()
    assert result.skipped == [
        "critic_loss.png: no critic_loss rows in the runs' train.csv",
        "critic_overestimation.png: no eval_q_ratio rows in the runs' train.csv "
        "(runs from before the critic probe, or rewards that earn nothing positive)",
    ]


def test_several_groups_default_to_a_new_comparison_directory(groups: dict[str, Path]) -> None:
    """Each report of several groups without --out makes a directory of its own (why it needs no
    lock: docs/faults.md)."""
    first = report([groups["baseline_mw"], groups["high_fk"]])
    second = report([groups["baseline_mw"], groups["high_fk"]])
    parent = groups["baseline_mw"].parent.parent / "comparison" / "baseline_mw+high_fk"
    assert first.out_dir.parent == parent == second.out_dir.parent
    assert first.out_dir != second.out_dir
    assert (first.out_dir / "tables" / "update_counts.md").is_file()
    assert (second.out_dir / "tables" / "update_counts.md").is_file()


def test_two_baselines_for_one_env_is_an_error(tmp_path: Path, groups: dict[str, Path]) -> None:
    other = _write_group(tmp_path / "reports", "baseline_mw", {0: BASELINE_MW[0]}, group="g2")
    with pytest.raises(SealError, match=r"several baseline groups for environment 'mw'"):
        report([groups["baseline_mw"], other], out=tmp_path / "o")


def test_two_groups_of_one_variant_get_group_labels(
    tmp_path: Path, groups: dict[str, Path]
) -> None:
    other = _write_group(tmp_path / "reports", "high_fk", {0: HIGH_FK[0]}, group="g2")
    result = report([groups["high_fk"], other], out=tmp_path / "o")
    assert set(result.update_counts["column"]) == {"High FK [high_fk/g1]", "High FK [high_fk/g2]"}


def test_threshold_changes_the_counts(tmp_path: Path, groups: dict[str, Path]) -> None:
    # At 0.5: baseline_mw reach-v3 seed 1 reaches at epoch 3 (0.50) too -> [2/2], mean 0.192.
    result = report([groups["baseline_mw"]], out=tmp_path / "o", threshold=0.5)
    row = result.update_counts.set_index("task").loc["reach-v3"]
    assert (row["reached"], row["updates_mean"]) == (2, pytest.approx(0.192))
    with pytest.raises(SealError, match="threshold 1.5 is not a success rate"):
        report([groups["baseline_mw"]], out=tmp_path / "o", threshold=1.5)


def _run(
    run_cfg: str,
    kind_metrics: str = "0,train,1,mw,a,0.5,0,1,1,0.1,0\n0,train,1,fk,b,0.5,0,1,1,0.1,0\n0,train,1,fk,c,0.5,0,1,1,0.1,0\n0,train,1,fk,d,0.5,0,1,1,0.1,0\n",
) -> RunData:
    import io
    import tomllib

    metrics = pd.read_csv(io.StringIO(HEADER + kind_metrics))
    return RunData(
        path=Path("/r/p/g/seed-0"),
        metrics=metrics,
        train=pd.DataFrame(),
        config=tomllib.loads(run_cfg),
    )


@pytest.mark.parametrize(
    ("config", "phase", "env", "label"),
    [
        ('[protocol]\nname="b"\nkind="baseline"', "train", "mw", "Single Env"),
        (
            '[protocol]\nname="mt10_smt"\nkind="baseline"\n[scheduler]\nkind="smt"',
            "train",
            "mw",
            "mt10_smt",
        ),
        (
            '[protocol]\nname="j"\nkind="joint"\n[envs.mw]\n[envs.fk]\n[scheduler]\nkind="constant"\nratio={mw=0.5, fk=0.5}',
            "train",
            "mw",
            "50/50",
        ),
        (
            '[protocol]\nname="j"\nkind="joint"\n[envs.mw]\n[envs.fk]\n[scheduler]\nkind="constant"\nratio=0.7',
            "train",
            "fk",
            "70/30",
        ),
        (
            '[protocol]\nname="j"\nkind="joint"\n[envs.mw]\n[envs.fk]\n[scheduler]\nkind="constant"',
            "train",
            "fk",
            "50/50",
        ),
        (
            '[protocol]\nname="j"\nkind="joint"\n[envs.mw]\n[envs.fk]\n[scheduler]\nkind="constant"\nratios={mw=0.25, fk=0.75}',
            "train",
            "fk",
            "25/75",
        ),
        # Uniform over tasks: 1 mw task and 3 fk tasks in metrics.csv -> 25/75.
        ('[protocol]\nname="j"\nkind="joint"\n[envs.mw]\n[envs.fk]', "train", "fk", "25/75"),
        (
            '[protocol]\nname="j"\nkind="joint"\n[envs.mw]\n[envs.fk]\nadapter="franka_kitchen_dense"\n[scheduler]\nkind="stepped"\nstart={mw=0.2, fk=0.8}',
            "train",
            "fk",
            "High FK",
        ),
        (
            '[protocol]\nname="j"\nkind="joint"\n[scheduler]\nkind="high_fk"',
            "train",
            "mw",
            "High FK",
        ),
        (
            '[protocol]\nname="j"\nkind="joint"\n[scheduler]\nkind="stepped"\npreset="high_mw"',
            "train",
            "mw",
            "High MW",
        ),
        ('[protocol]\nname="jsmt"\nkind="joint"\n[scheduler]\nkind="smt"', "train", "mw", "jsmt"),
        (
            '[protocol]\nname="f"\nkind="finetune"\n[envs.mw]\nadapter="metaworld"',
            "pretrain",
            "mw",
            "Pre-train on MW",
        ),
        (
            '[protocol]\nname="f"\nkind="finetune"\n[envs.k]\nadapter="franka_kitchen_dense"',
            "finetune",
            "k",
            "Fine-tune on FK",
        ),
        ('[protocol]\nname="f"\nkind="finetune"', "finetune", "point", "Fine-tune on point"),
    ],
)
def test_column_labels(config: str, phase: str, env: str, label: str) -> None:
    assert column_label(_run(config), phase, env) == label


def test_cli_report_json(
    tmp_path: Path, groups: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "cli"
    code = main(
        [
            "report",
            str(groups["baseline_mw"]),
            str(groups["high_fk"] / "seed-0"),
            str(groups["high_fk"] / "seed-1"),
            "--json",
            "--out",
            str(out),
        ]
    )
    assert code == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 1
    payload = json.loads(lines[0])
    assert payload["out_dir"] == str(out)
    dc = payload["update_counts"]["High FK"]["mw"]["drawer-close-v3"]
    assert dc["mean"] == pytest.approx(0.035) and dc["reached"] == 2 and dc["seeds"] == 2
    assert dc["pct_change"] == pytest.approx(-78.125)
    assert payload["update_counts"]["High FK"]["mw"]["reach-v3"]["std"] is None
    assert payload["update_count_totals"]["Single Env"]["mw"] == pytest.approx(0.352)
    assert Path(payload["tables"]["update_counts.md"]).is_file()
    assert all(Path(p).is_file() for p in payload["plots"])
    (change,) = [
        c
        for c in payload["changes"]
        if (c["task"], c["column"], c["vs"]) == ("drawer-close-v3", "High FK", "Single Env")
    ]
    assert change["pct_change"] == pytest.approx(-78.125)
    assert (change["paired"], change["n_column"], change["resolved"]) == (True, 2, False)
    assert Path(payload["tables"]["update_changes.md"]).is_file()


def test_cli_report_bad_path_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["report", str(tmp_path / "missing")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("seal report: error: ") and "missing does not exist" in err


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
        paths.append(_write_group(root, protocol, runs))
    return paths


def test_matched_alone_column_and_the_not_bold_rule(tmp_path: Path) -> None:
    result = report(_three_seed_groups(tmp_path / "reports"), out=tmp_path / "out")
    md = (tmp_path / "out" / "tables" / "update_counts.md").read_text()
    header, rows = _md_table(md)
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
    assert _md_table(md, "Gradient steps × per-step batch")[1]["a (FK)"][2] == "666.7 × 40"
    # Fieller's ends are the ratios c at which scipy's paired t-test of arm - c * reference sits
    # at p = 0.05, found apart by root-finding (scipy.optimize.brentq on ttest_1samp): against
    # Single Env (0.192 in every seed), the t CI of 0.02667 +- 4.303 * 0.00667 over 0.192; against
    # the matched arm (0.06, 0.06, 0.08), -105.3% to -42.0%. Both resolved: bold.
    changes = (tmp_path / "out" / "tables" / "update_changes.md").read_text()
    change_rows = _md_table(changes, "a (FK)")[1]
    assert change_rows["Single Env (High FK batch)"] == [
        "Single Env",
        "**-65.3%**",
        "**[-80.2, -50.3]**",
        "3",
    ]
    assert _md_rows_of(changes, "a (FK)", "High FK") == [
        ["Single Env", "**-86.1%**", "**[-101.1, -71.2]**", "3"],
        ["matched", "**-60.0%**", "**[-105.3, -42.0]**", "3"],
    ]
    b = counts.loc[("High FK", "fk", "b")]
    assert b["pct_change"] == pytest.approx(100 * (0.35 / 0.384 - 1))
    # Single Env's b (0.064, 0.128, 0.192) is within t(0.975, 2 df) = 4.3 standard errors of 0:
    # no ratio is excluded, so no CI and nothing resolved.
    assert math.isnan(b["pct_ci_low"]) and not b["resolved"]
    assert not rows["b (FK)"][2].startswith("**")
    assert _md_rows_of(changes, "b (FK)", "High FK")[0] == ["Single Env", "-8.9%", "[n/a]", "3"]
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
    assert _md_rows_of(changes, "Total (FK)", "High FK")[1] == [
        "matched",
        "-14.0%",
        f"[{100 * low:+.1f}, {100 * high:+.1f}]",
        "3",
        "2",
    ]
    assert rows["Total (FK)"][2] == "0.1433 (2/2 tasks)"  # the count alone
    assert "Fewer than 3 seeds" not in changes
    assert "vs matched = against the arm's batch-matched alone arm" in changes


def test_cli_report_consecutive(
    tmp_path: Path, groups: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    # High FK microwave: seed 0 reaches 0.9 only at its last evaluation, seed 1 never, so with 2
    # successive evaluations required no seed reaches it; slide-cabinet's seeds stay at epochs 2, 1.
    def counts(*extra: str) -> dict:
        out = tmp_path / f"cli{len(extra)}"
        assert main(["report", str(groups["high_fk"]), "--json", "--out", str(out), *extra]) == 0
        return json.loads(capsys.readouterr().out)["update_counts"]["High FK"]["fk"]

    assert counts()["microwave"]["reached"] == 1
    robust = counts("--consecutive", "2")
    assert robust["microwave"]["reached"] == 0
    assert robust["slide-cabinet"]["mean"] == pytest.approx(0.14)
    assert main(["report", str(groups["high_fk"]), "--consecutive", "0"]) == 2
    assert "consecutive" in capsys.readouterr().err


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
    assert _md_rows_of(changes, "a (FK)", "High FK") == [
        ["matched", "**-60.0%**", "**[-105.3, -42.0]**", "3"]
    ]


def test_seeds_that_differ_in_what_they_save_or_log_still_make_one_column(tmp_path: Path) -> None:
    # The mtrl bench's seed 0 saved no replay, its later seeds did (to resume across sessions):
    # [checkpoint] and [logging] say what a run keeps, not what it learns. [training] does not.
    root = tmp_path / "reports"
    _write_group(root, "high_fk", {0: HIGH_FK[0]}, group="g1")
    extra = {
        1: "[checkpoint]\ninterval = 25\nsave_replay = false\n",
        2: "[logging]\ntensorboard = false\n",
    }
    for seed, table in extra.items():
        group = _write_group(root, "high_fk", {seed: HIGH_FK[0]}, group=f"g{seed + 1}")
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


def test_reward_versions_are_compared_only_for_adapters_the_runs_have(
    tmp_path: Path, groups: dict[str, Path]
) -> None:
    def record(group: Path, version: str) -> None:
        for provenance in group.glob("seed-*/provenance.json"):
            data = json.loads(provenance.read_text())
            data["reward_versions"] = {"franka_kitchen_dense": version}
            provenance.write_text(json.dumps(data))

    # Older runs recorded the kitchen's version whatever they ran: baseline_mw has no kitchen.
    record(groups["baseline_mw"], "v2")
    record(groups["baseline_fk"], "v3")
    record(groups["high_fk"], "v3")
    result = report(
        [groups["baseline_mw"], groups["baseline_fk"], groups["high_fk"]], out=tmp_path / "o"
    )
    assert not any("reward version" in w for w in result.warnings)
    record(groups["high_fk"], "v2")
    result = report([groups["baseline_fk"], groups["high_fk"]], out=tmp_path / "o2")
    assert any("reward version of franka_kitchen_dense" in w for w in result.warnings)


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


def test_cli_report_prints_the_counts_and_the_changes(
    tmp_path: Path, groups: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    paths = [str(groups["baseline_mw"]), str(groups["high_fk"])]
    assert main(["report", *paths, "--out", str(tmp_path / "o")]) == 0
    printed = capsys.readouterr().out
    assert "# Millions of updates to reach 90% success" in printed
    assert "# Changes against the reference columns" in printed
    assert "**drawer-close-v3 (MW)**" in printed


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
    group = _write_group(tmp_path / "reports", "baseline_mw", runs)
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
            group = _write_group(tmp_path / str(stops), "stopping", rows)
        finally:
            del CONFIGS["stopping"]
        metrics = _labelled(_gather([group]), "metrics")
        curve = success_curves(metrics, "epoch").set_index("epoch")
        means[stops] = curve["mean"].round(6).tolist()
        assert curve["seeds"].tolist() == ([2, 2, 2] if stops else [2, 1, 1])
    assert means[True] == [0.5, 0.7, 0.975]
    assert means[False] == [0.5, 0.4, 0.95]
