"""`seal bench --learn kitchen`: the arms, reading a run's first crossing, and a tiny end-to-end run."""

from __future__ import annotations

import dataclasses
import json
import shutil
import warnings
from pathlib import Path

import pandas as pd
import pytest

from seal import load_run
from seal.errors import SealError, SealWarning
from seal.experiments.kitchen import (
    ARMS,
    _format_collapse_test,
    _format_default_ended,
    _format_learner_test,
    _format_reward_test,
    _format_v4,
    arm_config,
    arms,
    collapse_test,
    default_ended_goal,
    end_mean_q,
    end_q_ratio,
    format_result,
    learner_key,
    learner_test,
    pinned_version,
    reward_test,
    rewards_alone_goal,
    run_figures,
    run_kitchen_bench,
    v4_goal,
)
from seal.protocols import load_protocol


def _metrics(success: list[float]) -> pd.DataFrame:
    """One task evaluated every 10 epochs of 280 steps (2,800 env steps), one update per step at batch 256."""
    n = len(success)
    epochs = [10 * (i + 1) for i in range(n)]
    return pd.DataFrame(
        {
            "seed": 0,
            "phase": "train",
            "env": "fk",
            "task": "slide-cabinet",
            "epoch": epochs,
            "success": success,
            "grad_steps": [280 * e - 4000 for e in epochs],
            "env_steps": [280 * e for e in epochs],
            "updates": [(280 * e - 4000) * 256 / 1e6 for e in epochs],
        }
    )


def test_run_figures_first_crossing_and_censored_total() -> None:
    # First >= 0.9 at the third evaluation: epoch 30, 8,400 env steps, 4,400 gradient steps,
    # 4,400 x 256 = 1.1264 M transitions; the later 0.8 does not undo it.
    reached = run_figures(_metrics([0.1, 0.5, 0.9, 0.8]))
    assert reached == {
        "reached": True,
        "env_steps": 8400,
        "grad_steps": 4400,
        "updates_m": pytest.approx(1.1264),
        "best_success": 0.9,
        "final_success": 0.8,
        "held_90": 0,
        "after_first": 1,
    }
    # Kept: two more evaluations at >= 90% of the three after the first crossing.
    kept = run_figures(_metrics([0.1, 0.9, 0.6, 1.0, 0.9]))
    assert (kept["held_90"], kept["after_first"]) == (2, 3)
    # Never reached: censored at the run's last evaluation (epoch 20: 5,600 steps, 1,600 updates).
    censored = run_figures(_metrics([0.3, 0.7]))
    assert (censored["reached"], censored["env_steps"], censored["grad_steps"]) == (
        False,
        5600,
        1600,
    )
    assert censored["updates_m"] == pytest.approx(0.4096)
    assert (censored["held_90"], censored["after_first"]) == (0, 0)


def test_end_mean_q_is_the_last_logged_mean_q() -> None:
    rows = [(280, "mean_q", 5.0), (560, "alpha/microwave", 0.1), (840, "mean_q", 7.5)]
    train = pd.DataFrame(rows[::-1], columns=["grad_steps", "key", "value"])  # out of order
    assert end_mean_q(train) == 7.5
    assert end_mean_q(train[train["key"] != "mean_q"]) is None


def test_end_q_ratio_is_the_last_evaluations_probe_ratio() -> None:
    rows = [(280, "eval_q_ratio/microwave", 4.0), (560, "mean_q", 9.0)]
    rows += [(840, "eval_q_ratio/microwave", 1.25), (840, "eval_q/microwave", 500.0)]
    train = pd.DataFrame(rows[::-1], columns=["grad_steps", "key", "value"])  # out of order
    assert end_q_ratio(train) == 1.25
    assert end_q_ratio(train[train["key"] == "mean_q"]) is None  # a run from before the probe


