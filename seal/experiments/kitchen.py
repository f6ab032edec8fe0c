"""`seal bench --learn kitchen`: learning evidence on single dense kitchens, with and without demonstrations.

Every arm is an ordinary protocol under `protocols/kitchen_learn/` (MTMHSAC on one kitchen task,
stopping at its first evaluation at >= 90% success), each seed one Ray task that runs it as
`seal run` does (`seal.experiments.launcher`); this module reads the run directories. Per run it reports the env
steps (the learner's own: demonstrations are not counted) and the updates (millions of consumed
transitions) at the first evaluation at >= 90%; a run that never got there is censored at its total.
Goals: every arm's task reaches 90% within 150k env steps in every seed (issue 11); at least 4 of
the 5 demonstration-free reward-v3 arms reach it in at least one seed (issue 25, `goal.rewards_alone`);
under reward v4 (the `*_v4` arms, all 535 epochs run), at least 4 of the 5 tasks
reach it in at least 2 of 3 seeds (issue 37, `goal.v4`); at least 12 of the 15 runs (seeds 0-2) of
the default learner on the default reward end at >= 90% success (issue 54, `goal.default_ended`). The `*_v4_critic_ln` arms are issue 37's
collapse test, v4 with LayerNorm in the critics, set seed for seed against v4 alone (`collapse_test`).
`reward_test` sets each v4 arm seed for seed against its v3 arm run with stopping off, and applies
the rule that decides the default reward (envs/franka_kitchen_dense/README.md). `learner_test`
applies issue 54's rule to a learner change on v3 (`LEARNERS`: the `*_critic_ln` arms, LayerNorm
in the critics, and the `*_bronet` arms, BRO's residual critic) against the plain critic, and BroNet
against LayerNorm too (`LEARNER_TESTS`). The arms and their groups are `seal.experiments.kitchen_arms`.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np

from seal.errors import SealError
from seal.evaluation import SUCCESS_TOLERANCE
from seal.experiments.kitchen_arms import (
    ARMS,
    COLLAPSE_TEST_SUFFIX,
    KITCHEN_LEARN,
    LEARNER_TESTS,
    LEARNERS,
    V4_SUFFIX,
    arm_config,
    arms,
    default_arms,
    pinned_version,
    rule_tasks,
    v4_arms,
)
from seal.experiments.kitchen_rules import (
    ENV_STEP_BUDGET,
    RULE_SEEDS,
    ended_90,
    format_collapse_test,
    format_rule_test,
    rule_test,
    within_budget,
)
from seal.experiments.kitchen_rules import collapse_test as _collapse_test
from seal.experiments.launcher import bench_context, run_or_reuse
from seal.experiments.records import code_versions, finished_runs, versions_note
from seal.metrics import DEFAULT_THRESHOLD, first_reach

if TYPE_CHECKING:
    import pandas as pd


REWARDS_ALONE_NEEDED = 4
"""Issue 25: of the demonstration-free arms, at least this many reach 90% within the budget in at least one seed."""
V4_TASKS_NEEDED = 4
"""Issue 37: of the five reward-v4 arms, at least this many reach 90% within the budget in ..."""
V4_SEEDS_NEEDED = 2
"""... at least this many of ..."""
V4_SEEDS = RULE_SEEDS
"""... this many seeds."""
DEFAULT_ENDED_NEEDED = 12
"""Issue 54: of the runs of seeds 0-2 of the five tasks with the default learner on the default
reward (15), at least this many end at >= 90% success."""


class RunFigures(TypedDict):
    """`run_figures`' record of one run."""

    reached: bool
    env_steps: int
    grad_steps: int
    updates_m: float
    best_success: float
    final_success: float
    held_90: int
    """Evaluations at >= 90% after the first one (0 if never reached): how much of what was found is kept."""
    after_first: int
    """Evaluations after the first at >= 90% (0 if never reached): what `held_90` is out of."""


