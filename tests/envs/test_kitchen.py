"""The dense Franka kitchens: task table, rewards against hand-computed numbers, success and its
thresholds per task, seeding, spaces, gymnasium ids and the adapter's semantic check.

Kitchens take ~0.5 s each to build, so one env per task is built once (module scope) and every
test that edits its state starts with a seeded reset.
"""

from __future__ import annotations

import dataclasses
import math
import pathlib
import sys
from collections.abc import Callable

import gymnasium as gym
import numpy as np
import pytest
from franka_kitchen_dense import TASK_NAMES, gym_id
from franka_kitchen_dense.adapter import CLOSING_ACTION, FrankaKitchenDenseAdapter
from franka_kitchen_dense.env import FrankaKitchenDenseEnv
from franka_kitchen_dense.rewards import (
    POTENTIAL_SCALE,
    SHAPING_GAMMA,
    Constants,
    Reading,
    compute_reward,
    grip_effort,
)

from seal.envs import make_adapter
from seal.errors import UnknownNameError

# ---- fixtures ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def kitchen() -> Callable[[str], FrankaKitchenDenseEnv]:
    """kitchen(task): that task's env, built once per module and reset with seed 0 on each call."""
    built: dict[str, FrankaKitchenDenseEnv] = {}

    def get(task: str) -> FrankaKitchenDenseEnv:
        if task not in built:
            built[task] = FrankaKitchenDenseEnv(task, seed=0)
        built[task].reset(seed=0)
        return built[task]

    yield get
    for env in built.values():
        env.close()


ZERO = np.zeros(9)

# ---- the task table: hand-computed initial distances and goal positions ------------------------
#
# Hinged parts turn about vertical axes, so a site at horizontal radius r from the hinge moves by
# the chord 2 r sin(|dq| / 2) and its goal is the anchor plus (site - anchor) rotated by dq
# (x' = x cos - y sin, y' = x sin + y cos). Model readings at the initial state (4 decimals):
#   microwave:  anchor (-1.1276, 0.4549), handle (-0.6419, 0.4926), r 0.4871, q0 +0.00108
#     dq = -0.75 - 0.00108 = -0.75108: chord 0.9742 sin(0.37554) = 0.9742 * 0.36678 = 0.3573
#     goal: (0.4857, 0.0377) rotated by dq (cos 0.73096, sin -0.68242) = (0.3808, -0.3039)
#     -> (-0.7468, 0.1510, 1.792)
#   right door: anchor (-0.224, 0.71), handle (-0.5262, 0.5825), r 0.3280, q0 -0.00177
#     dq = 1.45177: chord 0.656 sin(0.72589) = 0.656 * 0.66393 = 0.4355
#     goal: (-0.3022, -0.1275) rotated (cos 0.11878, sin 0.99292) = (0.0907, -0.3152) -> (-0.1333, 0.3948, 2.6)
#   left door:  anchor (-0.984, 0.71), handle (-0.6828, 0.5801), r 0.3280, q0 -0.00644
#     dq = -1.44356: chord 0.656 sin(0.72178) = 0.656 * 0.66071 = 0.4334
#     goal: (0.3012, -0.1299) rotated (cos 0.12694, sin -0.99191) = (-0.0906, -0.3153) -> (-1.0746, 0.3947, 2.6)
#   light switch: joint distance |-0.69 - 0.00046| = 0.6905; its site (-0.3685, 0.6157) about
#     anchor (-0.4, 0.691) rotated by -0.69046 (cos 0.77103, sin -0.63670) -> (-0.4237, 0.6129, 2.28)
#   burners: knob sites lie on the knob axes, so the goal position is the site itself; joint
#     distances 0.92 (top) and 0.88 (bottom) minus q0 (|q0| < 3e-4)
#   slide cabinet: slides along x from q0 = -0.00047 to 0.37: 0.37047; goal x -0.1085 + 0.37047 = 0.2620
#   kettle: handle site (-0.2728, 0.3483, 1.8784) to its place at upstream's goal pose
#     (-0.2300, 0.7500, 1.8790): sqrt(0.0428^2 + 0.4017^2 + 0.0006^2) = 0.4040
TABLE = {
    # task: (initial distance, threshold, goal position)
    "microwave": (0.3573, 0.05, (-0.7468, 0.1510, 1.792)),
    "right-hinge-door": (0.4355, 0.05, (-0.1333, 0.3948, 2.6)),
    "left-hinge-door": (0.4334, 0.05, (-1.0746, 0.3947, 2.6)),
    "light-switch": (0.6905, 0.3, (-0.4237, 0.6129, 2.28)),
    "top-right-burner": (0.9200, 0.3, (-0.133, 0.6399, 2.3404)),
    "top-left-burner": (0.9201, 0.3, (-0.256, 0.6399, 2.3404)),
    "bottom-right-burner": (0.8797, 0.3, (-0.133, 0.6399, 2.2264)),
    "bottom-left-burner": (0.8800, 0.3, (-0.256, 0.6399, 2.2264)),
    "slide-cabinet": (0.3705, 0.05, (0.2620, 0.607, 2.6)),
    "kettle": (0.4040, 0.05, (-0.2300, 0.7500, 1.8790)),
}


