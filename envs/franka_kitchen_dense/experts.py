"""Scripted experts for the ten dense kitchens: `policy(obs, task) -> action`, from the observation only.

In the spirit of `metaworld.policies`: each expert is stateless and reads nothing but the 62-d
observation that `reset`/`step` return. It copies the observed joint positions (robot `[0:9]`,
kitchen objects `[18:39]`) into a private `MjData` of upstream's kitchen model, and from that
computes the gripper pose, the handle's pose and the Jacobian. One rule serves every articulated
task (doors, slide, switch, knobs): grasp the handle, then drag the grasp pose along the joint by a
small step towards the goal; the arm's joint step comes from damped-least-squares inverse
kinematics on the `end_effector` site. The kettle is grasped from the front and above, lifted,
carried and set down. Phases are read from the state (is the gripper on the handle? are the fingers closed? is
the kettle lifted?), never remembered.

Upstream's controller turns an action `a` into a position target `q_observed + 0.16 a` (velocity
`2 a` rad/s for one 80 ms step) for position actuators whose gains cannot hold the arm against
gravity, so each arm action adds the offset `bias / kp` that makes the actuator's force equal the
gravity torque at the observed pose (a stateless feed-forward: no integral term); an env made
with `gravity_compensation=True` needs none, and `policy(..., gravity_compensation=True)` adds none.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import io
from pathlib import Path

import mujoco
import numpy as np

from franka_kitchen_dense.tasks import TASKS, KitchenTask

ARM = 7
CONTROL_DT = 0.08  # s per env step: 40 MuJoCo steps of 2 ms
ACTION_SCALE = 2.0  # upstream act_rng: action 1 is 2 rad/s (or m/s for the fingers)
TARGET_PER_ACTION = ACTION_SCALE * CONTROL_DT  # position target offset per unit action: 0.16
OPEN, CLOSE = 1.0, -1.0  # finger actions: +1 opens, -1 closes
MAX_TCP_STEP = 0.035  # m per env step towards a waypoint (0.44 m/s): fast, yet tracked within ~1 cm
MAX_JOINT_STEP = 0.15  # rad per env step, within the action's 0.16
DAMPING = 0.05  # damped-least-squares damping (m)
ROTATION_WEIGHT = 0.3  # m per rad: how much orientation error weighs against position error
AT_HANDLE = 0.02  # m: the gripper counts as on the handle within this distance of its grasp point
IN_LINE = 0.02  # m: off the approach line by less than this, the gripper may move in
# Fingers closed on something (between empty and fully open, metres of total opening) and the
# gripper within HOLD_RADIUS of the grasp point: keep holding rather than re-approach.
EMPTY_GRIP, OPEN_GRIP, HOLD_RADIUS = 0.004, 0.07, 0.045
STANDOFF = 0.10  # m: the pre-grasp point lies this far back along the approach direction
DRAG_STEP = {"site": 0.06, "joint": 0.25}  # how far ahead of the handle the grasp point is dragged
# m: carry height of the kettle handle above its initial height. The 6.4 cm bar slips down through
# the closed fingers at ~1 mm per step whatever the speed, so the carry is kept short: low and at
# the full tcp step. Lift 0.05 m at 0.02 m/step (reward v1's expert) needed 138 steps to success
# with one re-grasp in most seeds (its reward dropped when the gripper left the handle, Spearman
# 0.80); 0.03 m at MAX_TCP_STEP needs 65 with none (10 seeds, `seal envs check`).
KETTLE_LIFT = 0.03
# Straight down, the wrist (link 6) hits the burner knobs on the way to the back burner; a hand
# tilted forward by 0.5 rad keeps it low and behind the handle (0.8 and 1.1 rad: IK stalls at reset).
KETTLE_APPROACH = np.array([0.0, np.sin(0.5), -np.cos(0.5)])
SET_DOWN_RADIUS = 0.02  # m: over its goal within this (horizontally), the kettle is lowered
# The handle slides a few cm in the fingers while carried; a looser hold radius keeps carrying it.
KETTLE_HOLD_RADIUS = 0.07
KETTLE_IN_LINE = 0.006  # m: the open fingers clear the 6.4 cm bar by only 8 mm a side
KETTLE_STANDOFF = 0.16  # m: the pre-grasp point clears the bar's top by 9 cm
# Close only once fully down: a grip over the bar's top half squeezes it out.
KETTLE_AT_HANDLE = 0.01
IK_ITERATIONS = 15  # per step, warm-started at the current pose with the target <= 3.5 cm away
POSTURE = 0.02  # weight of the pull towards the reference posture in the IK (small: a tie-breaker)
RESOLVE_ERROR = 0.01  # m: an IK from the current pose this far off is retried from the reference
REFERENCE_ERROR = 0.005  # m: a reference posture this near the handle ends the search
# Where the expert grasps, where it differs from the task table's approach (`tasks.py`):
# the microwave handle hangs low (1.79 m): square-on it is 7.4 cm out of reach, taken 45 degrees
# from above it is within 1 mm at reset and 1.8 cm at the goal; the light switch and the bottom
# right knob are reachable square-on only by postures that wrap the arm round (base joint at
# 1.8-2.4 rad), from which it cannot get there, but tilted down they are reached from near home.
# A knob's site is the blade's centre, whose front half (4.8 cm) the fingers cage, so the
# gripper stops 2.5 cm short of it.
TILT_DOWN = {
    "microwave": 1.0,
    "light-switch": 1.0,
    "bottom-right-burner": 0.6,
}  # added to the approach's downward component, then normalised
# The kettle handle (a 3.2 cm-radius bar) squeezes out of a grip over its top half, so the gripper
# goes as deep as the fingers let it (8 mm past the handle site, 1.5 cm below the bar's axis).
GRASP_DEPTH = {
    **{
        t: 0.025
        for t in (
            "top-right-burner",
            "top-left-burner",
            "bottom-right-burner",
            "bottom-left-burner",
        )
    },
    "kettle": -0.008,
}
# Upstream's initial arm pose (KitchenEnv's init_qpos[:7]); the reference-posture search starts here.
HOME = np.array([0.148388, -1.768486, 1.843903, -2.476858, 0.260252, 0.712533, 1.595154])


def _kitchen_xml() -> Path:
    with contextlib.redirect_stderr(io.StringIO()):
        import gymnasium_robotics.envs.franka_kitchen.kitchen_env as kitchen_env
    return (
        Path(kitchen_env.__file__).parent.parent
        / "assets"
        / "kitchen_franka"
        / "kitchen_assets"
        / "kitchen_env_model.xml"
    )


@functools.lru_cache(maxsize=1)
def _model() -> mujoco.MjModel:
    """Upstream's kitchen model, loaded once per process (experts never touch an env's model)."""
    return mujoco.MjModel.from_xml_path(str(_kitchen_xml()))


class _Kinematics:
    """A private MjData on upstream's model, set from an observation."""

    def __init__(self, task: KitchenTask) -> None:
        if task.name in TILT_DOWN:
            approach = np.asarray(task.approach) - np.array([0.0, 0.0, TILT_DOWN[task.name]])
            task = dataclasses.replace(task, approach=tuple(approach / np.linalg.norm(approach)))
        self.depth = GRASP_DEPTH.get(task.name, 0.0)
        self.model = _model()
        self.data = mujoco.MjData(self.model)
        self.task = task
        joint = self.model.joint(task.joint)
        self.qpos_adr = int(joint.qposadr[0])
        self.free = int(joint.type[0]) == mujoco.mjtJoint.mjJNT_FREE
        self.site = self.model.site(task.site).id
        self.body = int(self.model.site_bodyid[self.site])
        self.tcp = self.model.site("end_effector").id
        self.link = int(self.model.site_bodyid[self.tcp])
        self.fingers = [self.model.joint(f"robot:panda0_finger_joint{i}").id for i in (1, 2)]
        self.kp = self.model.actuator_gainprm[:ARM, 0].copy()
        lo, hi = self.model.jnt_range[:ARM, 0], self.model.jnt_range[:ARM, 1]
        self.lo, self.hi = lo + 0.02, hi - 0.02
        # The handle body's rotation with the task joint at 0 (kettle: at its initial pose):
        # the task's approach and finger directions are given in that configuration.
        self.set_qpos(np.zeros(9), self._initial_objects())
        self.body_rot0 = self.data.xmat[self.body].reshape(3, 3).copy()
        self.initial_handle = self.data.site_xpos[self.site].copy()
        self.joint_start = 0.0  # every articulated task starts with its joint at 0 (to 0.007)
        self.scratch = mujoco.MjData(self.model)
        self.feed_forward = True  # add gravity / kp to each arm action (off with gravcomp envs)
        self.reference: np.ndarray | None = None
        self.finger_sign = 0.0  # free while the reference posture is searched, then fixed
        self.reference = self._reference_posture()
        self.set_qpos(np.concatenate([self.reference, [0.04, 0.04]]), self._initial_objects())
        _, rot = self.grasp_pose()
        # The hand is symmetric under swapping its fingers; fixing which finger goes where (the
        # reference posture's choice) keeps the IK from flipping the wrist half a turn.
        self.finger_sign = float(np.sign(np.dot(self.hand_rotation()[:, 1], rot[:, 1])))

    def _reference_posture(self) -> np.ndarray:
        """The arm pose that grasps the handle in the initial state, best of a few IK starts
        (home, and the base joint turned either way)."""
        self.set_qpos(np.concatenate([HOME, [0.04, 0.04]]), self._initial_objects())
        handle, rot = self.grasp_pose()
        best, best_error = HOME, np.inf
        # the first start (nearest home first) that reaches the handle: the furthest starts find
        # poses that reach round the back, from which the arm cannot move far
        for turn in (0.0, 0.4, -0.4, 0.8, -0.8, 1.6, -1.6):
            start = HOME + np.array([turn, 0, 0, 0, 0, 0, 0])
            q, error = self.solve(handle, rot, start, iterations=300)
            if error < best_error - 1e-4:
                best, best_error = q, error
            if error < REFERENCE_ERROR:
                break
        return best

    def _initial_objects(self) -> np.ndarray:
        """Kitchen object qpos at reset: joints at 0 (upstream's are within 0.007), the kettle at
        upstream's initial position with its quaternion rounded to the identity."""
        objects = np.zeros(self.model.nq - 9)
        kettle = self.model.joint("kettle").qposadr[0] - 9
        objects[kettle : kettle + 7] = (-0.269, 0.350, 1.619, 1.0, 0.0, 0.0, 0.0)
        return objects

    def set_qpos(self, robot: np.ndarray, objects: np.ndarray) -> None:
        self.data.qpos[:9] = robot
        self.data.qpos[9:] = objects
        if self.free:
            quat = self.data.qpos[self.qpos_adr + 3 : self.qpos_adr + 7]
            quat /= np.linalg.norm(quat)
        self.data.qvel[:] = 0.0
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_comPos(self.model, self.data)

    def set_obs(self, obs: np.ndarray) -> None:
        self.set_qpos(obs[:9], obs[18:39])

    def joint_value(self) -> float:
        return float(self.data.qpos[self.qpos_adr])

    def grasp_pose(self, joint_value: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The handle site's position and the grasp rotation (columns: approach, fingers, their
        cross product) with the task joint at `joint_value` (default: as observed)."""
        saved = self.data.qpos[self.qpos_adr]
        if joint_value is not None:
            self.data.qpos[self.qpos_adr] = joint_value
            mujoco.mj_kinematics(self.model, self.data)
        turn = self.data.xmat[self.body].reshape(3, 3) @ self.body_rot0.T
        position = self.data.site_xpos[self.site].copy()
        if joint_value is not None:
            self.data.qpos[self.qpos_adr] = saved
            mujoco.mj_kinematics(self.model, self.data)
            mujoco.mj_comPos(self.model, self.data)
        approach = turn @ np.asarray(self.task.approach)
        if self.free:  # the kettle handle is taken from the front and above, whatever its yaw
            approach = KETTLE_APPROACH.copy()
        fingers = turn @ np.asarray(self.task.fingers)
        fingers -= np.dot(fingers, approach) * approach
        approach /= np.linalg.norm(approach)
        fingers /= np.linalg.norm(fingers)
        position -= self.depth * approach
        return position, np.column_stack([approach, fingers, np.cross(approach, fingers)])

    def hand_rotation(self) -> np.ndarray:
        """The hand's current (approach, finger axis, cross) columns."""
        return _hand_rotation(self, self.data)

    def tcp_position(self) -> np.ndarray:
        return self.data.site_xpos[self.tcp].copy()

    def solve(
        self,
        target: np.ndarray,
        target_rot: np.ndarray,
        start: np.ndarray,
        iterations: int = IK_ITERATIONS,
    ) -> tuple[np.ndarray, float]:
        """Arm joints putting the gripper at `target` with rotation `target_rot`, by damped least
        squares from `start` with a weak pull towards the task's reference posture (which keeps the
        solution in the elbow-up branch that reaches the handle). Returns (joints, position error)."""
        model, data = self.model, self.scratch
        data.qpos[:] = self.data.qpos
        data.qpos[:ARM] = start
        jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
        reference = self.reference if self.reference is not None else start
        error = np.inf
        for _ in range(iterations):
            mujoco.mj_kinematics(model, data)
            mujoco.mj_comPos(model, data)
            pos_err = target - data.site_xpos[self.tcp]
            error = float(np.linalg.norm(pos_err))
            rot_err = _rotation_error(target_rot, _hand_rotation(self, data), self.finger_sign)
            mujoco.mj_jacSite(model, data, jacp, jacr, self.tcp)
            jac = np.vstack([jacp[:, :ARM], ROTATION_WEIGHT * jacr[:, :ARM]])
            err = np.concatenate([pos_err, ROTATION_WEIGHT * rot_err])
            q = data.qpos[:ARM]
            lhs = jac.T @ jac + (DAMPING**2 + POSTURE**2) * np.eye(ARM)
            dq = np.linalg.solve(lhs, jac.T @ err + POSTURE**2 * (reference - q))
            data.qpos[:ARM] = np.clip(q + np.clip(dq, -0.3, 0.3), self.lo, self.hi)
        mujoco.mj_kinematics(model, data)
        error = float(np.linalg.norm(target - data.site_xpos[self.tcp]))
        return data.qpos[:ARM].copy(), error

    def arm_action(self, target: np.ndarray, target_rot: np.ndarray) -> np.ndarray:
        """Arm actions (0..6) for one step along the joint-space line to the target pose's solution."""
        q = self.data.qpos[:ARM].copy()
        tcp = self.tcp_position()
        offset = target - tcp
        # straight-line Cartesian progress: aim at most MAX_TCP_STEP ahead along the line
        target = tcp + offset * min(1.0, MAX_TCP_STEP / max(float(np.linalg.norm(offset)), 1e-9))
        goal, error = self.solve(target, target_rot, q)
        if error > RESOLVE_ERROR and self.reference is not None:
            other, other_error = self.solve(target, target_rot, self.reference)
            if other_error < error:
                goal = other
        dq = goal - q
        dq /= max(1.0, float(np.max(np.abs(dq))) / MAX_JOINT_STEP)
        hold = self._gravity() / self.kp if self.feed_forward else 0.0
        return np.clip((dq + hold) / TARGET_PER_ACTION, -1.0, 1.0)

    def _gravity(self) -> np.ndarray:
        """Generalised gravity torque on the arm joints at the observed pose (velocities zero)."""
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_comPos(self.model, self.data)
        torque = np.zeros(self.model.nv)
        mujoco.mj_rne(self.model, self.data, 0, torque)
        return torque[:ARM]


