"""The kitchen bench's goals and rules on hand-made runs: the rewards-alone, v4 and issue 54 goals,
the collapse test, the reward test (v4 against v3) and the learner test (a critic change against
the plain critic or LayerNorm), with their verdicts and printed lines."""

from __future__ import annotations

from seal.experiments.kitchen import (
    _format_collapse_test,
    _format_default_ended,
    _format_learner_test,
    _format_reward_test,
    _format_v4,
    collapse_test,
    default_ended_goal,
    learner_key,
    learner_test,
    reward_test,
    rewards_alone_goal,
    v4_goal,
)


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