def test_arms_are_single_kitchen_protocols_differing_only_in_demonstrations() -> None:
    with warnings.catch_warnings():  # the v4 arms' candidate-reward warning (once per process)
        warnings.simplefilter("ignore", SealWarning)
        configs = {arm.name: load_protocol(arm.protocol) for arm in ARMS}
    for name, config in configs.items():
        assert config.evaluation.mode == "async", name  # off the loop's critical path
        assert config.kind == "baseline" and config.envs["fk"].adapter == "franka_kitchen_dense"
        v4 = "_v4" in name
        # v4 arms and the learner tests run all epochs
        runs_on = v4 or name.endswith(("_critic_ln", "_bronet"))
        assert config.evaluation.stop_when_reached is not runs_on, name
        assert config.envs["fk"].options == {"reward_version": "v4" if v4 else "v3"}, name
        # 535 epochs x 280 steps = 149,800 env steps: within the issue's 150k budget.
        assert config.protocol.epochs * config.envs["fk"].episode_length == 149_800
    for task in ("slide_cabinet", "light_switch", "bottom_left_burner"):
        plain, demos = configs[task], configs[f"{task}_demos"]
        assert plain.training.demo_episodes == 0 and demos.training.demo_episodes == 10
        assert dataclasses.replace(demos.training, demo_episodes=0) == plain.training
        assert (demos.agent, demos.envs, demos.evaluation) == (
            plain.agent,
            plain.envs,
            plain.evaluation,
        )
    for task in (
        "slide_cabinet",
        "light_switch",
        "bottom_left_burner",
        "microwave",
        "bottom_right_burner",
    ):
        v3, v4 = configs[task], configs[f"{task}_v4"]  # only the reward and stopping differ
        assert dataclasses.replace(v4.evaluation, stop_when_reached=True) == v3.evaluation
        assert (v4.agent, v4.training, v4.envs["fk"].tasks) == (
            v3.agent,
            v3.training,
            v3.envs["fk"].tasks,
        )
        assert v4.protocol.seeds == 3
        # The learner tests (issue 54; issue 37's collapse test on v4): one change to the arm,
        # with the v3 arm's stopping turned off as its records were made.
        for base in (task, f"{task}_v4"):
            plain, changed = configs[base], configs[f"{base}_critic_ln"]
            assert changed.agent == dataclasses.replace(plain.agent, critic_layer_norm=True)
            assert not plain.agent.critic_layer_norm
            assert (changed.training, changed.envs, changed.protocol.seeds) == (
                plain.training,
                plain.envs,
                3,
            )
            assert changed.evaluation == dataclasses.replace(
                plain.evaluation, stop_when_reached=False
            )
        # BroNet's learner test (issue 54 rule 3), on v3 only: the critic block is the one change.
        plain, bronet = configs[task], configs[f"{task}_bronet"]
        assert bronet.agent == dataclasses.replace(plain.agent, critic_block="bronet")
        assert (bronet.training, bronet.envs, bronet.protocol.seeds) == (
            plain.training,
            plain.envs,
            3,
        )
        assert bronet.evaluation == dataclasses.replace(plain.evaluation, stop_when_reached=False)
    with pytest.raises(SealError, match="unknown kitchen arm 'nope'"):
        arms(["nope"])


TINY = [
    "envs.fk.episode_length=5",
    "training.warmup_steps=0",
    "training.demo_episodes=1",
    "training.batch_per_task=4",
    "training.grad_steps_per_epoch=2",
    "evaluation.interval=1",
    "evaluation.episodes=1",
    "agent.hidden=[8]",
]
"""A kitchen arm shrunk to seconds: the plumbing only (epochs are each test's)."""


@pytest.mark.slow
def test_tiny_end_to_end(tmp_path, capsys) -> None:
    tiny = ["protocol.epochs=1", *TINY]
    result = run_kitchen_bench(seeds=1, out=tmp_path, overrides=tiny, only=["slide_cabinet_demos"])
    arm = result["arms"]["slide_cabinet_demos"]
    (figures,) = arm["per_seed"]
    # One epoch of 5 env steps and 2 updates of batch 4: 8 transitions; 5 demonstration steps aside.
    assert (figures["env_steps"], figures["grad_steps"]) == (5, 2)
    assert figures["updates_m"] == pytest.approx(8e-6)
    assert arm["demos"] == [{"episodes": 1, "env_steps": 5, "expert_success": 0.0}]
    assert not arm["learned_within_budget"] and result["goal"]["met"] is False
    assert result["goal"]["rewards_alone"]["met"] is None  # one arm of five run
    assert result["goal"]["v4"]["met"] is None
    # Its protocol stops at the first crossing; no v4 arm ran, so the reward test has nothing.
    assert arm["stop_when_reached"] is True
    assert result["reward_test"]["tasks"] == {} and result["reward_test"]["default"] is None
    assert "slide-cabinet + demos" in format_result(result)
    assert "reward test" not in format_result(result)
    # A second call, through the CLI with the same --set values, takes the finished run instead of
    # running it again.
    from seal.cli.main import main

    args = ["bench", "--learn", "kitchen", "--arms", "slide_cabinet_demos", "--seeds", "1"]
    args += ["--out", str(tmp_path), "--reuse", "--json"]
    assert main(args + [a for value in tiny for a in ("--set", value)]) == 0
    again = json.loads(capsys.readouterr().out)
    assert again["reused"] == ["slide_cabinet_demos/seed-0"] and again["overrides"] == tiny
    # A run record (the run without checkpoints/ and tb/, as results/ keeps one) is read by
    # --no-run, which runs nothing and names the seed it did not find.
    run = Path(result["run_dirs"]["slide_cabinet_demos/seed-0"])
    record = tmp_path / "records" / run.relative_to(tmp_path)
    shutil.copytree(run, record, ignore=shutil.ignore_patterns("checkpoints", "tb"))
    args[args.index("--out") + 1] = str(tmp_path / "records")
    args[args.index("--seeds") + 1] = "2"
    args[args.index("--reuse")] = "--no-run"
    assert main(args + [a for value in tiny for a in ("--set", value)]) == 0
    read = json.loads(capsys.readouterr().out)
    assert read["missing"] == ["slide_cabinet_demos/seed-1"]
    assert read["run_dirs"] == {"slide_cabinet_demos/seed-0": str(record)}
    assert read["arms"]["slide_cabinet_demos"]["per_seed"] == [{"seed": 0, **figures}]
    assert read["arms"]["slide_cabinet_demos"]["reached"] == "0/1"
    assert read["goal"]["met"] is False  # seed 0 already missed it
    assert sorted(p.name for p in record.parent.parent.rglob("seed-*")) == ["seed-0"]
    text = format_result(read)
    assert "s0 5+ (0.00)" in text
    assert "not run (--no-run found no finished run): slide_cabinet_demos/seed-1" in text
    assert main(["bench", "--learn", "table1", "--no-run"]) == 2
    assert "error: --no-run only applies to --learn kitchen" in capsys.readouterr().err


