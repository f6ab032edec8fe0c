"""protocols/matched/: each batch-matched alone arm draws, epoch by epoch, the batch its env draws in its joint run."""

from __future__ import annotations

from pathlib import Path

import pytest

from seal.protocols import load_protocol
from seal.schedulers import Progress
from seal.schedulers.registry import build_scheduler

PROTOCOLS = Path(__file__).resolve().parents[2] / "protocols"
TEN = tuple(f"task{i}" for i in range(10))  # MT10 and the kitchens: 10 tasks each
ADAPTERS = {"mw": "metaworld", "fk": "franka_kitchen_dense"}


def _counts(path: Path, envs: tuple[str, ...], epoch: int) -> dict[str, list[int]]:
    config = load_protocol(path)
    scheduler = build_scheduler(
        config.scheduler, {e: TEN for e in envs}, adapters={e: ADAPTERS[e] for e in envs}
    )
    total = config.training.batch_per_task * 10 * len(envs)  # the runner's total batch
    plan = scheduler.plan(Progress(epoch=epoch))
    return {e: c.tolist() for e, c in plan.batch_counts(total).items()}


@pytest.mark.parametrize("joint", ["high_fk", "high_mw", "joint_50_50"])
@pytest.mark.parametrize("env", ["mw", "fk"])
def test_matched_alone_draws_the_joint_runs_batch(joint: str, env: str) -> None:
    alone = PROTOCOLS / "matched" / f"{joint}_{env}_alone.toml"
    config, joint_config = load_protocol(alone), load_protocol(PROTOCOLS / f"{joint}.toml")
    assert list(config.envs) == [env] and config.agent.architecture == "seal"
    # Same length, updates per epoch (the joint run's 500: its longest episode) and evaluation grid.
    assert config.protocol.epochs == joint_config.protocol.epochs
    assert config.training.grad_steps_per_epoch in (-1, 500)
    assert config.evaluation.every_grad_steps == joint_config.evaluation.every_grad_steps
    for epoch in (0, 999, 1000, 2500, 3999, 4000, 9999):
        want = _counts(PROTOCOLS / f"{joint}.toml", ("mw", "fk"), epoch)[env]
        assert _counts(alone, (env,), epoch) == {env: want}, epoch
    # Hand-computed, epoch 0 of high_fk: 2,560 = 25.6 x 10 (Meta-World) + 230.4 x 10 (kitchen);
    # floors 250 + 2,300 leave 10, which go to the 10 largest remainders, Meta-World's .6: 26 per
    # task. An alone run rounding its own 256 alone would draw 26 x 6 + 25 x 4 instead.
    if (joint, env) == ("high_fk", "mw"):
        assert _counts(alone, ("mw",), 0)["mw"] == [26] * 10


def test_an_epoch_whose_share_rounds_to_nothing_runs_no_update(tmp_path: Path) -> None:
    """An absent env holding all but a sliver of the share leaves this run 0 transitions an
    update: the epoch runs none (the matched joint run draws none of these tasks either); it
    was an empty-stack RuntimeError at the first update."""
    import pandas as pd

    from seal.run.runner import run_seed

    sets = [
        "protocol.epochs=2",
        "training.warmup_steps=0",
        "evaluation.interval=1",
        "evaluation.episodes=1",
        'scheduler.kind="constant"',
        "scheduler.ratios={pt=1e-9,g=1.0}",
        "scheduler.absent={g=4}",
    ]
    config = load_protocol(PROTOCOLS / "learn" / "point.toml", sets)
    run = run_seed(config, 0, tmp_path / "g").run_dir
    metrics = pd.read_csv(run / "metrics.csv")
    assert sorted(metrics["epoch"].unique()) == [1, 2]
    assert (metrics["grad_steps"] == 0).all() and (metrics["batch"] == 0).all()
    # The control: a share that rounds to transitions updates every epoch.
    config = load_protocol(
        PROTOCOLS / "learn" / "point.toml",
        [*sets[:-2], "scheduler.ratios={pt=0.5,g=0.5}", sets[-1]],
    )
    run = run_seed(config, 0, tmp_path / "h").run_dir
    assert (pd.read_csv(run / "metrics.csv")["grad_steps"] > 0).all()
