"""SMT's task-encoder step against one SAC update at a protocol's sizes, in one process.

    python scripts/encoder_step_seconds.py protocols/mt10_smt.toml

Builds the protocol's agent (agent.task_encoder = "smt_gru") for its first env on CPU at one
torch thread, fills a replay with 8 whole episodes per task of random transitions (the step column
0..T-1, so the encoder finds whole episodes), then times, interleaved, the best of 3 rounds of:
one SAC update on a batch of `training.batch_per_task` per task, and one encoder step (ELBO over
`encoder_episodes` whole episodes, backward, Adam). Prints both and their ratio: what
`encoder_interval` buys (the update's cost grows by ratio / interval).
"""

from __future__ import annotations

import sys
import time

import numpy as np
import torch


def main(path: str) -> None:
    from seal.learner import EnvSpec
    from seal.learner.replay import MultiTaskReplay
    from seal.learner.sac import Agent
    from seal.protocols import load_protocol
    from seal.run.phase_model import build_adapters

    torch.set_num_threads(1)
    config = load_protocol(path, ["agent.device=cpu"])
    name, adapter = next(iter(build_adapters(config).items()))
    spec = EnvSpec(name, adapter.obs_dim, adapter.act_dim, len(adapter.tasks))
    agent = Agent([spec], config.agent, seed=0)
    width, tasks = spec.obs_dim + config.agent.obs_extra, spec.num_tasks
    length = config.envs[name].episode_length or 500
    replay = MultiTaskReplay(
        [EnvSpec(name, width, spec.act_dim, tasks)], capacity=tasks * length * 8
    )
    rng = np.random.default_rng(0)
    for _ in range(8):
        for t in range(length):
            obs = rng.normal(size=(tasks, width)).astype(np.float32)
            obs[:, -1] = t
            nxt = rng.normal(size=(tasks, width)).astype(np.float32)
            nxt[:, -1] = t + 1
            actions = rng.uniform(-1, 1, size=(tasks, spec.act_dim)).astype(np.float32)
            rewards = rng.normal(size=tasks).astype(np.float32)
            replay.add(name, np.arange(tasks), obs, actions, rewards, nxt, np.zeros(tasks))
    counts = {name: np.full(tasks, config.training.batch_per_task)}
    assert agent.task_encoding is not None, "the protocol's agent has no task encoder"

    def update() -> None:
        agent.update(replay.sample(counts))

    def encoder() -> None:
        agent.task_encoding.update(replay, 0)  # type: ignore[union-attr]

    best = {"update": float("inf"), "encoder": float("inf")}
    for _ in range(3):
        for key, fn in (("update", update), ("encoder", encoder)):
            start = time.perf_counter()
            fn()
            best[key] = min(best[key], time.perf_counter() - start)
    print(
        f"{path}: SAC update {best['update']:.3f} s, encoder step {best['encoder']:.3f} s, "
        f"ratio {best['encoder'] / best['update']:.2f} (one torch thread, best of 3)"
    )


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "protocols/mt10_smt.toml")
