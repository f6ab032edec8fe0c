"""`seal report`'s success curves leave out the evaluations in which a task stopped early
(`evaluation.decide_early`, train.csv's `eval_decided_early/<task>`) and say so (issue 60)."""

from __future__ import annotations

from pathlib import Path

import matplotlib.image
import pandas as pd

from seal.reports.groups import _gather, _labelled
from seal.reports.plots import plot_success, success_curves
from tests.report_groups import TRAIN_HEADER, write_group

# Two seeds, three evaluations of drawer-close; seed 0's task stopped early at epoch 2 (6 of 50
# episodes, 0/6), seed 1's at epoch 2 ran every episode (its flag is 0).
METRICS = {
    0: "0,train,1,mw,drawer-close-v3,0.50,1,500,500,0.064,1\n"
    "0,train,2,mw,drawer-close-v3,0.00,1,1000,1000,0.128,2\n"
    "0,train,3,mw,drawer-close-v3,0.90,1,1500,1500,0.192,3\n",
    1: "1,train,1,mw,drawer-close-v3,0.30,1,500,500,0.064,1\n"
    "1,train,2,mw,drawer-close-v3,0.40,1,1000,1000,0.128,2\n"
    "1,train,3,mw,drawer-close-v3,0.70,1,1500,1500,0.192,3\n",
}
DECIDED = {0: 1.0, 1: 0.0}


def _metrics(tmp_path: Path, decided: bool = True) -> pd.DataFrame:
    group = write_group(tmp_path, "baseline_mw", METRICS)
    for seed, flag in DECIDED.items():
        episodes = 6 if flag else 50
        rows = (
            f"{seed},train,2,1000,mw,eval_episodes/drawer-close-v3,{episodes}\n"
            f"{seed},train,2,1000,mw,eval_decided_early/drawer-close-v3,{flag}\n"
        )
        (group / f"seed-{seed}" / "train.csv").write_text(TRAIN_HEADER + (rows if decided else ""))
    return _labelled(_gather([group]), "metrics")


def test_a_decided_early_evaluation_is_hidden_for_every_seed(tmp_path: Path) -> None:
    metrics = _metrics(tmp_path)
    assert metrics["decided_early"].tolist() == [False, True, False, False, False, False]
    curve = success_curves(metrics, "epoch").set_index("epoch")
    assert curve.index.tolist() == [1, 3]  # epoch 2 is gone for both seeds
    assert curve["mean"].round(6).tolist() == [0.4, 0.8]
    written = plot_success(metrics, "epoch", {"Single Env": "black"}, {}, tmp_path, 0.9)
    assert matplotlib.image.imread(written[0]).std() > 0.01


def test_without_the_option_every_evaluation_is_drawn(tmp_path: Path) -> None:
    metrics = _metrics(tmp_path, decided=False)
    assert not metrics["decided_early"].any()
    assert success_curves(metrics, "epoch")["epoch"].tolist() == [1, 2, 3]


def test_a_curve_with_every_evaluation_hidden_is_empty(tmp_path: Path) -> None:
    metrics = _metrics(tmp_path)
    metrics["decided_early"] = True
    assert success_curves(metrics, "epoch").empty
    assert plot_success(metrics, "epoch", {"Single Env": "black"}, {}, tmp_path, 0.9)
