"""Run groups written by hand for the report tests (tests/test_reports.py,
tests/test_report_seeds.py), and readers of the report's Markdown and PNGs."""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib.image
import pandas as pd

from seal.reports import RunData

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


def write_group(root: Path, protocol: str, runs: dict[int, str], group: str = "g1") -> Path:
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


def assert_png(path: Path) -> None:
    assert path.is_file() and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    image = matplotlib.image.imread(path)
    assert image.shape[0] > 200 and image.shape[1] > 300
    assert image.std() > 0.01  # something was drawn, not a blank canvas


def md_table(md: str, section: str = "") -> tuple[list[str], dict[str, list[str]]]:
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


def md_rows_of(md: str, section: str, arm: str) -> list[list[str]]:
    """Every row of the table under **section** whose first cell is `arm`, without that cell."""
    block = md.split(f"**{section}**\n\n", 1)[1].split("\n\n", 1)[0]
    cells = [[c.strip() for c in line.strip("|").split("|")] for line in block.splitlines()[2:]]
    return [row[1:] for row in cells if row[0] == arm]


def longest_line(path: Path) -> int:
    return max(len(line) for line in path.read_text().splitlines())


def run_data(
    run_cfg: str,
    kind_metrics: str = "0,train,1,mw,a,0.5,0,1,1,0.1,0\n0,train,1,fk,b,0.5,0,1,1,0.1,0\n0,train,1,fk,c,0.5,0,1,1,0.1,0\n0,train,1,fk,d,0.5,0,1,1,0.1,0\n",
) -> RunData:
    """A run read into memory, not from disk: its config (TOML text) and metrics.csv rows."""
    import io
    import tomllib

    metrics = pd.read_csv(io.StringIO(HEADER + kind_metrics))
    return RunData(
        path=Path("/r/p/g/seed-0"),
        metrics=metrics,
        train=pd.DataFrame(),
        config=tomllib.loads(run_cfg),
    )