def run_figures(metrics: pd.DataFrame, threshold: float = DEFAULT_THRESHOLD) -> RunFigures:
    """One run's figures: reached, env steps / gradient steps / M updates at the first >= threshold (else the run's totals), best success."""
    (row,) = first_reach(metrics, threshold).itertuples(index=False)
    ordered = metrics.sort_values(["epoch", "grad_steps"], kind="stable")
    last = ordered.iloc[-1]
    reached = bool(row.reached)
    hit = (ordered["success"] >= threshold - SUCCESS_TOLERANCE).to_numpy()
    return {
        "reached": reached,
        "env_steps": int(row.env_steps if reached else row.run_env_steps),
        "grad_steps": int(row.grad_steps if reached else row.run_grad_steps),
        "updates_m": float(row.updates if reached else row.run_updates),
        "best_success": float(metrics["success"].max()),
        "final_success": float(last["success"]),
        "held_90": max(int(hit.sum()) - 1, 0),
        "after_first": int(len(hit) - 1 - hit.argmax()) if hit.any() else 0,
    }


def end_mean_q(train: pd.DataFrame) -> float | None:
    """The critics' mean Q at a run's last training log (`train.csv`'s mean_q), None if it logged
    none: beside what a policy earns (at most ~1,190 under v4), how far its critic overestimates."""
    q = train[train["key"] == "mean_q"].sort_values("grad_steps", kind="stable")
    return float(q["value"].iloc[-1]) if len(q) else None


def end_q_ratio(train: pd.DataFrame) -> float | None:
    """The critic probe's ratio at a run's last evaluation (train.csv's `eval_q_ratio/<task>`, the
    one task's: `seal.learner.critic_probe`), None for a run made before the probe: its critic's Q at
    the evaluation episodes' first states over what they earned."""
    q = train[train["key"].astype(str).str.startswith("eval_q_ratio/")]
    return float(q.sort_values("grad_steps", kind="stable")["value"].iloc[-1]) if len(q) else None


def run_kitchen_bench(
    seeds: int = 2,
    out: str | os.PathLike[str] = "reports/bench_kitchen",
    parallel: int = 2,
    overrides: Sequence[str] = (),
    log: Callable[[str], None] = lambda _: None,
    only: Sequence[str] | None = None,
    reuse: bool = False,
    run: bool = True,
    address: str | None = None,
) -> dict[str, Any]:
    """Run (or, with `reuse`, take finished runs of) every arm's seeds; the figures as a JSON-able dict.

    Without `run`, nothing is run or resumed: the figures are those of the finished runs under `out`
    that `reuse` would take (committed run records, say), and `missing` names the rest. An arm
    with no such run is left out; the goals then count it as not run.
    """
    from seal import load_run
    from seal.bench.timing import machine_load

    if seeds < 1:
        raise SealError(f"--seeds must be >= 1, got {seeds}")
    chosen = arms(only)
    load_before = machine_load()
    started = time.monotonic()
    jobs = [(arm, seed) for seed in range(seeds) for arm in chosen]
    if run:
        run_dirs, reused = run_or_reuse(
            jobs, Path(out), overrides, parallel, log, reuse, address=address
        )
    else:
        run_dirs = reused = finished_runs(jobs, Path(out), overrides)
    loaded = {key: load_run(path) for key, path in run_dirs.items()}
    result_arms: dict[str, Any] = {}
    for arm in chosen:
        ran = [s for s in range(seeds) if (arm.name, s) in run_dirs]
        if not ran:
            continue
        runs = [loaded[(arm.name, s)] for s in ran]
        figures = [
            {
                "seed": s,
                **run_figures(r.metrics),
                "end_mean_q": end_mean_q(r.train),
                "end_q_ratio": end_q_ratio(r.train),
            }
            for s, r in zip(ran, runs, strict=True)
        ]
        within = [within_budget(f) for f in figures]
        result_arms[arm.name] = {
            "label": arm.label,
            "protocol": str(arm.protocol.relative_to(KITCHEN_LEARN.parents[1])),
            "per_seed": figures,
            "reached": f"{sum(f['reached'] for f in figures)}/{len(ran)}",
            "env_steps_to_90_mean": float(np.mean([f["env_steps"] for f in figures])),
            "learned_within_budget": all(within),
            "demos": [_demos(run_dirs[(arm.name, s)]) for s in ran],
            "reward_versions": [
                (r.provenance.get("reward_versions") or {}).get("franka_kitchen_dense")
                for r in runs
            ],
            # One value: `finished_run` takes only runs of the protocol as it resolves today.
            "stop_when_reached": bool(runs[0].config["evaluation"]["stop_when_reached"]),
        }
    shas = {key: run.provenance.get("git_sha") for key, run in loaded.items()}
    missing = [f"{a.name}/seed-{s}" for a, s in jobs if (a.name, s) not in run_dirs]
    failed = not all(a["learned_within_budget"] for a in result_arms.values())
    return {
        "arms": result_arms,
        "code_versions": code_versions(shas),
        "goal": {
            "env_steps_le": ENV_STEP_BUDGET,
            # Not judged while runs are missing, unless a run made has already missed it.
            "met": False if failed else (None if missing else True),
            "rewards_alone": rewards_alone_goal(result_arms),
            "v4": v4_goal(result_arms),
            "default_ended": default_ended_goal(result_arms),
        },
        "collapse_test": collapse_test(result_arms),
        "reward_test": reward_test(result_arms),
        **{
            learner_key(suffix, against): learner_test(result_arms, suffix, against)
            for suffix, against in LEARNER_TESTS
        },
        "reward_test_critic_ln": reward_test(result_arms, COLLAPSE_TEST_SUFFIX),
        "seeds": seeds,
        "overrides": list(overrides),
        "run_dirs": {f"{a}/seed-{s}": str(p) for (a, s), p in run_dirs.items()},
        "reused": sorted(f"{a}/seed-{s}" for a, s in reused),
        "missing": missing,
        **bench_context(time.monotonic() - started, parallel, address, load_before),
    }


