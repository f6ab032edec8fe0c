"""SMT pool transitions on a scripted fake against a hand trace of Algorithm 1."""

from __future__ import annotations

import json

import matplotlib.pyplot as plt
import numpy as np
import pytest
from png_colours import colours_drawn

from seal.errors import ConfigError
from seal.schedulers import Progress, SMTConfig, build_scheduler
from seal.schedulers.plots import STATUS_COLOURS, plot_budget_usage, plot_membership
from seal.schedulers.smt import SMTScheduler

L = 10  # env steps per episode of the fake env

# Every training episode of a task returns the same value, so each mean is hand-computable:
# a and d are solved at once (9 > M = 8), b and e are unsolvable (1 < m = 2), c is in between.
RETURNS = {"a": 9.0, "b": 1.0, "c": 5.0, "d": 9.0, "e": 1.0}

CONFIG = SMTConfig(
    budget_stage1=200,
    budget_stage2=60,
    kappa=0.5,
    slots=2,
    solved_return={"mw": 8.0},
    unsolvable_return={"mw": 2.0},
    recent_episodes=2,
    score_episodes=1,
    score_interval=60,
    reset_interval=60,
)


def make() -> SMTScheduler:
    sched = build_scheduler(CONFIG, {"mw": ("a", "b", "c", "d", "e")})
    assert isinstance(sched, SMTScheduler)
    return sched


def run_epoch(sched: SMTScheduler, epoch: int, scores: dict[str, float]) -> tuple[list[str], bool]:
    """One runner epoch: plan, collect the planned tasks, answer a score request."""
    plan = sched.plan(Progress(epoch=epoch))
    names = [t for t, c in zip(sched.env_tasks["mw"], plan.collect["mw"], strict=True) if c]
    if names:
        sched.observe_episodes(
            "mw", names, [RETURNS[t] for t in names], [0.0] * len(names), [L] * len(names)
        )
    request = sched.wants_scores()
    if request is not None:
        assert request.episodes == 1 and request.discount == 0.99
        sched.observe_scores({k: scores[k[1]] for k in request.tasks})
    return names, plan.reset_agent


def pools(sched: SMTScheduler) -> tuple[list[str], ...]:
    return tuple(
        [k[1] for k in sched.members(p)] for p in ("training", "main", "solved", "unsolvable")
    )


def test_hand_traced_algorithm_1() -> None:
    sched = make()
    # Scores given before the first plan make the first pick deterministic (hardest = lowest).
    sched.observe_scores(
        {("mw", t): s for t, s in {"a": 1, "b": 2, "c": 3, "d": 4, "e": 5}.items()}
    )
    later = {"a": 9, "b": 9, "c": 2, "d": 0, "e": 1}  # scores returned at every request

    # epoch 0: a, b enter with budget 0.5 * (200 - 0) / 2 = 50. a returns 9 > 8: solved.
    names, reset = run_epoch(sched, 0, later)
    assert (names, reset) == (["a", "b"], False)
    assert sched.budget[("mw", "a")] == 50 and sched.budget[("mw", "b")] == 50
    assert pools(sched) == (["b"], ["c", "d", "e"], ["a"], [])
    # epoch 1: refill with c (score 3 is the lowest in main {c:3, d:4, e:5}),
    # budget 0.5 * (200 - 20) / 2 = 45. Batch: uniform over a, b, c (all have data).
    plan = sched.plan(Progress(epoch=1))
    assert sched.budget[("mw", "c")] == 45
    np.testing.assert_allclose(plan.batch_weights["mw"], [1 / 3, 1 / 3, 1 / 3, 0, 0])
    assert plan.collect["mw"].tolist() == [False, True, True, False, False]
    sched.observe_episodes("mw", ["b", "c"], [1.0, 5.0], [0.0, 0.0], [L, L])  # b: 20/50, c: 10/45
    assert sched.wants_scores() is None  # 40 < T_eval = 60
    # epoch 2: b 30/50, c 20/45; B_used = 60 crosses T_eval: scores are asked for (d hardest now).
    assert run_epoch(sched, 2, later) == (["b", "c"], False)
    assert sched.scores is not None and sched.scores[("mw", "d")] == 0
    # epoch 3: 60 // T_reset = 1 reset due. b 40/50, c 30/45.
    assert run_epoch(sched, 3, later) == (["b", "c"], True)
    # epoch 4: b 50/50 spent, mean 1 < m = 2: unsolvable. c 40/45.
    assert run_epoch(sched, 4, later) == (["b", "c"], False)
    assert pools(sched) == (["c"], ["d", "e"], ["a"], ["b"])
    # epoch 5: refill with d (score 0 < e's 1), budget 0.5 * (200 - 100) / 2 = 25; d solved at once.
    # c 50/45 spent with mean 5 in [2, 8]: back to main. B_used = 120: scores again.
    assert run_epoch(sched, 5, later) == (["c", "d"], False)
    assert sched.budget[("mw", "d")] == 25
    assert pools(sched) == ([], ["c", "e"], ["a", "d"], ["b"])
    # epoch 6: reset (120 // 60 = 2). Refill e (1) then c (2), each 0.5 * (200 - 120) / 2 = 20.
    assert run_epoch(sched, 6, later) == (["c", "e"], True)
    assert [k[1] for k in sched.training] == ["e", "c"]
    assert sched.budget[("mw", "e")] == 20 and sched.budget[("mw", "c")] == 20
    # epoch 7: e 20/20 spent, mean 1: unsolvable; c 20/20, mean 5: main.
    assert run_epoch(sched, 7, later) == (["c", "e"], False)
    assert pools(sched) == ([], ["c"], ["a", "d"], ["b", "e"])
    # epochs 8-11: main holds only c, so one slot trains (fewer slots). Budgets
    # 0.5 * (200 - B_used) / 2 with B_used 160, 170, 180, 190: 10, 7, 5, 2; each spent by one
    # episode, c back to main each time. Epoch 10 resets (180 // 60 = 3).
    for epoch, budget, reset_due in [(8, 10, False), (9, 7, False), (10, 5, True), (11, 2, False)]:
        assert run_epoch(sched, epoch, later) == (["c"], reset_due)
        assert sched.budget[("mw", "c")] == budget
        assert pools(sched) == ([], ["c"], ["a", "d"], ["b", "e"])
    assert sched.stage_used[1] == 200 and sched.stage == 1
    # epochs 12-14: stage 2, only the unsolvable pool {b, e} collects, no resets, no scores.
    for epoch in (12, 13, 14):
        assert run_epoch(sched, epoch, later) == (["b", "e"], False)
        assert sched.plan is not None and not sched.done
    assert sched.stage == 2 and sched.stage_used[2] == 60
    # epoch 15: B2 spent: done, nothing collects.
    assert run_epoch(sched, 15, later) == ([], False)
    assert sched.done
    # Budgets spent add up to B1 + B2, and per task: a 10, b 50 + 30, c 50 + 20 + 4 * 10, d 10, e 20 + 30.
    assert sched.budget_used == 260 == CONFIG.budget_stage1 + CONFIG.budget_stage2
    assert {k[1]: v for k, v in sched.used.items()} == {
        "a": 10,
        "b": 80,
        "c": 110,
        "d": 10,
        "e": 50,
    }