def test_rewards_alone_goal_counts_arms_reached_in_any_seed_within_budget() -> None:
    def arm(label: str, *seeds: tuple[bool, int]) -> dict:
        return {"label": label, "per_seed": [{"reached": r, "env_steps": n} for r, n in seeds]}

    five = {
        "slide_cabinet": arm("slide-cabinet", (False, 149_800), (True, 100_800)),
        "light_switch": arm("light-switch", (True, 84_000), (False, 149_800)),
        "bottom_left_burner": arm("bottom-left-burner", (False, 149_800), (False, 149_800)),
        "microwave": arm("microwave", (False, 149_800), (True, 150_200)),  # past the budget
        "bottom_right_burner": arm("bottom-right-burner", (True, 140_000), (True, 120_000)),
        "slide_cabinet_demos": arm("slide-cabinet + demos", (True, 5_600), (True, 5_600)),
    }
    goal = rewards_alone_goal(five)
    # The demonstrations arm does not count; microwave crossed only after 150,000 env steps.
    assert goal["reached"] == ["slide-cabinet", "light-switch", "bottom-right-burner"]
    assert (goal["of"], goal["ran"], goal["met"]) == (5, 5, False)
    five["microwave"] = arm("microwave", (True, 149_800), (False, 149_800))
    assert rewards_alone_goal(five)["met"] is True
    # With an arm missing the goal is met once four have reached 90%, else not judged.
    del five["bottom_left_burner"]
    assert (rewards_alone_goal(five)["met"], rewards_alone_goal(five)["all_ran"]) == (True, False)
    five["microwave"] = arm("microwave", (False, 149_800), (False, 149_800))
    assert rewards_alone_goal(five)["met"] is None
    # Not met before every arm has run once the arms not run cannot make up the shortfall: two
    # reached, bottom-left-burner alone not run.
    five["slide_cabinet"] = arm("slide-cabinet", (False, 149_800), (False, 149_800))
    assert (rewards_alone_goal(five)["met"], rewards_alone_goal(five)["all_ran"]) == (False, False)


