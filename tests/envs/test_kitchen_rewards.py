"""Each kitchen task's reward v2 at real simulator states, against numbers worked out by hand.

(Reward v3's families are checked on hand-posed readings in test_kitchen.py; the families and the
env's geometry are the same, so this module keeps v2's figures.)

Three states per task, built in the env itself: "away" (upstream's reset, zero action), "near"
(the gripper posed on the handle, then backed 5 cm out along its approach, closing) and "on"
(the task joint halfway to its goal, the gripper posed on the handle, closing). A reward family
swapped between tasks (e.g. push for the microwave: 0.04 instead of 6.48 "on") fails here.

Notation as in the README: LT(x, b, m) = 1 if x <= b else 1 / ((3 (x - b) / m)^2 + 1);
G(x, b, m) = 1 if x <= b else exp(-(x - b)^2 / m^2 * ln 10) (Meta-World's gaussian, 0.1 at the
margin); H(a, b) = ab / (a + b - ab). Inputs read from the states (metres, rad) are given to 4-5
decimals, so the asserts allow 2e-3.
"""

from __future__ import annotations

from collections.abc import Callable

import mujoco
import numpy as np
import pytest
from franka_kitchen_dense import TASK_NAMES, TASKS
from franka_kitchen_dense.adapter import CLOSING_ACTION, interpolate_joint
from franka_kitchen_dense.env import FrankaKitchenDenseEnv
from franka_kitchen_dense.posing import (
    _grasp_directions,
    _initial_body_rotation,
    pose_gripper_at_object,
)

FAMILIES = {
    "microwave": "door-open",
    "right-hinge-door": "door-open",
    "left-hinge-door": "door-open",
    "light-switch": "sweep",
    "top-right-burner": "dial-turn",
    "top-left-burner": "dial-turn",
    "bottom-right-burner": "dial-turn",
    "bottom-left-burner": "dial-turn",
    "slide-cabinet": "push",
    "kettle": "pick-place",
}


def test_each_task_uses_its_seal_table_2_reward_family() -> None:
    assert {t: TASKS[t].family for t in TASK_NAMES} == FAMILIES