def rewards_alone_goal(result_arms: Mapping[str, Any]) -> dict[str, Any]:
    """Issue 25's goal over the demonstration-free arms: how many reached 90% within the budget in at
    least one seed; `met` as `_verdict` decides it."""
    plain = [
        a.name
        for a in ARMS
        if arm_config(a).training.demo_episodes == 0
        and pinned_version(a) == "v3"
        and not a.name.endswith(tuple(LEARNERS))
    ]
    ran = [name for name in plain if name in result_arms]
    reached = [
        result_arms[name]["label"]
        for name in ran
        if any(within_budget(f) for f in result_arms[name]["per_seed"])
    ]
    return {
        "needed": REWARDS_ALONE_NEEDED,
        "of": len(plain),
        "ran": len(ran),
        "reached": reached,
        # An arm not yet run may still reach it (as for `all_ran`, an arm has run once any seed has).
        **_verdict(
            len(reached),
            len(reached) + len(plain) - len(ran),
            REWARDS_ALONE_NEEDED,
            all_ran=len(ran) == len(plain),
        ),
    }


def _verdict(reached: int, reachable: int, needed: int, *, all_ran: bool) -> dict[str, Any]:
    """A goal of reaching 90% in enough arms is met as soon as `reached` arms have (a run not yet
    made cannot undo a crossing), not met as soon as `reachable`, the most that could once every
    run is made, falls short, else None (undecided)."""
    met = True if reached >= needed else (False if reachable < needed else None)
    return {"met": met, "all_ran": all_ran}


