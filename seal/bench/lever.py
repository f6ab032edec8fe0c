"""``ratio_lever``: the 90% environment's share of the shared policy trunk's step at a 90/10 data ratio.

`Agent.ratio_lever_expected` (``ratio_lever_expected``, the headline: the share of the expected
step, over `draws` independent batches from one state) and `Agent.ratio_lever` (``ratio_lever``:
one batch's step, which per-sample gradient noise caps near sqrt(n_A) / (sqrt(n_A) + sqrt(n_B)))
of a default-width SEAL agent on `point` / `point_view` replay, under every ``shared_update`` mode
(headlines under ``"weighted"``, the default), with the ratio of the two environments' trunk
gradient norms, the weighted mode's share of the raw (pre-Adam, unclipped) gradient, and the share
that a noise-dominated gradient allows any sample-count weighting. Not a timing.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

SHARED_UPDATES = ("weighted", "sequential", "per_env")


def bench_ratio_lever(
    seed: int = 0,
    warmup_updates: int = 100,
    ratio: float = 0.9,
    batch_per_task: int = 128,
    episodes: int = 3,
    draws: int = 32,
    modes: Sequence[str] = SHARED_UPDATES,
    agent: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """`Agent.ratio_lever` of a default-width SEAL agent under each shared_update mode.

    Replay: seeded uniform-random episodes of `point` (A, the `ratio` share) and `point_view`
    (B: other observation and action spaces), `episodes` per task. Each mode's agent (same seed)
    first takes `warmup_updates` updates at the ratio so that Adam's moments are not fresh, then
    `draws` batches are drawn: `ratio_lever` (v1) is measured on the first, `ratio_lever_expected`
    (v2) on all of them, each from the warmed-up state. Goal: >= 0.8 under "weighted".
    `agent` overrides AgentConfig fields (default widths otherwise).
    """
    from seal.envs import make_adapter
    from seal.learner import Agent, AgentConfig, EnvSpec, MultiTaskReplay
    from seal.learner.collection import Collector
    from seal.schedulers.base import counts_from_ratio

    adapters = {"a": make_adapter("point"), "b": make_adapter("point_view")}
    specs = [EnvSpec(name, ad.obs_dim, ad.act_dim, len(ad.tasks)) for name, ad in adapters.items()]
    replay = MultiTaskReplay(specs, capacity=sum(len(a.tasks) for a in adapters.values()) * 1000)
    with Collector(adapters, seed=seed, backend="sync") as collector:
        for _ in range(episodes):
            collector.collect_episodes(None, random_actions=True, sink=replay.add)
    counts = counts_from_ratio(
        {"a": ratio, "b": 1.0 - ratio}, {s.name: s.num_tasks for s in specs}, batch_per_task
    )
    out: dict[str, Any] = {
        "ratio": ratio,
        "warmup_updates": warmup_updates,
        "draws": draws,
        "batch": {k: int(v.sum()) for k, v in counts.items()},
        "modes": {},
    }
    for mode in modes:
        config = AgentConfig(
            architecture="seal",
            shared_update=mode,
            ratio_lever_interval=0,
            device="cpu",
            **(agent or {}),
        )
        learner = Agent(specs, config, seed)
        replay.reseed(seed)  # every mode sees the same batches
        for _ in range(warmup_updates):
            learner.update(replay.sample(counts))
        batch_draws = [replay.sample(counts) for _ in range(draws)]
        lever = learner.ratio_lever(batch_draws[0])
        g = lever["grad_norm"]
        out["modes"][mode] = {
            **lever,
            "grad_norm_ratio_a_over_b": g["a"] / g["b"],
            "expected": learner.ratio_lever_expected(batch_draws),
        }
    n = out["batch"]
    # Where the optimiser's lever comes from, for "weighted": the same share of the raw gradient
    # sum_X (n_X / N) g_X (no Adam, no clip), and that share were every per-sample gradient
    # independent noise, when ||(n_X / N) g_X|| grows as sqrt(n_X) (the ceiling of any weighting by
    # sample counts while gradients are noise-dominated): sqrt(n_A) / (sqrt(n_A) + sqrt(n_B)).
    weighted = out["modes"].get("weighted")
    if weighted is not None:
        part = {x: n[x] * weighted["grad_norm"][x] for x in ("a", "b")}
        out["gradient_lever"] = part["a"] / (part["a"] + part["b"])
    out["noise_ceiling"] = math.sqrt(n["a"]) / (math.sqrt(n["a"]) + math.sqrt(n["b"]))
    out["ratio_lever"] = out["modes"].get("weighted", {}).get("lever")
    out["ratio_lever_expected"] = out["modes"].get("weighted", {}).get("expected", {}).get("lever")
    return out