def test_v4_goal_counts_tasks_reached_in_two_of_three_seeds_within_budget() -> None:
    def arm(label: str, *seeds: tuple[bool, int]) -> dict:
        return {"label": label, "per_seed": [{"reached": r, "env_steps": n} for r, n in seeds]}

    yes, no, late = (True, 100_000), (False, 149_800), (True, 150_200)
    five = {
        "slide_cabinet_v4": arm("slide-cabinet v4", yes, yes, no),
        "light_switch_v4": arm("light-switch v4", yes, no, no),  # one seed of three
        "bottom_left_burner_v4": arm("bottom-left-burner v4", yes, late, yes),
        "microwave_v4": arm("microwave v4", yes, late, no),  # the second past the budget
        "bottom_right_burner_v4": arm("bottom-right-burner v4", yes, yes, yes),
        "slide_cabinet": arm("slide-cabinet", yes, yes),  # a v3 arm: not counted
    }
    goal = v4_goal(five)
    assert goal["reached"] == [
        "slide-cabinet v4",
        "bottom-left-burner v4",
        "bottom-right-burner v4",
    ]
    assert (goal["of"], goal["ran"], goal["met"]) == (5, 5, False)
    five["light_switch_v4"] = arm("light-switch v4", yes, no, yes)
    assert v4_goal(five)["met"] is True
    assert rewards_alone_goal(five)["of"] == 5  # the v3 goal counts only the v3 arms
    assert v4_goal(five)["all_ran"] is True
    # Two seeds of one arm: met once four tasks have reached 90% in two seeds (a third seed cannot
    # undo a crossing), not judged while fewer have, since the third could add one.
    five["microwave_v4"] = arm("microwave v4", yes, yes)
    assert (v4_goal(five)["met"], v4_goal(five)["all_ran"]) == (True, False)
    assert _format_v4(v4_goal(five)).endswith(
        ": 5 (slide-cabinet v4, light-switch v4, bottom-left-burner v4, microwave v4, "
        "bottom-right-burner v4): met before every run was made (5 of 5 run, 3 seeds each needed; "
        "a later run cannot undo a crossing)"
    )
    five["light_switch_v4"] = arm("light-switch v4", yes, no, no)
    five["bottom_right_burner_v4"] = arm("bottom-right-burner v4", yes, no)
    assert (len(v4_goal(five)["reached"]), v4_goal(five)["met"]) == (3, None)
    assert _format_v4(v4_goal(five)).endswith(": not judged (5 of 5 run, 3 seeds each needed)")
    # Not met as soon as the seeds left cannot bring a fourth task to two. Two tasks have (slide-
    # cabinet, bottom-left-burner), light-switch cannot (one of three); bottom-right-burner and
    # microwave could in their third seed: not judged, until microwave's second seed misses too.
    five["microwave_v4"] = arm("microwave v4", yes, no)
    assert (len(v4_goal(five)["reached"]), v4_goal(five)["met"]) == (2, None)
    five["microwave_v4"] = arm("microwave v4", no, no)
    assert (v4_goal(five)["met"], v4_goal(five)["all_ran"]) == (False, False)
    assert _format_v4(v4_goal(five)).endswith(
        ": 2 (slide-cabinet v4, bottom-left-burner v4): not met before every run was made (5 of 5 "
        "run, 3 seeds each needed; the runs left cannot make up the shortfall)"
    )
    del five["microwave_v4"]  # an arm not run at all could still cross in two of its three seeds
    assert (v4_goal(five)["ran"], v4_goal(five)["met"]) == (4, None)
    five["bottom_right_burner_v4"] = arm("bottom-right-burner v4", yes, no, no)
    five["microwave_v4"] = arm("microwave v4", yes, yes, no)  # every run made, 3 tasks reached
    assert v4_goal(five)["met"] is False and _format_v4(v4_goal(five)).endswith(": not met")
    # A collapse-test arm is a learner change, not v4's evidence: it is not counted.
    five["microwave_v4"] = arm("microwave v4", no, no, no)
    five["microwave_v4_critic_ln"] = arm("microwave v4 + critic LN", yes, yes, yes)
    assert v4_goal(five)["of"] == 5
    assert v4_goal(five)["reached"] == ["slide-cabinet v4", "bottom-left-burner v4"]


def test_issue_54s_goal_counts_the_default_learners_runs_on_the_default_reward_that_end_at_90() -> (
    None
):
    default = [
        f"{t}_v4_critic_ln"
        for t in ("light_switch", "microwave", "slide_cabinet", "bottom_left_burner")
        + ("bottom_right_burner",)
    ]

    def arm(name: str, *finals: float) -> dict:
        per_seed = [{"seed": s, "final_success": f} for s, f in enumerate(finals)]
        return {"label": name.replace("_", "-"), "per_seed": per_seed}

    # Today's defaults (LayerNorm critic, MLP block, reward v4) make the v4 + LayerNorm arms these.
    assert default_ended_goal({})["arms"] == default
    five = {name: arm(name, 1.0, 0.9, 1.0) for name in default}  # 0.9 ends at 90%
    five["microwave_v4"] = arm("microwave_v4", 1.0, 1.0, 1.0)  # the plain critic: not counted
    five["slide_cabinet_v4_critic_ln"] = arm("slide_cabinet_v4_critic_ln", 1.0, 0.8, 0.0, 1.0)
    goal = default_ended_goal(five)
    # 4 arms x 3 + slide-cabinet's seed 0 (its seed 3 is past the rule's seeds) = 13 of 15.
    assert (goal["of"], goal["made"], len(goal["ended"]), goal["met"]) == (15, 15, 13, True)
    assert "slide-cabinet-v4-critic-ln s1" not in goal["ended"]
    five["light_switch_v4_critic_ln"] = arm("light_switch_v4_critic_ln", 0.0, 0.5, 1.0)
    assert (len(default_ended_goal(five)["ended"]), default_ended_goal(five)["met"]) == (11, False)
    # With runs left: met once 12 have ended at 90%, not met once the rest cannot make up the
    # shortfall, not judged between.
    five["light_switch_v4_critic_ln"] = arm("light_switch_v4_critic_ln", 1.0)
    five["slide_cabinet_v4_critic_ln"] = arm("slide_cabinet_v4_critic_ln", 1.0, 0.0)
    goal = default_ended_goal(five)
    assert (goal["made"], len(goal["ended"]), goal["met"]) == (12, 11, None)
    labels = {n: n for n in five}
    assert _format_default_ended(goal, labels).endswith(
        "end >= 90%: 11 of 12 made: not judged (12 of 15 runs made)"
    )
    five["light_switch_v4_critic_ln"] = arm("light_switch_v4_critic_ln", 1.0, 1.0)
    goal = default_ended_goal(five)
    assert (goal["made"], len(goal["ended"]), goal["met"], goal["all_ran"]) == (13, 12, True, False)
    assert _format_default_ended(goal, labels).endswith(
        ": 12 of 13 made: met before every run was made (13 of 15 runs made; a run made cannot "
        "change how it ended)"
    )
    five["light_switch_v4_critic_ln"] = arm("light_switch_v4_critic_ln", 0.0, 0.0)
    five["microwave_v4_critic_ln"] = arm("microwave_v4_critic_ln", 1.0, 1.0, 0.1)
    goal = default_ended_goal(five)  # 0 + 2 + 1 + 3 + 3 = 9 ended, 2 runs left: at most 11
    assert (goal["made"], len(goal["ended"]), goal["met"]) == (13, 9, False)