def v4_goal(result_arms: Mapping[str, Any]) -> dict[str, Any]:
    """Issue 37's goal over the reward-v4 arms: how many reached 90% within the budget in at least
    `V4_SEEDS_NEEDED` seeds; `met` as `_verdict` decides it, every run made when all five ran with
    `V4_SEEDS` seeds or more."""
    v4 = v4_arms()
    ran = [name for name in v4 if name in result_arms]
    seeds = {name: result_arms[name]["per_seed"] if name in ran else [] for name in v4}
    crossed = {name: sum(within_budget(f) for f in runs) for name, runs in seeds.items()}
    # A seed not yet run may still cross: the most seeds each arm can have crossed in.
    most = {name: crossed[name] + max(0, V4_SEEDS - len(seeds[name])) for name in v4}
    reached = [result_arms[name]["label"] for name in ran if crossed[name] >= V4_SEEDS_NEEDED]
    all_ran = all(len(runs) >= V4_SEEDS for runs in seeds.values())
    return {
        "needed": V4_TASKS_NEEDED,
        "seeds_needed": V4_SEEDS_NEEDED,
        "of_seeds": V4_SEEDS,
        "of": len(v4),
        "ran": len(ran),
        "reached": reached,
        **_verdict(
            len(reached),
            sum(n >= V4_SEEDS_NEEDED for n in most.values()),
            V4_TASKS_NEEDED,
            all_ran=all_ran,
        ),
    }


def default_ended_goal(result_arms: Mapping[str, Any]) -> dict[str, Any]:
    """Issue 54's goal: of the `RULE_SEEDS` seeds of each default-learner, default-reward arm, how
    many runs ended at >= 90% success (`kitchen_rules.ended_90`); met once `DEFAULT_ENDED_NEEDED`
    have, not met once the runs left cannot make up the shortfall (a run's end is final)."""
    names = default_arms()
    judged = {
        n: [f for f in result_arms[n]["per_seed"] if f["seed"] < RULE_SEEDS]
        for n in names
        if n in result_arms
    }
    made = sum(len(runs) for runs in judged.values())
    ended = [
        f"{result_arms[n]['label']} s{f['seed']}"
        for n, runs in judged.items()
        for f in runs
        if ended_90(f)
    ]
    of = RULE_SEEDS * len(names)
    return {
        "needed": DEFAULT_ENDED_NEEDED,
        "of": of,
        "arms": names,
        "made": made,
        "ended": ended,
        **_verdict(len(ended), len(ended) + of - made, DEFAULT_ENDED_NEEDED, all_ran=made == of),
    }


def collapse_test(result_arms: Mapping[str, Any]) -> dict[str, Any]:
    """Each `*_critic_ln` arm run beside its arm, seed for seed (`kitchen_rules.collapse_test`):
    issue 37's collapse test on v4, issue 54's learner change on v3."""
    return _collapse_test(result_arms, COLLAPSE_TEST_SUFFIX)


def reward_test(result_arms: Mapping[str, Any], learner: str = "") -> dict[str, Any]:
    """Issue 37's rule, v4 against v3 on one learner ("" the plain critic, `COLLAPSE_TEST_SUFFIX`
    LayerNorm): `kitchen_rules.rule_test`, the old side's keys ending in "_v3"; `default` "v4" if
    v4 crosses in more runs and ends at >= 90% in at least as many, "v3" if not, None while the
    runs left could change it."""
    pairs = [(f"{t}{V4_SUFFIX}{learner}", f"{t}{learner}") for t in rule_tasks()]
    test = rule_test(result_arms, pairs, "_v3", strict="crossed", weak="ended_90")
    wins = test["new_wins"]
    return {**test, "default": None if wins is None else ("v4" if wins else "v3")}


def learner_key(suffix: str, against: str = "") -> str:
    """The bench result's key of a learner test: "learner_test" for critic LN against the plain
    critic (the records' readers know it by that name), "learner_test<suffix>" for another change
    against it; with a learner to set it against (suffix `against`), "_vs<against>" follows."""
    new = "" if suffix == COLLAPSE_TEST_SUFFIX else suffix
    return f"learner_test{new}" + (f"_vs{against}" if against else "")


def _side(suffix: str) -> str:
    """A learner's name in the learner tests: `LEARNERS`'s, "plain" for no suffix."""
    return LEARNERS[suffix] if suffix else "plain"


