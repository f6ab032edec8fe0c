"""Provenance records the kitchens' reward version, the same one their gymnasium ids carry."""

from __future__ import annotations

from franka_kitchen_dense import gym_id

from seal.provenance import collect, reward_versions


def test_reward_version_is_recorded_and_matches_the_gym_ids() -> None:
    assert reward_versions() == {"franka_kitchen_dense": "v2"}
    assert gym_id("kettle") == "seal/FrankaKitchenDense-kettle-v2"
    record = collect(command=["seal", "run"], device="cpu")
    assert record["reward_versions"] == {"franka_kitchen_dense": "v2"}