def test_the_collapse_test_sets_each_seed_against_v4_alone() -> None:
    def arm(label: str, *seeds: tuple[float, int]) -> dict:
        return {
            "label": label,
            "per_seed": [{"seed": s, "final_success": f, "held_90": h} for s, f, h in seeds],
        }

    result_arms = {
        "light_switch_v4": arm("light-switch v4", (0, 0.2, 1), (1, 0.0, 0), (2, 1.0, 30)),
        "light_switch_v4_critic_ln": arm("light-switch v4 + critic LN", (0, 0.9, 12), (1, 0.1, 0)),
        "microwave_v4_critic_ln": arm("microwave v4 + critic LN", (0, 1.0, 40)),  # v4 alone not run
    }
    tests = collapse_test(result_arms)
    assert tests == {  # the two seeds both arms ran, in seed order
        "light_switch_v4_critic_ln": {
            "against": "light_switch_v4",
            "seeds": [0, 1],
            "final_success": [0.9, 0.1],
            "final_success_alone": [0.2, 0.0],
            "held_90": [12, 0],
            "held_90_alone": [1, 0],
        }
    }
    labels = {k: a["label"] for k, a in result_arms.items()}
    (line,) = _format_collapse_test(tests, labels)
    assert line == (
        "collapse test, light-switch v4 + critic LN against light-switch v4, seeds 0, 1: final "
        "success 0.9, 0.1 against 0.2, 0; evaluations >= 90% after the first 12, 0 against 1, 0"
    )
    # Seeds are paired by number, not by position: seed 2 of the change against seed 2 alone.
    result_arms["light_switch_v4_critic_ln"]["per_seed"] = arm("", (2, 0.7, 5))["per_seed"]
    (line,) = _format_collapse_test(collapse_test(result_arms), labels)
    assert "light-switch v4, seed 2: final success 0.7 against 1;" in line
    # A change whose seeds v4 alone has not run is not set against it.
    result_arms["light_switch_v4"]["per_seed"].pop()
    assert collapse_test(result_arms) == {}


FIVE = ("slide_cabinet", "light_switch", "bottom_left_burner", "microwave", "bottom_right_burner")
"""The five demonstration-free tasks the rules compare."""