def test_table_covers_the_ten_tasks_of_seal_table_2() -> None:
    assert tuple(TABLE) == TASK_NAMES
    assert len(TASK_NAMES) == 10


@pytest.mark.parametrize("task", TASK_NAMES)
def test_reset_is_far_from_success(
    kitchen: Callable[[str], FrankaKitchenDenseEnv], task: str
) -> None:
    """At reset: success 0, the hand-computed initial distance, and at least twice the threshold."""
    env = kitchen(task)
    distance, threshold, goal = TABLE[task]
    obs, info = env.reset(seed=0)
    assert info["success"] == 0.0
    assert env.task.threshold == threshold
    assert info["distance"] == pytest.approx(distance, abs=2e-3)
    assert info["distance"] >= 2 * threshold
    np.testing.assert_allclose(obs[59:62], goal, atol=2e-3)


@pytest.mark.parametrize("task", TASK_NAMES)
def test_goal_configuration_is_success(
    kitchen: Callable[[str], FrankaKitchenDenseEnv], task: str
) -> None:
    env = kitchen(task)
    env.set_task_joint(env.task.goal_array)
    _, info = env.evaluate(CLOSING_ACTION)
    assert info["success"] == 1.0
    assert info["distance"] == pytest.approx(0.0, abs=1e-6)


def _hinge_offset(env: FrankaKitchenDenseEnv, chord: float) -> float:
    """Joint angle that moves the task site by `chord` metres: 2 asin(chord / 2r), r read from the model."""
    joint = env.model.joint(env.task.joint).id
    r = float(np.linalg.norm((env.data.site_xpos[env._site_id] - env.data.xanchor[joint])[:2]))
    return 2.0 * math.asin(chord / (2.0 * r))


@pytest.mark.parametrize("task", TASK_NAMES)
@pytest.mark.parametrize("inside", [True, False])
def test_success_threshold(
    kitchen: Callable[[str], FrankaKitchenDenseEnv], task: str, inside: bool
) -> None:
    """Just inside the threshold (98%) is success; just outside (102%) is not."""
    env = kitchen(task)
    threshold = TABLE[task][1]
    off = threshold * (0.98 if inside else 1.02)
    goal = env.task.goal_array.copy()
    towards_start = -np.sign(goal[0] - env.initial_task_joint()[0])
    if task == "kettle":
        goal[0] += off  # translating the kettle translates its handle site by the same amount
    elif env.task.measure == "joint" or task == "slide-cabinet":
        goal[0] += towards_start * off  # joint distance, or a slide along x: metres = joint units
    else:
        goal[0] += towards_start * _hinge_offset(env, off)
    env.set_task_joint(goal)
    _, info = env.evaluate(ZERO)
    assert info["distance"] == pytest.approx(off, abs=1e-6)
    assert info["success"] == (1.0 if inside else 0.0)


def test_only_the_chosen_task_counts(kitchen: Callable[[str], FrankaKitchenDenseEnv]) -> None:
    """Opening the microwave in the slide-cabinet kitchen is a distractor: no success, same reward."""
    env = kitchen("slide-cabinet")
    before, _ = env.evaluate(ZERO)
    env.data.qpos[env.model.joint("microwave").qposadr[0]] = -0.75
    env.sync()
    after, info = env.evaluate(ZERO)
    assert info["success"] == 0.0
    assert after == pytest.approx(before)


# ---- rewards against hand-computed numbers ------------------------------------------------------
#
# tolerance(x, bounds=(0, b), margin=m, "long_tail") = 1 for x <= b, else 1 / ((3 d)^2 + 1) with
# d = (x - b) / m (scale sqrt(1 / 0.1 - 1) = 3, so 0.1 at d = 1). hamacher(a, 1) = a, hamacher(a, 0) = 0.

