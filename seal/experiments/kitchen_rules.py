"""The kitchen bench's paired comparisons and the rules written before their runs.

Every comparison sets one arm against another seed for seed (seeds paired by number), over the
runs made with stopping off (a run that stopped at its first crossing has no final success):
- `collapse_test`: a learner change (`<arm>_critic_ln`) against its arm: final success and the
  evaluations >= 90% after the first (issue 37, on v4; issue 54, on v3 too).
- `reward_test`: v4 against v3 on one learner (issue 37's rule: v4 becomes the default if it
  crosses 90% in more runs and ends at >= 90% in at least as many, of 15 each).
- `learner_test`: a learner change against the plain critic (or another learner) on reward v3
  (issue 54's rule, docs/hyperparameters.md: LayerNorm becomes the default if it ends at >= 90% in
  more runs and crosses in at least as many, of 15 each).
A rule's verdict is given as soon as no run left to make could change it, None before.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from seal.evaluation import SUCCESS_TOLERANCE
from seal.metrics import DEFAULT_THRESHOLD

RULE_SEEDS = 3
"""The seeds the rules name: 0 to RULE_SEEDS - 1 of each task."""
ENV_STEP_BUDGET = 150_000
"""Env steps per task within which each arm must reach 90% (issue 11), and a crossing counts."""


def _paired(
    arm: Mapping[str, Any], other: Mapping[str, Any], keys: Sequence[str], other_suffix: str
) -> dict[str, Any] | None:
    """Two arms' figures seed for seed, over the seeds both ran (paired by number): `seeds`, and per
    key the arm's list and the other's (`<key><other_suffix>`); None if they share no seed."""
    theirs = {f["seed"]: f for f in other["per_seed"]}
    pairs = [(f, theirs[f["seed"]]) for f in arm["per_seed"] if f["seed"] in theirs]
    if not pairs:
        return None
    return {
        "seeds": [f["seed"] for f, _ in pairs],
        **{
            f"{key}{suffix}": [p[i][key] for p in pairs]
            for key in keys
            for i, suffix in enumerate(("", other_suffix))
        },
    }


def within_budget(figures: Mapping[str, Any]) -> bool:
    """Whether a run crossed 90% within `ENV_STEP_BUDGET` env steps."""
    return bool(figures["reached"] and figures["env_steps"] <= ENV_STEP_BUDGET)


def ended_90(figures: Mapping[str, Any]) -> bool:
    """Whether a run's final evaluation was at >= 90% success."""
    return bool(figures["final_success"] >= DEFAULT_THRESHOLD - SUCCESS_TOLERANCE)


def _judged(arm: Mapping[str, Any]) -> list[dict[str, Any]]:
    """An arm's runs of the seeds the rules name, each with its two verdicts: crossed 90% within
    the budget, final success >= 90%."""
    return [
        {
            **f,
            "crossed": within_budget(f),
            "ended_90": ended_90(f),
        }
        for f in arm["per_seed"]
        if f["seed"] < RULE_SEEDS
    ]


def collapse_test(result_arms: Mapping[str, Any], suffix: str) -> dict[str, Any]:
    """Per arm `<arm><suffix>` run beside `<arm>`: seed for seed (the seeds both ran), the final
    success and the evaluations >= 90% after the first (`held_90`), the change's and the arm's."""
    out: dict[str, Any] = {}
    for name, arm in result_arms.items():
        alone = name.removesuffix(suffix)
        if alone == name or alone not in result_arms:
            continue
        paired = _paired(arm, result_arms[alone], ("final_success", "held_90"), "_alone")
        if paired is not None:
            out[name] = {"against": alone, **paired}
    return out


