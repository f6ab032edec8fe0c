"""Curriculum V1 (staged) and V2 (progressive): phase lengths, distributions and threshold gates."""

from __future__ import annotations

import numpy as np
import pytest

from seal.errors import ConfigError
from seal.schedulers import (
    CurriculumPhase,
    CurriculumV1Config,
    CurriculumV2Config,
    Progress,
    ProgressivePhase,
    build_scheduler,
)
from seal.schedulers.curriculum import CurriculumV2Scheduler

MT3 = {"mw": ("reach-v3", "push-v3", "pick-place-v3")}
MT10 = {
    "mw": (
        "reach-v3",
        "push-v3",
        "pick-place-v3",
        "door-open-v3",
        "drawer-open-v3",
        "drawer-close-v3",
        "button-press-topdown-v3",
        "peg-insert-side-v3",
        "window-open-v3",
        "window-close-v3",
    )
}


def collect_all(sched, plan, length: int = 100) -> None:
    for env, mask in plan.collect.items():
        names = [t for t, c in zip(sched.env_tasks[env], mask, strict=True) if c]
        sched.observe_episodes(
            env, names, [0.0] * len(names), [0.0] * len(names), [length] * len(names)
        )


def test_v1_table_b3_phases_at_one_thousandth_scale() -> None:
    # Table B.3 scaled by 1e-3: phases of 9000, 3000, 3000, 3000, 3000, 12000 env steps.
    config = CurriculumV1Config(preset="table_b3").scale(1e-3)
    assert [p.env_steps for p in config.phases] == [9000, 3000, 3000, 3000, 3000, 12000]
    sched = build_scheduler(config, MT3)
    seen = []
    epoch = 0
    while not sched.done:
        plan = sched.plan(Progress(epoch=epoch))
        seen.append(
            (
                plan.phase,
                plan.collect["mw"].tolist(),
                np.round(plan.batch_weights["mw"], 4).tolist(),
            )
        )
        collect_all(sched, plan)  # 100 env steps per collecting task
        epoch += 1
    # P0: reach/push 50/50 collect 200 steps per epoch -> 45 epochs for 9000 steps.
    assert seen[0] == ("P0", [True, True, False], [0.5, 0.5, 0.0])
    assert sum(1 for s in seen if s[0] == "P0") == 45
    # P1: 20/70/10, all three collect 300 per epoch -> 10 epochs for 3000.
    assert seen[45] == ("P1", [True, True, True], [0.2, 0.7, 0.1])
    assert sum(1 for s in seen if s[0] == "P1") == 10
    # P2: push only (100%): 30 epochs of 100 steps.
    assert seen[55] == ("P2", [False, True, False], [0.0, 1.0, 0.0])
    # P3: 13.3/53.3/33.3 normalised by their sum 99.9.
    assert seen[85][2] == [round(13.3 / 99.9, 4), round(53.3 / 99.9, 4), round(33.3 / 99.9, 4)]
    # Phase lengths add up: the run ends after 33000 env steps (the report's 33e6 at full scale).
    assert sched.env_steps == 33000 and len(seen) == 45 + 10 + 30 + 10 + 10 + 40
    assert [r["status"] for r in sched.timeline() if r["task"] == "pick-place-v3"] == [
        "off",
        "P1",
        "off",
        "P3",
        "P4",
        "P5",
    ]


def test_v1_table_c3_sums_to_100_percent_and_lasts_24e6_steps() -> None:
    phases = CurriculumV1Config(preset="table_c3").resolved_phases()
    assert sum(p.env_steps for p in phases) == 24_000_000
    # Ten shares printed to one decimal (3.3 for 1/30): each phase sums to 100 within 10 x 0.05.
    assert [round(sum(p.weights.values()), 1) for p in phases] == [
        100.0,
        100.0,
        100.0,
        99.9,
        99.8,
        100.0,
    ]
    sched = build_scheduler(CurriculumV1Config(preset="table_c3"), MT10)
    plan = sched.plan(Progress(epoch=0))
    np.testing.assert_allclose(plan.batch_weights["mw"], [0.1] * 10)


