"""The task table of the ten dense single-task kitchens (SEAL Table 2 and issue 2's success table).

Each task names the kitchen joint that it moves, the joint's goal value, how success is measured
(distance of a site that moves with the object to the site's position at the goal, or the joint's
own distance to its goal), the success threshold, and which Meta-World v2 reward family it uses.
This module imports nothing heavy, so `import franka_kitchen_dense` stays fast.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

Family = Literal["door-open", "sweep", "dial-turn", "push", "pick-place"]
Measure = Literal["site", "joint"]

# Upstream KitchenEnv goal pose of the kettle's free joint: position (x, y, z) and quaternion
# (w, x, y, z), gymnasium_robotics.envs.franka_kitchen.kitchen_env.OBS_ELEMENT_GOALS["kettle"].
KETTLE_GOAL_QPOS = (-0.23, 0.75, 1.62, 0.99, 0.0, 0.0, -0.06)

SITE_THRESHOLD = 0.05  # metres: the SEAL paper's "within 5 cm" (Appendix C)
JOINT_THRESHOLD = 0.3  # upstream BONUS_THRESH, in the joint's own units (rad)


@dataclass(frozen=True)
class KitchenTask:
    """One dense kitchen task: the joint it moves, its goal, and how success and reward read it."""

    name: str
    joint: str
    """Kitchen joint moved by the task (MuJoCo joint name)."""
    goal: tuple[float, ...]
    """Goal qpos of `joint` (one value, or 7 for the kettle's free joint)."""
    site: str
    """Site the reward reaches for (handle, switch, knob or kettle handle); its goal position is the observation's goal."""
    measure: Measure
    """"site": success is `site`'s distance to its goal position; "joint": the joint's distance to `goal`."""
    threshold: float
    """Success when the measured distance is <= this (metres for "site", rad for "joint")."""
    family: Family
    """Meta-World v2 reward family (SEAL Table 2)."""
    approach: tuple[float, float, float]
    """World direction the gripper approaches along, at the initial configuration (turns with `site`'s body)."""
    fingers: tuple[float, float, float]
    """World direction the fingers close along, at the initial configuration (turns with `site`'s body)."""
    obj_radius: float | None = None
    """Caging terms' object radius; None: measured from the handle's geom (push, pick-place; `env.py`)."""

    @property
    def goal_array(self) -> np.ndarray:
        """`goal` as a float array."""
        return np.asarray(self.goal, dtype=np.float64)


_Y = (0.0, 1.0, 0.0)
_X = (1.0, 0.0, 0.0)
_DOWN = (0.0, 0.0, -1.0)

# Approach/finger directions: handles are vertical bars, taken from the front (+y) with the fingers
# closing horizontally; the microwave door starts turned 17 degrees, so its directions follow the
# door panel; the light-switch lever points at the robot (taken along the lever); the kettle
# handle is a horizontal bar along x, taken from above; the knob blades are vertical.
_MICRO_IN = (-0.297, 0.955, 0.0)
_MICRO_ALONG = (0.955, 0.297, 0.0)
_LEVER = (-0.39, 0.921, 0.0)
_LEVER_ACROSS = (0.921, 0.39, 0.0)

# fmt: off
_ROWS = (
    # name                 joint                  goal               site                measure  threshold        family        approach   fingers
    ("microwave",           "microwave",           (-0.75,),          "microhandle_site", "site",  SITE_THRESHOLD,  "door-open",  _MICRO_IN, _MICRO_ALONG),
    ("right-hinge-door",    "right_hinge_cabinet", (1.45,),           "hinge_site2",      "site",  SITE_THRESHOLD,  "door-open",  _Y,        _X),
    ("left-hinge-door",     "left_hinge_cabinet",  (-1.45,),          "hinge_site1",      "site",  SITE_THRESHOLD,  "door-open",  _Y,        _X),
    ("light-switch",        "light_switch",        (-0.69,),          "light_site",       "joint", JOINT_THRESHOLD, "sweep",      _LEVER,    _LEVER_ACROSS),
    ("top-right-burner",    "knob_Joint_3",        (-0.92,),          "knob3_site",       "joint", JOINT_THRESHOLD, "dial-turn",  _Y,        _X),
    ("top-left-burner",     "knob_Joint_4",        (-0.92,),          "knob4_site",       "joint", JOINT_THRESHOLD, "dial-turn",  _Y,        _X),
    ("bottom-right-burner", "knob_Joint_1",        (-0.88,),          "knob1_site",       "joint", JOINT_THRESHOLD, "dial-turn",  _Y,        _X),
    ("bottom-left-burner",  "knob_Joint_2",        (-0.88,),          "knob2_site",       "joint", JOINT_THRESHOLD, "dial-turn",  _Y,        _X),
    ("slide-cabinet",       "slide_cabinet",       (0.37,),           "slide_site",       "site",  SITE_THRESHOLD,  "push",       _Y,        _X),
    ("kettle",              "kettle",              KETTLE_GOAL_QPOS,  "kettle_site",      "site",  SITE_THRESHOLD,  "pick-place", _DOWN,     _Y),
)
# fmt: on
# The light-switch lever has a 0.021 m radius: Meta-World sweep's own 0.02 object radius is kept.
# Push and pick-place read theirs from the handle's geom (see env.FrankaKitchenDenseEnv); door-open
# and dial-turn have no caging term.
_RADIUS = {"light-switch": 0.02}

TASKS: dict[str, KitchenTask] = {
    row[0]: KitchenTask(*row, obj_radius=_RADIUS.get(row[0]))  # type: ignore[arg-type]
    for row in _ROWS
}

TASK_NAMES: tuple[str, ...] = tuple(TASKS)
DEFAULT_EPISODE_LENGTH = 280  # upstream FrankaKitchen-v1 max_episode_steps


# Bumped whenever a reward changes, with the gymnasium ids' version; recorded in run provenance.
# v0: Meta-World's push / pick-place object radius 0.015 and 2 cm "near" gate;
# v1: both from the measured handle geometry (see README, "Departures from Meta-World's constants");
# v2: dial-turn (burners) pays reach with open fingers: (reach + H(reach, closed)) / 2, not H(reach, closed);
# v3: dial-turn gains a success override; dial-turn's reach and sweep's caging margins are the
#     distance to the nearest other task's site (not the initial distance); sweep's in_place
#     margin is its travel (initial distance - threshold), so the start pays the tail 0.1.
# v4: v3 plus a potential-based approach term F = gamma * Phi(s') - Phi(s), Phi = -k * |tcp - site|,
#     added after the success override and the [0, 10] clip (the default since issue 54's rule 4,
#     with critic LayerNorm, on its records; issue 37's rule had chosen v3 with the plain critic).
REWARD_VERSIONS: tuple[str, ...] = ("v2", "v3", "v4")
"""Reward versions this package still builds (each has its gymnasium ids), oldest first."""
REWARD_VERSION = "v4"
"""The default, named explicitly: v4, which the rule written before the runs chose over v3 on the
committed records with the default learner (README, "Which reward is the default")."""
SHAPED_VERSIONS: tuple[str, ...] = ("v4",)
"""Versions whose reward adds the potential-based approach term (`rewards.approach_shaping`)."""


def newer_than_default(version: str) -> bool:
    """Whether reward `version` is newer than the default (a candidate: its own id name, its own warning)."""
    return REWARD_VERSIONS.index(version) > REWARD_VERSIONS.index(REWARD_VERSION)


def gym_id(task: str, version: str = REWARD_VERSION) -> str:
    """The gymnasium id registered for `task` under reward `version`, e.g. "seal/FrankaKitchenDense-kettle-v4".

    A version newer than the default is registered under its own name,
    "seal/FrankaKitchenDenseCandidate-<task>-<version>": gymnasium calls an id "out of date" when a
    higher "-v<N>" of the same name exists, which would otherwise hit every `gym.make` of the default.
    """
    return f"seal/FrankaKitchenDense{'Candidate' if newer_than_default(version) else ''}-{task}-{version}"