def test_the_reward_test_sets_v4_against_v3_seed_for_seed_and_applies_the_rule() -> None:
    def arm(label: str, *seeds: tuple[int, int | None, float], stops: bool = False) -> dict:
        """Runs as (seed, env steps at the first crossing or None, final success)."""
        return {
            "label": label,
            "stop_when_reached": stops,
            "per_seed": [
                {
                    "seed": s,
                    "reached": at is not None,
                    "env_steps": 149_800 if at is None else at,
                    "final_success": f,
                }
                for s, at, f in seeds
            ],
        }

    result_arms = {
        # v4 crosses in 3 of 3 and ends at >= 0.9 in 1 (0.9 counts); v3 crosses in 1 and ends in 1.
        "light_switch_v4": arm(
            "light-switch v4", (0, 14_000, 0.0), (1, 50_000, 0.9), (2, 90_000, 0.2)
        ),
        "light_switch": arm("light-switch", (2, 84_000, 1.0), (1, None, 0.0), (0, None, 0.0)),
        # Seed 1 of v3 only: one pair; v4 never crosses, v3 does past the budget (not counted).
        "microwave_v4": arm("microwave v4", (1, None, 0.0), (2, None, 0.1)),
        "microwave": arm("microwave", (1, 151_200, 1.0)),
        # A run that stopped at its first crossing has no final success: not set against the other.
        "slide_cabinet_v4": arm("slide-cabinet v4", (0, 11_200, 0.9)),
        "slide_cabinet": arm("slide-cabinet", (0, 86_800, 0.9), stops=True),
        "bottom_left_burner_v4": arm("bottom-left-burner v4", (0, 11_200, 0.9), stops=True),
        "bottom_left_burner": arm("bottom-left-burner", (0, 86_800, 0.9)),
        # Seed 3 is past the seeds the rule names: not counted.
        "bottom_right_burner_v4": arm("bottom-right-burner v4", (3, 11_200, 1.0)),
        "bottom_right_burner": arm("bottom-right-burner", (3, None, 0.0)),
    }
    test = reward_test(result_arms)
    assert test["tasks"] == {
        "light_switch_v4": {
            "against": "light_switch",
            "seeds": [0, 1, 2],  # paired by seed number, not by position
            "crossed": [True, True, True],
            "crossed_v3": [False, False, True],
            "ended_90": [False, True, False],
            "ended_90_v3": [False, False, True],
            "final_success": [0.0, 0.9, 0.2],
            "final_success_v3": [0.0, 0.0, 1.0],
        },
        "microwave_v4": {
            "against": "microwave",
            "seeds": [1],
            "crossed": [False],
            "crossed_v3": [False],
            "ended_90": [False],
            "ended_90_v3": [True],
            "final_success": [0.0],
            "final_success_v3": [1.0],
        },
    }
    # Each side's runs count on their own: v4 over light-switch 0-2, microwave 1-2, slide-cabinet 0;
    # v3 over light-switch 0-2, microwave 1, bottom-left-burner 0 (its v4 arm stopped).
    assert {
        k: test[k]
        for k in ("of", "made", "made_v3", "crossed", "crossed_v3", "ended_90", "ended_90_v3")
    } == {
        "of": 15,  # five v4 tasks, three seeds
        "made": 6,
        "made_v3": 5,
        "crossed": 4,
        "crossed_v3": 2,
        "ended_90": 2,
        "ended_90_v3": 3,
    }
    assert test["default"] is None  # 9 and 10 runs left: either way is still open
    labels = {k: a["label"] for k, a in result_arms.items()}
    lines = _format_reward_test(test, labels)
    assert lines[0] == (
        "reward test with the plain critic, light-switch v4 against light-switch, seeds 0, 1, 2: "
        "crossed 90% within the budget 1, 1, 1 "
        "against 0, 0, 1; final success 0, 0.9, 0.2 against 0, 0, 1"
    )
    assert lines[-1] == (
        "reward test with the plain critic, v4 against v3, seeds 0-2 of 5 tasks: crossed 90% in 4 "
        "of 6 runs made against 2 of 5, ended >= 90% in 2 against 3; the rule's verdict (v4 if it crosses in more "
        "runs and ends in at least as many, of 15 each): not decided (the runs left could change it)"
    )

    five = FIVE
    # Four tasks with seeds 0-3 and the fifth not run: v4 crosses and ends at >= 0.9 in 12 runs, v3
    # in none; the fifth task's 3 runs a side cannot change it, so v4 is decided with 12 of 15 made.
    full = {}
    for task in five[:4]:
        full[f"{task}_v4"] = arm(f"{task} v4", *[(s, 20_000, 1.0) for s in range(4)])
        full[task] = arm(task, *[(s, None, 0.0) for s in range(4)])
    test = reward_test(full)
    assert (test["made"], test["made_v3"], test["default"]) == (12, 12, "v4")
    assert _format_reward_test(test, {n: a["label"] for n, a in full.items()})[-1].endswith(
        ": v4 (no run left to make can change it)"
    )
    # v3 ends at >= 0.9 in 4 runs; v4 in none of 12, so at most 3 with its 3 runs left: v3.
    early = {
        "slide_cabinet": arm("slide-cabinet", *[(s, 20_000, 1.0) for s in range(3)]),
        "light_switch": arm("light-switch", (0, 20_000, 1.0)),
        "slide_cabinet_v4": arm("slide-cabinet v4", (0, 20_000, 0.0)),
        "light_switch_v4": arm("light-switch v4", (0, 20_000, 0.0), (1, 20_000, 0.0)),
        **{f"{t}_v4": arm(t, *[(s, 20_000, 0.0) for s in range(3)]) for t in five[2:]},
    }
    assert reward_test(early)["default"] == "v3"
    # v3 at >= 0.9 in 3: v4's 3 runs left could all end there and tie it, so it is open again.
    early["light_switch"]["per_seed"][0]["final_success"] = 0.0
    assert reward_test(early)["default"] is None
    # Every pair made: v4 crosses in more runs but ends at >= 0.9 in fewer, so v3 stays.
    full = {}
    for task in five:
        full[f"{task}_v4"] = arm(f"{task} v4", *[(s, 20_000, 0.0) for s in range(3)])
        full[task] = arm(task, (0, 20_000, 1.0), (1, None, 0.0), (2, None, 0.0))
    # The collapse test's arm is a learner change, not v4 against v3: it changes nothing.
    full["light_switch_v4_critic_ln"] = arm("light-switch v4 + critic LN", (1, 8_400, 1.0))
    test = reward_test(full)
    totals = ("made", "made_v3", "crossed", "crossed_v3", "ended_90", "ended_90_v3")
    assert [test[k] for k in totals] == [15, 15, 15, 5, 0, 5]
    assert test["default"] == "v3"
    # v4 ending at >= 0.9 as often as v3 (here in seed 0 of each task) and crossing more: v4.
    for task in five:
        full[f"{task}_v4"]["per_seed"][0]["final_success"] = 1.0
    assert reward_test(full)["default"] == "v4"
    # Crossing in as many runs as v3, not more: v3 stays, and a fourth seed that v4 alone crosses
    # in does not tip it.
    for task in five:
        full[task] = arm(task, *[(s, 30_000, 1.0) for s in range(3)], (3, None, 0.0))
        full[f"{task}_v4"] = arm(f"{task} v4", *[(s, 20_000, 1.0) for s in range(4)])
    assert (reward_test(full)["made"], reward_test(full)["default"]) == (15, "v3")


