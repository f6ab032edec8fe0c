"""The kitchens are solvable through `env.step`: each scripted expert, which sees only the
observations that `reset`/`step` return, succeeds from several seeds; and the evidence figures
that `seal envs check` reports are computed as documented.

The experts run through `Opaque`, a wrapper that hides `unwrapped` and every attribute of the
env, so an expert that peeked at the simulator would fail here.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from franka_kitchen_dense import TASK_NAMES
from franka_kitchen_dense.adapter import UNSOLVABLE, FrankaKitchenDenseAdapter
from franka_kitchen_dense.evidence import flat_stretch
from franka_kitchen_dense.experts import policy

from seal.errors import SealWarning

SOLVABLE = [t for t in TASK_NAMES if t not in UNSOLVABLE]
SEEDS = (0, 1, 2)


class Opaque:
    """Only reset() and step(); no unwrapped, model, data or attribute forwarding."""

    def __init__(self, env: gym.Env) -> None:
        self._reset, self._step = env.reset, env.step

    def reset(self, seed: int) -> tuple[np.ndarray, dict[str, Any]]:
        return self._reset(seed=seed)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        return self._step(action)


def test_opaque_hides_the_simulator() -> None:
    env = Opaque(FrankaKitchenDenseAdapter(tasks=["microwave"]).make("microwave", 0))
    for name in ("unwrapped", "env", "model", "data", "kitchen"):
        assert not hasattr(env, name)


def _first_success(env: Opaque, task: str, seed: int, episode_length: int) -> int | None:
    """Steps until the expert's first success from `reset(seed=seed)`, or None within the episode."""
    obs, _ = env.reset(seed=seed)
    for t in range(episode_length):
        obs, _, _, _, info = env.step(policy(obs, task))
        if info["success"] == 1.0:
            return t + 1
    return None


@pytest.mark.parametrize("task", SOLVABLE)
def test_expert_solves_its_task_from_three_seeds(task: str) -> None:
    adapter = FrankaKitchenDenseAdapter(tasks=[task])
    raw = adapter.make(
        task, SEEDS[0]
    )  # one env, reset with each seed (a kitchen takes ~0.5 s to build)
    env = Opaque(raw)
    steps = [_first_success(env, task, seed, adapter.episode_length) for seed in SEEDS]
    raw.close()
    assert all(s is not None for s in steps), f"{task}: first success per seed {steps}"


def test_left_hinge_door_is_declared_unsolvable_only() -> None:
    assert UNSOLVABLE == ("left-hinge-door",)


# ---- evidence figures ---------------------------------------------------------------------------


def test_flat_stretch_by_hand() -> None:
    # rewards 1.00, 1.05, 1.08, 2.0, 2.05 after steps 0..4; distances at reset, then after steps
    # 0..4: 0.40, 0.38, 0.30, 0.25, 0.24, 0.10. Steps 0-2 stay within a 0.1 band (1.00..1.08) over
    # the states after them, distances 0.38, 0.30, 0.25: 0.13 of progress; steps 3-4 (2.0..2.05)
    # over 0.24, 0.10: 0.14. Travel 0.40 - 0.05 = 0.35 -> 0.14 / 0.35 = 0.4
    rewards = [1.00, 1.05, 1.08, 2.0, 2.05]
    distances = [0.40, 0.38, 0.30, 0.25, 0.24, 0.10]
    assert flat_stretch(rewards, distances, 0.35) == pytest.approx(0.4, abs=1e-9)
    # a reward that rises by 0.2 every step has no flat stretch: a single state spans no progress
    assert flat_stretch([1.0, 1.2, 1.4, 1.6, 1.8], distances, 0.35) == 0.0


def test_reward_along_the_slide_experts_trajectory() -> None:
    """Seed 0 of the slide-cabinet expert, through an Opaque env, at three hand-picked steps.

    Steps 58 and 60: the gripper holds the handle (2 mm from its site, fingers on it, closing):
    caging 1 and gripping 1, so grasped g = 1, and reward v3's push is 10 H(g, in_place) =
    10 LT(d, 0.05, travel) with travel = d0 - 0.05 = 0.320466 (test_kitchen.py):
      step 58, d 0.26270: (0.2127 / 0.320466) * 3 = 1.991163 -> 1 / (1.991163^2 + 1) = 0.201424
        -> 2.0142
      step 60, d 0.24013: (0.19013 / 0.320466) * 3 = 1.779877 -> 0.239925 -> 2.3993
    Step 77: the handle within 5 cm of its goal (d 0.04733): success, 10.
    """
    with pytest.warns(SealWarning, match="older reward than the default"):  # v3 is not the default
        adapter = FrankaKitchenDenseAdapter(tasks=["slide-cabinet"], reward_version="v3")
    env = adapter.make("slide-cabinet", 0)
    opaque = Opaque(env)
    obs, _ = opaque.reset(seed=0)
    rewards, distances, successes = {}, {}, {}
    for t in range(1, 78):
        obs, reward, _, _, info = opaque.step(policy(obs, "slide-cabinet"))
        rewards[t], distances[t], successes[t] = reward, info["distance"], info["success"]
    env.close()
    assert distances[58] == pytest.approx(0.26270, abs=1e-4)
    assert rewards[58] == pytest.approx(2.0142, abs=1e-3)
    assert distances[60] == pytest.approx(0.24013, abs=1e-4)
    assert rewards[60] == pytest.approx(2.3993, abs=1e-3)
    assert successes[76] == 0.0 and successes[77] == 1.0 and rewards[77] == 10.0
