"""`evaluation.decide_early` and `end_on_success` change no training and no first crossing: a
short protocol run with both on against the same run with both off, on two seeds (issue 60)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import pandas as pd
import pytest
import torch

from seal.evaluation import reaches
from seal.learner.checkpoint import read_checkpoint
from seal.metrics import first_reach
from seal.protocols import load_protocol
from seal.protocols.evaluation_cost import early_decisions_off, explain_lines
from seal.reports.load import decided_early
from seal.run.runner import resume_run, run_seed
from tests.crash import CrashAfter

THRESHOLD = 0.7
# The push env (tests/protocols/push_adapter.py): success rates between 0 and 1 from the first
# evaluation, and tasks cross 70% within the run. 10 episodes at 0.7: a task is settled at 7
# successes or 4 failures, so evaluations stop early both ways (what they record does not
# depend on how many instances run at once, this machine's cores).
PROTOCOL = f"""
[protocol]
name = "decide_early"
kind = "baseline"
epochs = 12
seeds = 1
device = "cpu"
threads = 1
[envs.pu]
adapter = "tests.protocols.push_adapter:PushAdapter"
[agent]
hidden = [16, 16]
[training]
warmup_steps = 20
batch_per_task = 16
grad_steps_per_epoch = 20
collector = "sync"
[evaluation]
interval = 1
episodes = 10
threshold = {THRESHOLD}
[checkpoint]
interval = 6
[logging]
tensorboard = false
train_interval = 1
"""
ON = ["evaluation.decide_early=true", "evaluation.end_on_success=true", "evaluation.full_every=3"]


def _tensors_equal(a: Any, b: Any) -> bool:
    if isinstance(a, torch.Tensor):
        return isinstance(b, torch.Tensor) and torch.equal(a, b)
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_tensors_equal(a[k], b[k]) for k in a)
    if isinstance(a, list | tuple):
        return len(a) == len(b) and all(_tensors_equal(x, y) for x, y in zip(a, b, strict=True))
    return a == b


def assert_same_training(on: Path, off: Path) -> pd.DataFrame:
    """The runs trained alike and crossed alike; `on`'s metrics with its decided-early flags."""
    m_on, m_off = pd.read_csv(on / "metrics.csv"), pd.read_csv(off / "metrics.csv")
    t_on, t_off = pd.read_csv(on / "train.csv"), pd.read_csv(off / "train.csv")
    # Training rows (losses, Q, temperatures) equal bit for bit; evaluation's own (eval_q,
    # eval_episodes, ...) differ by design. Sorted: asynchronous evaluations append theirs late.
    order = ["phase", "epoch", "grad_steps", "env", "key"]

    def training(t: pd.DataFrame) -> pd.DataFrame:
        kept = t[~t["key"].str.startswith("eval_")]
        return kept.sort_values(order, kind="stable").reset_index(drop=True)

    pd.testing.assert_frame_equal(training(t_on), training(t_off))
    # The same evaluations of the same snapshots (counters, consumed updates, batch) ...
    same = ["seed", "phase", "epoch", "env", "task", "grad_steps", "env_steps", "updates", "batch"]
    pd.testing.assert_frame_equal(m_on[same], m_off[same])
    # ... each with the full evaluation's verdict, so the same first crossings.
    hit_on = [reaches(s, THRESHOLD) for s in m_on["success"]]
    assert hit_on == [reaches(s, THRESHOLD) for s in m_off["success"]]
    pd.testing.assert_frame_equal(first_reach(m_on, THRESHOLD), first_reach(m_off, THRESHOLD))
    # Evaluations that ran every episode read the same success (returns are cut ones).
    flags = decided_early(m_on, t_on)
    pd.testing.assert_series_equal(m_on["success"][~flags], m_off["success"][~flags])
    # The agents are the same at the end, optimiser states included.
    last = sorted((on / "checkpoints").glob("ckpt-*.pt"))[-1]
    agent_on = read_checkpoint(last)["agent"]
    assert _tensors_equal(agent_on, read_checkpoint(off / "checkpoints" / last.name)["agent"])
    return m_on.assign(decided_early=flags)


