"""Evaluation episodes in waves: `Collector.evaluate`'s schedule of which episode runs where.

Episode e of an (env, task) resets with `episode_seed(seed, env, task, draw, e)`, so it is the
same episode on every backend, replica count and wave. A Collector with `replicas` instances per
task runs episodes `first .. first + replicas - 1` of every running task together (replica r
runs episode first + r), then the next wave. With a `Decide` rule (`seal.evaluation.EarlyDecision`)
a task whose verdict its episodes so far settle runs no further wave; the others run theirs
exactly as before, so the k-th episode of a task is the same episode, on the same instance,
whether or not other tasks stopped. A settled task counts its episodes up to the one that
settled it: the rest of that wave ran but is not counted, so what is recorded does not depend
on the number of parallel instances (the machine's cores), as full evaluations do not.
"""

from __future__ import annotations

import zlib
from collections.abc import Mapping, Sequence
from typing import Protocol

import numpy as np

# Tags the spawn keys of evaluation episode seeds apart from instance seeds.
_EPISODE_KEY = 0x45564131

# Per environment: which of its instances (indices into Collector.tasks[env], replica r of task
# i at r * len(tasks[env]) + i) run, and their reset seeds, in the same order.
Selection = dict[str, np.ndarray]
Seeds = dict[str, np.ndarray]
# Per environment: per selected instance (in the Selection's order) "return", "success" and,
# with a critic probe, "q_start" and "earned".
Played = dict[str, dict[str, np.ndarray]]
Results = dict[str, dict[str, dict[str, float]]]


def episode_seed(seed: int, env: str, task: str, draw: int, episode: int) -> int:
    """The reset seed of evaluation episode `episode` of (env, task) in evaluation `draw`.

    It fixes the episode by itself: the same on every backend, replica count and round.
    """
    key = (zlib.crc32(env.encode()), zlib.crc32(task.encode()), _EPISODE_KEY, draw, episode)
    return int(np.random.SeedSequence(seed, spawn_key=key).generate_state(1, np.uint32)[0])


class Play(Protocol):
    """Runs one episode on each selected instance from its seed; what each episode gave."""

    def __call__(self, running: Selection, seeds: Seeds) -> Played: ...


class Decide(Protocol):
    """Per task, from its successes and failures so far (arrays): whether its verdict is settled."""

    def __call__(self, successes: np.ndarray, failures: np.ndarray) -> np.ndarray: ...


def evaluate_in_waves(
    play: Play,
    tasks: Mapping[str, Sequence[str]],
    mask: Mapping[str, np.ndarray],
    *,
    seed: int,
    draw: int,
    episodes: int,
    replicas: int,
    whole: bool = False,
    decide: Decide | None = None,
) -> Results:
    """`episodes` episodes of every task in `mask`, in waves of `replicas`: {env: {task: {...}}}
    with "success_rate", "mean_return", "episodes" (those counted: all, or up to the one that
    settled the task), the probe's means if `play` gave them, and with `decide` "decided_early"
    (1.0 when it counted fewer than `episodes`).

    `whole`: every wave resets all instances of an environment (gym-async), so a short last wave
    and a settled task run spare episodes whose results are dropped.
    """
    size = {env: len(ts) for env, ts in tasks.items()}
    outcome: dict[str, dict[str, np.ndarray]] = {
        env: {key: np.zeros((episodes, n)) for key in ("success", "return", "q_start", "earned")}
        for env, n in size.items()
    }
    # Per task, its first episodes recorded, in order; once settled, those up to the settling one.
    counted = {env: np.zeros(n, dtype=np.int64) for env, n in size.items()}
    settled = {env: ~np.asarray(mask[env], dtype=bool) for env in size}
    probed = False
    for first in range(0, episodes, replicas):
        count = replicas if whole else min(replicas, episodes - first)
        running: Selection = {}
        seeds: Seeds = {}
        for env, ts in tasks.items():
            if settled[env].all():
                continue
            on = np.flatnonzero(mask[env] if whole else ~settled[env])
            running[env] = np.concatenate([r * len(ts) + on for r in range(count)])
            seeds[env] = np.array(
                [
                    episode_seed(seed, env, ts[i % len(ts)], draw, first + i // len(ts))
                    for i in running[env]
                ],
                dtype=np.uint32,
            )
        if not running:
            break
        played = play(running, seeds)
        for env, run in running.items():
            rows, cols = first + run // size[env], run % size[env]
            keep = (rows < episodes) & ~settled[env][cols]
            for key, values in played[env].items():
                outcome[env][key][rows[keep], cols[keep]] = np.asarray(values)[keep]
            probed = probed or "q_start" in played[env]
            np.add.at(counted[env], cols[keep], 1)
        if decide is None:
            continue
        for env in running:
            for i in np.flatnonzero(~settled[env]):
                # The first of its episodes so far after which the verdict is settled, if any.
                wins = np.cumsum(outcome[env]["success"][: counted[env][i], i]).astype(np.int64)
                after = np.arange(1, len(wins) + 1)
                hit = np.flatnonzero(np.asarray(decide(wins, after - wins), dtype=bool))
                if hit.size:
                    settled[env][i], counted[env][i] = True, hit[0] + 1
    out: Results = {}
    for env, ts in tasks.items():
        for i, task in enumerate(ts):
            if not mask[env][i]:
                continue
            n = int(counted[env][i])
            means = {k: float(np.mean(v[:n, i])) for k, v in outcome[env].items()}
            result = {
                "success_rate": means["success"],
                "mean_return": means["return"],
                "episodes": float(n),
            }
            if probed:
                result.update(q_start=means["q_start"], earned=means["earned"])
            if decide is not None:
                result["decided_early"] = float(n < episodes)
            out.setdefault(env, {})[task] = result
    return out
