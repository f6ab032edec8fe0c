"""`seal bench --learn kitchen`: learning evidence on single dense kitchens, with and without demonstrations.

Every arm is an ordinary protocol under `protocols/kitchen_learn/` (MTMHSAC on one kitchen task,
stopping at its first evaluation at >= 90% success), run by `seal run` in its own process through
the transfer bench's launcher; this module reads the run directories. Per run it reports the env
steps (the learner's own: demonstrations are not counted) and the updates (millions of consumed
transitions) at the first evaluation at >= 90%; a run that never got there is censored at its total.
Goals: every arm's task reaches 90% within 150k env steps in every seed (issue 11); at least 4 of
the 5 demonstration-free reward-v3 arms reach it in at least one seed (issue 25, `goal.rewards_alone`);
under reward v4 (the `*_v4` arms, all 535 epochs run), at least 4 of the 5 tasks
reach it in at least 2 of 3 seeds (issue 37, `goal.v4`). The `*_v4_critic_ln` arms are issue 37's
collapse test, v4 with LayerNorm in the critics, set seed for seed against v4 alone (`collapse_test`).
`reward_test` sets each v4 arm seed for seed against its v3 arm run with stopping off, and applies
the rule that decides the default reward (envs/franka_kitchen_dense/README.md).
"""

from __future__ import annotations

import os
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np

from seal.errors import SealError, SealWarning, UnknownNameError
from seal.evaluation import SUCCESS_TOLERANCE
from seal.experiments.transfer import (
    Arm,
    code_versions,
    finished_run,
    run_or_reuse,
    versions_note,
)
from seal.metrics import DEFAULT_THRESHOLD, first_reach
from seal.protocols import load_protocol

if TYPE_CHECKING:
    import pandas as pd

    from seal.protocols.config import ProtocolConfig

KITCHEN_LEARN = Path(__file__).resolve().parents[2] / "protocols" / "kitchen_learn"
"""The kitchen learning protocols."""
ENV_STEP_BUDGET = 150_000
"""Env steps per task within which each arm must reach 90% (issue 11)."""
REWARDS_ALONE_NEEDED = 4
"""Issue 25: of the demonstration-free arms, at least this many reach 90% within the budget in at least one seed."""
V4_TASKS_NEEDED = 4
"""Issue 37: of the five reward-v4 arms, at least this many reach 90% within the budget in ..."""
V4_SEEDS_NEEDED = 2
"""... at least this many of ..."""
V4_SEEDS = 3
"""... this many seeds."""


def _arm(name: str, label: str) -> Arm:
    return Arm(name, label, None, directory=KITCHEN_LEARN)


ARMS: tuple[Arm, ...] = (
    _arm("slide_cabinet", "slide-cabinet"),
    _arm("slide_cabinet_demos", "slide-cabinet + demos"),
    _arm("light_switch", "light-switch"),
    _arm("light_switch_demos", "light-switch + demos"),
    _arm("bottom_left_burner", "bottom-left-burner"),
    _arm("bottom_left_burner_demos", "bottom-left-burner + demos"),
    _arm("microwave", "microwave"),
    _arm("bottom_right_burner", "bottom-right-burner"),
    _arm("slide_cabinet_v4", "slide-cabinet v4"),
    _arm("light_switch_v4", "light-switch v4"),
    _arm("bottom_left_burner_v4", "bottom-left-burner v4"),
    _arm("microwave_v4", "microwave v4"),
    _arm("bottom_right_burner_v4", "bottom-right-burner v4"),
    _arm("light_switch_v4_critic_ln", "light-switch v4 + critic LN"),
    _arm("microwave_v4_critic_ln", "microwave v4 + critic LN"),
    _arm("slide_cabinet_v4_critic_ln", "slide-cabinet v4 + critic LN"),
    _arm("bottom_left_burner_v4_critic_ln", "bottom-left-burner v4 + critic LN"),
    _arm("bottom_right_burner_v4_critic_ln", "bottom-right-burner v4 + critic LN"),
    _arm("slide_cabinet_critic_ln", "slide-cabinet + critic LN"),
    _arm("light_switch_critic_ln", "light-switch + critic LN"),
    _arm("bottom_left_burner_critic_ln", "bottom-left-burner + critic LN"),
    _arm("microwave_critic_ln", "microwave + critic LN"),
    _arm("bottom_right_burner_critic_ln", "bottom-right-burner + critic LN"),
)
"""The arms, each pinned to a reward version by its protocol's `options.reward_version`: v3, and
v4 for the `*_v4` arms (which run all 535 epochs: `evaluation.stop_when_reached = false`)
and for the collapse test's `*_v4_critic_ln` arms (v4 with `agent.critic_layer_norm`)."""
COLLAPSE_TEST_SUFFIX = "_critic_ln"
"""A collapse-test arm is its v4 arm's name with this suffix: the same protocol with one change."""
V4_SUFFIX = "_v4"
"""A reward-v4 arm is its v3 arm's name with this suffix: the same protocol on reward v4."""


