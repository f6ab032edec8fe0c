"""Every shipped protocol at a tiny --scale, on the real Meta-World and kitchen adapters.

--scale 0.0001 makes every protocol one epoch long (evaluation and checkpoint at that epoch);
--set shrinks the per-epoch work (5-step episodes, one evaluation episode, 8-wide networks, a
1,000-transition replay) so each run takes seconds, while the env adapters stay the real ones.
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

from seal.cli.main import main
from seal.protocols import load_protocol

PROTOCOLS = Path(__file__).resolve().parents[2] / "protocols"
SHIPPED = [
    "baseline_mw",
    "baseline_fk",
    "finetune_fk_to_mw",
    "finetune_mw_to_fk",
    "joint_50_50",
    "high_fk",
    "high_mw",
    "quickstart",
    # issue 5: schedulers, curricula and transfer
    "mt1_pick_place",
    "mt10_smt",
    # issue 56: the one-hot ablation of SMT's task encoder
    "mt10_smt_one_hot",
    "mt3_curriculum_v1",
    "mt10_curriculum_v1",
    "mt10_progressive_sequential",
    "mt3_transfer",
    "joint_smt",
    # issue 22: batch-matched alone arms (one per environment; the other four differ only in the schedule)
    "matched/high_fk_mw_alone",
    "matched/high_fk_fk_alone",
]
# Per-protocol shrinks of per-epoch work the common list does not cover.
EXTRA: dict[str, list[str]] = {
    "mt3_transfer": ["training.grad_steps_per_epoch=-1"],
    "mt10_curriculum_v1": ["scheduler.grad_steps=-1"],
    # Eq. 5 scores build their own env instances: at most once in the smoke run (T_eval past it).
    "mt10_smt": [
        "scheduler.score_episodes=1",
        # Once, after the first epoch: Eq. 5's rollouts step the task encoder (issue 56).
        "scheduler.score_interval=10",
        "agent.encoder_gru=8",
        "agent.encoder_hidden=[8]",
        "agent.decoder_hidden=[8]",
    ],
    "mt10_smt_one_hot": ["scheduler.score_episodes=1", "scheduler.score_interval=100000000"],
    "joint_smt": ["scheduler.score_episodes=1", "scheduler.score_interval=100000000"],
}
SHRINK = [
    "evaluation.episodes=1",
    "training.warmup_steps=0",
    "training.batch_per_task=4",
    # A few updates an epoch: at --scale 0.0001 an update-count grid (evaluation.every_grad_steps)
    # shrinks to ~2, so the protocols' 500-update epochs evaluated ~250 times (issue 55: 89 s).
    "training.grad_steps_per_epoch=4",
    "agent.hidden=[8]",
    "agent.translator_hidden=[8]",
    "agent.latent_dim=8",
    "agent.trunk_hidden=[8]",
    "replay.capacity_per_env=1000",
    "protocol.threads=1",
    "training.collector=sync",
]


# Over ~20 s each on the reference machine (issue 55): building MT10's and the ten kitchens' envs
# twice (training and evaluation) dominates; the slow tier (`-m slow`) runs them.
SLOW = {
    "quickstart",
    "joint_smt",
    "matched/high_fk_fk_alone",
    "high_fk",
    "high_mw",
    "joint_50_50",
    "finetune_fk_to_mw",
    "finetune_mw_to_fk",
}


@pytest.mark.parametrize(
    "name", [pytest.param(n, marks=pytest.mark.slow) if n in SLOW else n for n in SHIPPED]
)
def test_shipped_protocol_smoke(
    name: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = PROTOCOLS / f"{name}.toml"
    # Two seeds for one protocol (each seed is its own run), one for the others to save time.
    seeds = "0-1" if name == "baseline_mw" else "0"
    args = [
        "run",
        str(path),
        "--scale",
        "0.0001",
        "--out",
        str(tmp_path),
        "--quiet",
        "--json",
        "--no-report",
        "--seeds",
        seeds,
    ]
    config = load_protocol(path)
    shrink = [
        *SHRINK,
        *(f"envs.{env}.episode_length=5" for env in config.envs),
        *EXTRA.get(name, []),
    ]
    if config.transfer is not None:
        # The two commands of mt3_transfer.toml's header: pre-train its MT1 source, then transfer.
        source = [
            "run",
            str(PROTOCOLS / "mt1_pick_place.toml"),
            *args[2:],
            *(x for item in [*SHRINK, "envs.mw.episode_length=5"] for x in ("--set", item)),
        ]
        assert main(source) == 0
        best = Path(json.loads(capsys.readouterr().out.strip().splitlines()[-1])["run_dir"])
        shrink.append(f"transfer.checkpoint={best / 'checkpoints' / 'best.pt'}")
    for item in shrink:
        args += ["--set", item]
    assert main(args) == 0
    line = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    runs = [Path(p) for p in line.get("run_dirs", [line["run_dir"]])]
    assert len(runs) == (2 if name == "baseline_mw" else 1)
    for run in runs:
        metrics = pd.read_csv(run / "metrics.csv")
        trained = (
            {config.finetune.source, config.finetune.target}
            if config.finetune
            else set(config.envs)
        )
        for env in trained:
            # At least one evaluation row for every task of every env the protocol trains on.
            assert set(metrics[metrics["env"] == env]["task"]) == set(config.envs[env].tasks), env
        assert list((run / "checkpoints").glob("ckpt-*.pt")), "no epoch checkpoint"
        assert list((run / "checkpoints").glob("best*.pt")), "no best checkpoint"
        assert set(line["final_success"]) == trained
