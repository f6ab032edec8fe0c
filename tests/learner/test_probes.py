"""The alignment probe: linear CKA, the testbed's paired states, and the translators' activations."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from seal.envs.registry import make_adapter
from seal.envs.testbed import VIEW_MATRIX, paired_states
from seal.errors import SealError
from seal.learner import AgentConfig, EnvSpec
from seal.learner.probes import (
    agent_from_state,
    corresponding_tasks,
    latent_activations,
    linear_cka,
    shared_world_cka,
    translator_cka,
)
from seal.learner.sac import Agent

TINY_SEAL = AgentConfig(
    architecture="seal",
    translator_hidden=(8,),
    latent_dim=8,
    trunk_hidden=(8,),
    critic_hidden=(8,),
    device="cpu",
)


def _agent(seed: int = 0) -> Agent:
    return Agent([EnvSpec("source", 4, 2, 4), EnvSpec("target", 6, 5, 4)], TINY_SEAL, seed)


def test_cka_is_one_for_identical_and_for_rotated_and_scaled_copies() -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(size=(500, 12)) + 3.0  # an offset: the columns are centred first
    rotation, _ = np.linalg.qr(rng.normal(size=(12, 12)))
    assert linear_cka(x, x) == pytest.approx(1.0, abs=1e-12)
    assert linear_cka(x, 2.5 * x @ rotation - 7.0) == pytest.approx(1.0, abs=1e-12)
    # Orthonormal columns into a wider space also keep every inner product.
    wide, _ = np.linalg.qr(rng.normal(size=(20, 12)))
    assert linear_cka(torch.from_numpy(x), x @ wide.T) == pytest.approx(1.0, abs=1e-12)


def test_cka_of_independent_noise_is_near_zero() -> None:
    rng = np.random.default_rng(1)
    assert linear_cka(rng.normal(size=(2000, 16)), rng.normal(size=(2000, 16))) < 0.1


def test_cka_by_hand() -> None:
    # Centred already: X^T X = [[2, 1], [1, 2]] (Frobenius sqrt(10)), Y^T Y = [[2]], Y^T X = [2, 1].
    x = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, -1.0]])
    y = np.array([[1.0], [0.0], [-1.0]])
    assert linear_cka(x, y) == pytest.approx(5.0 / (2.0 * math.sqrt(10.0)), rel=1e-12)
    # One column each: CKA is the squared correlation, here 4^2 / (2 * 26/3) = 12/13.
    assert linear_cka([[0.0], [1.0], [2.0]], [[0.0], [1.0], [4.0]]) == pytest.approx(12 / 13)


def test_cka_refuses_unpaired_or_constant_representations() -> None:
    with pytest.raises(SealError, match="same rows"):
        linear_cka(np.zeros((3, 2)), np.zeros((4, 2)))
    with pytest.raises(SealError, match="constant"):
        linear_cka(np.ones((3, 2)), np.arange(6.0).reshape(3, 2))
    with pytest.raises(SealError, match="2-D"):
        linear_cka(np.arange(3.0), np.arange(3.0))


def test_paired_states_are_one_world_seen_by_both_envs() -> None:
    point, view = paired_states(500, seed=3)
    assert point.shape == (500, 4) and view.shape == (500, 6)
    np.testing.assert_allclose(view, (VIEW_MATRIX @ point.T).T)
    space = make_adapter("point").observation_space
    assert space.contains(point[0]) and np.all(np.abs(point) <= space.high)
    assert np.abs(point[:, :2]).max() > 1.0  # positions over the arena, not only near the start
    np.testing.assert_array_equal(paired_states(500, seed=3)[0], point)
    assert not np.array_equal(paired_states(500, seed=4)[0], point)


def test_corresponding_tasks_follow_the_testbed_table() -> None:
    point, view = make_adapter("point"), make_adapter("point_view")
    # point's tasks: east, north, west, south; t0 <-> north, t1 <-> east, t2 <-> south, t3 <-> west.
    assert corresponding_tasks(view, point) == ([0, 1, 2, 3], [1, 0, 3, 2])
    assert corresponding_tasks(point, view) == ([0, 1, 2, 3], [1, 0, 3, 2])
    assert corresponding_tasks(point, make_adapter("point", tasks=["west", "east"])) == (
        [0, 2],
        [1, 0],
    )
    # No task of point_diagonal has a counterpart: paired by position (the control).
    assert corresponding_tasks(make_adapter("point_diagonal"), view) == ([0, 1, 2, 3], [0, 1, 2, 3])


def test_latent_activations_are_the_forward_pass_up_to_the_heads() -> None:
    agent = _agent()
    _, view = paired_states(16, seed=0)
    ids = np.arange(16) % 4
    latent, trunk = latent_activations(agent, "target", view, ids)
    assert latent.shape == (16, 8) and trunk.shape == (16, 8)
    x = torch.cat(
        (
            torch.as_tensor(view, dtype=torch.float32),
            torch.nn.functional.one_hot(torch.as_tensor(ids), 4),
        ),
        dim=-1,
    )
    with torch.no_grad():
        expected = agent.actor("target", x, torch.as_tensor(ids))
        torch.testing.assert_close(
            agent.actor.heads["target"](trunk, torch.as_tensor(ids)), expected
        )
    with pytest.raises(SealError, match="no env 'nope'"):
        latent_activations(agent, "nope", view, ids)
    with pytest.raises(SealError, match=r"expected obs \(N, 6\)"):
        latent_activations(agent, "target", view[:, :4], ids)


def test_translator_cka_of_an_env_with_itself_is_one_and_draws_nothing() -> None:
    agent = _agent()
    before = agent.state_dict()["rng"]
    point, _ = paired_states(256, seed=0)
    same = translator_cka(agent, "source", point, [0, 1], agent, "source", point, [0, 1])
    assert same == pytest.approx({"translator": 1.0, "trunk": 1.0})
    after = agent.state_dict()["rng"]
    assert all(torch.equal(before[k], after[k]) for k in before)
    with pytest.raises(SealError, match="one to one"):
        translator_cka(agent, "source", point, [0, 1], agent, "source", point, [0])


def test_shared_world_cka_is_in_the_unit_interval_and_agents_rebuild_from_their_state() -> None:
    agent = _agent(seed=5)
    point, view = make_adapter("point"), make_adapter("point_view")
    cka = shared_world_cka(agent, "source", point, agent, "target", view, n=512)
    assert set(cka) == {"translator", "trunk"} and all(0.0 <= v <= 1.0 for v in cka.values())
    rebuilt = agent_from_state(agent.state_dict())
    assert shared_world_cka(rebuilt, "source", point, rebuilt, "target", view, n=512) == cka
    with pytest.raises(SealError, match="does not see the testbed's world"):
        other = SimpleNamespace(name="metaworld", tasks=("reach-v3",))
        shared_world_cka(agent, "source", other, agent, "target", view)  # type: ignore[arg-type]