def _arm_config(arm: Arm) -> ProtocolConfig:
    """An arm's protocol, read to classify it: the reward-version warning a run of it gives is not
    the reader's to see (the goals read every arm, run or not)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SealWarning)
        return load_protocol(arm.protocol)


def _pinned_version(arm: Arm) -> str | None:
    """The kitchen reward version an arm's protocol pins (None if it pins none)."""
    config = _arm_config(arm)
    return next(iter(config.envs.values())).options.get("reward_version")


def arms(only: Sequence[str] | None = None) -> list[Arm]:
    """All arms, or the named ones."""
    if not only:
        return list(ARMS)
    by_name = {a.name: a for a in ARMS}
    for name in only:
        if name not in by_name:
            raise UnknownNameError("kitchen arm", name, list(by_name))
    return [a for a in ARMS if a.name in only]


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
        run_dirs, reused = run_or_reuse(jobs, Path(out), overrides, parallel, log, reuse)
    else:
        found = {(a.name, s): finished_run(a, s, Path(out), overrides) for a, s in jobs}
        run_dirs = reused = {key: path for key, path in found.items() if path is not None}
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
        within = [_within_budget(f) for f in figures]
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
        },
        "collapse_test": collapse_test(result_arms),
        "reward_test": reward_test(result_arms),
        "seeds": seeds,
        "overrides": list(overrides),
        "run_dirs": {f"{a}/seed-{s}": str(p) for (a, s), p in run_dirs.items()},
        "reused": sorted(f"{a}/seed-{s}" for a, s in reused),
        "missing": missing,
        "wall_s": time.monotonic() - started,
        "parallel": parallel,
        "load_before": load_before,
        "load_after": machine_load(),
    }