def _hand_rotation(kin: _Kinematics, data: mujoco.MjData) -> np.ndarray:
    """The hand's (approach, finger axis, cross) columns in `data`."""
    approach = data.xmat[kin.link].reshape(3, 3)[:, 2]
    u = data.xaxis[kin.fingers[0]] - data.xaxis[kin.fingers[1]]
    u /= np.linalg.norm(u)
    return np.column_stack([approach, u, np.cross(approach, u)])


def _rotation_error(target_rot: np.ndarray, hand: np.ndarray, finger_sign: float) -> np.ndarray:
    """World-frame rotation vector from `hand` to `target_rot`, with the finger axis flipped when
    `finger_sign` is -1 (0: whichever sign is nearer)."""
    sign = finger_sign or (1.0 if np.dot(hand[:, 1], target_rot[:, 1]) >= 0 else -1.0)
    if sign < 0:
        target_rot = target_rot @ np.diag([1.0, -1.0, -1.0])
    quat, vel = np.zeros(4), np.zeros(3)
    mujoco.mju_mat2Quat(quat, (target_rot @ hand.T).ravel())
    mujoco.mju_quat2Vel(vel, quat, 1.0)
    return vel


@functools.cache
def _kinematics(task: str) -> _Kinematics:
    return _Kinematics(TASKS[task])


