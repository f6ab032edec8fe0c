"""`absent` envs: a one-env run draws exactly the batch its env gets in the joint run it stands in for."""

from __future__ import annotations

import numpy as np
import pytest

from seal.errors import ConfigError
from seal.schedulers import Progress
from seal.schedulers.registry import build_scheduler

TASKS = ("t0", "t1", "t2", "t3")
STEPPED = {"kind": "stepped", "start": {"source": 0.9, "target": 0.1}, "interval": 20}


def _counts(scheduler, epoch: int, total: int) -> dict[str, list[int]]:
    plan = scheduler.plan(Progress(epoch=epoch))
    return {e: c.tolist() for e, c in plan.batch_counts(total).items()}


def test_alone_run_draws_the_targets_joint_batch() -> None:
    joint = build_scheduler(STEPPED, {"source": ("a", "b", "c", "d"), "target": TASKS})
    alone = build_scheduler({**STEPPED, "absent": {"source": 4}}, {"target": TASKS})
    # Batch 40 per task: the joint runner's total is 40 x 8 = 320, the alone runner's 40 x 4 = 160.
    # Epoch 0, 90/10: the target gets 0.1 x 320 = 32, 8 per task; alone, 160 x (0.1 x 8 / 4) = 32.
    assert _counts(joint, 0, 320)["target"] == [8, 8, 8, 8]
    assert _counts(alone, 0, 160) == {"target": [8, 8, 8, 8]}
    # Epoch 20, 80/20: 64 = 16 per task; epoch 80 on, 50/50: 160 = 40 per task (the whole alone batch).
    assert _counts(joint, 20, 320)["target"] == _counts(alone, 20, 160)["target"] == [16] * 4
    assert _counts(joint, 80, 320)["target"] == _counts(alone, 80, 160)["target"] == [40] * 4


def test_constant_absent_and_collect_ratio() -> None:
    table = {
        "kind": "constant",
        "ratios": {"source": 0.75, "target": 0.25},
        "absent": {"source": 2},
    }
    alone = build_scheduler({**table, "collect": "ratio"}, {"target": ("t0", "t1")})
    # Joint total 10 x 4 tasks = 40, target's quarter = 10; alone total 10 x 2 = 20, scale 0.25 x 2.
    plans = [alone.plan(Progress(epoch=e)) for e in range(3)]
    assert [p.batch_counts(20)["target"].tolist() for p in plans] == [[5, 5]] * 3
    # With collect = "ratio" the target collects a third as often as the absent source would:
    # credit 1 at epoch 0, then +1/3 per epoch.
    assert [bool(p.collect["target"].all()) for p in plans] == [True, False, False]


def test_without_absent_the_batch_is_unscaled() -> None:
    joint = build_scheduler(STEPPED, {"source": ("a",), "target": ("t0",)})
    plan = joint.plan(Progress(epoch=0))
    assert plan.absent_weights == {}
    assert np.sum([c.sum() for c in plan.batch_counts(100).values()]) == 100


def test_absent_errors_name_the_key() -> None:
    with pytest.raises(
        ConfigError, match=r"scheduler.absent.target: 'target' is one of the protocol's envs"
    ):
        build_scheduler({**STEPPED, "absent": {"target": 4}}, {"target": TASKS})
    with pytest.raises(
        ConfigError, match=r"scheduler.absent.source = 0: expected a task count >= 1"
    ):
        build_scheduler({**STEPPED, "absent": {"source": 0}}, {"target": TASKS})
    with pytest.raises(ConfigError, match="scheduler.start"):
        # An absent env is one of the joint run's envs: the fractions must name it.
        build_scheduler(
            {**STEPPED, "start": {"target": 1.0}, "absent": {"source": 4}}, {"target": TASKS}
        )
    with pytest.raises(ConfigError, match="scheduler.absent: a preset"):
        build_scheduler(
            {"kind": "stepped", "preset": "high_fk", "absent": {"mw": 10}}, {"fk": TASKS}
        )