def test_v2_thresholds_gate_progression() -> None:
    config = CurriculumV2Config(
        phases=(
            ProgressivePhase(tasks=("a",), threshold=0.8),
            ProgressivePhase(tasks=("a", "b"), threshold=0.5),
            ProgressivePhase(tasks=("a", "b", "c"), threshold=0.9),
        )
    )
    sched = build_scheduler(config, {"e": ("a", "b", "c")})

    def phase(epoch: int) -> tuple[str, list[bool]]:
        plan = sched.plan(Progress(epoch=epoch))
        return plan.phase, plan.collect["e"].tolist()

    assert phase(0) == ("P1", [True, False, False])
    sched.observe_eval(
        0, {("e", "a"): 1.0, ("e", "b"): 0.0, ("e", "c"): 0.0}
    )  # before any training in P1: ignored
    assert phase(1) == ("P1", [True, False, False])
    sched.observe_eval(2, {("e", "a"): 0.7, ("e", "b"): 0.0, ("e", "c"): 0.0})  # 0.7 < 0.8: stay
    assert phase(2) == ("P1", [True, False, False])
    sched.observe_eval(
        3, {("e", "a"): 0.8, ("e", "b"): 0.0, ("e", "c"): 0.0}
    )  # 0.8 >= 0.8: move on
    assert phase(3) == ("P2", [True, True, False])  # P2 starts at epoch 3
    sched.observe_eval(
        3, {("e", "a"): 1.0, ("e", "b"): 1.0, ("e", "c"): 0.0}
    )  # made before P2 trained: ignored
    assert phase(4) == ("P2", [True, True, False])
    sched.observe_eval(
        5, {("e", "a"): 0.6, ("e", "b"): 0.3, ("e", "c"): 1.0}
    )  # mean(a, b) 0.45 < 0.5
    assert phase(5) == ("P2", [True, True, False])
    sched.observe_eval(6, {("e", "a"): 0.6, ("e", "b"): 0.4, ("e", "c"): 0.0})  # mean 0.5 >= 0.5
    plan = sched.plan(Progress(epoch=6))
    assert plan.phase == "P3" and plan.collect["e"].tolist() == [True, True, True]
    np.testing.assert_allclose(plan.batch_weights["e"], [1 / 3] * 3)
    sched.observe_eval(8, {("e", "a"): 1.0, ("e", "b"): 1.0, ("e", "c"): 1.0})  # last phase: stays
    assert phase(9) == ("P3", [True, True, True])
    assert [r["epoch"] for r in sched.timeline() if r["task"] == "a"] == [0, 3, 6]


def test_v2_step_limit_moves_on_without_the_threshold() -> None:
    config = CurriculumV2Config(
        phases=(
            ProgressivePhase(tasks=("a",), threshold=1.0, max_env_steps=250),
            ProgressivePhase(tasks=("a", "b")),
        )
    )
    sched = build_scheduler(config, {"e": ("a", "b")})
    phases = []
    for epoch in range(5):
        plan = sched.plan(Progress(epoch=epoch))
        phases.append(plan.phase)
        collect_all(sched, plan)  # a alone: 100 env steps per epoch -> 300 >= 250 after 3 epochs
    assert phases == ["P1", "P1", "P1", "P2", "P2"]


def test_v2_presets_on_mt10() -> None:
    sequential = build_scheduler(CurriculumV2Config(preset="sequential", threshold=0.7), MT10)
    assert isinstance(sequential, CurriculumV2Scheduler)
    assert [len(p[0]) for p in sequential.phases] == list(range(1, 11))
    assert [p[0][-1][1] for p in sequential.phases][:3] == [
        "reach-v3",
        "drawer-close-v3",
        "window-open-v3",
    ]
    assert (
        sequential.phases[-1][0][-1] == ("mw", "pick-place-v3") and sequential.phases[0][1] == 0.7
    )
    mixed = build_scheduler(CurriculumV2Config(preset="mixed"), MT10)
    added = [
        sorted(t for _, t in set(p[0]) - set(q[0]))
        for p, q in zip(mixed.phases, [((), 0, 0), *mixed.phases], strict=False)
    ]
    assert added == [
        ["drawer-close-v3", "reach-v3"],
        ["window-close-v3", "window-open-v3"],
        ["button-press-topdown-v3", "drawer-open-v3"],
        ["door-open-v3"],
        ["peg-insert-side-v3"],
        ["push-v3"],
        ["pick-place-v3"],
    ]


