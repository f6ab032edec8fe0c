"""What a phase's evaluations cost: all their episodes, or each task's only until its verdict is
settled (`evaluation.decide_early`, every `full_every`-th in full), and episodes cut at their
first success (`evaluation.end_on_success`).

The phase loop (`seal.run.evaluation`) asks `decides_early` once per phase and
`runs_all_episodes` at each evaluation; the train.csv rows that say how many episodes each task
ran (keys `EPISODES_KEY`, `DECIDED_KEY`) are `seal.run.eval_rows.decision_rows`; `explain_lines` is what `seal protocol explain` says of the options. The
decision rule itself is `seal.evaluation.EarlyDecision`, beside `reaches`.
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING

from seal.evaluation import EarlyDecision

if TYPE_CHECKING:
    from seal.protocols.config import ProtocolConfig

EPISODES_KEY = "eval_episodes"
"""train.csv key prefix: `eval_episodes/<task>`, the episodes counted for a task (its success is over them) at an evaluation that may decide early."""
DECIDED_KEY = "eval_decided_early"
"""train.csv key prefix: `eval_decided_early/<task>`, 1 when it counted fewer than `evaluation.episodes` (it stopped early)."""


def early_decisions_off(config: ProtocolConfig, phase: str, reads_eval: bool) -> str:
    """Why a phase's evaluations run all their episodes ("" when `decide_early` applies to it).

    A decided-early rate is exact only as a verdict against the threshold; where a rate steers
    training, every evaluation runs in full, so that the run is the one it would be with the
    option off.
    """
    if not config.evaluation.decide_early:
        return "evaluation.decide_early is off"
    if reads_eval:
        return "its scheduler reads the evaluations' success rates"
    if config.kind == "finetune" and phase == "pretrain":
        return "its best.pt, chosen by mean success, starts the fine-tuning"
    return ""


def decides_early(config: ProtocolConfig, phase: str, reads_eval: bool, quiet: bool) -> bool:
    """Whether `decide_early` applies to the phase; if it is on and does not, says why (unless `quiet`)."""
    off = early_decisions_off(config, phase, reads_eval)
    if config.evaluation.decide_early and off and not quiet:
        print(
            f"[seal] phase {phase}: evaluation.decide_early does not apply ({off}); "
            "its evaluations run every episode",
            file=sys.stderr,
        )
    return not off


def runs_all_episodes(count: int, full_every: int, final: bool) -> bool:
    """Whether a phase's `count`-th evaluation (from 1) runs in full: every `full_every`-th, and
    the phase's last epoch's (`final`), so the run's final numbers are full ones."""
    return final or count % full_every == 0


def explain_lines(config: ProtocolConfig) -> list[str]:
    """Comment lines for `seal protocol explain`: whether the options are on and the evaluation
    env steps they can save at most."""
    ev = config.evaluation
    out: list[str] = []
    if ev.decide_early:
        rule = EarlyDecision(ev.episodes, ev.threshold)
        least = rule.fewest_episodes
        saved = 1 - least / ev.episodes
        share = (ev.full_every - 1) / ev.full_every
        out += [
            f"# decide_early is on: a task stops at {rule.needed} successes or "
            f"{ev.episodes - rule.needed + 1} failures of {ev.episodes} episodes, so after at least "
            f"{least} (rounded up to whole waves of its parallel instances).",
            f"# decide_early saves at most {ev.episodes - least} of a task's {ev.episodes} "
            f"episodes ({saved:.0%}) in {ev.full_every - 1} of every {ev.full_every} evaluations (full_every; the phase's "
            f"last runs in full): at most {saved * share:.0%} of evaluation env steps.",
            "# decide_early is off in a phase whose scheduler reads evaluations (curriculum_v2) "
            "and in a finetune protocol's pre-training: those run every episode.",
        ]
    if ev.end_on_success:
        out.append(
            "# end_on_success is on: an episode ends at its first success, saving up to "
            "episode_length - 1 of its steps; returns are then cut returns."
        )
    return out
