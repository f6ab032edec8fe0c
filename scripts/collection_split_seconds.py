"""Seconds per 100-step episode of the quickstart's two training envs, in one process and in two.

    python scripts/collection_split_seconds.py [REPEATS]   # default 5

Times `Collector.collect_episodes(random_actions=True)` (best of REPEATS, after one warm-up
episode) for the kitchen alone, Meta-World alone, both on ``sync`` (one process) and both on
``inline-batched`` with 2 workers (the kitchen in a worker). The evidence behind
`AUTO_PARALLEL_MIN_SAVING_S`: a split that saves only the cheap env's step gains little or nothing.
"""

import sys
import time

from seal.envs.registry import make_adapter
from seal.learner.collection import Collector
from seal.protocols import load_protocol

repeats = int(sys.argv[1]) if len(sys.argv) > 1 else 5
config = load_protocol("protocols/quickstart.toml")
adapters = {
    name: make_adapter(env.adapter, env.tasks, episode_length=env.episode_length)
    for name, env in config.envs.items()
}


def best_episode_seconds(envs: dict, backend: str) -> float:
    with Collector(envs, seed=0, backend=backend, num_workers=2) as collector:
        collector.collect_episodes(None, random_actions=True)
        best = float("inf")
        for _ in range(repeats):
            start = time.perf_counter()
            collector.collect_episodes(None, random_actions=True)
            best = min(best, time.perf_counter() - start)
    return best


for label, envs, backend in (
    ("fk alone, sync", {"fk": adapters["fk"]}, "sync"),
    ("mw alone, sync", {"mw": adapters["mw"]}, "sync"),
    ("both, sync (one process)", adapters, "sync"),
    ("both, inline-batched (two)", adapters, "inline-batched"),
):
    print(f"{label:28s} {best_episode_seconds(envs, backend):.3f} s per episode")
