"""What a protocol's evaluations cost in env steps under `evaluation.decide_early` and
`evaluation.end_on_success`: the share of the full evaluation's env steps the floor projection
(`seal.bench.protocol`) counts.

A decided-early evaluation's cost depends on the outcomes, so the projection uses a model, the
clean one: a task fails every evaluation episode before its first crossing and succeeds in every
one after. Then per task and evaluation (n episodes of T steps, `replicas` r of them at once,
`EarlyDecision`'s `needed` successes, L the steps to the first success):

    full evaluation, before / after the crossing:    n T          / n L'
    decided early,   before / after the crossing:    ceil(f / r) r T / ceil(needed / r) r L'

where f = n - needed + 1 failures settle it, L' = L with end_on_success (else T), and a wave's
episodes beyond the settling one run but are not counted (`seal.learner.evaluation_waves`).
Every `full_every`-th evaluation runs in full, so the share is

    max over {before, after} of [(1 / k) full + (1 - 1 / k) decided] / (n T),   k = full_every,

the larger of the two ends, whatever share of the run lies before the crossing (the cost is
linear in it). A task whose success hovers near the threshold settles later, up to all n
episodes: the model is not a bound for such runs, and says so where it is printed.

L is measured: the adapter's scripted expert (`EnvAdapter.expert`), one episode per task, the
step of its first success (T where it has no expert or never succeeds). A learned policy may
take longer than the expert; the projection names L per environment.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping

import numpy as np

from seal.envs.base import EnvAdapter
from seal.evaluation import EarlyDecision
from seal.protocols.config import ProtocolConfig


def success_steps(
    config: ProtocolConfig, adapters: Mapping[str, EnvAdapter], seed: int = 0
) -> dict[str, float]:
    """env -> mean over its tasks of the step (1-based) at which the scripted expert first
    succeeds in one episode; the episode length for a task without an expert or success."""
    out: dict[str, float] = {}
    for env, adapter in adapters.items():
        length = config.envs[env].episode_length
        steps = []
        for task in adapter.tasks:
            expert = adapter.expert(task)
            first = (
                length if expert is None else _first_success(adapter, task, expert, length, seed)
            )
            steps.append(float(first))
        out[env] = float(np.mean(steps))
    return out


def _first_success(
    adapter: EnvAdapter,
    task: str,
    expert: Callable[[np.ndarray], np.ndarray],
    length: int,
    seed: int,
) -> int:
    env = adapter.make(task, seed)
    try:
        obs, _ = env.reset(seed=seed)
        for step in range(1, length + 1):
            obs, _, terminated, truncated, info = env.step(expert(obs))
            if info.get("success"):
                return step
            if terminated or truncated:
                break
        return length
    finally:
        env.close()


def evaluation_share(
    config: ProtocolConfig, env: str, success_step: float, replicas: int
) -> dict[str, float]:
    """{"share", "before", "after"}: the share of the full evaluation's env steps that `env`'s
    evaluations take under the protocol's options, by the clean model (module docstring)."""
    ev = config.evaluation
    n, length = ev.episodes, config.envs[env].episode_length
    if not (ev.decide_early or ev.end_on_success):
        return {"share": 1.0, "before": 1.0, "after": 1.0}
    cut = min(float(success_step), float(length)) if ev.end_on_success else float(length)
    full_before, full_after = n * length, n * cut
    if ev.decide_early:
        rule = EarlyDecision(n, ev.threshold)
        waves = lambda k: math.ceil(k / replicas) * replicas  # noqa: E731 - episodes that ran
        decided_before = min(n, waves(n - rule.needed + 1)) * length
        decided_after = min(n, waves(rule.needed)) * cut
        k = ev.full_every
    else:
        decided_before, decided_after, k = full_before, full_after, 1
    before = (full_before + (k - 1) * decided_before) / k / (n * length)
    after = (full_after + (k - 1) * decided_after) / k / (n * length)
    return {"share": max(before, after), "before": before, "after": after}


def evaluation_shares(
    config: ProtocolConfig, success: Mapping[str, float]
) -> dict[str, dict[str, float]]:
    """env -> `evaluation_share`, with the replicas the runner evaluates with (all envs' tasks)."""
    from seal.learner.collection import evaluation_replicas

    tasks = sum(len(config.envs[e].tasks) for e in config.envs)
    replicas = evaluation_replicas(config.evaluation.episodes, tasks)
    return {e: evaluation_share(config, e, success[e], replicas) for e in config.envs}