def policy(obs: np.ndarray, task: str, gravity_compensation: bool = False) -> np.ndarray:
    """The scripted expert's action (9 floats in [-1, 1]) for `task` given one 62-d observation.

    `gravity_compensation`: whether the env was made with that option (like the task, a fact
    about the env, not its state); then the arm needs no gravity feed-forward, and adding it
    would drive the joints by `bias / kp` every step.
    """
    obs = np.asarray(obs, dtype=np.float64)
    kin = _kinematics(task)
    kin.feed_forward = not gravity_compensation
    kin.set_obs(obs)
    if kin.free:
        arm, fingers = _kettle(kin, obs)
    else:
        arm, fingers = _articulated(kin)
    return np.concatenate([arm, [fingers, fingers]]).astype(np.float32)


def _approach_plan(
    kin: _Kinematics, handle: np.ndarray, rot: np.ndarray
) -> tuple[np.ndarray, float] | None:
    """Waypoint and finger action while the gripper is not yet on the handle; None once it is."""
    tcp = kin.tcp_position()
    offset = tcp - handle
    opening = float(kin.data.qpos[7] + kin.data.qpos[8])
    radius = KETTLE_HOLD_RADIUS if kin.free else HOLD_RADIUS
    holding = EMPTY_GRIP < opening < OPEN_GRIP and np.linalg.norm(offset) < radius
    if np.linalg.norm(offset) < (KETTLE_AT_HANDLE if kin.free else AT_HANDLE) or holding:
        return None
    approach = rot[:, 0]
    depth = -float(np.dot(offset, approach))  # how far behind the handle, along the approach
    off_line = float(np.linalg.norm(offset + depth * approach))
    aligned = float(np.dot(kin.hand_rotation()[:, 0], approach)) > 0.97
    standoff = KETTLE_STANDOFF if kin.free else STANDOFF
    if (
        off_line < (KETTLE_IN_LINE if kin.free else IN_LINE)
        and -0.01 < depth < standoff + 0.03
        and aligned
    ):
        return handle, OPEN
    return handle - standoff * approach, OPEN


