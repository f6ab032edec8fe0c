"""Same seed on CPU: identical losses over 100 updates in two separate processes; other seeds differ."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

# Runs in a fresh interpreter: a small SEAL agent (two envs, widths 32) and replay filled from the
# seed, then 100 updates; prints the critic and actor losses of every update as JSON.
_SCRIPT = textwrap.dedent(
    """
    import json, sys
    import numpy as np
    import torch
    torch.set_num_threads(1)
    from seal.learner import Agent, AgentConfig, EnvSpec, MultiTaskReplay
    from seal.schedulers.base import counts_from_ratio

    seed = int(sys.argv[1])
    specs = [EnvSpec("mw", 6, 2, 3), EnvSpec("fk", 8, 3, 2)]
    config = AgentConfig(architecture="seal", translator_hidden=(32,), latent_dim=32, trunk_hidden=(32, 32), device="cpu")
    agent = Agent(specs, config, seed=seed)
    replay = MultiTaskReplay(specs, capacity=500, seed=seed)
    rng = np.random.default_rng(seed)
    for spec in specs:
        ids = np.arange(spec.num_tasks)
        for _ in range(40):
            obs = rng.normal(size=(spec.num_tasks, spec.obs_dim)).astype(np.float32)
            replay.add(spec.name, ids, obs, agent.act(spec.name, obs, ids), rng.normal(size=spec.num_tasks), obs * 0.9, rng.random(spec.num_tasks) < 0.05)
    counts = counts_from_ratio({"mw": 0.6, "fk": 0.4}, {"mw": 3, "fk": 2}, batch_per_task=16)
    losses = []
    for _ in range(100):
        metrics = agent.update(replay.sample(counts))
        losses.append([metrics["losses/mw/critic"], metrics["losses/mw/actor"], metrics["losses/fk/critic"], metrics["losses/fk/actor"]])
    print(json.dumps(losses))
    """
)


def _losses(seeds: list[int]) -> list[np.ndarray]:
    """Run the script once per seed, each in its own process (all started together)."""
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", _SCRIPT, str(seed)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for seed in seeds
    ]
    results = []
    for proc in procs:
        out, err = proc.communicate()
        assert proc.returncode == 0, err
        results.append(np.array(json.loads(out.strip().splitlines()[-1])))
    return results


@pytest.mark.slow
def test_same_seed_same_losses_in_separate_processes_other_seed_differs() -> None:
    first, second, other = _losses([0, 0, 1])
    assert first.shape == (100, 4)
    np.testing.assert_array_equal(first, second)  # bitwise, every update
    assert not np.any(first == other)  # a different seed differs at every update and loss
    # and the losses move over the updates (learning is happening, not a constant)
    assert np.all(np.abs(first[-10:].mean(0) - first[:10].mean(0)) > 1e-3)