def test_random_first_pick_is_seeded_and_refill_waits_for_scores() -> None:
    tasks = {"mw": ("a", "b", "c", "d", "e")}

    def first_pick(seed: int) -> tuple[int, ...]:
        plan = build_scheduler(CONFIG, tasks, seed=seed).plan(Progress(epoch=0))
        return tuple(int(i) for i in np.flatnonzero(plan.collect["mw"]))

    assert first_pick(3) == first_pick(3)  # the same seed, the same pick
    picks = [first_pick(s) for s in range(20)]
    assert all(len(p) == 2 for p in picks)  # K = 2 distinct tasks
    # Random over seeds: 10 possible pairs; a fixed rule (e.g. the first K tasks) would give one.
    # 20 uniform draws give >= 5 distinct pairs with probability > 0.999; the seeds are fixed.
    assert len(set(picks)) >= 5


def test_budgets_add_up_with_random_returns_and_uneven_episodes() -> None:
    """Budgets spent = B1 + B2 up to one epoch's collection per stage (epochs are never cut)."""
    rng = np.random.default_rng(0)
    config = SMTConfig(
        budget_stage1=5000,
        budget_stage2=1000,
        kappa=0.8,
        slots=3,
        solved_return={"mw": 8.0, "fk": 4.0},
        unsolvable_return={"mw": 2.0, "fk": 1.0},
        score_interval=700,
        reset_interval=700,
    )
    env_tasks = {"mw": tuple("abcdef"), "fk": tuple("xyz")}
    lengths = {"mw": 50, "fk": 28}
    sched = build_scheduler(config, env_tasks, seed=1)
    epoch = 0
    while not sched.done and epoch < 10_000:
        plan = sched.plan(Progress(epoch=epoch))
        for env, mask in plan.collect.items():
            names = [t for t, c in zip(env_tasks[env], mask, strict=True) if c]
            if names:
                sched.observe_episodes(
                    env,
                    names,
                    rng.uniform(0, 10, len(names)).tolist(),
                    [0.0] * len(names),
                    [lengths[env]] * len(names),
                )
        if (request := sched.wants_scores()) is not None:
            sched.observe_scores({k: float(rng.uniform()) for k in request.tasks})
        epoch += 1
    assert sched.done
    per_epoch_max = 3 * 50  # K slots of the longest episode
    assert 5000 <= sched.stage_used[1] < 5000 + per_epoch_max
    if sched.members("unsolvable"):
        assert 1000 <= sched.stage_used[2] < 1000 + 9 * 50
    assert sum(sched.used.values()) == sched.budget_used