# task: (away, near, on). Shared inputs: away has effort 0 (grab (0 + 1) / 2 = 0.5, closed 0),
# near and on close at full effort (grab 1, closed 1). Initial distances d0 from test_kitchen.py.
#
# door-open: 2 H(LT(|tcp - obj|, 0.06, 0.5), grab) + 8 (0.2 [progress > pi/90] + 0.8 LT(d, 0.05, d0))
#   microwave  d0 0.3573. away |tcp - obj| 0.4877: LT = 1 / ((3 * 0.4277 / 0.5)^2 + 1) = 0.131833,
#     H(0.131833, 0.5) = 0.065917 / 0.565917 = 0.116478; LT(0.3573, 0.05, 0.3573) = 0.130590 (d = 1
#     - 0.05 / 0.3573 = 0.860062) -> 2 * 0.116478 + 6.4 * 0.130590 = 1.0687.
#     near |tcp - obj| 0.05 <= 0.06: 2 + 0.835776 = 2.8358.
#     on d 0.18186, progress 0.3755 > pi/90: LT = 1 / ((3 * 0.13186 / 0.3573)^2 + 1) = 0.449286
#     -> 2 + 8 * (0.2 + 0.8 * 0.449286) = 6.4754 (LT from 0.13186 / 0.3573 = 0.369046).
#   right door d0 0.4355. away |tcp - obj| 0.7450: LT = 0.055890, H(., 0.5) = 0.052932;
#     LT(d0) = 0.124208 (d = 0.885189) -> 0.105864 + 0.794929 = 0.9008.
#     near 0.0501: 2 + 0.794929 = 2.7949. on d 0.23290, progress 0.726: LT = 1 / ((3 * 0.1829 /
#     0.4355)^2 + 1) = 0.386488 -> 2 + 8 * (0.2 + 0.8 * 0.386488) = 6.0735.
#   left door (out of reach: the posed gripper stays 10.6 cm off the handle) d0 0.4334.
#     away |tcp - obj| 0.7790: LT = 0.050993, H(., 0.5) = 0.048519; LT(d0) = 0.124329
#     -> 0.097038 + 0.795706 = 0.8927.
#     near 0.1062: LT = 1 / ((3 * 0.0462 / 0.5)^2 + 1) = 0.928644 -> 1.857288 + 0.795706 = 2.6530.
#     on |tcp - obj| 0.1061 (LT 0.928930), d 0.23164 (LT 0.387472): 1.857860 + 8 * (0.2 + 0.8 *
#     0.387472) = 5.9377.
# dial-turn (reward v2): 10 H(R, LT(d, 0.3, d0 - 0.3)), R = (G + H(G, closed)) / 2,
#   G = G(|tcp - knob|, 0.005, |knob0 - tcp0| - 0.005); with closed = 1, R = G.
#   away: |tcp - knob| = |knob0 - tcp0| (no step taken), so G = 0.1 (the margin); closed 0:
#     R = (0.1 + 0) / 2 = 0.05; d = d0: LT = 0.1 -> 10 H(0.05, 0.1) = 10 * 0.005 / 0.145 = 0.3448
#     for every burner (reward v1, Meta-World's gate H(G, closed), gave 0).
#   top-right |knob0 - tcp0| 0.6786. near |tcp - knob| 0.05: G = exp(-(0.045 / 0.6736)^2 ln 10)
#     = 0.989776; LT(0.92, 0.3, 0.62) = 0.1 -> 10 H(0.989776, 0.1) = 10 * 0.0989776 / 0.990798
#     = 0.9990. on d 0.46: LT = 1 / ((3 * 0.16 / 0.62)^2 + 1) = 0.625244, G(0) = 1 -> 6.2524.
#   top-left: the same shape (|knob0 - tcp0| 0.6342, d 0.46) -> 0.9988, 6.2520.
#   bottom-right |knob0 - tcp0| 0.6337, d0 0.8797. near 0.04907 -> 0.9989.
#     on |tcp - knob| 0.00899 (posing error): G = 0.999907; LT(0.43987, 0.3, 0.5797) = 0.656190
#     -> 10 H(0.999907, 0.656190) = 6.5615 (6.5619 with unrounded inputs).
#   bottom-left (|knob0 - tcp0| 0.5858, d0 0.88): near 0.0497 -> 0.9986; on d 0.44 -> 6.5598.
# sweep (light switch, obj_radius 0.02): 2 g + 6 H(g, LT(d, 0.3, 0.6905)), g = (caging +
#   gripping) / 2, caging = H(H(pad_r, pad_l), xz); LT(0.6905, 0.3, 0.6905) = 0.257838.
#   away: signed pad gaps along u 0.01395 (below the 0.02 bound: 1 / ((3 * 0.00605 / 0.0361)^2 + 1)
#     = 0.798230) and 0.07112 (0.1 at its margin), xz 0.1 at its margin: caging = H(H(0.1,
#     0.798230), 0.1) = H(0.097535, 0.1) = 0.051941, no gripping -> g = 0.025971;
#     2 g + 6 H(0.025971, 0.257838) = 0.051942 + 0.144986 = 0.1969.
#   near: gaps 0.04759, 0.03241 inside (0.02, 0.05); across 0.04809: xz = LT(0.04809, 0.005,
#     0.5612 - 0.005) = 0.948752 = caging (< 0.95: no gripping) -> g = 0.474376;
#     0.948752 + 6 * 0.200544 = 2.1520.
#   on: gaps 0.04, 0.04, across 0: caging 1; gripping band (0.02, 0.03) with margins 0.03424 and
#     0.05005 (current finger axis): 0.565716, 0.735683, H = 0.470160 -> g = 0.735080;
#     d 0.34523: LT = 0.962820 -> 1.470160 + 6 H(0.735080, 0.962820) = 1.470160 + 4.288746 = 5.7589.
# push (slide, handle radius 0.022 -> obj_radius 0.017, near gate 0.022): 2 g, plus
#   (1 + 2 g + 5 LT(d, 0.05, 0.3705)) within the gate; g = (H(caging, gripping) + caging) / 2.
#   away: both pads and xz at their margins: 0.1 each, caging = H(H(0.1, 0.1), 0.1) = 0.035714,
#     g = 0.017857 -> 0.0357.
#   near: pads 0.04 inside (0.017, 0.05); xz = LT(0.05, 0.005, 0.7626 - 0.005) = 0.969224 < 0.97:
#     no gripping, g = 0.484612; 5 cm > gate -> 0.9692.
#   on: caging 1, gripping 1: g = 1; d 0.18523: LT = 0.454866 -> 2 + 1 + 2 + 2.274330 = 7.2743.
# pick-place (kettle, handle radius 0.032 -> obj_radius 0.027, gate 0.032): H(g, LT(d, 0.05,
#   0.404)), plus (1 + 5 in_place) within the gate when lifted 1 cm (never here); LT(0.404) = 0.126420.
#   away: signed gaps -0.0887 (0.012278) and 0.1738 (0.1), xz 0.1: caging = H(H(0.012278, 0.1),
#     0.1) = 0.010055, g = 0.005028 -> H(0.005028, 0.126420) = 0.0049.
#   near (5 cm above): pads inside; xz = LT(0.05, 0.005, 0.2839 - 0.005) = 0.810177 -> g = 0.405089
#     -> H(0.405089, 0.126420) = 0.1066.
#   on: g = 1, d 0.20195: LT = 0.439910 -> 0.4399.
EXPECTED = {
    "microwave": (1.0687, 2.8358, 6.4757),
    "right-hinge-door": (0.9007, 2.7948, 6.0732),
    "left-hinge-door": (0.8927, 2.6532, 5.9381),
    "light-switch": (0.1969, 2.1520, 5.7589),
    "top-right-burner": (0.3448, 0.9990, 6.2524),
    "top-left-burner": (0.3448, 0.9988, 6.2520),
    "bottom-right-burner": (0.3448, 0.9989, 6.5615),
    "bottom-left-burner": (0.3448, 0.9986, 6.5598),
    "slide-cabinet": (0.0357, 0.9692, 7.2743),
    "kettle": (0.0049, 0.1066, 0.4399),
}