def test_the_learner_test_applies_issue_54s_rule_and_the_reward_test_pairs_by_learner() -> None:
    def arm(*seeds: tuple[int, bool, float]) -> dict:
        """Runs as (seed, crossed within the budget, final success), stopping off."""
        return {
            "label": "",
            "stop_when_reached": False,
            "per_seed": [
                {"seed": s, "reached": c, "env_steps": 30_000, "final_success": f}
                for s, c, f in seeds
            ],
        }

    five = FIVE
    # Today's v3 records in shape: crossed in 8 of 15, ended >= 0.9 in 2.
    plain = [[(0, True, 1.0), (1, True, 1.0), (2, True, 0.1)]] + [
        [(0, True, 0.0), (1, i < 1, 0.0), (2, False, 0.0)] for i in range(4)
    ]
    runs = {t: arm(*p) for t, p in zip(five, plain, strict=True)}
    # LayerNorm: crosses in 8 and ends in 3 of its first 14 runs; its last run cannot change it.
    ln = [[(0, True, 1.0), (1, True, 1.0), (2, True, 1.0)]] + [
        [(0, True, 0.0), (1, i < 1, 0.0), (2, False, 0.0)] for i in range(4)
    ]
    ln[-1].pop()
    runs |= {f"{t}_critic_ln": arm(*p) for t, p in zip(five, ln, strict=True)}
    test = learner_test(runs)
    totals = ("made", "made_plain", "crossed", "crossed_plain", "ended_90", "ended_90_plain")
    assert [test[k] for k in totals] == [14, 15, 8, 8, 3, 2]
    assert test["default"] == "critic LN"  # more endings, as many crossings: decided at 14 of 15
    assert test["tasks"]["slide_cabinet_critic_ln"]["ended_90_plain"] == [True, True, False]
    # One fewer crossing: the last run could make it up, so it is open again.
    runs["slide_cabinet_critic_ln"]["per_seed"][2]["reached"] = False
    assert learner_test(runs)["default"] is None
    # Ending in no more runs than the plain critic, with every run made: the plain critic stays.
    runs["bottom_right_burner_critic_ln"]["per_seed"].append(
        {"seed": 2, "reached": True, "env_steps": 30_000, "final_success": 0.0}
    )
    runs["slide_cabinet_critic_ln"]["per_seed"][2]["final_success"] = 0.0
    assert learner_test(runs)["default"] == "plain"
    # The reward test on the LayerNorm learner pairs <task>_v4_critic_ln with <task>_critic_ln,
    # and the plain learner's reward test sees none of them.
    runs["microwave_v4_critic_ln"] = arm((0, True, 1.0))
    with_ln = reward_test(runs, "_critic_ln")
    assert with_ln["tasks"]["microwave_v4_critic_ln"]["against"] == "microwave_critic_ln"
    assert (with_ln["made"], with_ln["made_v3"]) == (1, 15)
    assert reward_test(runs)["made"] == 0
    # BroNet's learner test pairs <task>_bronet with <task> and reads none of the LayerNorm arms:
    # ending in 3 of 15 against 2, crossing in 8 as the plain critic, it wins as "BroNet".
    runs |= {f"{t}_bronet": arm(*p) for t, p in zip(five, ln, strict=True)}
    runs["bottom_right_burner_bronet"]["per_seed"].append(
        {"seed": 2, "reached": False, "env_steps": 30_000, "final_success": 0.0}
    )
    bronet = learner_test(runs, "_bronet")
    assert [bronet[k] for k in totals] == [15, 15, 8, 8, 3, 2]
    assert bronet["default"] == "BroNet"
    assert bronet["tasks"]["microwave_bronet"]["against"] == "microwave"
    # Against LayerNorm (ended in 2 of 15, crossed in 8 after the edits above), the same 15 BroNet
    # runs win too: its side's keys end in "_critic_ln".
    against_ln = learner_test(runs, "_bronet", "_critic_ln")
    ln_totals = [t.replace("_plain", "_critic_ln") for t in totals]
    assert [against_ln[k] for k in ln_totals] == [15, 15, 8, 8, 3, 2]
    assert against_ln["tasks"]["microwave_bronet"]["against"] == "microwave_critic_ln"
    assert against_ln["default"] == "BroNet"
    # One more LayerNorm run ending >= 0.9 (3 against 3): LayerNorm stays, named as such.
    runs["slide_cabinet_critic_ln"]["per_seed"][2]["final_success"] = 1.0
    assert learner_test(runs, "_bronet", "_critic_ln")["default"] == "critic LN"
    # Rows as the bench prints them: the comparison named, each side by its learner's name.
    assert learner_key("_bronet", "_critic_ln") == "learner_test_bronet_vs_critic_ln"
    labels = {name: name for name in runs}
    test = learner_test(runs, "_bronet", "_critic_ln")
    lines = _format_learner_test(test, labels, "_bronet", "_critic_ln")
    assert lines[0].startswith(
        "learner test (BroNet), slide_cabinet_bronet against slide_cabinet_critic_ln, seeds 0, 1, 2:"
    )
    (line,) = [line for line in lines if "seeds 0-2" in line]
    assert line.startswith("learner test (BroNet), BroNet against critic LN,")
    assert "crossed 90% in 8 of 15 runs made against 8 of 15, ended >= 90% in 3 against 3" in line
    assert line.endswith("critic LN (no run left to make can change it)")