def test_state_dict_round_trip_resumes_identically(tmp_path) -> None:
    def drive(sched: SMTScheduler, epochs: range) -> list[tuple[list[str], bool]]:
        return [run_epoch(sched, e, {"a": 9, "b": 9, "c": 2, "d": 0, "e": 1}) for e in epochs]

    straight = make()
    expected = drive(straight, range(16))
    first = make()
    drive(first, range(6))
    state = json.loads(json.dumps(first.state_dict()))  # must survive JSON
    resumed = make()
    resumed.load_state_dict(state)
    assert drive(resumed, range(6, 16)) == expected[6:]
    assert resumed.timeline() == straight.timeline()
    # The timeline plots of SMT Fig. 6 and pool membership render from the records.
    timeline = resumed.timeline()
    pools = {STATUS_COLOURS[str(r["status"]).split(":")[-1]] for r in timeline}
    drawn = colours_drawn(plot_membership(timeline, tmp_path / "pools.png"), sorted(pools))
    assert len(pools) >= 2 and drawn == pools
    cycle = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    tasks = len({(r["env"], r["task"]) for r in timeline})
    usage = plot_budget_usage(timeline, tmp_path / "usage.png")
    assert colours_drawn(usage, cycle[:tasks]) == set(cycle[:tasks])


def test_timeline_records_pool_changes() -> None:
    sched = make()
    sched.observe_scores(
        {("mw", t): s for t, s in {"a": 1, "b": 2, "c": 3, "d": 4, "e": 5}.items()}
    )
    run_epoch(sched, 0, {t: 0.0 for t in "abcde"})
    run_epoch(sched, 1, {t: 0.0 for t in "abcde"})
    rows = [r for r in sched.timeline() if r["task"] == "a"]
    # epoch 0: a in training; epoch 1: the snapshot after a was solved (and c refilled).
    assert [(r["epoch"], r["status"]) for r in rows] == [(0, "training"), (1, "solved")]
    assert rows[1]["used"] == 10 and rows[1]["env_steps"] == 20 and rows[1]["budget"] == 50


def test_kitchen_defaults_scale_with_episode_length() -> None:
    sched = build_scheduler(
        SMTConfig(),
        {"mw": ("a",), "fk": ("b",)},
        adapters={"mw": "metaworld", "fk": "franka_kitchen_dense"},
    )
    # Paper values M = 4000, m = 1000 for 500-step episodes; the kitchen's are x 280 / 500.
    assert sched.solved_return == {"mw": 4000.0, "fk": 2240.0}
    assert sched.unsolvable_return == {"mw": 1000.0, "fk": 560.0}
    point = build_scheduler(SMTConfig(), {"point": ("a",)}, episode_lengths={"point": 50})
    assert point.solved_return == {"point": 400.0}


def test_bad_values_name_the_key() -> None:
    with pytest.raises(ConfigError, match=r"scheduler.kappa = 1.5"):
        build_scheduler(SMTConfig(kappa=1.5), {"mw": ("a",)}, adapters={"mw": "metaworld"})
    with pytest.raises(ConfigError, match=r"scheduler.solved_return.point"):
        build_scheduler(SMTConfig(), {"point": ("a",)})
    with pytest.raises(ConfigError, match=r"unknown env\(s\) \['kitchen'\]"):
        build_scheduler(
            SMTConfig(solved_return={"kitchen": 1.0}), {"mw": ("a",)}, adapters={"mw": "metaworld"}
        )


def test_early_end_of_stage_1_hands_the_leftover_budget_to_stage_2() -> None:
    # Both tasks return 1 < m = 2. Budgets 0.1 * 1000 / 2 = 50 env steps = 5 episodes of 10.
    config = SMTConfig(
        budget_stage1=1000,
        budget_stage2=60,
        kappa=0.1,
        slots=2,
        solved_return={"mw": 8.0},
        unsolvable_return={"mw": 2.0},
        score_interval=10_000,
        reset_interval=10_000,
    )
    sched = build_scheduler(config, {"mw": ("a", "b")})
    epoch = 0
    while not sched.done:
        plan = sched.plan(Progress(epoch=epoch))
        names = [t for t, c in zip(("a", "b"), plan.collect["mw"], strict=True) if c]
        if names:
            sched.observe_episodes(
                "mw", names, [1.0] * len(names), [0.0] * len(names), [L] * len(names)
            )
        epoch += 1
    # Epochs 0-4 spend 100 env steps and make both unsolvable; with main and training empty,
    # stage 2 starts at epoch 5 with B2 + (B1 - 100) = 960 env steps: 48 epochs of 20. The
    # epoch-53 plan finds them spent and ends the run.
    assert sched.stage_used == {1: 100, 2: 960} and sched.stage2_budget == 960
    assert epoch == 54
    assert sched.budget_used == config.budget_stage1 + config.budget_stage2
