"""Kitchen reward v4: the potential-based approach term by hand, in the env, in the semantic check's
held states and approach cycle, its gymnasium ids, and the protocol loader's discount check."""

from __future__ import annotations

import pathlib
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from franka_kitchen_dense import REWARD_VERSION, REWARD_VERSIONS, TASK_NAMES, gym_id
from franka_kitchen_dense.adapter import FrankaKitchenDenseAdapter
from franka_kitchen_dense.env import FrankaKitchenDenseEnv
from franka_kitchen_dense.evidence import _posed_reward, _posed_step, exploit_evidence
from franka_kitchen_dense.posing import best_gripper_pose
from franka_kitchen_dense.rewards import (
    POTENTIAL_SCALE,
    SHAPING_GAMMA,
    Constants,
    Reading,
    approach_shaping,
    compute_reward,
)

from seal.errors import ConfigError
from seal.protocols import load_protocol

ROOT = pathlib.Path(__file__).resolve().parents[2]
K, GAMMA = POTENTIAL_SCALE, SHAPING_GAMMA
KNOB = np.array([-0.256, 0.6399, 2.2264])


def _reading(distance: float) -> Reading:
    """A dial-turn reading with the gripper `distance` m in front of the knob (-y), knob untouched."""
    tcp = KNOB + np.array([0.0, -distance, 0.0])
    u = np.array([1.0, 0.0, 0.0])
    return Reading(tcp, tcp + 0.04 * u, tcp - 0.04 * u, u, KNOB, 0.88, 0.0, 1.0, 0.0)


CONSTANTS = Constants(
    target=KNOB,
    obj_init=KNOB,
    tcp_init=KNOB + np.array([0.0, -0.6, 0.0]),
    left_pad_init=KNOB,
    right_pad_init=KNOB,
    finger_axis_init=np.array([1.0, 0.0, 0.0]),
    distance_init=0.88,
    threshold=0.3,
    obj_radius=0.0,
    travel=0.88,
    reach_margin=0.114,
)


def test_k_and_gamma_are_the_documented_ones() -> None:
    assert (K, GAMMA) == (20.0, 0.99)
    assert REWARD_VERSION == "v4" == REWARD_VERSIONS[-1]  # the default is the newest built


def test_approach_term_telescopes_on_a_hand_worked_trajectory() -> None:
    # The gripper at 30, 25, 18, 10, 12 and 5 cm from the knob: Phi = -20 d = -6, -5, -3.6, -2,
    # -2.4, -1. F_t = 0.99 Phi_{t+1} - Phi_t: 1.05, 1.436, 1.62, -0.376, 1.41.
    distances = [0.30, 0.25, 0.18, 0.10, 0.12, 0.05]
    phi = [-K * d for d in distances]
    np.testing.assert_allclose(phi, [-6.0, -5.0, -3.6, -2.0, -2.4, -1.0], rtol=0, atol=1e-12)
    shaping = []
    for t in range(1, len(distances)):
        v4, terms = compute_reward("dial-turn", _reading(distances[t]), CONSTANTS, "v4", phi[t - 1])
        v3, _ = compute_reward("dial-turn", _reading(distances[t]), CONSTANTS, "v3")
        assert v4 == pytest.approx(v3 + terms["approach"], abs=1e-12)  # added after the clip
        assert terms["potential"] == pytest.approx(phi[t], abs=1e-12)
        shaping.append(terms["approach"])
    np.testing.assert_allclose(shaping, [1.05, 1.436, 1.62, -0.376, 1.41], rtol=0, atol=1e-12)
    # sum_t gamma^t F_t = gamma^T Phi(s_T) - Phi(s_0) = 0.99^5 * -1 + 6 = 5.0490099501
    discounted = sum(GAMMA**t * f for t, f in enumerate(shaping))
    assert discounted == pytest.approx(GAMMA**5 * phi[-1] - phi[0], abs=1e-12)
    assert discounted == pytest.approx(5.0490099501, abs=1e-10)


def test_a_still_gripper_earns_gamma_minus_one_times_phi() -> None:
    for d in (0.0, 0.03, 0.12, 0.27):
        reading = _reading(d)
        phi = -K * d
        _, terms = compute_reward("dial-turn", reading, CONSTANTS, "v4", previous_potential=phi)
        assert terms["approach"] == pytest.approx((GAMMA - 1.0) * phi, rel=1e-12, abs=0)
        assert approach_shaping(phi, phi, GAMMA) == pytest.approx((GAMMA - 1.0) * phi, rel=1e-12)


def test_v4_needs_the_previous_potential_and_v3_ignores_it() -> None:
    with pytest.raises(ValueError, match="previous state's potential"):
        compute_reward("dial-turn", _reading(0.1), CONSTANTS, "v4")
    assert compute_reward("dial-turn", _reading(0.1), CONSTANTS, "v3", -99.0) == compute_reward(
        "dial-turn", _reading(0.1), CONSTANTS, "v3"
    )


