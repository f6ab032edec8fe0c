"""`seal.load_run`, `seal.reports.report` and `seal report` on run directories written by hand."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import seal
from seal.cli.main import main
from seal.errors import SealError
from seal.reports import RunData, column_label, load_run, report
from seal.stats import mde
from tests.report_groups import (
    BASELINE_FK,
    BASELINE_MW,
    FINETUNE,
    HEADER,
    HIGH_FK,
    assert_png,
    longest_line,
    md_table,
    run_data,
    write_group,
)


@pytest.fixture()
def groups(tmp_path: Path) -> dict[str, Path]:
    root = tmp_path / "reports"
    return {
        "baseline_mw": write_group(root, "baseline_mw", BASELINE_MW),
        "baseline_fk": write_group(root, "baseline_fk", BASELINE_FK),
        "high_fk": write_group(root, "high_fk", HIGH_FK),
        "finetune": write_group(root, "finetune_fk_to_mw", FINETUNE),
    }


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


@pytest.mark.parametrize("cut", [1, 20, 60, -2])
def test_a_row_cut_by_a_kill_is_left_out(groups: dict[str, Path], cut: int) -> None:
    """A kill mid-write leaves the last row without its newline: it is dropped wherever it was
    cut (in the env, the task or the numbers), and the rows before it read as they were."""
    run = groups["high_fk"] / "seed-1"
    whole = (run / "metrics.csv").read_text()
    last = whole.rstrip("\n").rsplit("\n", 1)[1]
    (run / "metrics.csv").write_text(whole + last[:cut])
    got = load_run(run).metrics
    (run / "metrics.csv").write_text(whole)
    pd.testing.assert_frame_equal(got, load_run(run).metrics)
    assert len(got) == 12


def test_a_row_without_its_task_names_the_line(groups: dict[str, Path]) -> None:
    run = groups["high_fk"] / "seed-1"
    lines = (run / "metrics.csv").read_text().splitlines(keepends=True)
    cells = lines[3].split(",")
    cells[4] = ""  # the task
    (run / "metrics.csv").write_text("".join([*lines[:3], ",".join(cells), *lines[4:]]))
    with pytest.raises(SealError, match=r"seed-1/metrics.csv: line 4 has no 'task'"):
        load_run(run)


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
    header, rows = md_table(md)
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
    assert md.count("| Task ") == 3 and longest_line(out / "tables" / "update_counts.md") <= 100
    # Gradient steps x per-step batch, e.g. 750 steps x 46.67 = 35,000 transitions.
    _, steps = md_table(md, "Gradient steps × per-step batch")
    assert steps["drawer-close-v3 (MW)"] == ["1250 × 128", "750 × 46.67", "500 × 128", ""]
    assert steps["microwave (FK)"] == ["—", "1500 × 160", "", "—"]
    assert "— = never reached 90% in any seed" in md

    # The changes: one row per (task, arm, reference). Two seeds a group: nothing is bold,
    # whatever the CI (MIN_SEEDS_RESOLVED = 3). High FK and Single Env ran seeds 0 and 1 on MW, so
    # drawer-close is paired by seed: 0.035/0.16 - 1 = -78.1%. Its CI is [n/a]: Single Env's
    # 0.128 and 0.192 put its mean within t(0.975, 1 df) = 12.7 standard errors (0.032) of 0, so
    # Fieller's set of ratios is unbounded, as it should be from 2 seeds.
    changes = (out / "tables" / "update_changes.md").read_text()
    assert longest_line(out / "tables" / "update_changes.md") <= 100
    header, rows = md_table(changes, "drawer-close-v3 (MW)")
    assert header == ["Arm", "vs", "Change", "95% CI", "n"]
    assert rows["High FK"] == ["Single Env", "-78.1%", "[n/a]", "2"]
    assert rows["Fine-tune on MW"] == ["Single Env", "-60.0%", "[n/a]", "1 vs 2"]
    _, rows = md_table(changes, "slide-cabinet (FK)")
    assert rows["High FK"] == ["Single Env", "-27.1%", "[n/a]", "2 vs 1"]  # one baseline seed
    assert rows["Pre-train on FK"] == ["Single Env", "-33.3%", "[n/a]", "1"]
    _, rows = md_table(changes, "microwave (FK)")
    assert rows["High FK"] == ["Single Env", "n/a", "[n/a]", "1 vs 0"]
    header, rows = md_table(changes, "Total (MW)")
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
        assert_png(plot)


def test_single_group_writes_into_the_group(groups: dict[str, Path]) -> None:
    result = report([groups["high_fk"]], x="epoch")
    assert result.out_dir == groups["high_fk"]
    assert (groups["high_fk"] / "tables" / "update_counts.md").is_file()
    assert_png(groups["high_fk"] / "plots" / "success_mw.png")
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
    other = write_group(tmp_path / "reports", "baseline_mw", {0: BASELINE_MW[0]}, group="g2")
    with pytest.raises(SealError, match=r"several baseline groups for environment 'mw'"):
        report([groups["baseline_mw"], other], out=tmp_path / "o")


def test_two_groups_of_one_variant_get_group_labels(
    tmp_path: Path, groups: dict[str, Path]
) -> None:
    other = write_group(tmp_path / "reports", "high_fk", {0: HIGH_FK[0]}, group="g2")
    result = report([groups["high_fk"], other], out=tmp_path / "o")
    assert set(result.update_counts["column"]) == {"High FK [high_fk/g1]", "High FK [high_fk/g2]"}


def test_threshold_changes_the_counts(tmp_path: Path, groups: dict[str, Path]) -> None:
    # At 0.5: baseline_mw reach-v3 seed 1 reaches at epoch 3 (0.50) too -> [2/2], mean 0.192.
    result = report([groups["baseline_mw"]], out=tmp_path / "o", threshold=0.5)
    row = result.update_counts.set_index("task").loc["reach-v3"]
    assert (row["reached"], row["updates_mean"]) == (2, pytest.approx(0.192))
    with pytest.raises(SealError, match="threshold 1.5 is not a success rate"):
        report([groups["baseline_mw"]], out=tmp_path / "o", threshold=1.5)


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
    assert column_label(run_data(config), phase, env) == label


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


def test_cli_report_mistakes_leave_no_directory_and_no_lock(
    tmp_path: Path, groups: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "a.png").write_text("a file")
    (tmp_path / "notes").mkdir()
    group = str(groups["baseline_mw"])
    before = sorted(p.name for p in groups["baseline_mw"].iterdir())
    for argv, says in [
        ([group, "--out", str(tmp_path / "a.png")], "a.png is a file, not a directory"),
        ([group, "--out", str(tmp_path / "new"), "--threshold", "2"], "threshold 2.0 is not"),
        ([str(tmp_path / "notes")], "neither a run nor a group directory"),
        ([group, "--consecutive", "0"], "consecutive = 0: expected a whole number"),
    ]:
        assert main(["report", *argv]) == 2
        err = capsys.readouterr().err
        assert err.startswith("seal report: error: ") and says in err, err
    assert not (tmp_path / "new").exists()
    assert not any((tmp_path / "notes").iterdir())  # no .seal.lock left in the user's folder
    assert sorted(p.name for p in groups["baseline_mw"].iterdir()) == before  # no plots/ tables/
    # Refused while the runs are read, after the lock: the --out it made is removed again.
    twin = write_group(tmp_path / "reports", "baseline_mw", BASELINE_MW, group="g2")
    assert main(["report", group, str(twin), "--out", str(tmp_path / "both")]) == 2
    assert "several baseline groups" in capsys.readouterr().err
    assert not (tmp_path / "both").exists()


def test_a_report_that_fails_midway_leaves_no_new_out_and_no_lock(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Not only a refused input: a bug or a Ctrl-C while the tables are written removes the new
    --out, and the lock and folders a report made in a group directory."""
    import seal.reports

    def half_written(paths: list[str], out: str | None = None, **_: object) -> None:
        target = Path(out) if out else Path(paths[0])
        (target / "tables").mkdir(parents=True, exist_ok=True)
        (target / "tables" / "update_counts.md").write_text("| half |")
        raise KeyboardInterrupt

    monkeypatch.setattr(seal.reports, "report", half_written)
    group = write_group(tmp_path / "reports", "baseline_mw", BASELINE_MW, group="fresh")
    before = sorted(p.name for p in group.iterdir())
    assert "tables" not in before
    assert main(["report", str(group), "--out", str(tmp_path / "new")]) == 130  # interrupted
    assert not (tmp_path / "new").exists()
    monkeypatch.setattr(seal.reports, "report", half_written)  # now into the group itself
    assert main(["report", str(group)]) == 130
    assert sorted(p.name for p in group.iterdir()) == before  # no lock, no tables/ it began


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


