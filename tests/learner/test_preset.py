"""agent.preset = "seal_prototype": the values it sets, explicit keys winning, and the network it builds."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from seal.errors import ConfigError
from seal.learner import Agent, AgentConfig, EnvSpec, MultiTaskReplay
from seal.learner.presets import PRESETS
from seal.protocols import explain, load_protocol
from seal.schedulers.base import counts_from_ratio

HIGH_FK = "protocols/high_fk.toml"
PRESET = 'agent.preset="seal_prototype"'


def test_explain_shows_every_value_the_preset_sets_and_an_explicit_key_winning() -> None:
    config = load_protocol(HIGH_FK, [PRESET, "agent.actor_lr=1e-4"])
    agent = config.agent
    assert (agent.translator_hidden, agent.latent_dim) == ((400, 400), 400)
    assert agent.trunk_hidden == (400,) * 6
    assert (agent.head_hidden, agent.head_per_task) == ((400, 400, 400), True)
    assert (agent.critic_lr, agent.alpha_lr, agent.clip_per) == (3e-5, 3e-5, "component")
    assert agent.actor_lr == 1e-4  # the explicit key wins
    text = explain(config)
    assert "# agent.preset = 'seal_prototype' sets:" in text
    assert "#   trunk_hidden = [400, 400, 400, 400, 400, 400]" in text
    assert "#   critic_lr = 3e-05" in text
    assert "#   actor_lr = 3e-05, overridden: the explicit actor_lr = 0.0001 wins" in text
    assert len([line for line in text.splitlines() if line.startswith("#   ")]) == len(
        PRESETS["seal_prototype"]
    )


def test_no_preset_changes_nothing_and_an_unknown_one_is_one_line() -> None:
    assert load_protocol(HIGH_FK).agent == load_protocol(HIGH_FK, ['agent.preset=""']).agent
    assert load_protocol(HIGH_FK).agent.head_hidden == ()
    with pytest.raises(
        ConfigError, match="agent.preset 'nope' is not a preset; valid: 'seal_prototype'"
    ):
        load_protocol(HIGH_FK, ['agent.preset="nope"'])
    with pytest.raises(ConfigError, match="head_per_task = true needs a hidden layer"):
        AgentConfig(architecture="seal", head_per_task=True)


SPECS = [EnvSpec("mw", 39, 4, 10), EnvSpec("fk", 59, 9, 10)]


def _prototype(**changes: object) -> AgentConfig:
    config = load_protocol(HIGH_FK, [PRESET, 'agent.device="cpu"']).agent
    return dataclasses.replace(config, **changes)


def test_the_built_network_has_the_prototypes_layer_shapes() -> None:
    agent = Agent(SPECS, _prototype(), seed=0)
    shapes = {n: tuple(p.shape) for n, p in agent.actor.named_parameters()}
    # By hand from the prototype (docs/hyperparameters.md): each env's TranslationLayer is
    # 3 Dense layers over [obs, one-hot] (R:140-159): 39 + 10 = 49 -> 400 -> 400 -> 400 for
    # Meta-World, 59 + 10 = 69 -> ... for the kitchen; the shared SEAL trunk is 6 Dense 400 -> 400
    # (R:162-179); each env's actor has 2 shared hidden layers of 400, a per-task third (400 per
    # task, 10 tasks: 4,000 wide, R:195) and mean/log-std outputs its tasks share (2 x |A|, R:208-217).
    for env, obs in (("mw", 49), ("fk", 69)):
        assert [shapes[f"translators.{env}.weights.{i}"] for i in range(3)] == [
            (1, obs, 400),
            (1, 400, 400),
            (1, 400, 400),
        ]
    assert [shapes[f"trunk.weights.{i}"] for i in range(6)] == [(1, 400, 400)] * 6
    assert "trunk.weights.6" not in shapes
    for env, act in (("mw", 4), ("fk", 9)):
        assert [shapes[f"heads.{env}.body.weights.{i}"] for i in range(2)] == [(1, 400, 400)] * 2
        assert shapes[f"heads.{env}.task_layer.weight"] == (1, 400, 10 * 400)
        assert shapes[f"heads.{env}.out.weight"] == (1, 400, 2 * act)
    # 3 + 6 + 3 + 1 = 13 layers on each env's path (the doc's count).
    mw_layers = [n for n in shapes if n.endswith("weight") or ".weights." in n]
    assert len([n for n in mw_layers if "fk" not in n]) == 13
    # Each env's twin critic: 3 x 400 over [obs, one-hot, action], one Q output per task.
    critic = {n: tuple(p.shape) for n, p in agent.critic.named_parameters()}
    assert critic["nets.mw.trunk.weights.0"] == (2, 39 + 10 + 4, 400)
    assert critic["nets.mw.heads.mw.weight"] == (2, 400, 10)
    # Plain Dense layers (R:300-315), though the default critic has LayerNorm (issue 54).
    assert not [name for name in critic if "norm" in name]


def _agent_and_batches(config: AgentConfig) -> tuple[Agent, object]:
    specs = [EnvSpec("mw", 6, 2, 3), EnvSpec("fk", 8, 3, 2)]
    agent = Agent(specs, config, seed=0)
    replay = MultiTaskReplay(specs, capacity=200, seed=0)
    rng = np.random.default_rng(0)
    for spec in specs:
        ids = np.arange(spec.num_tasks)
        for _ in range(20):
            obs = rng.normal(size=(spec.num_tasks, spec.obs_dim)).astype(np.float32)
            act = agent.act(spec.name, obs, ids)
            done = rng.random(spec.num_tasks) < 0.05
            replay.add(spec.name, ids, obs, act, rng.normal(size=spec.num_tasks), obs, done)
    counts = counts_from_ratio({"mw": 0.5, "fk": 0.5}, {"mw": 3, "fk": 2}, batch_per_task=8)
    return agent, replay.sample(counts)


SMALL = {
    "translator_hidden": (16, 16),
    "latent_dim": 16,
    "trunk_hidden": (16,) * 6,
    "head_hidden": (16, 16, 16),
    "critic_hidden": (16, 16, 16),
}


def test_one_update_runs_and_the_per_task_layer_takes_the_tasks_block() -> None:
    agent, batches = _agent_and_batches(_prototype(**SMALL))
    metrics = agent.update(batches)
    assert all(np.isfinite(v) for v in metrics.values())
    head = agent.actor.heads["mw"]
    x = torch.randn(3, 16)
    tasks = torch.tensor([0, 2, 1])
    hidden = head.body(x)
    # The task's block of the per-task layer, by hand: columns [16 t, 16 (t + 1)).
    blocks = [
        torch.relu(
            hidden[i] @ head.task_layer.weight[0][:, 16 * t : 16 * t + 16]
            + head.task_layer.bias[0, 0, 16 * t : 16 * t + 16]
        )
        for i, t in enumerate(tasks.tolist())
    ]
    want = torch.stack(blocks) @ head.out.weight[0] + head.out.bias[0]
    torch.testing.assert_close(head(x, tasks), want)


def test_component_clipping_bounds_each_component_apart() -> None:
    config = _prototype(**SMALL, max_grad_norm=0.5)
    agent, batches = _agent_and_batches(config)
    slots = agent.actor_slots
    (slot,) = slots.of(["mw", "fk"])
    # The slot's parameters run as: mw translator, trunk, mw head, fk translator, fk head.
    components = agent.actor.components()
    assert slots.groups[slot] == [
        len(components[c])
        for c in ("translator.mw", "trunk", "head.mw", "translator.fk", "head.fk")
    ]
    params = slots.params[slot]
    loss = sum((p.float() ** 2).sum() * 100 for p in params)
    grads = slots.grads(loss, ["mw", "fk"])
    start = 0
    norms = []
    for size in slots.groups[slot]:
        part = [g for g in grads[start : start + size] if g is not None]
        norms.append(float(torch.linalg.vector_norm(torch.stack([g.norm() for g in part]))))
        start += size
    assert all(n == pytest.approx(0.5, rel=1e-4) for n in norms)  # each one clipped to 0.5
    # Under "optimizer" the whole slot has one norm of 0.5, so its components' norms are smaller.
    whole = dataclasses.replace(config, clip_per="optimizer")
    agent, _ = _agent_and_batches(whole)
    params = agent.actor_slots.params[slot]
    loss = sum((p.float() ** 2).sum() * 100 for p in params)
    grads = [g for g in agent.actor_slots.grads(loss, ["mw", "fk"]) if g is not None]
    total = float(torch.linalg.vector_norm(torch.stack([g.norm() for g in grads])))
    assert total == pytest.approx(0.5, rel=1e-4)


class _Crash(Exception):
    pass


def test_a_preset_run_saves_its_keys_and_resumes_to_the_same_rows(tmp_path) -> None:
    """config.toml holds the preset's keys and loads back equal; a run killed after its epoch-2
    checkpoint resumes (the per-task head layer and component clipping restored) to the rows of
    the uninterrupted run."""
    import json
    import tomllib

    import pandas as pd

    from seal.protocols.loader import config_from_dict
    from seal.run.loop import LoopCallback, PhaseLoop
    from seal.run.runner import load_policy, run_seed
    from tests.protocols.test_runner import JOINT_ENVS, protocol

    small = [f"agent.{k}={list(v) if isinstance(v, tuple) else v}" for k, v in SMALL.items()]
    path = protocol(tmp_path, JOINT_ENVS, kind="joint", epochs=4, warmup=16)
    config = load_protocol(path, [PRESET, "logging.tensorboard=false", *small])
    assert (config.agent.head_per_task, config.agent.clip_per) == (True, "component")

    reference = run_seed(config, 0, tmp_path / "ref").run_dir
    saved = config_from_dict(tomllib.loads((reference / "config.toml").read_text()), "saved")
    assert saved.agent == config.agent
    _, _, agent, _ = load_policy(reference / "checkpoints" / "best.pt", device="cpu")
    assert agent.actor.heads["b"].task_layer.weight.shape == (1, 16, 2 * 16)

    class Crash(LoopCallback):
        def on_epoch_end(self, loop: PhaseLoop) -> None:
            if loop.state.epoch == 3:
                raise _Crash

    with pytest.raises(_Crash):
        run_seed(config, 0, tmp_path / "g", callbacks=[Crash()])
    resumed = run_seed(config, 0, tmp_path / "g", resume=True).run_dir
    resumes = json.loads((resumed / "provenance.json").read_text())["resumes"]
    assert [r["from"] for r in resumes] == ["ckpt-0000002.pt"]
    got, want = (
        pd.read_csv(run / "metrics.csv").drop(columns="wall_s") for run in (resumed, reference)
    )
    assert got["epoch"].tolist() == want["epoch"].tolist() == [1, 1, 1, 2, 2, 2, 3, 3, 3, 4, 4, 4]
    pd.testing.assert_frame_equal(got, want)


@pytest.mark.parametrize("shared_update", ["weighted", "sequential", "per_env"])
@pytest.mark.parametrize("critic_sharing", ["per_env", "shared"])
def test_component_groups_under_every_update_mode(shared_update: str, critic_sharing: str) -> None:
    """Every slot's clipping groups are its components, each once, in the slot's order."""
    config = _prototype(**SMALL, shared_update=shared_update, critic_sharing=critic_sharing)
    agent = Agent([EnvSpec("mw", 6, 2, 3), EnvSpec("fk", 8, 3, 2)], config, seed=0)
    for net, slots in ((agent.actor, agent.actor_slots), (agent.critic, agent.critic_slots)):
        owner = {id(p): c for c, ps in net.components().items() for p in ps}
        for params, groups in zip(slots.params, slots.groups, strict=True):
            names, start = [], 0
            for size in groups:
                run = {owner[id(p)] for p in params[start : start + size]}
                assert len(run) == 1
                names.append(run.pop())
                start += size
            assert start == len(params) and len(set(names)) == len(names)
            members = {n.split(".")[-1] for n in names if "." in n}
            assert all(f"head.{m}" in names or f"critic.{m}" in names for m in members)
