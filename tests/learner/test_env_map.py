"""`map_env` through the transfer testbed's oracle map: the mapped target computes what the source did.

A source agent with random weights (every parameter redrawn, so no zero bias or near-zero head
hides a wrong map) is saved; a joint agent takes it with `transfer_from` and maps its `point_view`
env from it with `seal.envs.testbed.ORACLE_MAP`. On random states of the one world both envs see,
the target's translator, deterministic action and critics must reproduce the source's.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from seal.envs.point import GOALS, PointAdapter
from seal.envs.testbed import (
    ORACLE_MAP,
    VIEW_MATRIX,
    PointViewAdapter,
    paired_states,
    point_action,
    view_goal,
)
from seal.errors import SealError
from seal.learner import Agent, AgentConfig, EnvSpec
from seal.learner.agent_state import AgentState
from seal.learner.networks import LOG_STD_MIN
from seal.learner.transfer import map_env, transfer_from

SOURCE = EnvSpec("source", obs_dim=4, act_dim=2, num_tasks=4)
TARGET = EnvSpec("target", obs_dim=6, act_dim=5, num_tasks=4)
SMALL = {"translator_hidden": (16,), "latent_dim": 16, "trunk_hidden": (16, 16)}
ORDER = ORACLE_MAP.task_order(PointAdapter.all_tasks, PointViewAdapter.all_tasks)
TOL = {"rtol": 1e-5, "atol": 1e-5}


def _config(**changes: object) -> AgentConfig:
    return AgentConfig(architecture="seal", critic_hidden=(16, 16), **SMALL, **changes)


def _source_state(config: AgentConfig) -> AgentState:
    """A pre-trained stand-in: the source alone with every parameter and temperature random."""
    source = Agent([SOURCE], config, seed=0)
    g = torch.Generator().manual_seed(1)
    with torch.no_grad():
        nets = (source.actor, source.critic, source.critic_target)
        for p in [*(p for net in nets for p in net.parameters()), *source.log_alpha.values()]:
            p.copy_(0.5 * torch.randn(p.shape, generator=g))
    return source.state_dict()


def _mapped(config: AgentConfig, modules: str = "all") -> tuple[Agent, Agent]:
    """(the source agent restored from its state, the joint agent with `target` mapped from it)."""
    state = _source_state(config)
    source = Agent([SOURCE], config, seed=0)
    source.load_state_dict(state)
    joint = Agent([SOURCE, TARGET], config, seed=2)
    transfer_from(joint, state)
    map_env(
        joint,
        state,
        "source",
        "target",
        obs_map=ORACLE_MAP.obs,
        task_order=ORDER,
        actions=ORACLE_MAP.actions,
        modules=modules,
    )
    return source, joint


def _inputs(n: int = 256) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Random states as (point obs + one-hot, point_view obs + one-hot, target ids, source ids)."""
    point_obs, view_obs = paired_states(n, seed=3)
    ids = torch.arange(n) % 4
    source_ids = torch.tensor(ORDER)[ids]
    x_source = torch.cat((torch.tensor(point_obs).float(), F.one_hot(source_ids, 4).float()), -1)
    x_target = torch.cat((torch.tensor(view_obs).float(), F.one_hot(ids, 4).float()), -1)
    return x_source, x_target, ids, source_ids


def test_the_oracle_map_is_the_testbed_by_construction() -> None:
    # t0..t3 = north, east, south, west; point runs east, north, west, south.
    assert ORDER == [1, 0, 3, 2]
    for task, index in zip(PointViewAdapter.all_tasks, ORDER, strict=True):
        assert view_goal(task) == GOALS[PointAdapter.all_tasks[index]]
    np.testing.assert_allclose(ORACLE_MAP.obs @ VIEW_MATRIX, np.eye(4), atol=1e-12)
    assert (ORACLE_MAP.source, ORACLE_MAP.target) == ("point", "point_view")
    # The action map is the env's: the source's move (x, y) is point_action of the target's entries.
    move = np.array([0.3, -0.7])
    view = np.zeros(5)
    for k, (index, sign) in enumerate(ORACLE_MAP.actions):
        view[index] = sign * move[k]
    np.testing.assert_array_equal(point_action(view), move)


