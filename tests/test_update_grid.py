"""The update-count grid: evaluations every K gradient steps, and Appendix B's C x GS x BS beside
the exact count when the batch changes (issue 10 item 5)."""

from __future__ import annotations

import io
import json
import re
from pathlib import Path

import pandas as pd
import pytest

from seal.metrics import first_reach
from seal.protocols import load_protocol
from seal.reports import report
from seal.run.runner import run_seed

PROTOCOL = """
[protocol]
kind = "baseline"
epochs = 4
seeds = 1
device = "cpu"
threads = 1
[envs.pt]
adapter = "point"
tasks = ["east", "north"]
episode_length = 10
[agent]
hidden = [8, 8]
[training]
warmup_steps = 0
batch_per_task = 4
grad_steps_per_epoch = 10
collector = "sync"
[evaluation]
every_grad_steps = {k}
episodes = 1
[checkpoint]
interval = 2
[logging]
tensorboard = false
"""


@pytest.mark.parametrize(
    ("k", "expected"),
    [
        # 10 gradient steps per epoch, 40 in all. K = 15: evaluations inside the 2nd and 3rd
        # epochs (1 and 2 epochs completed) at 15 and 30 steps, and at the end (4 epochs, 40).
        (15, [(1, 15), (2, 30), (4, 40)]),
        # K = 20: at the last update of the 2nd epoch (1 completed) and of the 4th (3 completed);
        # the end-of-run evaluation would repeat step 40, so it is not made again.
        (20, [(1, 20), (3, 40)]),
    ],
)
def test_evaluations_fall_on_multiples_of_k_gradient_steps(
    tmp_path: Path, k: int, expected: list[tuple[int, int]]
) -> None:
    path = tmp_path / "grid.toml"
    path.write_text(PROTOCOL.replace("{k}", str(k)))
    run = run_seed(load_protocol(path), 0, tmp_path / "out").run_dir
    metrics = pd.read_csv(run / "metrics.csv")
    east = metrics[metrics["task"] == "east"]
    assert list(zip(east["epoch"], east["grad_steps"], strict=True)) == expected
    # 4 samples per task per step: consumed = grad steps x 4, and the batch in force is 4.
    assert list(east["updates"]) == pytest.approx([gs * 4 / 1e6 for _, gs in expected])
    assert set(metrics["batch"]) == {4}


def test_scale_shrinks_k_like_every_other_schedule_duration(tmp_path: Path) -> None:
    path = tmp_path / "grid.toml"
    path.write_text(PROTOCOL.replace("{k}", "16667"))
    assert load_protocol(path, scale=0.01).evaluation.every_grad_steps == 167
    path.write_text(PROTOCOL.replace("{k}", "0"))
    assert load_protocol(path, scale=0.01).evaluation.every_grad_steps == 0  # 0 stays "off"


# A stepped ratio: 100 gradient steps with 2 of the task's samples each, then 100 with 6.
# Exact consumed = 100 x 2 + 100 x 6 = 800 transitions = 0.0008 M. Appendix B's C x GS x BS with
# the batch in force at the reaching evaluation = 200 x 6 = 1200 = 0.0012 M.
HEADER = "seed,phase,epoch,env,task,success,return,grad_steps,env_steps,updates,batch,wall_s\n"
RATIO = HEADER + (
    "0,train,1,fk,slide-cabinet,0.10,1,100,100,0.0002,2,1\n"
    "0,train,2,fk,slide-cabinet,0.95,1,200,200,0.0008,6,2\n"
)


def test_paper_product_uses_the_batch_in_force_at_the_reaching_evaluation() -> None:
    frame = pd.read_csv(io.StringIO(RATIO), dtype={"phase": str, "env": str, "task": str})
    row = first_reach(frame, 0.9).iloc[0]
    assert row["updates"] == pytest.approx(0.0008)
    assert row["paper_updates"] == pytest.approx(0.0012)


def _group(root: Path, name: str, metrics: str, agent: str) -> Path:
    run = root / name / "g1" / "seed-0"
    run.mkdir(parents=True)
    (run / "config.toml").write_text(
        f'[protocol]\nname = "{name}"\nkind = "joint"\n\n[envs.fk]\nadapter = "franka_kitchen_dense"\n'
        f"\n[agent]\n{agent}\n"
    )
    (run / "metrics.csv").write_text(metrics)
    (run / "provenance.json").write_text(json.dumps({"seed": 0, "protocol": name, "group": "g1"}))
    return run.parent


def test_report_shows_the_paper_product_and_flags_groups_that_differ(tmp_path: Path) -> None:
    weighted = _group(tmp_path / "r", "high_fk", RATIO, 'shared_update = "weighted"')
    constant = RATIO.replace(",0.0008,6,", ",0.0012,6,")  # a constant batch: both counts agree
    per_env = _group(tmp_path / "r", "high_fk_per_env", constant, 'shared_update = "per_env"')
    result = report([weighted, per_env], out=tmp_path / "cmp")
    table = result.tables["update_counts.md"].read_text()
    # The counts, then the steps x per-step batch of each (800 = 200 steps x 4 a step under the
    # changing batch, 1,200 = 200 x 6 under the constant), with C×GS×BS where the two differ.
    assert re.search(r"\| 0\.0008 \[1/1\] +\|", table)
    assert re.search(r"\| 0\.0012 \[1/1\] +\|", table)
    assert "200 × 4 {C×GS×BS: 0.0012}" in table
    assert re.search(r"\| 200 × 6 +\|", table)
    assert result.warnings == [
        "groups differ in agent.shared_update: weighted in high_fk/g1; per_env in high_fk_per_env/g1"
    ]
    assert "WARNING: groups differ in agent.shared_update" in table
    counts = result.to_json()["update_counts"]
    (cells,) = [c for c in counts.values() if c["fk"]["slide-cabinet"]["mean"] == 0.0008]
    assert cells["fk"]["slide-cabinet"]["paper_updates"] == pytest.approx(0.0012)
