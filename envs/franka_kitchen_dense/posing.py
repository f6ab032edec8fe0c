"""Put the kitchen in a chosen configuration with the gripper at the task's handle or object.

Used by the adapter's semantic check and by tests. The arm is posed by a damped-least-squares
inverse kinematics on MuJoCo's site Jacobian (`mj_jacSite` on `end_effector`): position at the
task site, hand axis along the task's approach direction and fingers closing across the handle
(both directions turn with the handle's body). No controller runs; the pose is written to qpos.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import mujoco
import numpy as np

if TYPE_CHECKING:
    from franka_kitchen_dense.env import FrankaKitchenDenseEnv

ARM_DOFS = 7
FINGER_OPEN = 0.04  # each finger joint's upper limit: fully open


def _grasp_directions(
    env: FrankaKitchenDenseEnv, data: mujoco.MjData, init_rot: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The task's approach and finger directions, turned with the site's body since the initial state."""
    body = env.model.site_bodyid[env._site_id]
    turn = data.xmat[body].reshape(3, 3) @ init_rot.T
    approach = turn @ np.asarray(env.task.approach)
    fingers = turn @ np.asarray(env.task.fingers)
    fingers -= np.dot(fingers, approach) * approach  # exactly perpendicular to the approach
    return approach / np.linalg.norm(approach), fingers / np.linalg.norm(fingers)


def _initial_body_rotation(env: FrankaKitchenDenseEnv) -> np.ndarray:
    scratch = mujoco.MjData(env.model)
    scratch.qpos[:] = env._init_qpos
    mujoco.mj_kinematics(env.model, scratch)
    return scratch.xmat[env.model.site_bodyid[env._site_id]].reshape(3, 3).copy()


def solve_gripper_at_object(
    env: FrankaKitchenDenseEnv,
    start: np.ndarray | None = None,
    iterations: int = 300,
    damping: float = 0.05,
    rotation_weight: float = 0.3,
    offset: np.ndarray | None = None,
) -> tuple[np.ndarray, float]:
    """Arm joint angles (7) putting `end_effector` at the task site (plus `offset`, world metres),
    oriented to grasp it.

    Works on a copy of the env's current state (the task joint as set). `start` seeds the solver
    (default: the current arm pose). Returns (arm qpos, remaining position error in metres).
    """
    model = env.model
    data = mujoco.MjData(model)
    data.qpos[:] = env.data.qpos
    if start is not None:
        data.qpos[:ARM_DOFS] = start
    mujoco.mj_kinematics(model, data)
    init_rot = _initial_body_rotation(env)
    approach, fingers = _grasp_directions(env, data, init_rot)
    site, link = env._tcp_id, model.site_bodyid[env._tcp_id]
    rot = data.xmat[link].reshape(3, 3)
    # Hand frame directions in link7 coordinates: the hand points along local z (the site's offset)
    # and the left finger opens along the finger joint's world axis.
    hand_local = np.array([0.0, 0.0, 1.0])
    u = data.xaxis[env._finger_joints[0]] - data.xaxis[env._finger_joints[1]]
    finger_local = rot.T @ (u / np.linalg.norm(u))
    # The hand is symmetric under swapping the fingers: aim the finger axis at whichever sign is nearer.
    if np.dot(rot @ finger_local, fingers) < 0:
        fingers = -fingers
    local = np.column_stack([hand_local, finger_local, np.cross(hand_local, finger_local)])
    world = np.column_stack([approach, fingers, np.cross(approach, fingers)])
    target_rot = world @ local.T
    target_quat = np.zeros(4)
    mujoco.mju_mat2Quat(target_quat, target_rot.ravel())
    lo, hi = model.jnt_range[:ARM_DOFS, 0], model.jnt_range[:ARM_DOFS, 1]
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    quat, rot_err = np.zeros(4), np.zeros(3)
    target = data.site_xpos[env._site_id].copy()
    if offset is not None:
        target += offset
    for _ in range(iterations):
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        pos_err = target - data.site_xpos[site]
        mujoco.mju_mat2Quat(quat, data.xmat[link])
        mujoco.mju_subQuat(rot_err, target_quat, quat)
        rot_err_world = data.xmat[link].reshape(3, 3) @ rot_err
        mujoco.mj_jacSite(model, data, jacp, jacr, site)
        jac = np.vstack([jacp[:, :ARM_DOFS], rotation_weight * jacr[:, :ARM_DOFS]])
        err = np.concatenate([pos_err, rotation_weight * rot_err_world])
        step = jac.T @ np.linalg.solve(jac @ jac.T + damping**2 * np.eye(6), err)
        data.qpos[:ARM_DOFS] = np.clip(data.qpos[:ARM_DOFS] + np.clip(step, -0.2, 0.2), lo, hi)
    mujoco.mj_kinematics(model, data)
    return data.qpos[:ARM_DOFS].copy(), float(np.linalg.norm(target - data.site_xpos[site]))


def best_gripper_pose(
    env: FrankaKitchenDenseEnv,
    start: np.ndarray | None = None,
    tolerance: float = 0.005,
    offset: np.ndarray | None = None,
) -> tuple[np.ndarray, float]:
    """`solve_gripper_at_object` from a few starting poses, each with the grasp orientation and then
    with a looser one; returns the first pose within `tolerance` metres, else the closest found.

    Loosening the orientation lets the hand reach handles the arm cannot reach square-on (the left
    hinge door's handle leaves the arm's reach as the door opens; then the pose is the nearest one).
    """
    starts = [
        env.data.qpos[:ARM_DOFS].copy() if start is None else np.asarray(start, dtype=np.float64)
    ]
    home = env._init_qpos[:ARM_DOFS]
    for turn in (0.0, 0.8, -0.8):  # the initial pose, and the base joint turned left and right
        starts.append(home + np.array([turn, 0, 0, 0, 0, 0, 0]))
    best: tuple[np.ndarray, float] | None = None
    for weight in (0.3, 0.03):
        for q0 in starts:
            arm, error = solve_gripper_at_object(env, q0, rotation_weight=weight, offset=offset)
            if best is None or error < best[1] - 1e-4:
                best = (arm, error)
            if error <= tolerance:
                return best
    assert best is not None
    return best


def pose_gripper_at_object(
    env: FrankaKitchenDenseEnv, start: np.ndarray | None = None, offset: np.ndarray | None = None
) -> float:
    """Write the best IK arm pose into the env with the fingers open and the robot at rest.

    Returns the remaining distance (m) from `end_effector` to the task site (plus `offset`).
    """
    arm, error = best_gripper_pose(env, start, offset=offset)
    env.data.qpos[:ARM_DOFS] = arm
    env.data.qpos[ARM_DOFS : ARM_DOFS + 2] = FINGER_OPEN
    env.data.qvel[: ARM_DOFS + 2] = 0.0
    env.sync()
    return error
