"""`FrankaKitchenDenseEnv`: one kitchen task with a flat observation, a dense reward and a success flag.

It wraps gymnasium-robotics' `KitchenEnv` (the class behind `FrankaKitchen-v1`) unchanged: same
model, frame skip (40 x 2 ms = 80 ms per step), velocity action interface, fixed initial state and
uniform observation noise (robot 0.01, objects 0.0005 of upstream's amplitudes). It replaces
upstream's sparse all-task reward with the task's Meta-World-style dense reward (`rewards.py`),
adds `info["success"]`, never terminates, and truncates after `episode_length` steps.

Observation (62 float64):

| slice    | content                                                       | layout  |
|----------|---------------------------------------------------------------|---------|
| [0:9]    | robot joint positions (7 arm, 2 fingers), upstream noise       | robot   |
| [9:18]   | robot joint velocities, upstream noise                         | robot   |
| [18:39]  | kitchen object qpos (knobs, burners, switch, doors, kettle)    | objects |
| [39:59]  | kitchen object qvel                                            | objects |
| [59:62]  | goal: the task site's position at the goal configuration       | goal    |

[0:59] is upstream's 59-d `observation`, in upstream's order.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
from pathlib import Path
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

# gymnasium-robotics prints a notice about its Adroit envs' rewards on import; it does not concern
# the kitchen, so keep it out of every seal command's output.
with contextlib.redirect_stderr(io.StringIO()):
    from gymnasium_robotics.envs.franka_kitchen.kitchen_env import KitchenEnv

from franka_kitchen_dense.rewards import (
    FINGER_MAX_OPENING,
    MW_PAD_SQUEEZE,
    POTENTIAL_SCALE,
    SHAPING_GAMMA,
    TCP_NEAR_OBJECT,
    Constants,
    Reading,
    compute_reward,
    grip_effort,
)
from franka_kitchen_dense.tasks import (
    DEFAULT_EPISODE_LENGTH,
    REWARD_VERSION,
    REWARD_VERSIONS,
    TASKS,
    KitchenTask,
)

UPSTREAM_OBS_DIM = 59
OBS_DIM = UPSTREAM_OBS_DIM + 3
ACT_DIM = 9
LEFT_FINGER_JOINT = "robot:panda0_finger_joint1"  # in body panda0_leftfinger
RIGHT_FINGER_JOINT = "robot:panda0_finger_joint2"  # in body panda0_rightfinger
TCP_SITE = "end_effector"
KITCHEN_XML = "../assets/kitchen_franka/kitchen_assets/kitchen_env_model.xml"  # from franka_env.py
ROBOT_BODY_PREFIX = "panda0_"


class FrankaKitchenDenseEnv(gym.Env):
    """One dense single-task Franka kitchen (see the module docstring for the observation).

    `seed` is used by the first `reset()` that is given no seed, so an env is fully determined by
    the seed it is made with; later `reset()` calls continue the seeded generator.
    """

    metadata = {"render_modes": ["human", "rgb_array", "depth_array"], "render_fps": 12}

    def __init__(
        self,
        task: str,
        episode_length: int = DEFAULT_EPISODE_LENGTH,
        seed: int | None = None,
        render_mode: str | None = None,
        gravity_compensation: bool = False,
        reward_version: str = REWARD_VERSION,
        gamma: float = SHAPING_GAMMA,
    ) -> None:
        """`gamma`: reward v4's approach-term discount; it must equal the learner's `agent.gamma`."""
        from seal.errors import SealError, UnknownNameError

        if task not in TASKS:
            raise UnknownNameError("franka_kitchen_dense task", task, list(TASKS))
        if reward_version not in REWARD_VERSIONS:
            raise UnknownNameError(
                "franka_kitchen_dense reward version", reward_version, list(REWARD_VERSIONS)
            )
        if not 0.0 < float(gamma) <= 1.0:
            raise SealError(f"franka_kitchen_dense: gamma must be in (0, 1], got {gamma!r}")
        self.task: KitchenTask = TASKS[task]
        self.reward_version = reward_version
        self.gamma = float(gamma)
        self._potential = 0.0  # Phi of the state the next step starts from (reward v4)
        self.episode_length = int(episode_length)
        self.render_mode = render_mode
        self._pending_seed = seed
        # Upstream's own termination and task bookkeeping are switched off: only this task counts.
        self.kitchen = KitchenEnv(
            terminate_on_tasks_completed=False,
            remove_task_when_completed=False,
            render_mode=render_mode,
        )
        self.gravity_compensation = bool(gravity_compensation)
        if self.gravity_compensation:
            self._compile_with_gravity_compensation()
        self.model: mujoco.MjModel = self.kitchen.model
        self.data: mujoco.MjData = self.kitchen.data
        self._init_qpos = np.array(self.kitchen.robot_env.init_qpos, dtype=np.float64)

        joint = self.model.joint(self.task.joint)
        self._qpos_adr = int(joint.qposadr[0])
        self._qpos_width = 7 if int(joint.type[0]) == mujoco.mjtJoint.mjJNT_FREE else 1
        self._site_id = self.model.site(self.task.site).id
        self._tcp_id = self.model.site(TCP_SITE).id
        self._finger_joints = [
            self.model.joint(n).id for n in (LEFT_FINGER_JOINT, RIGHT_FINGER_JOINT)
        ]
        self._finger_qpos = [int(self.model.jnt_qposadr[j]) for j in self._finger_joints]

        self.constants = self._task_constants()
        self.goal_position = self.constants.target.copy()

        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(OBS_DIM,), dtype=np.float64)
        # float32 like Meta-World's, so both adapters share an action dtype; upstream clips anyway.
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(ACT_DIM,), dtype=np.float32)
        self._steps = 0

    def _compile_with_gravity_compensation(self) -> None:
        """Rebuild upstream's model with MuJoCo's `gravcomp` = 1 on every robot body (links, hand,
        fingers): a passive force that cancels gravity on them. Upstream has none, and its position
        actuators (kp 870 / 120, joint damping 100 / 10) let the arm sag under a zero action.
        (`gravcomp` must be set before compiling: MuJoCo sizes its gravcomp pass at compile time.)"""
        import gymnasium_robotics.envs.franka_kitchen.franka_env as franka_env

        robot = self.kitchen.robot_env
        xml = Path(franka_env.__file__).parent / KITCHEN_XML
        spec = mujoco.MjSpec.from_file(str(xml))
        for body in spec.bodies:
            if body.name.startswith(ROBOT_BODY_PREFIX):
                body.gravcomp = 1.0
        model = spec.compile()
        data = mujoco.MjData(model)
        robot.model, robot.data = model, data
        robot.init_qvel = data.qvel.copy()
        renderer = getattr(robot, "mujoco_renderer", None)
        if renderer is not None:
            renderer.model, renderer.data = model, data
        self.kitchen.model, self.kitchen.data = model, data

    # ----- geometry -------------------------------------------------------------------------

    def _task_constants(self) -> Constants:
        """Task site, gripper and pads at the initial configuration, and the site at the goal."""
        scratch = mujoco.MjData(self.model)
        scratch.qpos[:] = self._init_qpos
        mujoco.mj_kinematics(self.model, scratch)
        init = self._read_geometry(scratch)
        init_joint = float(self._init_qpos[self._qpos_adr])
        other_sites = [
            scratch.site_xpos[self.model.site(t.site).id]
            for t in TASKS.values()
            if t.site != self.task.site
        ]
        # Reward v3's reach margin: the nearest other task's site (knobs 0.114 m apart).
        reach_margin = min(float(np.linalg.norm(init["obj"] - site)) for site in other_sites)
        scratch.qpos[self._qpos_adr : self._qpos_adr + self._qpos_width] = self.task.goal_array
        mujoco.mj_kinematics(self.model, scratch)
        target = scratch.site_xpos[self._site_id].copy()
        radius = self._handle_radius(scratch)
        obj_radius, near_object = self.task.obj_radius, TCP_NEAR_OBJECT
        if self.task.family in ("push", "pick-place"):
            # Meta-World's push / pick-place puck has radius 0.02: its gate ("tcp_to_obj < 0.02")
            # is that radius and its obj_radius (0.015) lies 5 mm inside; the same from the handle.
            obj_radius, near_object = radius - MW_PAD_SQUEEZE, radius
        constants = Constants(
            target=target,
            obj_init=init["obj"],
            tcp_init=init["tcp"],
            left_pad_init=init["left_pad"],
            right_pad_init=init["right_pad"],
            finger_axis_init=init["finger_axis"],
            distance_init=0.0,
            threshold=self.task.threshold,
            obj_radius=0.0 if obj_radius is None else obj_radius,  # door-open, dial-turn: unused
            near_object=near_object,
            reach_margin=reach_margin,
            travel=float(abs(self.task.goal[0] - init_joint)) if self._qpos_width == 1 else 0.0,
        )
        return dataclasses.replace(
            constants, distance_init=self._distance(self._init_qpos, init["obj"], constants)
        )

    def _handle_radius(self, data: mujoco.MjData) -> float:
        """Radius of the collision capsule or cylinder of the task site's body nearest the site (the
        bar the gripper holds: slide handle 0.022 m, kettle handle 0.032 m, read from the model)."""
        model, site = self.model, data.site_xpos[self._site_id]
        best, radius = np.inf, np.nan
        for g in np.flatnonzero(model.geom_bodyid == model.site_bodyid[self._site_id]):
            bar = model.geom_type[g] in (
                mujoco.mjtGeom.mjGEOM_CAPSULE,
                mujoco.mjtGeom.mjGEOM_CYLINDER,
            )
            if not bar or not (model.geom_contype[g] or model.geom_conaffinity[g]):
                continue
            axis = data.geom_xmat[g].reshape(3, 3)[:, 2]
            offset = site - data.geom_xpos[g]
            along = np.clip(offset @ axis, -model.geom_size[g, 1], model.geom_size[g, 1])
            distance = float(np.linalg.norm(offset - along * axis))
            if distance < best:
                best, radius = distance, float(model.geom_size[g, 0])
        return radius

    def _read_geometry(self, data: mujoco.MjData) -> dict[str, np.ndarray]:
        """Gripper centre, finger axis, inner finger surfaces and the task site, from `data`."""
        tcp = data.site_xpos[self._tcp_id].copy()
        # Each finger joint's world axis is the direction that finger opens; u points right -> left.
        axis_left = data.xaxis[self._finger_joints[0]].copy()
        axis_right = data.xaxis[self._finger_joints[1]].copy()
        u = axis_left - axis_right
        u /= np.linalg.norm(u)
        q_left, q_right = (float(data.qpos[a]) for a in self._finger_qpos)
        return {
            "tcp": tcp,
            "finger_axis": u,
            "left_pad": tcp + q_left * u,
            "right_pad": tcp - q_right * u,
            "obj": data.site_xpos[self._site_id].copy(),
            "finger_opening": np.array(np.clip((q_left + q_right) / FINGER_MAX_OPENING, 0.0, 1.0)),
        }

    def _distance(self, qpos: np.ndarray, obj: np.ndarray, constants: Constants) -> float:
        """The success measure: site distance to its goal position, or joint distance to its goal."""
        if self.task.measure == "site":
            return float(np.linalg.norm(obj - constants.target))
        return float(abs(qpos[self._qpos_adr] - self.task.goal[0]))

    def reading(self, action: np.ndarray) -> Reading:
        """What the reward reads now: the true simulator state (no observation noise) and `action`."""
        g = self._read_geometry(self.data)
        if self._qpos_width == 1:
            direction = np.sign(self.task.goal[0] - self._init_qpos[self._qpos_adr])
            progress = float(
                direction * (self.data.qpos[self._qpos_adr] - self._init_qpos[self._qpos_adr])
            )
        else:
            progress = 0.0  # a free joint has no single coordinate; pick-place does not use it
        return Reading(
            tcp=g["tcp"],
            left_pad=g["left_pad"],
            right_pad=g["right_pad"],
            finger_axis=g["finger_axis"],
            obj=g["obj"],
            distance=self._distance(self.data.qpos, g["obj"], self.constants),
            progress=progress,
            finger_opening=float(g["finger_opening"]),
            effort=grip_effort(action),
        )

    def potential(self) -> float:
        """Reward v4's potential of the current state: -k * |tcp - site| (metres)."""
        g = self._read_geometry(self.data)
        return -POTENTIAL_SCALE * float(np.linalg.norm(g["tcp"] - g["obj"]))

    def evaluate(self, action: np.ndarray) -> tuple[float, dict[str, float]]:
        """Reward and info (with "success") of the current state under `action`, without stepping;
        v4's approach term runs from the potential of the state the last step started from."""
        r = self.reading(np.asarray(action, dtype=np.float64))
        reward, terms = compute_reward(
            self.task.family, r, self.constants, self.reward_version, self._potential, self.gamma
        )
        info = {
            "success": float(r.distance <= self.task.threshold),
            "distance": r.distance,
            **terms,
        }
        return reward, info

    # ----- gymnasium API --------------------------------------------------------------------

    def _flat_obs(self, upstream_obs: dict[str, Any]) -> np.ndarray:
        return np.concatenate(
            [np.asarray(upstream_obs["observation"], dtype=np.float64), self.goal_position]
        )

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Upstream's fixed initial state; `seed` (or the make-time seed) seeds the observation noise."""
        if seed is None and self._pending_seed is not None:
            seed = self._pending_seed
        self._pending_seed = None
        super().reset(seed=seed)
        if seed is not None:
            self.action_space.seed(seed)
        upstream_obs, _ = self.kitchen.reset(seed=seed)
        self._steps = 0
        self._potential = self.potential()  # the first step's Phi(s) is the reset state's
        _, info = self.evaluate(np.zeros(ACT_DIM))
        return self._flat_obs(upstream_obs), info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """One 80 ms upstream step; reward and success of this task only; truncation at episode_length."""
        action = np.asarray(action, dtype=np.float64)
        upstream_obs, _, _, _, _ = self.kitchen.step(action)
        self._steps += 1
        reward, info = self.evaluate(action)
        self._potential = self.potential()
        truncated = self._steps >= self.episode_length
        return self._flat_obs(upstream_obs), reward, False, truncated, info

    def render(self) -> Any:
        """Upstream rendering (pass render_mode at construction)."""
        return self.kitchen.render()

    def close(self) -> None:
        self.kitchen.close()

    # ----- state editing (semantic checks and tests) ----------------------------------------

    def set_task_joint(self, value: np.ndarray | float) -> None:
        """Put the task's joint at `value` (1 or 7 numbers), zero its velocity, and recompute positions."""
        self.data.qpos[self._qpos_adr : self._qpos_adr + self._qpos_width] = np.atleast_1d(value)
        dof = int(self.model.jnt_dofadr[self.model.joint(self.task.joint).id])
        self.data.qvel[dof : dof + (6 if self._qpos_width == 7 else 1)] = 0.0
        self.sync()

    def task_joint(self) -> np.ndarray:
        """The task joint's current qpos (1 or 7 numbers)."""
        return self.data.qpos[self._qpos_adr : self._qpos_adr + self._qpos_width].copy()

    def initial_task_joint(self) -> np.ndarray:
        """The task joint's qpos in upstream's initial state."""
        return self._init_qpos[self._qpos_adr : self._qpos_adr + self._qpos_width].copy()

    def sync(self, previous_potential: float | None = None) -> None:
        """After editing qpos/qvel: recompute derived quantities and point upstream's velocity
        controller at the edited robot pose (it integrates from the last observed qpos). It does
        not hold it: under a zero action the arm sags from there, 34 cm in 50 steps, unless the env
        was made with `gravity_compensation=True` (4 mm; README, "Gravity compensation").

        The next step's Phi(s) (reward v4) becomes the edited state's, so a posed step does not
        pay the jump from the state before the edit; or `previous_potential`, as if the step
        started from a state of that potential and the edit were its own motion (the approach
        cycle: the previous pose's step)."""
        mujoco.mj_forward(self.model, self.data)
        self.kitchen.robot_env._last_robot_qpos = self.data.qpos[:9].copy()
        self._potential = self.potential() if previous_potential is None else previous_potential