@pytest.mark.slow
def test_a_run_a_session_left_unfinished_is_resumed_not_restarted(tmp_path) -> None:
    """`--reuse` continues an unfinished run from its last checkpoint (`seal run --resume`) in
    its own directory, where it used to start the seed again from epoch 1."""
    tiny = ["protocol.epochs=2", "checkpoint.interval=1", *TINY]
    only = ["slide_cabinet_demos"]
    first = run_kitchen_bench(seeds=1, out=tmp_path, overrides=tiny, only=only)
    run = Path(first["run_dirs"]["slide_cabinet_demos/seed-0"])
    full = pd.read_csv(run / "metrics.csv")
    # As a session that ended during epoch 2 leaves it: no epoch-2 checkpoint, rows or end time.
    (run / "checkpoints" / "ckpt-0000002.pt").unlink()
    full[full["epoch"] < 2].to_csv(run / "metrics.csv", index=False)
    provenance = json.loads((run / "provenance.json").read_text())
    provenance["end_time"] = None
    (run / "provenance.json").write_text(json.dumps(provenance))
    logs: list[str] = []
    again = run_kitchen_bench(
        seeds=1, out=tmp_path, overrides=tiny, only=only, reuse=True, log=logs.append
    )
    assert any(line.startswith("resume slide_cabinet_demos seed 0") for line in logs), logs
    assert again["reused"] == [] and Path(again["run_dirs"]["slide_cabinet_demos/seed-0"]) == run
    resumed = pd.read_csv(run / "metrics.csv")
    assert resumed["epoch"].tolist() == full["epoch"].tolist()  # epoch 2 run again, once
    assert json.loads((run / "provenance.json").read_text())["end_time"]


RECORDS = Path(__file__).resolve().parents[1] / "results" / "kitchen_learn"
"""The committed records of the kitchen learning runs (results/README.md)."""


def test_every_committed_run_record_is_read_as_a_finished_run_of_todays_protocol() -> None:
    """A record that today's code would not take (a default changed under it, a file missing) is
    silently left out of `--no-run`'s table: this names it instead. The v3 arms ran with
    `evaluation.stop_when_reached=false`, as the issue-37 table sets them beside v4."""
    by_protocol = {arm_config(a).name: a for a in ARMS}
    records = sorted(RECORDS.glob("*/*/seed-*"))
    assert records, f"no run records under {RECORDS}"
    with warnings.catch_warnings():  # the v4 records' candidate-reward warning, expected here
        warnings.simplefilter("ignore", SealWarning)
        taken = {r: _taken(r, by_protocol) for r in records}
    for record, (arm, found) in taken.items():
        seed = int(record.name.removeprefix("seed-"))
        assert found == record, f"{record}: not taken as the finished run of {arm.name} seed {seed}"
        run = load_run(record)
        assert run.metrics["epoch"].max() == arm_config(arm).protocol.epochs  # stopping off
        assert run.provenance["reward_versions"] == {"franka_kitchen_dense": pinned_version(arm)}


def _taken(record: Path, by_protocol: dict) -> tuple:
    """(the record's arm, the run `--no-run` takes for its arm and seed)."""
    from seal.experiments.records import finished_run

    arm = by_protocol[record.parents[1].name]
    seed = int(record.name.removeprefix("seed-"))
    return arm, finished_run(arm, seed, RECORDS, ["evaluation.stop_when_reached=false"])