def learner_test(
    result_arms: Mapping[str, Any], suffix: str = COLLAPSE_TEST_SUFFIX, against: str = ""
) -> dict[str, Any]:
    """Issue 54's rule on the default reward (docs/hyperparameters.md): a learner change (an arm
    suffix of `LEARNERS`) against the plain critic (or the learner of suffix `against`) on the five
    v3 arms; `default` the change's name if it ends at >= 90% in more runs and crosses in at least
    as many, the old side's name if not, None while the runs left could change it. The old side's
    keys end in "_plain" (or in `against`)."""
    pairs = [(f"{t}{suffix}", f"{t}{against}") for t in rule_tasks()]
    test = rule_test(result_arms, pairs, against or "_plain", strict="ended_90", weak="crossed")
    wins = test["new_wins"]
    return {**test, "default": None if wins is None else _side(suffix if wins else against)}


def _format_collapse_test(tests: Mapping[str, Any], labels: Mapping[str, str]) -> list[str]:
    return format_collapse_test(tests, labels)


def _format_reward_test(
    test: Mapping[str, Any], labels: Mapping[str, str], learner: str = ""
) -> list[str]:
    if not any(name + learner in labels for name in v4_arms()):
        return []
    what = "reward test" + (" with critic LN" if learner else " with the plain critic")
    rule = "v4 if it crosses in more runs and ends in at least as many"
    return format_rule_test(test, labels, what, "_v3", ("v4", "v3"), rule)


def _format_learner_test(
    test: Mapping[str, Any],
    labels: Mapping[str, str],
    suffix: str = COLLAPSE_TEST_SUFFIX,
    against: str = "",
) -> list[str]:
    if not any(f"{t}{suffix}" in labels for t in rule_tasks()):
        return []
    name, old = _side(suffix), _side(against)
    rule = f"{name} if it ends >= 90% in more runs and crosses in at least as many"
    what = "learner test" + ("" if suffix == COLLAPSE_TEST_SUFFIX else f" ({name})")
    return format_rule_test(test, labels, what, against or "_plain", (name, old), rule)


def _q(value: float | None) -> str:
    return "-" if value is None else f"{value:,.0f}"