def _articulated(kin: _Kinematics) -> tuple[np.ndarray, float]:
    """Grasp the handle, then drag its grasp pose along the joint towards the goal."""
    task = kin.task
    q = kin.joint_value()
    handle, rot = kin.grasp_pose()
    plan = _approach_plan(kin, handle, rot)
    if plan is not None:
        return kin.arm_action(plan[0], rot), plan[1]
    goal = task.goal[0]
    if task.measure == "site":
        # a joint step that moves the site by about DRAG_STEP metres (radius from the geometry)
        ahead, _ = kin.grasp_pose(q + 0.01 * np.sign(goal - q))
        per_unit = max(np.linalg.norm(ahead - handle) / 0.01, 1e-6)
        step = DRAG_STEP["site"] / per_unit
    else:
        step = DRAG_STEP["joint"]
    # overshoot the goal a little so that the success band is entered, not approached forever
    overshoot = 0.3 * task.threshold if task.measure == "joint" else 0.0
    aim = goal + np.sign(goal - kin.joint_start) * overshoot
    next_q = q + np.clip(aim - q, -step, step)
    target, target_rot = kin.grasp_pose(next_q)
    return kin.arm_action(target, target_rot), CLOSE


def _kettle(kin: _Kinematics, obs: np.ndarray) -> tuple[np.ndarray, float]:
    """Grasp the kettle handle from the front and above, lift it, carry it over its goal, set it down."""
    handle, rot = kin.grasp_pose()
    plan = _approach_plan(kin, handle, rot)
    if plan is not None:
        return kin.arm_action(plan[0], rot), plan[1]
    opening = float(kin.data.qpos[7] + kin.data.qpos[8])
    tcp = kin.tcp_position()
    if opening > OPEN_GRIP - 0.002:  # still closing on the handle: stay
        return kin.arm_action(tcp, rot), CLOSE
    goal = obs[59:62]  # the handle's position at the goal pose
    carry = kin.initial_handle[2] + KETTLE_LIFT
    if np.linalg.norm((goal - handle)[:2]) > SET_DOWN_RADIUS:
        if handle[2] < carry - 0.03:  # lift straight up first
            aim = np.array([handle[0], handle[1], carry])
        else:
            aim = np.array([goal[0], goal[1], carry])
    else:
        aim = goal
    return kin.arm_action(aim + (tcp - handle), rot), CLOSE