def rule_test(
    result_arms: Mapping[str, Any],
    pairs: Sequence[tuple[str, str]],
    old: str,
    strict: str,
    weak: str,
) -> dict[str, Any]:
    """(new arm, old arm) per task over seeds 0 to RULE_SEEDS - 1, runs with stopping off only: per
    task whose two arms share a seed, their crossings, endings >= 90% and final successes seed for
    seed; per side the runs made, how many crossed and how many ended >= 90% (the old side's keys
    end in `old`); `new_wins` True if the new side has more runs of `strict` and at least as many
    of `weak` (keys "crossed" or "ended_90"), False if not, as soon as no run left could change
    it, else None. With every run made it is the rule applied to the totals."""
    tasks: dict[str, Any] = {}
    totals = {f"{k}{s}": 0 for k in ("made", "crossed", "ended_90") for s in ("", old)}
    for new_name, old_name in pairs:
        judged = {}
        for suffix, name in (("", new_name), (old, old_name)):
            arm = result_arms.get(name)
            if arm is None or arm.get("stop_when_reached", True):
                continue
            judged[suffix] = runs = _judged(arm)
            totals[f"made{suffix}"] += len(runs)
            totals[f"crossed{suffix}"] += sum(f["crossed"] for f in runs)
            totals[f"ended_90{suffix}"] += sum(f["ended_90"] for f in runs)
        if len(judged) == 2:
            keys = ("crossed", "ended_90", "final_success")
            paired = _paired({"per_seed": judged[""]}, {"per_seed": judged[old]}, keys, old)
            if paired is not None:
                tasks[new_name] = {"against": old_name, **paired}
    of = len(pairs) * RULE_SEEDS

    def bounds(key: str, suffix: str) -> tuple[int, int]:
        """The fewest and the most runs of `key` once all are made (a run left may go either way)."""
        return totals[key + suffix], totals[key + suffix] + of - totals["made" + suffix]

    new_s, old_s = bounds(strict, ""), bounds(strict, old)
    new_w, old_w = bounds(weak, ""), bounds(weak, old)
    new_wins = None
    if new_s[0] > old_s[1] and new_w[0] >= old_w[1]:
        new_wins = True
    elif new_s[1] <= old_s[0] or new_w[1] < old_w[0]:
        new_wins = False
    return {"tasks": tasks, "of": of, **totals, "new_wins": new_wins}


def _listed(values: Sequence[float]) -> str:
    return ", ".join(f"{v:g}" for v in values)


def _s(seeds: Sequence[int]) -> str:
    return f"seed{'s' * (len(seeds) != 1)} {_listed(seeds)}"


def format_collapse_test(tests: Mapping[str, Any], labels: Mapping[str, str]) -> list[str]:
    return [
        f"collapse test, {labels[name]} against {labels[t['against']]}, {_s(t['seeds'])}: final "
        f"success {_listed(t['final_success'])} against {_listed(t['final_success_alone'])}; "
        f"evaluations >= 90% after the first {_listed(t['held_90'])} against {_listed(t['held_90_alone'])}"
        for name, t in tests.items()
    ]


def format_rule_test(
    test: Mapping[str, Any],
    labels: Mapping[str, str],
    what: str,
    old: str,
    sides: tuple[str, str],
    rule: str,
) -> list[str]:
    """One line per task pair, then the totals and the verdict; `sides` = (new, old) as named."""
    lines = [
        f"{what}, {labels[name]} against {labels[t['against']]}, {_s(t['seeds'])}: crossed 90% "
        f"within the budget {_listed(t['crossed'])} against {_listed(t[f'crossed{old}'])}; final "
        f"success {_listed(t['final_success'])} against {_listed(t[f'final_success{old}'])}"
        for name, t in test["tasks"].items()
    ]
    wins = test["new_wins"]
    verdict = (
        "not decided (the runs left could change it)"
        if wins is None
        else f"{sides[0] if wins else sides[1]} (no run left to make can change it)"
    )
    lines.append(
        f"{what}, {sides[0]} against {sides[1]}, seeds 0-{RULE_SEEDS - 1} of "
        f"{test['of'] // RULE_SEEDS} tasks: crossed 90% in {test['crossed']} of {test['made']} "
        f"runs made against {test[f'crossed{old}']} of {test[f'made{old}']}, ended >= 90% in "
        f"{test['ended_90']} against {test[f'ended_90{old}']}; the rule's verdict ({rule}, "
        f"of {test['of']} each): {verdict}"
    )
    return lines