def _ratio(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def _demos(run_dir: Path) -> dict[str, Any] | None:
    """The demonstration figures the run's last checkpoint saved (None without demonstrations)."""
    from seal.learner.checkpoint import read_checkpoint

    checkpoints = sorted((run_dir / "checkpoints").glob("ckpt-*.pt"))
    if not checkpoints:
        return None
    demos = read_checkpoint(checkpoints[-1])["runner"]["state"].get("demos") or {}
    return next(iter(demos.values()), None)


def _format_default_ended(goal: Mapping[str, Any], labels: Mapping[str, str]) -> str:
    arms = ", ".join(labels.get(n, n) for n in goal["arms"])
    runs_left = f"{goal['made']} of {goal['of']} runs made"
    return (
        f"goal (issue 54): >= {goal['needed']} of the {goal['of']} runs of the default learner on the "
        f"default reward ({arms}) end >= 90%: {len(goal['ended'])} of {goal['made']} made: "
        f"{_format_verdict(goal, runs_left, 'a run made cannot change how it ended')}"
    )


def _format_verdict(
    goal: Mapping[str, Any], runs_left: str, final: str = "a later run cannot undo a crossing"
) -> str:
    """`final`: why a goal met before every run was made stays met."""
    if goal["met"] is None:
        return f"not judged ({runs_left})"
    if goal["all_ran"]:
        return "met" if goal["met"] else "not met"
    if goal["met"]:
        return f"met before every run was made ({runs_left}; {final})"
    return f"not met before every run was made ({runs_left}; the runs left cannot make up the shortfall)"


def _format_rewards_alone(goal: Mapping[str, Any]) -> str:
    reached = ", ".join(goal["reached"]) or "none"
    verdict = _format_verdict(goal, f"{goal['ran']} of {goal['of']} run")
    return (
        f"goal: >= {goal['needed']} of the {goal['of']} demonstration-free arms >= 90% in at least one "
        f"seed: {len(goal['reached'])} ({reached}): {verdict}"
    )


def _format_v4(goal: Mapping[str, Any]) -> str:
    reached = ", ".join(goal["reached"]) or "none"
    runs_left = f"{goal['ran']} of {goal['of']} run, {goal['of_seeds']} seeds each needed"
    return (
        f"goal v4: >= {goal['needed']} of the {goal['of']} reward-v4 arms >= 90% in >= "
        f"{goal['seeds_needed']} of {goal['of_seeds']} seeds: {len(goal['reached'])} ({reached}): "
        f"{_format_verdict(goal, runs_left)}"
    )


def format_result(result: Mapping[str, Any]) -> str:
    """The human-readable table of `run_kitchen_bench`."""
    width = max([24, *(len(a["label"]) for a in result["arms"].values())])
    lines = [
        f"{'arm':<{width}} {'reached':>7}  env steps to 90% per seed (M updates)   "
        "best / final success / evaluations >= 90% after the first (of) / end mean Q / end Q ratio",
        "-" * 92,
    ]
    for a in result["arms"].values():
        # With runs missing (--no-run), each cell names its seed.
        named = [f"s{f['seed']} " if result.get("missing") else "" for f in a["per_seed"]]
        cells = ", ".join(
            f"{n}{f['env_steps']:,}{'' if f['reached'] else '+'} ({f['updates_m']:.2f})"
            for n, f in zip(named, a["per_seed"], strict=True)
        )
        success = ", ".join(
            f"{f['best_success']:.1f}/{f['final_success']:.1f}/{f['held_90']} of {f['after_first']}"
            f"/{_q(f['end_mean_q'])}/{_ratio(f.get('end_q_ratio'))}"
            for f in a["per_seed"]
        )
        lines.append(f"{a['label']:<{width}} {a['reached']:>7}  {cells:<38} {success}")
    goal = result["goal"]
    met = {True: "met", False: "not met", None: "not judged (runs missing)"}[goal["met"]]
    load = result["load_before"]
    note = versions_note(result["code_versions"])
    if note:
        lines.append(f"note, {note}")
    rewards = {
        str(v): [a["label"] for a in result["arms"].values() if v in a.get("reward_versions", [])]
        for a in result["arms"].values()
        for v in a.get("reward_versions", [])
    }
    if len(rewards) > 1:
        listed = "; ".join(f"{v}: {', '.join(labels)}" for v, labels in sorted(rewards.items()))
        lines.append(f"note, runs on {len(rewards)} kitchen reward versions: {listed}")
    reused = f" ({len(result['reused'])} runs reused)" if result["reused"] else ""
    by_name = {k: a["label"] for k, a in result["arms"].items()}
    lines += [
        "env steps: the learner's own (demonstrations excluded) at the first evaluation >= 90%; "
        "+ = never reached, the run's total.",
        f"goal: every arm >= 90% within {goal['env_steps_le']:,} env steps in every seed: {met}",
        _format_rewards_alone(goal["rewards_alone"]),
        _format_v4(goal["v4"]),
        *(
            [_format_default_ended(goal["default_ended"], by_name)]
            if "default_ended" in goal
            else []
        ),
        *_format_collapse_test(result.get("collapse_test", {}), by_name),
        *(_format_reward_test(result["reward_test"], by_name) if "reward_test" in result else []),
        *(
            line
            for suffix, against in LEARNER_TESTS
            if learner_key(suffix, against) in result
            for line in _format_learner_test(
                result[learner_key(suffix, against)], by_name, suffix, against
            )
        ),
        *(
            _format_reward_test(result["reward_test_critic_ln"], by_name, COLLAPSE_TEST_SUFFIX)
            if "reward_test_critic_ln" in result
            else []
        ),
        *(
            [f"not run (--no-run found no finished run): {', '.join(result['missing'])}"]
            if result.get("missing")
            else []
        ),
        f"{result['seeds']} seeds on {result['ray']}, {result['wall_s']:.0f} s wall"
        f"{reused}; load before "
        f"{load['loadavg_1m']} (1 min) on {load['cpus']} CPUs, after {result['load_after']['loadavg_1m']}",
    ]
    return "\n".join(lines)