ORIGIN = np.zeros(3)
U = np.array([1.0, 0.0, 0.0])


def _reading(
    distance: float,
    effort: float,
    *,
    gap: float = 0.025,
    progress: float = 0.0,
    obj: np.ndarray = ORIGIN,
    opening: float = 0.5,
) -> Reading:
    """Gripper centred on the object, pads `gap` either side along x."""
    return Reading(
        tcp=obj,
        left_pad=obj + gap * U,
        right_pad=obj - gap * U,
        finger_axis=U,
        obj=obj,
        distance=distance,
        progress=progress,
        finger_opening=opening,
        effort=effort,
    )


def _constants(distance_init: float, threshold: float, obj_radius: float = 0.015) -> Constants:
    """Object at the origin, gripper starting 0.5 m away along y; target 0.4 m along z."""
    return Constants(
        target=np.array([0.0, 0.0, 0.4]),
        obj_init=ORIGIN,
        tcp_init=np.array([0.0, -0.5, 0.0]),
        left_pad_init=np.array([0.04, -0.5, 0.0]),
        right_pad_init=np.array([-0.04, -0.5, 0.0]),
        finger_axis_init=U,
        distance_init=distance_init,
        threshold=threshold,
        obj_radius=obj_radius,
    )


@pytest.mark.parametrize(
    ("a7", "a8", "effort"),
    [(-1.0, -1.0, 1.0), (1.0, 1.0, -1.0), (-1.0, 0.0, 0.5), (-3.0, -3.0, 1.0), (0.2, -0.6, 0.2)],
)
def test_grip_effort_reads_the_finger_actions(a7: float, a8: float, effort: float) -> None:
    # effort = clip(-(a7 + a8) / 2, -1, 1): e.g. (0.2, -0.6) -> -(-0.4) / 2 = 0.2
    action = np.zeros(9)
    action[7], action[8] = a7, a8
    assert grip_effort(action) == pytest.approx(effort)


def test_door_open_reward_v2_by_hand() -> None:
    c = _constants(distance_init=0.35, threshold=0.05)
    # ready = 1 (gripper on the handle), grab = (1 + 1) / 2 = 1 -> 2 * hamacher(1, 1) = 2.
    # opened: d = (0.35 - 0.05) / 0.35 = 0.857143, 1 / ((3d)^2 + 1) = 1 / 7.612245 = 0.131367;
    # 0.8 * 0.131367 = 0.105094, no "trying" bonus (progress 0) -> 2 + 8 * 0.105094 = 2.840751
    assert compute_reward("door-open", _reading(0.35, 1.0), c, "v2")[0] == pytest.approx(
        2.840751, abs=1e-5
    )
    # moved 0.1 rad > pi/90 towards the goal: + 8 * 0.2 = 1.6 -> 4.440751
    assert compute_reward("door-open", _reading(0.35, 1.0, progress=0.1), c, "v2")[
        0
    ] == pytest.approx(4.440751, abs=1e-5)
    # fingers opening (effort -1): grab 0, hamacher(1, 0) = 0 -> 8 * 0.105094 = 0.840751
    assert compute_reward("door-open", _reading(0.35, -1.0), c, "v2")[0] == pytest.approx(
        0.840751, abs=1e-5
    )
    # within 5 cm of the goal: 10 whatever the gripper does
    assert compute_reward("door-open", _reading(0.049, -1.0), c, "v2")[0] == 10.0


