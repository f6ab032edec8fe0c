"""SMT Table 1's layout in `seal report` (issue 57): [protocol].column names a learner's column,
and tables/success_by_task.{md,csv} give success % by task id at the end, mean ± std over seeds."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pandas as pd

from seal.reports import report
from tests.report_groups import HEADER, run_data

# Two learners on Meta-World with two tasks, two seeds each, three epochs; the table reads epoch 3.
#   PaCo:   drawer-close 1.0, 0.8 -> 90.0 ± 14.1; reach 0.4, 0.0 -> 20.0 ± 28.3;
#           averages per seed 0.7, 0.4 -> 55.0 ± 21.2
#   SAC-MT: drawer-close 0.6, 0.6 -> 60.0 ± 0.0; reach 0.2, 0.6 -> 40.0 ± 28.3;
#           averages per seed 0.4, 0.6 -> 50.0 ± 14.1
FINAL = {
    "PaCo": {0: (1.0, 0.4), 1: (0.8, 0.0)},
    "SAC-MT": {0: (0.6, 0.2), 1: (0.6, 0.6)},
}


def _group(root: Path, name: str, column: str) -> Path:
    group = root / name / "g1"
    for seed, (drawer, reach) in FINAL[column].items():
        run = group / f"seed-{seed}"
        run.mkdir(parents=True)
        (run / "config.toml").write_text(
            f'[protocol]\nname = "{name}"\nkind = "baseline"\ncolumn = "{column}"\n\n'
            '[envs.mw]\nadapter = "metaworld"\n'
        )
        rows = "".join(
            f"{seed},train,{e},mw,drawer-close-v3,{0.1 * e if e < 3 else drawer},1,{500 * e},{500 * e},{0.064 * e},{e}\n"
            f"{seed},train,{e},mw,reach-v3,{0.0 if e < 3 else reach},1,{500 * e},{500 * e},{0.064 * e},{e}\n"
            for e in (1, 2, 3)
        )
        (run / "metrics.csv").write_text(HEADER + rows)
        (run / "provenance.json").write_text(
            json.dumps({"git_sha": "abc", "seed": seed, "protocol": name, "group": "g1"})
        )
    return group


def test_a_protocols_column_names_its_baseline_and_not_a_finetunes_phases() -> None:
    from seal.reports import column_label

    named = '[protocol]\nname="p"\nkind="baseline"\ncolumn="PaCo"'
    assert column_label(run_data(named), "train", "mw") == "PaCo"
    finetune = '[protocol]\nname="f"\nkind="finetune"\ncolumn="X"\n[envs.mw]\nadapter="metaworld"'
    assert column_label(run_data(finetune), "pretrain", "mw") == "Pre-train on MW"


def test_two_learners_give_smt_table1s_layout(tmp_path: Path) -> None:
    root = tmp_path / "reports"
    groups = [_group(root, "smt_table1_paco", "PaCo"), _group(root, "smt_table1_sac_mt", "SAC-MT")]
    result = report(groups, out=tmp_path / "out")
    md = result.tables["success_by_task.md"].read_text()
    lines = [line for line in md.splitlines() if line.startswith("|")]
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    assert header == ["Algorithm", "0", "1", "Average"]
    cells = {
        row[0]: row[1:]
        for row in ([c.strip() for c in line.strip("|").split("|")] for line in lines[2:])
    }
    assert list(cells) == ["SAC-MT", "PaCo"]  # SMT Table 1's order, not the alphabet's
    assert cells["PaCo"] == ["90.0 ± 14.1", "20.0 ± 28.3", "55.0 ± 21.2"]
    assert cells["SAC-MT"] == ["60.0 ± 0.0", "40.0 ± 28.3", "50.0 ± 14.1"]
    assert "MW task ids: 0 = drawer-close-v3, 1 = reach-v3" in " ".join(md.split())
    csv = pd.read_csv(result.tables["success_by_task.csv"])
    paco = csv[(csv["column"] == "PaCo") & (csv["task_id"] == -1)].iloc[0]
    assert math.isclose(paco["success_mean"], 0.55) and paco["seeds"] == 2
    assert math.isclose(paco["success_std"], math.sqrt((0.7 - 0.55) ** 2 + (0.4 - 0.55) ** 2))