def test_in_the_env_phi_starts_at_reset_and_the_sum_telescopes() -> None:
    env = FrankaKitchenDenseEnv("bottom-left-burner", seed=0, reward_version="v4")
    env.reset(seed=0)
    phi0 = env.potential()
    rng = np.random.default_rng(0)
    total, shaping = 0.0, []
    for t in range(30):
        prev = env.potential()
        _, reward, _, _, info = env.step(rng.uniform(-1, 1, 9).astype(np.float32))
        base = reward - info["approach"]
        assert 0.0 <= base <= 10.0  # v3's part stays in [0, 10]; F lies outside it
        d_prev, d_now = -prev / K, -info["potential"] / K
        assert abs(info["approach"]) <= K * max(d_prev, d_now) + 1e-12
        shaping.append(info["approach"])
        total += GAMMA**t * info["approach"]
    assert total == pytest.approx(GAMMA**30 * env.potential() - phi0, abs=1e-9)
    env.close()


@pytest.mark.filterwarnings("ignore:adapter 'franka_kitchen_dense'. reward_version = 'v3' is")
def test_posing_resets_phi_and_a_held_state_pays_the_still_term() -> None:
    # The same posed state under v3 and v4: the held step's reward differs by (gamma - 1) Phi(s)
    # exactly, whatever one step of the unsupported arm's sag would pay.
    v3 = FrankaKitchenDenseAdapter(tasks=["bottom-left-burner"], reward_version="v3").make(
        "bottom-left-burner", 0
    )
    v4 = FrankaKitchenDenseAdapter(tasks=["bottom-left-burner"]).make("bottom-left-burner", 0)
    raw = v4.unwrapped
    v4.reset(seed=0)
    joint = raw.initial_task_joint()
    arm, _ = best_gripper_pose(raw, offset=np.array([0.0, -0.12, 0.0]))
    raw.data.qpos[:7] = arm
    raw.sync()
    assert raw._potential == pytest.approx(raw.potential(), abs=0)  # Phi(s) after posing
    held3, _ = _posed_reward(v3, 0, joint, arm, -1.0)
    held4, _ = _posed_reward(v4, 0, joint, arm, -1.0)
    _, _, info = _posed_step(v4, 0, joint, arm, -1.0)  # the same step, for its Phi(s')
    assert held4 - held3 == pytest.approx((GAMMA - 1.0) * info["potential"], abs=1e-9)
    assert held4 > held3  # parked 12 cm away, a still gripper earns (1 - gamma) k d > 0
    v3.close()
    v4.close()


def _broken(name: str) -> type:
    sys.path.insert(0, str(pathlib.Path(__file__).parent))
    try:
        import broken_adapters
    finally:
        sys.path.pop(0)
    return getattr(broken_adapters, name)


@pytest.mark.slow
def test_the_approach_cycle_fails_a_reward_with_the_approach_term_inside_the_clip() -> None:
    # The kettle: v3 pays ~0.13 per step near its handle, so the clip eats the retreat's negative F.
    broken = _broken("ApproachPayingKitchen")(tasks=["kettle"]).semantic_check(
        "kettle", seed=0, episodes=1
    )
    assert broken["spearman"] >= 0.9 and broken["scripted_success"] == 1.0  # all else passes ...
    assert broken["exploit_ratio"] <= 0.5  # ... and no exploit earns half the expert's ...
    returns = broken["exploit_returns"]
    assert returns["approach_cycle"] > 2 * returns["parking"]  # ... but the cycle beats parking
    assert broken["approach_cycle_ok"] is False and broken["ok"] is False
    honest = FrankaKitchenDenseAdapter(tasks=["kettle"], reward_version="v4")
    env = honest.make("kettle", 0)
    figures = exploit_evidence(env, expert_return=2256.0)
    env.close()
    assert figures["approach_cycle_ok"] is True
    assert figures["exploit_returns"]["approach_cycle"] < figures["exploit_returns"]["parking"]
    assert figures["exploit_returns"]["parking"] == pytest.approx(returns["parking"], rel=0.05)


def test_the_default_ids_are_the_newest_of_their_name() -> None:
    assert gym_id("microwave") == "seal/FrankaKitchenDense-microwave-v4"
    assert gym_id("microwave", "v3") == "seal/FrankaKitchenDense-microwave-v3"
    assert {gym_id(t, "v3") for t in TASK_NAMES} <= set(gym.registry)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env = gym.make(gym_id("light-switch"), episode_length=2)
    env.close()
    assert not [w for w in caught if "out of date" in str(w.message)], caught
    env = gym.make(gym_id("light-switch", "v4"), episode_length=2, gamma=0.95)
    assert env.unwrapped.reward_version == "v4" and env.unwrapped.gamma == 0.95
    env.close()


def test_the_protocol_loader_holds_the_shaping_discount_to_agent_gamma() -> None:
    path = ROOT / "protocols" / "kitchen_learn" / "slide_cabinet_v4.toml"
    config = load_protocol(path)
    assert config.envs["fk"].options == {"reward_version": "v4"} and config.agent.gamma == 0.99
    with pytest.raises(ConfigError, match=r"agent.gamma = 0.95.*options.gamma = 0.95"):
        load_protocol(path, ["agent.gamma=0.95"])
    load_protocol(path, ["agent.gamma=0.95", "envs.fk.options={reward_version='v4', gamma=0.95}"])
    v3 = ROOT / "protocols" / "kitchen_learn" / "slide_cabinet.toml"
    load_protocol(v3, ["agent.gamma=0.95"])  # v3 has no shaping term: nothing to match
