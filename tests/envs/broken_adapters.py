"""Deliberately broken kitchen adapters: `seal envs check` must fail each of them.

Each subclass of the real `FrankaKitchenDenseAdapter` wraps the env it makes in one lie, and
keeps everything else (spaces, seeding, the semantic check) intact, so the check that fails is
the one about the lie. tests/envs/test_check.py loads this file by path and checks each class.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from franka_kitchen_dense.adapter import FrankaKitchenDenseAdapter
from metaworld.utils.reward_utils import tolerance


class _AlwaysSuccess(gym.Wrapper):
    """Reports success on every reset and step, whatever the kitchen's state."""

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        return obs, {**info, "success": 1.0}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, terminated, truncated, {**info, "success": 1.0}


class _ObjectBlindReward(gym.Wrapper):
    """Rewards only keeping the gripper at the object's *initial* position, closed: the object's
    state never enters the reward, so moving the object towards its goal earns nothing."""

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        obs, _, terminated, truncated, info = self.env.step(action)
        raw = self.env.unwrapped
        near = float(np.linalg.norm(raw.reading(action).tcp - raw.constants.obj_init))
        reward = 10.0 * float(tolerance(near, bounds=(0.0, 0.05), margin=0.5, sigmoid="long_tail"))
        return obs, reward, terminated, truncated, info


class AlwaysSuccessKitchen(FrankaKitchenDenseAdapter):
    """info["success"] is always 1: fails "success == 0 at reset"."""

    name = "broken_always_success_kitchen"

    def make(self, task: str, seed: int) -> gym.Env:
        return _AlwaysSuccess(super().make(task, seed))


class ObjectBlindKitchen(FrankaKitchenDenseAdapter):
    """The reward ignores the object: fails "reward >= 9 at the goal" and "reward rises"."""

    name = "broken_object_blind_kitchen"

    def make(self, task: str, seed: int) -> gym.Env:
        return _ObjectBlindReward(super().make(task, seed))


class _HoverPayingReward(gym.Wrapper):
    """The kitchen's own reward plus 5 while the gripper is within 5 cm of the task's handle and
    the object is untouched (its distance within 1% of the initial one): hovering pays. The reward
    still rises along the posed path to the goal (Spearman >= 0.9), so only the exploit check
    catches it."""

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        raw = self.env.unwrapped
        reading = raw.reading(action)
        near = float(np.linalg.norm(reading.tcp - reading.obj)) < 0.05
        if near and reading.distance >= 0.99 * raw.constants.distance_init:
            reward += 5.0
        return obs, reward, terminated, truncated, info


class HoverPayingKitchen(FrankaKitchenDenseAdapter):
    """The reward pays for hovering at the handle: fails the exploit check (exploit_ratio > 0.5)."""

    name = "broken_hover_paying_kitchen"

    def make(self, task: str, seed: int) -> gym.Env:
        return _HoverPayingReward(super().make(task, seed))


class _ClippedApproachReward(gym.Wrapper):
    """Reward v4 with the approach term inside the [0, 10] clip, where the issue warns it must not
    go: the clip eats the negative F of backing off wherever v3's reward is small, so an
    approach-and-retreat cycle pays. Every posed check, the expert and the exploit ratio pass;
    only the approach cycle earns more than parking."""

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, float(np.clip(reward, 0.0, 10.0)), terminated, truncated, info


class ApproachPayingKitchen(FrankaKitchenDenseAdapter):
    """Reward v4 with F clipped with v3's reward, so backing off is not charged: fails the
    approach-cycle check."""

    name = "broken_approach_paying_kitchen"
    # The kettle, where v3 pays ~0.13 per step near the handle, so the clip eats the retreat's F;
    # near a burner knob v3 pays enough that it eats little (cycle 270 against parking 280).
    all_tasks = ("kettle",)

    def __init__(self, *args: Any, **options: Any) -> None:
        super().__init__(*args, **{"reward_version": "v4", **options})

    def make(self, task: str, seed: int) -> gym.Env:
        return _ClippedApproachReward(super().make(task, seed))
