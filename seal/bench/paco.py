"""``paco_update_speedup``: seconds per update of PaCo with every layer run through its K
parameter sets and mixed per row (the compiled path's map, `PaCo.forward_sets`) / with each task's
layer composed first (the eager path, `PaCo.forward_per_task`), at the mtrl bench's shapes
(protocols/mtrl_learn/paco.toml: two Meta-World tasks, 2 x 256, K = 5, 128 rows a task), one
torch thread. Same seed, same batches, repeats interleaved; the two agents' losses after five
updates are compared as a check that both compute the same update."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from seal.bench.flops import QUICKSTART, _agent_batches, quickstart_setup
from seal.bench.timing import best_interleaved, updates_of
from seal.device import torch_threads

PACO_PROTOCOL = QUICKSTART.parent / "mtrl_learn" / "paco.toml"


def bench_paco_update(
    updates: int = 30, repeats: int = 3, seed: int = 0, protocol: str | Path = PACO_PROTOCOL
) -> dict[str, Any]:
    """Both paths' seconds per update and their ratio (see the module docstring)."""
    from seal.learner import Agent
    from seal.learner.mtrl.paco import PaCo

    specs, config, per_task = quickstart_setup(protocol)
    config = dataclasses.replace(config, compile=False)  # compiled, both sides run the sets
    agents = {"per_task": Agent(specs, config, seed), "sets": Agent(specs, config, seed)}
    for net in (agents["sets"].actor, agents["sets"].critic):
        for module in net.modules():
            if isinstance(module, PaCo):
                module.compose_first = False
    batches = _agent_batches(specs, per_task, seed)
    with torch_threads(1):
        losses = {}
        for name, agent in agents.items():
            for _ in range(5):
                metrics = agent.update(batches)
            losses[name] = {k: v for k, v in metrics.items() if k.startswith("losses")}
        runs = {name: updates_of(agent, batches, updates) for name, agent in agents.items()}
        best = best_interleaved(runs, repeats, updates)
    rel = {
        k: abs(losses["per_task"][k] - v) / max(abs(v), 1e-12) for k, v in losses["sets"].items()
    }
    return {
        "paco_update_speedup": best["sets"] / best["per_task"],
        "per_task_update_s": best["per_task"],
        "sets_update_s": best["sets"],
        "loss_max_rel_diff": max(rel.values()),
        "batch": per_task * sum(s.num_tasks for s in specs),
        "sets": config.paco_sets,
        "hidden": list(config.hidden),
        "updates_timed": updates,
        "threads": 1,
    }