@pytest.mark.parametrize("critic_layer_norm", [False, True], ids=["", "critic_layer_norm"])
@pytest.mark.parametrize("critic_sharing", ["per_env", "shared"])
def test_the_mapped_target_computes_the_sources_latent_action_and_q(
    critic_sharing: str, critic_layer_norm: bool
) -> None:
    config = _config(critic_sharing=critic_sharing, critic_layer_norm=critic_layer_norm)
    source, joint = _mapped(config)
    x_source, x_target, ids, source_ids = _inputs()
    with torch.no_grad():
        # The translator: the target's latent of V s under task j is the source's of s under σ(j).
        latent = joint.actor.translators["target"](x_target)
        torch.testing.assert_close(latent, source.actor.translators["source"](x_source), **TOL)
        assert latent.abs().max() > 0.1  # a real comparison, not of zeros
        # The policy: tanh(mean) on entries 3 and 1 is the source's deterministic x and -y move.
        mean_log_std = joint.policy("target", ids)(x_target)
        source_out = source.policy("source", source_ids)(x_source)
    mean, log_std = mean_log_std.chunk(2, -1)
    source_mean, source_log_std = source_out.chunk(2, -1)
    torch.testing.assert_close(torch.tanh(mean[:, 3]), torch.tanh(source_mean[:, 0]), **TOL)
    torch.testing.assert_close(torch.tanh(mean[:, 1]), -torch.tanh(source_mean[:, 1]), **TOL)
    torch.testing.assert_close(log_std[:, [3, 1]], source_log_std, **TOL)
    # The distractors: mean 0, log std at the lower clamp, whatever the state.
    assert torch.equal(mean[:, [0, 2, 4]], torch.zeros(len(ids), 3))
    assert torch.equal(log_std[:, [0, 2, 4]], torch.full((len(ids), 3), LOG_STD_MIN))
    # The same through the public acting API, and through the env's own action map.
    point_obs, view_obs = paired_states(len(ids), seed=3)
    acted = joint.act("target", view_obs, ids.numpy(), deterministic=True)
    expected = source.act("source", point_obs, source_ids.numpy(), deterministic=True)
    np.testing.assert_allclose(point_action(acted), expected, rtol=1e-5, atol=1e-5)
    assert np.all(acted[:, [0, 2, 4]] == 0.0)
    # The critics, online and target: Q of (V s, t_j, a) is the source's of (s, σ(j), point_action(a)).
    g = torch.Generator().manual_seed(4)
    actions = torch.rand(len(ids), 5, generator=g) * 2 - 1
    source_actions = torch.as_tensor(point_action(actions.numpy()))
    with torch.no_grad():
        for online in (True, False):
            # The target critics start as copies of the online ones, as transfer_from's do.
            qf, source_qf = (joint.qf if online else joint.qf_target), source.qf
            q = qf("target", ids)(x_target, actions)
            torch.testing.assert_close(
                q, source_qf("source", source_ids)(x_source, source_actions), **TOL
            )
            assert q.abs().max() > 0.1
    # The per-task temperatures follow their tasks.
    torch.testing.assert_close(
        joint.log_alpha_of("target").detach(), source.log_alpha_of("source").detach()[ORDER]
    )


def test_translator_only_leaves_the_targets_head_critic_and_temperatures_fresh() -> None:
    config = _config()
    fresh = Agent([SOURCE, TARGET], config, seed=2)
    transfer_from(fresh, _source_state(config))
    source, joint = _mapped(config, modules="translator")
    x_source, x_target, _, _ = _inputs()
    with torch.no_grad():
        torch.testing.assert_close(
            joint.actor.translators["target"](x_target),
            source.actor.translators["source"](x_source),
            **TOL,
        )
    for name, module in (
        ("actor.heads", lambda a: a.actor.heads["target"]),
        ("critic", lambda a: a.critic.nets["target"]),
        ("critic_target", lambda a: a.critic_target.nets["target"]),
    ):
        for key, value in module(fresh).state_dict().items():
            assert torch.equal(value, module(joint).state_dict()[key]), f"{name}.{key}"
    assert torch.equal(fresh.log_alpha_of("target"), joint.log_alpha_of("target"))
    # The shared trunk is the source's in both (transfer_from), so the target reads its latents.
    assert torch.equal(fresh.actor.trunk.weights[0], joint.actor.trunk.weights[0])