def test_cli_report_prints_the_counts_and_the_changes(
    tmp_path: Path, groups: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    paths = [str(groups["baseline_mw"]), str(groups["high_fk"])]
    assert main(["report", *paths, "--out", str(tmp_path / "o")]) == 0
    printed = capsys.readouterr().out
    assert "# Millions of updates to reach 90% success" in printed
    assert "# Changes against the reference columns" in printed
    assert "**drawer-close-v3 (MW)**" in printed


def test_a_seed_without_evaluation_rows_is_named_not_dropped_silently(tmp_path: Path) -> None:
    group = write_group(tmp_path / "reports", "baseline_mw", {**BASELINE_MW, 2: ""})
    result = report([group], out=tmp_path / "o")
    assert [n for n in result.skipped if "seed-2" in n] == [
        f"{group / 'seed-2'}: metrics.csv has no evaluation rows (a run that stopped before its "
        "first evaluation); it is left out of the tables and plots"
    ]
    assert set(result.per_seed["seed"]) == set(BASELINE_MW)  # the others are counted as before


def _with_success(rows: str, row: int, value: str) -> str:
    """`rows` (metrics.csv without its header) with data row `row`'s success set to `value`."""
    lines = rows.splitlines()
    cells = lines[row].split(",")
    cells[HEADER.split(",").index("success")] = value
    lines[row] = ",".join(cells)
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(
    ("value", "shown"),
    [
        ("nan", "nan"),
        ("", "nan"),
        ("2.5", "2.5"),
        ("-0.1", "-0.1"),
        ("inf", "inf"),
        ("1.01", "1.01"),
    ],
)
def test_a_success_that_is_not_a_rate_is_refused_before_anything_is_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], value: str, shown: str
) -> None:
    # Seed 1's third evaluation row is line 4 of its metrics.csv (the header is line 1).
    runs = {**BASELINE_MW, 1: _with_success(BASELINE_MW[1], 2, value)}
    group = write_group(tmp_path / "reports", "baseline_mw", runs)
    says = (
        f"{group / 'seed-1' / 'metrics.csv'}: line 4 has success = {shown}; expected a success "
        "rate, a finite number in [0, 1]"
    )
    with pytest.raises(SealError) as refused:
        load_run(group / "seed-1")
    assert str(refused.value) == says
    before = sorted(p.name for p in group.iterdir())
    for argv in ([str(group), "--out", str(tmp_path / "out")], [str(group)]):
        assert main(["report", *argv]) == 2
        err = capsys.readouterr().err
        assert err == f"seal report: error: {says}\n"
    assert not (tmp_path / "out").exists()  # no tables, plots or lock under --out
    assert sorted(p.name for p in group.iterdir()) == before  # nor in the group