def test_sweep_reward_v2_by_hand() -> None:
    c = _constants(distance_init=0.69, threshold=0.3, obj_radius=0.02)
    # pads 0.025 from the lever: inside (0.02, 0.05) and the gripping band (0.02, 0.03): grasped 1.
    # in_place: d = (0.69 - 0.3) / 0.69 = 0.565217, 1 / ((3d)^2 + 1) = 1 / 3.875236 = 0.258049
    # reward = 2 * 1 + 6 * hamacher(1, 0.258049) = 3.548293
    assert compute_reward("sweep", _reading(0.69, 1.0), c, "v2")[0] == pytest.approx(
        3.548293, abs=1e-5
    )
    # sweep ignores the effort (as Meta-World's sweep-v3 does): same with the fingers opening
    assert compute_reward("sweep", _reading(0.69, -1.0), c, "v2")[0] == pytest.approx(
        3.548293, abs=1e-5
    )
    # pads 0.04 away: caging 1 but outside the gripping band (0.02, 0.03); margins
    # | |0 -/+ 0.04| - 0.05 | = 0.01, d = (0.04 - 0.03) / 0.01 = 1 -> 0.1 each, hamacher(0.1, 0.1)
    # = 0.01 / 0.19 = 0.052632; grasped = (1 + 0.052632) / 2 = 0.526316
    # reward = 2 * 0.526316 + 6 * hamacher(0.526316, 0.258049) = 1.052632 + 6 * 0.209414 = 2.309114
    assert compute_reward("sweep", _reading(0.69, 1.0, gap=0.04), c, "v2")[0] == pytest.approx(
        2.309114, abs=1e-5
    )
    assert compute_reward("sweep", _reading(0.29, 1.0), c, "v2")[0] == 10.0


def test_dial_turn_reward_v2_by_hand() -> None:
    c = _constants(distance_init=0.88, threshold=0.3)
    # reach = 1 (on the knob), closed = 1; in_place at margin |0.88 - 0.3|: 0.1 -> 10 * 0.1 = 1
    assert compute_reward("dial-turn", _reading(0.88, 1.0), c, "v2")[0] == pytest.approx(1.0)
    # half closed: reach term (1 + hamacher(1, 0.5)) / 2 = 0.75; at the goal in_place = 1:
    # 10 * hamacher(0.75, 1) = 7.5
    assert compute_reward("dial-turn", _reading(0.0, 0.5), c, "v2")[0] == pytest.approx(7.5)
    assert compute_reward("dial-turn", _reading(0.0, 1.0), c, "v2")[0] == pytest.approx(10.0)
    # fingers opening (reward v2): reach term (1 + 0) / 2 = 0.5 -> 10 * hamacher(0.5, 1) = 5, even at
    # the goal (dial-turn has no success override); Meta-World's gate H(reach, closed) gave 0 here
    assert compute_reward("dial-turn", _reading(0.0, -1.0), c, "v2")[0] == pytest.approx(5.0)


def _v3_constants(distance_init: float, threshold: float, **kw: float) -> Constants:
    """As `_constants`, with reward v3's geometry: reach margin 0.114 m (the burner knobs'
    spacing), and the joint's travel = the initial distance (joint-measured tasks)."""
    return dataclasses.replace(
        _constants(distance_init, threshold, **kw), reach_margin=0.114, travel=distance_init
    )


@pytest.mark.parametrize("family", ["door-open", "sweep", "dial-turn", "push"])
def test_v3_success_override_pays_10_with_the_gripper_gone(family: str) -> None:
    c = _v3_constants(0.88, 0.3, obj_radius=0.02)
    away = dataclasses.replace(_reading(0.29, -1.0), tcp=np.array([0.0, -1.0, 0.0]))
    assert compute_reward(family, away, c, "v3")[0] == 10.0
    if family == "dial-turn":  # v2's dial-turn had no override: a turned knob, gripper gone, ~0
        assert compute_reward(family, away, c, "v2")[0] < 0.01


def test_dial_turn_v3_reach_margin_at_the_knob_spacing() -> None:
    c = _v3_constants(0.88, 0.3)
    # on the knob, closing: reach 1; untouched knob: in_place = tail 0.1 -> 10 * H(1, 0.1) = 1.0
    assert compute_reward("dial-turn", _reading(0.88, 1.0), c, "v3")[0] == pytest.approx(1.0)
    # the gripper at bounds + margin = 0.005 + 0.114 = 0.119 m from the knob: long tail 0.1 (the
    # neighbouring knob's distance); closing, reach = (0.1 + H(0.1, 1)) / 2 = 0.1
    far = dataclasses.replace(_reading(0.88, 1.0), tcp=np.array([0.0, -0.119, 0.0]))
    assert compute_reward("dial-turn", far, c, "v3")[1]["grasp_reward"] == pytest.approx(0.1)
    # 27 cm away (where the v2 policy parked): 1 / ((0.265 * 3 / 0.114)^2 + 1) = 0.020147,
    # 10 * H(0.020147, 0.1) = 10 * 0.002015 / 0.118132 = 0.1706 (v2 paid 0.93 there)
    parked = dataclasses.replace(_reading(0.88, 1.0), tcp=np.array([0.0, -0.27, 0.0]))
    assert compute_reward("dial-turn", parked, c, "v3")[0] == pytest.approx(0.1706, abs=1e-3)


