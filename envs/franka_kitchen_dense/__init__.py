"""Ten dense single-task Franka kitchens (SEAL Table 2), as gymnasium envs and a SEAL adapter.

Importing the package registers `seal/FrankaKitchenDense-<task>-v2` for every task; the heavy
modules (gymnasium-robotics, MuJoCo) load only when an env is made.
"""

from __future__ import annotations

import gymnasium as gym

from franka_kitchen_dense.tasks import (
    DEFAULT_EPISODE_LENGTH,
    REWARD_VERSION,
    TASK_NAMES,
    TASKS,
    KitchenTask,
    gym_id,
)

__all__ = [
    "DEFAULT_EPISODE_LENGTH",
    "REWARD_VERSION",
    "TASKS",
    "TASK_NAMES",
    "KitchenTask",
    "gym_id",
    "register_envs",
]


def register_envs() -> None:
    """Register every task's gymnasium id (idempotent). The env truncates itself at `episode_length`."""
    for task in TASK_NAMES:
        if gym_id(task) not in gym.registry:
            gym.register(
                id=gym_id(task),
                entry_point="franka_kitchen_dense.env:FrankaKitchenDenseEnv",
                kwargs={"task": task},
            )


register_envs()