def test_maps_that_do_not_fit_are_refused_in_one_line() -> None:
    config = _config()
    state = _source_state(config)
    joint = Agent([SOURCE, TARGET], config, seed=2)
    kwargs = {"obs_map": ORACLE_MAP.obs, "task_order": ORDER, "actions": ORACLE_MAP.actions}
    with pytest.raises(SealError, match=r"obs_map is \(6, 4\), expected"):
        map_env(joint, state, "source", "target", **{**kwargs, "obs_map": VIEW_MATRIX})
    with pytest.raises(SealError, match="task_order"):
        map_env(joint, state, "source", "target", **{**kwargs, "task_order": [0, 1, 2, 4]})
    with pytest.raises(SealError, match="its own target entry"):
        map_env(joint, state, "source", "target", **{**kwargs, "actions": ((3, 1.0), (3, -1.0))})
    with pytest.raises(SealError, match="no env 'nowhere'"):
        map_env(joint, state, "nowhere", "target", **kwargs)
    with pytest.raises(SealError, match="modules = 'heads'"):
        map_env(joint, state, "source", "target", **kwargs, modules="heads")
    deep = _config(head_hidden=(8,))
    with pytest.raises(SealError, match="linear action heads"):
        map_env(
            Agent([SOURCE, TARGET], deep, seed=2), _source_state(deep), "source", "target", **kwargs
        )


def test_a_map_that_is_not_its_own_inverse() -> None:
    # The testbed's task order [1, 0, 3, 2] is its own inverse and its obs map orthogonal-like, so
    # a map applied backwards would pass above; this one is neither: tasks 2, 0, 3, 1, a random
    # obs map, and the source's x on target entry 4 with its sign flipped, y on entry 0.
    config = _config()
    state = _source_state(config)
    source = Agent([SOURCE], config, seed=0)
    source.load_state_dict(state)
    joint = Agent([SOURCE, TARGET], config, seed=2)
    transfer_from(joint, state)
    rng = np.random.default_rng(5)
    obs_map, order, actions = rng.normal(size=(4, 6)), [2, 0, 3, 1], ((4, -1.0), (0, 1.0))
    map_env(joint, state, "source", "target", obs_map=obs_map, task_order=order, actions=actions)
    view_obs = rng.normal(size=(64, 6)).astype(np.float32)
    point_obs = (view_obs.astype(np.float64) @ obs_map.T).astype(np.float32)
    ids = np.arange(64) % 4
    source_ids = np.array(order)[ids]
    acted = joint.act("target", view_obs, ids, deterministic=True)
    expected = source.act("source", point_obs, source_ids, deterministic=True)
    np.testing.assert_allclose(np.stack([-acted[:, 4], acted[:, 0]], -1), expected, **TOL)
    a_target = rng.uniform(-1, 1, size=(64, 5)).astype(np.float32)
    a_source = np.stack([-a_target[:, 4], a_target[:, 0]], -1)
    one_hot = np.eye(4, dtype=np.float32)
    with torch.no_grad():
        q = joint.qf("target", torch.tensor(ids))(
            torch.tensor(np.concatenate([view_obs, one_hot[ids]], -1)), torch.tensor(a_target)
        )
        q_source = source.qf("source", torch.tensor(source_ids))(
            torch.tensor(np.concatenate([point_obs, one_hot[source_ids]], -1)),
            torch.tensor(a_source),
        )
    torch.testing.assert_close(q, q_source, rtol=1e-4, atol=1e-4)