def test_sweep_v3_caging_margins_at_the_geometry() -> None:
    c = _v3_constants(0.69, 0.3, obj_radius=0.02)
    # lever caged (pads 0.025): grasped 1; in_place = tail 0.1 -> 2 + 6 * H(1, 0.1) = 2.6 (v2: 3.55)
    assert compute_reward("sweep", _reading(0.69, 1.0), c, "v3")[0] == pytest.approx(2.6)
    # gripper centred, pads 0.05 + 0.114 away: each pad's caging at its margin, 0.1;
    # caging = H(0.01 / 0.19, 1) = 0.052632, below 0.95: grasped = 0.052632 / 2 = 0.026316
    wide = _reading(0.69, 1.0, gap=0.164)
    assert compute_reward("sweep", wide, c, "v3")[1]["grasp_reward"] == pytest.approx(
        0.026316, abs=1e-5
    )


@pytest.mark.parametrize("family", ["door-open", "dial-turn", "push"])
def test_v3_holding_the_untouched_object_pays_1_per_step(family: str) -> None:
    c = _v3_constants(0.37, 0.05)
    # contact 1 (on the handle, closing), in_place = tail 0.1: 10 * H(1, 0.1) = 1.0
    assert compute_reward(family, _reading(0.37, 1.0), c, "v3")[0] == pytest.approx(1.0)


def test_v3_past_the_goal_reads_as_untouched() -> None:
    c = _v3_constants(0.88, 0.3)
    untouched = compute_reward("dial-turn", _reading(0.88, 1.0), c, "v3")[0]
    # the knob turned 0.88 + 0.35 rad: 0.35 past its goal, out of the 0.3 band
    past = _reading(0.35, 1.0, progress=0.88 + 0.35)
    assert compute_reward("dial-turn", past, c, "v3")[0] == pytest.approx(untouched)
    assert compute_reward("dial-turn", past, c, "v2")[0] > 9.0  # v2 paid nearly the success's 10
    # inside the band, past the goal: still a success
    assert compute_reward("dial-turn", _reading(0.2, 1.0, progress=1.08), c, "v3")[0] == 10.0


@pytest.mark.parametrize(
    ("task", "margin"), [("bottom-left-burner", 0.114), ("light-switch", 0.127)]
)
def test_v3_reach_margin_is_the_nearest_other_tasks_site(
    kitchen: Callable[[str], FrankaKitchenDenseEnv], task: str, margin: float
) -> None:
    # knobs 0.114 m apart (top-bottom, 2.340 - 2.226 m); the switch 0.127 m from the bottom-left knob
    assert kitchen(task).constants.reach_margin == pytest.approx(margin, abs=1e-3)


def test_push_reward_v2_by_hand() -> None:
    c = _constants(distance_init=0.37, threshold=0.05)
    # caging 1 (pads 0.025 in (0.015, 0.05), centred) > 0.97 so gripping = effort 1: grasped 1.
    # in_place: d = 0.32 / 0.37 = 0.864865, 1 / ((3d)^2 + 1) = 1 / 7.731921 = 0.129334
    # near the handle and open: 2 + (1 + 2 + 5 * 0.129334) = 5.646671
    assert compute_reward("push", _reading(0.37, 1.0), c, "v2")[0] == pytest.approx(
        5.646671, abs=1e-5
    )
    # effort 0: gripping 0, grasped = (hamacher(1, 0) + 1) / 2 = 0.5 -> 1 + (1 + 1 + 0.646671) = 3.646671
    assert compute_reward("push", _reading(0.37, 0.0), c, "v2")[0] == pytest.approx(
        3.646671, abs=1e-5
    )
    # fingers shut (opening 0): no bonus, 2 * grasped = 2
    assert compute_reward("push", _reading(0.37, 1.0, opening=0.0), c, "v2")[0] == pytest.approx(
        2.0
    )
    assert compute_reward("push", _reading(0.04, 1.0), c, "v2")[0] == 10.0