def _back_off(env: FrankaKitchenDenseEnv, distance: float) -> None:
    """Move the gripper `distance` metres back along its approach direction (position-only IK)."""
    model, data = env.model, env.data
    approach, _ = _grasp_directions(env, data, _initial_body_rotation(env))
    target = data.site_xpos[env._tcp_id] - distance * approach
    jacp = np.zeros((3, model.nv))
    for _ in range(100):
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        mujoco.mj_jacSite(model, data, jacp, None, env._tcp_id)
        jac = jacp[:, :7]
        error = target - data.site_xpos[env._tcp_id]
        data.qpos[:7] += jac.T @ np.linalg.solve(jac @ jac.T + 1e-4 * np.eye(3), error)
    env.sync()


@pytest.fixture(scope="module")
def kitchen() -> Callable[[str], FrankaKitchenDenseEnv]:
    built: dict[str, FrankaKitchenDenseEnv] = {}

    def get(task: str) -> FrankaKitchenDenseEnv:
        if task not in built:
            built[task] = FrankaKitchenDenseEnv(task, seed=0, reward_version="v2")
        built[task].reset(seed=0)
        return built[task]

    yield get
    for env in built.values():
        env.close()


@pytest.mark.parametrize("task", TASK_NAMES)
def test_reward_away_near_and_on_the_handle(
    kitchen: Callable[[str], FrankaKitchenDenseEnv], task: str
) -> None:
    away, near, on = EXPECTED[task]
    env = kitchen(task)
    assert env.evaluate(np.zeros(9))[0] == pytest.approx(away, abs=2e-3)
    env.reset(seed=0)
    pose_gripper_at_object(env)
    _back_off(env, 0.05)
    assert env.evaluate(CLOSING_ACTION)[0] == pytest.approx(near, abs=2e-3)
    env.reset(seed=0)
    env.set_task_joint(interpolate_joint(env.initial_task_joint(), env.task.goal_array, 0.5))
    pose_gripper_at_object(env)
    assert env.evaluate(CLOSING_ACTION)[0] == pytest.approx(on, abs=2e-3)