def test_the_options_change_no_training_and_no_crossing(tmp_path: Path) -> None:
    path = tmp_path / "decide_early.toml"
    path.write_text(PROTOCOL)
    decided = []
    for seed in (0, 1):
        off = run_seed(load_protocol(path), seed, tmp_path / "off")
        on = run_seed(load_protocol(path, ON), seed, tmp_path / "on")
        metrics = assert_same_training(on.run_dir, off.run_dir)
        assert on.update_counts == off.update_counts
        assert on.final_success == off.final_success  # the last epoch's evaluation runs in full
        decided.append(metrics)
        # Every 3rd evaluation (3, 6, 9) and the last (12) ran in full: no decision rows.
        train = pd.read_csv(on.run_dir / "train.csv")
        episodes = train[train["key"].str.startswith("eval_episodes/")]
        assert sorted(set(episodes["epoch"])) == [1, 2, 4, 5, 7, 8, 10, 11]
        # Counted up to the settling episode: 4 failures or 7 successes take 4 episodes or more.
        assert set(episodes["value"]) <= set(map(float, range(4, 11)))
    stopped = pd.concat(decided)
    stopped = stopped[stopped["decided_early"]]
    # Both kinds of early decision happened: settled below the threshold and above it.
    assert (stopped["success"] < THRESHOLD).any() and (stopped["success"] >= THRESHOLD).any()


def test_phases_whose_evaluations_steer_training_run_every_episode(tmp_path: Path) -> None:
    path = tmp_path / "decide_early.toml"
    path.write_text(PROTOCOL)
    on = load_protocol(path, ON)
    assert early_decisions_off(on, "train", reads_eval=False) == ""
    assert "scheduler" in early_decisions_off(on, "train", reads_eval=True)  # curriculum_v2
    finetune = on.replace(protocol=dataclasses.replace(on.protocol, kind="finetune"))
    assert "starts the fine-tuning" in early_decisions_off(finetune, "pretrain", reads_eval=False)
    assert early_decisions_off(finetune, "finetune", reads_eval=False) == ""
    assert early_decisions_off(load_protocol(path), "train", reads_eval=False)  # off by default


def test_explain_says_what_the_options_can_save(tmp_path: Path) -> None:
    path = tmp_path / "decide_early.toml"
    path.write_text(PROTOCOL)
    assert explain_lines(load_protocol(path)) == []
    paper = load_protocol(path, [*ON, "evaluation.episodes=50", "evaluation.threshold=0.9"])
    text = "\n".join(explain_lines(paper))
    assert "stops at 45 successes or 6 failures of 50 episodes, so after at least 6" in text
    # 44 of 50 episodes in 2 of every 3 evaluations: 88% x 2/3 = 59% at most.
    assert "saves at most 44 of a task's 50 episodes (88%) in 2 of every 3" in text
    assert "at most 59% of evaluation env steps" in text
    assert "end_on_success is on" in text


def test_a_resumed_run_decides_as_the_uninterrupted_one(tmp_path: Path) -> None:
    """The evaluation count that `full_every` reads is in the checkpoint: killed after epoch 9
    and resumed from epoch 8's checkpoint (8 evaluations, not a multiple of 3), the run writes
    the rows it would have written."""
    path = tmp_path / "decide_early.toml"
    path.write_text(PROTOCOL)
    config = load_protocol(path, [*ON, "checkpoint.interval=4"])
    whole = run_seed(config, 0, tmp_path / "whole").run_dir
    with pytest.raises(KeyboardInterrupt):
        run_seed(config, 0, tmp_path / "killed", callbacks=[CrashAfter(at=9)])
    (killed,) = (tmp_path / "killed").glob("seed-0")
    resume_run(killed)
    for name in ("metrics.csv", "train.csv"):
        got, want = pd.read_csv(killed / name), pd.read_csv(whole / name)
        pd.testing.assert_frame_equal(
            got.drop(columns="wall_s", errors="ignore"),
            want.drop(columns="wall_s", errors="ignore"),
        )


@pytest.mark.slow
def test_asynchronous_evaluation_decides_as_synchronous(tmp_path: Path) -> None:
    """The worker evaluates with the same rules: its rows are the synchronous run's, and
    training is that of a run with the options off."""
    path = tmp_path / "decide_early.toml"
    path.write_text(PROTOCOL)
    off = run_seed(load_protocol(path), 0, tmp_path / "off")
    sync = run_seed(load_protocol(path, ON), 0, tmp_path / "sync")
    asyn = run_seed(load_protocol(path, [*ON, 'evaluation.mode="async"']), 0, tmp_path / "async")
    assert_same_training(asyn.run_dir, off.run_dir)
    rows = ["epoch", "task", "success", "return", "updates"]
    m_sync, m_async = (
        pd.read_csv(sync.run_dir / "metrics.csv"),
        pd.read_csv(asyn.run_dir / "metrics.csv"),
    )
    pd.testing.assert_frame_equal(m_async[rows], m_sync[rows])
    assert asyn.update_counts == off.update_counts