def test_pick_place_reward_v2_by_hand() -> None:
    c = _constants(distance_init=0.4, threshold=0.05)
    # grasped 1 (as push); in_place: d = 0.35 / 0.4 = 0.875, 1 / ((3d)^2 + 1) = 1 / 7.890625 = 0.126733
    # kettle not lifted: hamacher(1, 0.126733) = 0.126733
    assert compute_reward("pick-place", _reading(0.4, 1.0), c, "v2")[0] == pytest.approx(
        0.126733, abs=1e-5
    )
    # lifted 2 cm (> 1 cm) with the gripper on it: + 1 + 5 * 0.126733 = 1.760396
    lifted = np.array([0.0, 0.0, 0.02])
    assert compute_reward("pick-place", _reading(0.4, 1.0, obj=lifted), c, "v2")[
        0
    ] == pytest.approx(1.760396, abs=1e-5)
    assert compute_reward("pick-place", _reading(0.04, 1.0), c, "v2")[0] == 10.0


def test_slide_cabinet_reset_reward_in_the_env(
    kitchen: Callable[[str], FrankaKitchenDenseEnv],
) -> None:
    """The env feeds the reward real geometry: in_place at reset, by hand from the initial distance."""
    env = kitchen("slide-cabinet")
    _, info = env.evaluate(ZERO)
    # v3: margin = the travel 0.370466 - 0.05, so at the start d = 1 and in_place = 1 / (9 + 1) = 0.1
    assert info["in_place_reward"] == pytest.approx(0.1, abs=1e-9)
    assert env.constants.travel == pytest.approx(0.370466, abs=1e-5)
    v2 = FrankaKitchenDenseEnv("slide-cabinet", seed=0, reward_version="v2")
    v2.reset(seed=0)
    # v2: margin = the initial distance: d = 1 - 0.05 / 0.370466 = 0.865034,
    # 1 / ((3d)^2 + 1) = 1 / 7.734551 = 0.129290
    assert v2.evaluate(ZERO)[1]["in_place_reward"] == pytest.approx(0.129290, abs=1e-5)
    v2.close()


@pytest.mark.parametrize("version", ["v3", "v4"])
def test_rewards_stay_in_range_under_random_actions(version: str) -> None:
    # v3 in [0, 10]; v4 adds F = gamma Phi(s') - Phi(s) = k d - gamma k d' after the clip, so its
    # rewards lie in [-k d_max, 10 + k d_max], d_max the largest gripper-to-site distance.
    env = FrankaKitchenDenseEnv("kettle", seed=0, reward_version=version)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    previous = env.potential()
    for _ in range(30):
        _, reward, terminated, _, info = env.step(rng.uniform(-1, 1, 9).astype(np.float32))
        assert not terminated and info["success"] in (0.0, 1.0)
        shaping = info.get("approach", 0.0)
        assert 0.0 <= reward - shaping <= 10.0
        if version == "v4":
            assert shaping == pytest.approx(SHAPING_GAMMA * info["potential"] - previous, abs=1e-12)
            d_max = -min(previous, info["potential"]) / POTENTIAL_SCALE  # Phi = -k d
            assert -POTENTIAL_SCALE * d_max <= reward <= 10.0 + POTENTIAL_SCALE * d_max
            previous = info["potential"]
    env.close()


# ---- episodes, spaces, seeding, registration -----------------------------------------------------


def test_spaces_and_observation_layout() -> None:
    adapter = FrankaKitchenDenseAdapter()
    assert adapter.name == "franka_kitchen_dense" and adapter.tasks == TASK_NAMES
    assert (adapter.obs_dim, adapter.act_dim, adapter.episode_length) == (62, 9, 280)
    assert adapter.observation_space.dtype == np.float64
    assert adapter.action_space.dtype == np.float32
    assert adapter.action_space.low.min() == -1.0 and adapter.action_space.high.max() == 1.0
    layout = adapter.obs_layout
    assert layout.robot == tuple(range(18))
    assert layout.objects == tuple(range(18, 59))
    assert layout.goal == (59, 60, 61)


def test_make_truncates_at_episode_length_and_never_terminates() -> None:
    adapter = make_adapter("franka_kitchen_dense", tasks=["slide-cabinet"], episode_length=3)
    env = adapter.make("slide-cabinet", seed=1)
    obs, _ = env.reset()
    assert obs.shape == (62,) and obs.dtype == np.float64 and env.observation_space.contains(obs)
    raw = env.unwrapped
    raw.set_task_joint(raw.task.goal_array)  # success from the first step on: still no termination
    flags = [env.step(np.zeros(9, dtype=np.float32))[2:4] for _ in range(3)]
    assert flags == [(False, False), (False, False), (False, True)]
    # the object state block holds the slide joint (qpos 19 -> object index 10 -> obs 28)
    obs, *_ = env.step(np.zeros(9, dtype=np.float32))
    assert obs[28] == pytest.approx(0.37, abs=0.01)