def rewards_alone_goal(result_arms: Mapping[str, Any]) -> dict[str, Any]:
    """Issue 25's goal over the demonstration-free arms: how many reached 90% within the budget in at
    least one seed; `met` as `_verdict` decides it."""
    plain = [
        a.name
        for a in ARMS
        if _arm_config(a).training.demo_episodes == 0
        and _pinned_version(a) == "v3"
        and not a.name.endswith(COLLAPSE_TEST_SUFFIX)
    ]
    ran = [name for name in plain if name in result_arms]
    reached = [
        result_arms[name]["label"]
        for name in ran
        if any(_within_budget(f) for f in result_arms[name]["per_seed"])
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


def _within_budget(figures: Mapping[str, Any]) -> bool:
    return bool(figures["reached"] and figures["env_steps"] <= ENV_STEP_BUDGET)


def _v4_arms() -> list[str]:
    """The reward-v4 arms (the collapse test's are a learner change on v4, not v4's evidence)."""
    return [
        a.name
        for a in ARMS
        if _pinned_version(a) == "v4" and not a.name.endswith(COLLAPSE_TEST_SUFFIX)
    ]


def v4_goal(result_arms: Mapping[str, Any]) -> dict[str, Any]:
    """Issue 37's goal over the reward-v4 arms: how many reached 90% within the budget in at least
    `V4_SEEDS_NEEDED` seeds; `met` as `_verdict` decides it, every run made when all five ran with
    `V4_SEEDS` seeds or more."""
    v4 = _v4_arms()
    ran = [name for name in v4 if name in result_arms]
    seeds = {name: result_arms[name]["per_seed"] if name in ran else [] for name in v4}
    crossed = {name: sum(_within_budget(f) for f in runs) for name, runs in seeds.items()}
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


def _judged(arm: Mapping[str, Any]) -> dict[str, Any]:
    """An arm's runs of the seeds the reward test names (0 to `V4_SEEDS` - 1), each with its two
    verdicts: crossed 90% within the budget, final success >= 90%."""
    return {
        "per_seed": [
            {
                **f,
                "crossed": _within_budget(f),
                "ended_90": f["final_success"] >= DEFAULT_THRESHOLD - SUCCESS_TOLERANCE,
            }
            for f in arm["per_seed"]
            if f["seed"] < V4_SEEDS
        ]
    }


def collapse_test(result_arms: Mapping[str, Any]) -> dict[str, Any]:
    """Issue 37's collapse test, per collapse-test arm run beside its v4 arm: seed for seed (the
    seeds both ran), the final success and the evaluations >= 90% after the first (`held_90`), the
    change's and v4 alone's."""
    out: dict[str, Any] = {}
    for name, arm in result_arms.items():
        alone = name.removesuffix(COLLAPSE_TEST_SUFFIX)
        if alone == name or alone not in result_arms:
            continue
        paired = _paired(arm, result_arms[alone], ("final_success", "held_90"), "_alone")
        if paired is not None:
            out[name] = {"against": alone, **paired}
    return out


def reward_test(result_arms: Mapping[str, Any]) -> dict[str, Any]:
    """Issue 37's v4 against v3 over seeds 0 to `V4_SEEDS` - 1 of the five tasks, runs with stopping
    off only: per task whose two arms share a seed, their first crossings within the budget and
    final successes seed for seed; per side, the runs made and how many crossed and ended at >= 90%;
    and the rule written before the other 14 of v3's runs (the kitchen README): v4 becomes the
    default if it crosses in more runs than v3 and ends at >= 90% in at least as many. `default` is
    "v4" or "v3" as soon as no run left to make could change it (as `_verdict` decides a goal),
    None before; with every run made it is the rule applied to the totals."""
    tasks: dict[str, Any] = {}
    totals = dict.fromkeys(
        ("made", "made_v3", "crossed", "crossed_v3", "ended_90", "ended_90_v3"), 0
    )
    for name in _v4_arms():
        judged = {}
        for suffix, arm_name in (("", name), ("_v3", name.removesuffix(V4_SUFFIX))):
            arm = result_arms.get(arm_name)
            # A run that stopped at its first crossing has no final success to set against another's.
            if arm is None or arm.get("stop_when_reached", True):
                continue
            judged[suffix] = _judged(arm)
            runs = judged[suffix]["per_seed"]
            totals[f"made{suffix}"] += len(runs)
            totals[f"crossed{suffix}"] += sum(f["crossed"] for f in runs)
            totals[f"ended_90{suffix}"] += sum(f["ended_90"] for f in runs)
        if len(judged) == 2:
            paired = _paired(
                judged[""], judged["_v3"], ("crossed", "ended_90", "final_success"), "_v3"
            )
            if paired is not None:
                tasks[name] = {"against": name.removesuffix(V4_SUFFIX), **paired}
    of = len(_v4_arms()) * V4_SEEDS

    def bounds(key: str, suffix: str) -> tuple[int, int]:
        """The fewest and the most runs of `key` once all are made (a run left may go either way)."""
        return totals[key + suffix], totals[key + suffix] + of - totals["made" + suffix]

    crossed, crossed_v3 = bounds("crossed", ""), bounds("crossed", "_v3")
    ended, ended_v3 = bounds("ended_90", ""), bounds("ended_90", "_v3")
    default = None
    if crossed[0] > crossed_v3[1] and ended[0] >= ended_v3[1]:
        default = "v4"
    elif crossed[1] <= crossed_v3[0] or ended[1] < ended_v3[0]:
        default = "v3"
    return {"tasks": tasks, "of": of, **totals, "default": default}


def _format_collapse_test(tests: Mapping[str, Any], labels: Mapping[str, str]) -> list[str]:
    return [
        f"collapse test, {labels[name]} against {labels[t['against']]}, "
        f"seed{'s' * (len(t['seeds']) != 1)} {_listed(t['seeds'])}: final "
        f"success {_listed(t['final_success'])} against {_listed(t['final_success_alone'])}; "
        f"evaluations >= 90% after the first {_listed(t['held_90'])} against {_listed(t['held_90_alone'])}"
        for name, t in tests.items()
    ]


def _format_reward_test(test: Mapping[str, Any], labels: Mapping[str, str]) -> list[str]:
    if not any(name in labels for name in _v4_arms()):
        return []
    lines = [
        f"reward test, {labels[name]} against {labels[t['against']]}, "
        f"seed{'s' * (len(t['seeds']) != 1)} {_listed(t['seeds'])}: crossed 90% within the budget "
        f"{_listed(t['crossed'])} against {_listed(t['crossed_v3'])}; final success "
        f"{_listed(t['final_success'])} against {_listed(t['final_success_v3'])}"
        for name, t in test["tasks"].items()
    ]
    verdict = (
        "not decided (the runs left could change it)"
        if test["default"] is None
        else f"{test['default']} (no run left to make can change it)"
    )
    lines.append(
        f"reward test, v4 against v3, seeds 0-{V4_SEEDS - 1} of {test['of'] // V4_SEEDS} tasks: "
        f"crossed 90% in {test['crossed']} of {test['made']} runs made against "
        f"{test['crossed_v3']} of {test['made_v3']}, ended >= 90% in {test['ended_90']} against "
        f"{test['ended_90_v3']}; the default by the rule (v4 if it crosses in more runs and ends "
        f"in at least as many, of {test['of']} each): {verdict}"
    )
    return lines


def _q(value: float | None) -> str:
    return "-" if value is None else f"{value:,.0f}"


def _ratio(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def _listed(values: Sequence[float]) -> str:
    return ", ".join(f"{v:g}" for v in values)


def _demos(run_dir: Path) -> dict[str, Any] | None:
    """The demonstration figures the run's last checkpoint saved (None without demonstrations)."""
    from seal.learner.checkpoint import read_checkpoint

    checkpoints = sorted((run_dir / "checkpoints").glob("ckpt-*.pt"))
    if not checkpoints:
        return None
    demos = read_checkpoint(checkpoints[-1])["runner"]["state"].get("demos") or {}
    return next(iter(demos.values()), None)


def _format_verdict(goal: Mapping[str, Any], runs_left: str) -> str:
    if goal["met"] is None:
        return f"not judged ({runs_left})"
    if goal["all_ran"]:
        return "met" if goal["met"] else "not met"
    if goal["met"]:
        return f"met before every run was made ({runs_left}; a later run cannot undo a crossing)"
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
        *_format_collapse_test(result.get("collapse_test", {}), by_name),
        *(_format_reward_test(result["reward_test"], by_name) if "reward_test" in result else []),
        *(
            [f"not run (--no-run found no finished run): {', '.join(result['missing'])}"]
            if result.get("missing")
            else []
        ),
        f"{result['seeds']} seeds, {result['parallel']} runs at a time, {result['wall_s']:.0f} s wall"
        f"{reused}; load before "
        f"{load['loadavg_1m']} (1 min) on {load['cpus']} CPUs, after {result['load_after']['loadavg_1m']}",
    ]
    return "\n".join(lines)