def test_distractors_at_zero_log_density_add_nothing_to_the_soft_target() -> None:
    from seal.learner.networks import tanh_gaussian
    from seal.learner.transfer import UNMAPPED_ZERO_LOG_DENSITY
    from seal.protocols.config import TransferConfig

    # The protocol's default is the lower clamp; the other choice has expected log-density 0.
    assert TransferConfig().map_unmapped_log_std == LOG_STD_MIN
    config = _config()
    state = _source_state(config)
    joint = Agent([SOURCE, TARGET], config, seed=2)
    transfer_from(joint, state)
    map_env(
        joint,
        state,
        "source",
        "target",
        obs_map=ORACLE_MAP.obs,
        task_order=ORDER,
        actions=ORACLE_MAP.actions,
        unmapped_log_std=UNMAPPED_ZERO_LOG_DENSITY,
    )
    _, x_target, ids, _ = _inputs(8)
    with torch.no_grad():
        _, log_std = joint.policy("target", ids)(x_target).chunk(2, -1)
    assert torch.allclose(log_std[:, [0, 2, 4]], torch.tensor(UNMAPPED_ZERO_LOG_DENSITY))
    # One distractor entry alone: mean 0 at that log std, E[log pi] over 2e5 draws is 0.
    g = torch.Generator().manual_seed(0)
    noise = torch.randn(200_000, 1, generator=g, dtype=torch.float64)
    head = torch.tensor([[0.0, UNMAPPED_ZERO_LOG_DENSITY]], dtype=torch.float64)
    _, log_prob = tanh_gaussian(head.expand(len(noise), 2), noise)
    assert abs(float(log_prob.mean())) < 0.01


def _state_after(config: AgentConfig, modules: object) -> dict[str, torch.Tensor]:
    """Every tensor of the joint agent's state (networks, targets, temperatures) after the mapped start."""
    _, joint = _mapped(config, modules=modules)  # type: ignore[arg-type]
    state = joint.state_dict()
    out = {}
    for part in ("actor", "critic", "critic_target"):
        out.update({f"{part}.{k}": v for k, v in state[part].items()})
    out.update({f"log_alpha.{k}": v for k, v in state["log_alpha"].items()})
    return out


@pytest.mark.parametrize("critic_sharing", ["per_env", "shared"])
def test_the_spellings_all_and_translator_are_their_lists(critic_sharing: str) -> None:
    config = _config(critic_sharing=critic_sharing)
    for spelling, pieces in (
        ("all", ["translator", "head", "critic", "temperature"]),
        ("all", ["temperature", "critic", "head", "translator"]),  # any order
        ("translator", ["translator"]),
    ):
        left, right = _state_after(config, spelling), _state_after(config, pieces)
        assert left.keys() == right.keys()
        for key, value in left.items():
            assert torch.equal(value, right[key]), (spelling, pieces, key)


@pytest.mark.parametrize(
    "pieces",
    [("head",), ("critic",), ("temperature",), ("head", "critic"), ("critic", "temperature")],
)
def test_each_piece_is_mapped_alone_and_the_rest_stays_fresh(pieces: tuple[str, ...]) -> None:
    """A subset maps exactly its pieces: each is the full map's, each other one the translator
    rung's (fresh), so the 2^3 factorial's cells differ in nothing else."""
    config = _config()
    subset = _state_after(config, ["translator", *pieces])
    full, fresh = _state_after(config, "all"), _state_after(config, "translator")
    owner = {
        "translator": ("actor.translators.target.",),
        "head": ("actor.heads.target.",),
        "critic": ("critic.nets.target.", "critic_target.nets.target."),
        "temperature": ("log_alpha.target",),
    }
    for key, value in subset.items():
        piece = next((p for p, prefixes in owner.items() if key.startswith(prefixes)), None)
        expected = full if piece == "translator" or piece in pieces else fresh
        assert torch.equal(value, expected[key]), (pieces, key)
    # Every piece differs between the full map and the fresh start (the test can tell them apart).
    for piece, prefixes in owner.items():
        if piece != "translator":
            keys = [k for k in full if k.startswith(prefixes)]
            assert any(not torch.equal(full[k], fresh[k]) for k in keys), piece


def test_a_set_without_the_translator_is_refused() -> None:
    config = _config()
    state = _source_state(config)
    joint = Agent([SOURCE, TARGET], config, seed=2)
    kwargs = {"obs_map": ORACLE_MAP.obs, "task_order": ORDER, "actions": ORACLE_MAP.actions}
    with pytest.raises(SealError, match=r"map_env: map_modules = \['head'\] is not valid \(no"):
        map_env(joint, state, "source", "target", **kwargs, modules=["head"])