def test_seeding() -> None:
    adapter = FrankaKitchenDenseAdapter(tasks=["microwave"])
    a, b, c = (adapter.make("microwave", seed=s) for s in (7, 7, 8))
    first_a, _ = a.reset()
    first_b, _ = b.reset()
    first_c, _ = c.reset()
    np.testing.assert_array_equal(first_a, first_b)  # the make-time seed drives the first reset
    assert not np.array_equal(first_a, first_c)
    again, _ = a.reset()  # later resets continue the generator
    assert not np.array_equal(first_a, again)
    reseeded, _ = a.reset(seed=7)
    np.testing.assert_array_equal(first_a, reseeded)


def test_unknown_task_names_the_valid_ones() -> None:
    with pytest.raises(
        UnknownNameError, match="unknown franka_kitchen_dense task 'oven'.*microwave"
    ):
        FrankaKitchenDenseAdapter(tasks=["oven"])
    with pytest.raises(UnknownNameError, match="'kettle'"):
        FrankaKitchenDenseAdapter(tasks=["microwave"]).make("kettle", seed=0)


def test_gymnasium_ids_are_registered() -> None:
    ids = {gym_id(t) for t in TASK_NAMES}
    assert ids <= set(gym.registry)
    assert {gym_id(t, "v2") for t in TASK_NAMES} <= set(gym.registry)  # v2 stays available
    assert gym_id("light-switch") == "seal/FrankaKitchenDense-light-switch-v4"
    env = gym.make("seal/FrankaKitchenDense-light-switch-v4", episode_length=2)
    assert (
        isinstance(env.unwrapped, FrankaKitchenDenseEnv)
        and env.unwrapped.task.joint == "light_switch"
    )
    env.reset(seed=0)
    assert env.step(env.action_space.sample())[3] is False
    assert env.step(env.action_space.sample())[3] is True
    env.close()


# ---- semantic check -------------------------------------------------------------------------------


def test_semantic_check_passes_on_a_kitchen_task() -> None:
    # episodes=0: the expert's episodes are tested in test_kitchen_experts.py
    result = FrankaKitchenDenseAdapter(tasks=["right-hinge-door"]).semantic_check(
        "right-hinge-door", seed=0, episodes=0
    )
    assert result["ok"] is True
    assert result["goal_success"] == 1.0 and result["goal_reward"] >= 9.0
    assert result["reset_success"] == 0.0 and result["spearman"] >= 0.9
    assert len(result["interpolation_rewards"]) >= 20


def test_broken_kitchen_adapters_fail_the_semantic_check() -> None:
    sys.path.insert(0, str(pathlib.Path(__file__).parent))
    try:
        from broken_adapters import AlwaysSuccessKitchen, ObjectBlindKitchen
    finally:
        sys.path.pop(0)
    always = AlwaysSuccessKitchen(tasks=["right-hinge-door"]).semantic_check(
        "right-hinge-door", seed=0
    )
    assert always["ok"] is False and always["reset_success"] == 1.0
    blind = ObjectBlindKitchen(tasks=["right-hinge-door"]).semantic_check(
        "right-hinge-door", seed=0
    )
    assert blind["ok"] is False and blind["goal_reward"] < 9.0 and blind["spearman"] < 0.0


@pytest.mark.slow
def test_the_exploit_check_fails_a_reward_that_pays_for_hovering() -> None:
    sys.path.insert(0, str(pathlib.Path(__file__).parent))
    try:
        from broken_adapters import HoverPayingKitchen
    finally:
        sys.path.pop(0)
    broken = HoverPayingKitchen(tasks=["bottom-left-burner"]).semantic_check(
        "bottom-left-burner", seed=0, episodes=2
    )
    assert broken["spearman"] >= 0.9 and broken["scripted_success"] == 1.0  # all else passes ...
    assert broken["exploit_ratio"] > 0.5 and broken["ok"] is False  # ... but hovering pays
    assert broken["exploit_best"] in ("hover", "parking", "oscillate")
    honest = FrankaKitchenDenseAdapter(tasks=["bottom-left-burner"]).semantic_check(
        "bottom-left-burner", seed=0, episodes=2
    )
    assert honest["ok"] is True and honest["exploit_ratio"] <= 0.5
