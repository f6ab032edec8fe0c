"""No Python loop over tasks or heads in the update: the torch op count does not depend on task count."""

from __future__ import annotations

from collections import Counter

import pytest
import torch
from torch.profiler import ProfilerActivity, profile

from seal.learner import Agent, AgentConfig, Batch, EnvSpec

SMALL = {"hidden": (16, 16), "translator_hidden": (16,), "latent_dim": 16, "trunk_hidden": (16, 16)}


def _batch(spec: EnvSpec, per_task: int) -> Batch:
    n = per_task * spec.num_tasks
    g = torch.Generator().manual_seed(0)
    return Batch(
        torch.randn(n, spec.obs_dim, generator=g),
        torch.rand(n, spec.act_dim, generator=g) * 2 - 1,
        torch.randn(n, generator=g),
        torch.randn(n, spec.obs_dim, generator=g),
        torch.zeros(n),
        torch.arange(spec.num_tasks).repeat_interleave(per_task),
    )


def _ops_of_one_update(config: AgentConfig, num_tasks: int) -> Counter[str]:
    """Names and counts of every torch op the profiler records during one (warmed-up) update."""
    specs = [EnvSpec("mw", 6, 2, num_tasks)]
    if config.architecture == "seal":
        specs.append(EnvSpec("fk", 9, 3, num_tasks))
    agent = Agent(specs, config, seed=0)
    batches = {s.name: _batch(s, 4) for s in specs}
    agent.update(batches)  # first update creates the optimiser states
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        agent.update(batches)
    return Counter(event.name for event in prof.events())


@pytest.mark.parametrize(
    "config",
    [
        AgentConfig(**SMALL),
        AgentConfig(multi_head_critic=False, **SMALL),
        *(
            AgentConfig(architecture="seal", shared_update=mode, critic_sharing=critics, **SMALL)
            for mode in ("weighted", "sequential", "per_env")
            for critics in ("per_env", "shared")
        ),
    ],
    ids=[
        "mtmhsac",
        "mtmhsac-single-head-critic",
        *(
            f"seal-{mode}-{critics}-critics"
            for mode in ("weighted", "sequential", "per_env")
            for critics in ("per_env", "shared")
        ),
    ],
)
def test_op_count_is_the_same_for_2_and_10_tasks(config: AgentConfig) -> None:
    two, ten = _ops_of_one_update(config, 2), _ops_of_one_update(config, 10)
    assert sum(two.values()) > 100  # the profiler saw the update
    assert two["aten::gather"] > 0  # heads are gathered, not looped
    assert two == ten
