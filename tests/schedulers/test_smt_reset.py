"""SMT's reset (`Plan.reset_agent` -> `Agent.reset_parameters`): buffers intact, every reset parameter changed."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from seal.learner.config import AgentConfig, EnvSpec
from seal.learner.replay import MultiTaskReplay
from seal.learner.sac import Agent
from seal.schedulers import Progress, SMTConfig, build_scheduler


def test_reset_keeps_buffers_and_changes_every_reset_parameter() -> None:
    spec = EnvSpec(name="mw", obs_dim=4, act_dim=2, num_tasks=2)
    agent = Agent([spec], AgentConfig(hidden=(16, 16)), seed=0)
    replay = MultiTaskReplay([spec], capacity=200, check_memory=False)
    rng = np.random.default_rng(0)
    for _ in range(50):
        ids = np.array([0, 1])
        replay.add(
            "mw",
            ids,
            rng.normal(size=(2, 4)),
            rng.uniform(-1, 1, (2, 2)),
            rng.normal(size=2),
            rng.normal(size=(2, 4)),
            np.zeros(2),
        )
    for _ in range(5):  # move every parameter away from its initial value and fill Adam's state
        agent.update(replay.sample({"mw": np.array([8, 8])}))

    # The scheduler asks for the reset once T_reset env steps of stage 1 have been spent.
    sched = build_scheduler(
        SMTConfig(
            budget_stage1=1000,
            slots=2,
            reset_interval=20,
            solved_return={"mw": 1e9},
            unsolvable_return={"mw": 0.0},
        ),
        {"mw": ("a", "b")},
    )
    assert not sched.plan(Progress(epoch=0)).reset_agent
    sched.observe_episodes("mw", ["a", "b"], [0.0, 0.0], [0.0, 0.0], [10, 10])
    plan = sched.plan(Progress(epoch=1))
    assert plan.reset_agent  # 20 env steps // T_reset 20 = 1 reset due

    buffers = {k: v.clone() for k, v in replay.storage["mw"].items()}
    sizes, consumed = replay.size["mw"].copy(), replay.consumed["mw"].copy()
    nets = {"actor": agent.actor, "critic": agent.critic, "critic_target": agent.critic_target}
    before = {
        f"{n}.{k}": v.detach().clone()
        for n, net in nets.items()
        for k, v in net.state_dict().items()
    }
    old_target_params = list(agent.critic_target.parameters())
    assert not np.allclose(
        agent.log_alpha["mw"].detach().numpy(), math.log(agent.config.init_alpha)
    )
    agent.reset_parameters()

    # Buffers, sizes and consumed counters are untouched.
    for k, v in buffers.items():
        np.testing.assert_array_equal(replay.storage["mw"][k], v)
    np.testing.assert_array_equal(replay.size["mw"], sizes)
    np.testing.assert_array_equal(replay.consumed["mw"], consumed)
    # Every tensor of the actor, the twin critics and their targets has new values.
    nets = {"actor": agent.actor, "critic": agent.critic, "critic_target": agent.critic_target}
    after = {f"{n}.{k}": v.detach() for n, net in nets.items() for k, v in net.state_dict().items()}
    assert before.keys() == after.keys() and len(after) > 6
    unchanged = [k for k in before if torch.equal(before[k], after[k])]
    assert unchanged == []
    # Targets are fresh copies of the new critic, not the old target tensors.
    for k, v in agent.critic.state_dict().items():
        assert torch.equal(agent.critic_target.state_dict()[k], v)
    assert all(
        p is not q for p, q in zip(agent.critic_target.parameters(), old_target_params, strict=True)
    )
    # Temperatures are back at init_alpha (they had moved), and every Adam state is empty again,
    # holding the live parameters.
    np.testing.assert_allclose(
        agent.log_alpha["mw"].detach().numpy(), [math.log(agent.config.init_alpha)] * 2
    )
    for opt in [*agent.actor_optimizers, *agent.critic_optimizers, agent.alpha_optimizer]:
        assert len(opt.state) == 0
    live = {
        id(p)
        for p in [*agent.actor.parameters(), *agent.critic.parameters(), *agent.log_alpha.values()]
    }
    assert all(
        id(p) in live
        for opt in [*agent.actor_optimizers, *agent.critic_optimizers, agent.alpha_optimizer]
        for g in opt.param_groups
        for p in g["params"]
    )
    # Training goes on from the kept buffers.
    logs = agent.update(replay.sample({"mw": np.array([8, 8])}))
    assert all(math.isfinite(v) for v in logs.values())


RUN = """
[protocol]
kind = "baseline"
epochs = 8
seeds = 1
device = "cpu"
threads = 1
[envs.pt]
adapter = "point"
tasks = ["east", "north", "west"]
episode_length = 10
[agent]
hidden = [8, 8]
[training]
warmup_steps = 0
batch_per_task = 4
collector = "sync"
[evaluation]
interval = 4
episodes = 1
[logging]
tensorboard = false
[scheduler]
kind = "smt"
budget_stage1 = 1000
budget_stage2 = 0
slots = 2
reset_interval = 40
score_interval = 40
solved_return = { pt = 1e9 }
unsolvable_return = { pt = -1e9 }
"""


def test_the_runner_applies_every_reset_the_scheduler_asks_for(
    tmp_path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # 2 slots x 10 steps = 20 stage-1 env steps an epoch, T_reset = 40: resets are due at the
    # plans of epochs 2, 4 and 6 (after 40, 80, 120 steps) within 8 epochs. The spy calls the
    # real reset, and records the critic's first weight just before and after it.
    from seal.learner.checkpoint import read_checkpoint
    from seal.protocols import load_protocol
    from seal.run.runner import run_seed

    calls: list[tuple[torch.Tensor, torch.Tensor]] = []
    real = Agent.reset_parameters

    def spy(self: Agent) -> None:
        before = next(self.critic.parameters()).detach().clone()
        real(self)
        calls.append((before, next(self.critic.parameters()).detach().clone()))

    monkeypatch.setattr(Agent, "reset_parameters", spy)
    path = tmp_path / "smt.toml"
    path.write_text(RUN)
    run = run_seed(load_protocol(path), 0, tmp_path / "out").run_dir
    state = read_checkpoint(run / "checkpoints" / "ckpt-0000008.pt")
    assert state["scheduler"]["resets_done"] == 3
    assert len(calls) == 3
    assert all(not torch.equal(before, after) for before, after in calls)