def test_a_group_whose_runs_never_evaluated_names_their_files_and_what_to_do(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Both seeds crashed before their first evaluation: metrics.csv holds its header only.
    group = write_group(tmp_path / "reports", "baseline_mw", {0: "", 1: ""})
    assert main(["report", str(group), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    files = f"{group / 'seed-0' / 'metrics.csv'}, {group / 'seed-1' / 'metrics.csv'}"
    assert err == (
        f"seal report: error: {files}: no evaluation rows, so there is nothing to report: these "
        "runs stopped before the first evaluation (see the log, then resume or rerun) or are "
        "still running (report after the first evaluation)\n"
    )
    assert not (tmp_path / "out").exists()
    assert sorted(p.name for p in group.iterdir()) == ["seed-0", "seed-1"]  # no lock, no tables
    # One seed: named alone, as one run.
    (group / "seed-1" / "metrics.csv").unlink()
    with pytest.raises(SealError) as refused:
        report([group], out=tmp_path / "out")
    message = str(refused.value)
    assert message.startswith(f"{group / 'seed-0' / 'metrics.csv'}: no evaluation rows")
    assert ": this run stopped before the first evaluation" in message
    assert "or is still running" in message
    # No seed with a metrics.csv at all: the seed directories, named without list syntax.
    (group / "seed-0" / "metrics.csv").unlink()
    with pytest.raises(SealError) as refused:
        report([group], out=tmp_path / "out")
    assert str(refused.value) == (
        f"{group}: none of its seed directories (seed-0, seed-1) has a metrics.csv; their runs "
        "stopped before their first evaluation or are still running (report them after it)"
    )
