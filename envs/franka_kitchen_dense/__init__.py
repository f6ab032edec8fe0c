"""Ten dense single-task Franka kitchens (SEAL Table 2), as gymnasium envs and a SEAL adapter.

Importing the package registers `seal/FrankaKitchenDense-<task>-<version>` for every task and every
reward version still built (`REWARD_VERSIONS`: v2, v3, v4; v4, the newest, is the default,
`gym_id`); the heavy
modules (gymnasium-robotics, MuJoCo) load only when an env is made.
"""

from __future__ import annotations

import gymnasium as gym

from franka_kitchen_dense.tasks import (
    DEFAULT_EPISODE_LENGTH,
    REWARD_VERSION,
    REWARD_VERSIONS,
    TASK_NAMES,
    TASKS,
    KitchenTask,
    gym_id,
)

__all__ = [
    "DEFAULT_EPISODE_LENGTH",
    "REWARD_VERSION",
    "REWARD_VERSIONS",
    "TASKS",
    "TASK_NAMES",
    "KitchenTask",
    "gym_id",
    "register_envs",
]


def register_envs() -> None:
    """Register every task's gymnasium id under every reward version (idempotent). The env
    truncates itself at `episode_length`."""
    for version in REWARD_VERSIONS:
        for task in TASK_NAMES:
            if gym_id(task, version) not in gym.registry:
                gym.register(
                    id=gym_id(task, version),
                    entry_point="franka_kitchen_dense.env:FrankaKitchenDenseEnv",
                    kwargs={"task": task, "reward_version": version},
                )


register_envs()