def test_v2_mixed_splits_unknown_tasks_into_seven_groups() -> None:
    tasks = {"point": tuple(f"t{i}" for i in range(10))}
    mixed = build_scheduler(CurriculumV2Config(preset="mixed"), tasks)
    assert [len(p[0]) for p in mixed.phases] == [
        2,
        4,
        6,
        7,
        8,
        9,
        10,
    ]  # group sizes 2, 2, 2, 1, 1, 1, 1
    three = build_scheduler(
        CurriculumV2Config(preset="mixed", order=("t2", "t0", "t1")), {"point": ("t0", "t1", "t2")}
    )
    assert [[t for _, t in p[0]] for p in three.phases] == [
        ["t2"],
        ["t2", "t0"],
        ["t2", "t0", "t1"],
    ]
    for order, says in [
        (("t2", "t0"), r"once; missing: \['point/t1'\]$"),
        (("t2", "t0", "t0", "t1"), r"once; listed twice: \['point/t0'\]$"),
    ]:
        with pytest.raises(ConfigError, match=says):
            build_scheduler(
                CurriculumV2Config(preset="mixed", order=order), {"point": ("t0", "t1", "t2")}
            )


def test_v2_state_round_trip() -> None:
    config = CurriculumV2Config(
        phases=(ProgressivePhase(tasks=("a",), threshold=0.5), ProgressivePhase(tasks=("b",)))
    )
    first = build_scheduler(config, {"e": ("a", "b")})
    first.plan(Progress(epoch=0))
    first.observe_eval(1, {("e", "a"): 0.9, ("e", "b"): 0.0})
    resumed = build_scheduler(config, {"e": ("a", "b")})
    resumed.load_state_dict(first.state_dict())
    assert resumed.plan(Progress(epoch=1)).phase == "P2" == first.plan(Progress(epoch=1)).phase


def test_scale_floors_at_one_and_keeps_no_limit() -> None:
    v1 = CurriculumV1Config(phases=(CurriculumPhase(env_steps=3, weights={"a": 1.0}),)).scale(0.01)
    assert v1.phases[0].env_steps == 1
    v2 = CurriculumV2Config(preset="mixed", max_phase_env_steps=1000, phases=()).scale(1e-6)
    assert v2.max_phase_env_steps == 1
    assert (
        CurriculumV2Config(preset="mixed").scale(0.001).max_phase_env_steps == 0
    )  # 0 = no limit stays


def test_bad_curricula_name_the_key() -> None:
    with pytest.raises(ConfigError, match=r"scheduler.phases\[0\].weights: unknown task 'reach'"):
        build_scheduler(
            CurriculumV1Config(phases=(CurriculumPhase(env_steps=10, weights={"reach": 1.0}),)), MT3
        )
    with pytest.raises(ConfigError, match=r"scheduler.preset = 'table_x'"):
        build_scheduler(CurriculumV1Config(preset="table_x"), MT3)
    with pytest.raises(ConfigError, match=r"scheduler.phases\[1\].threshold = 1.5"):
        build_scheduler(
            CurriculumV2Config(
                phases=(
                    ProgressivePhase(tasks=("push-v3",)),
                    ProgressivePhase(tasks=("reach-v3",), threshold=1.5),
                )
            ),
            MT3,
        )
    with pytest.raises(ConfigError, match=r"task 'a' is in several envs"):
        build_scheduler(
            CurriculumV2Config(phases=(ProgressivePhase(tasks=("a",)),)), {"x": ("a",), "y": ("a",)}
        )
