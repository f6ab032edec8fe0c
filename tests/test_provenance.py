"""Provenance records the kitchens' reward version, the same one their gymnasium ids carry."""

from __future__ import annotations

import os
import platform
import re
from pathlib import Path

from franka_kitchen_dense import gym_id

from seal.protocols.config import EnvConfig
from seal.provenance import collect, cpu_model, reward_versions


def test_reward_version_is_recorded_and_matches_the_gym_ids() -> None:
    assert reward_versions() == {"franka_kitchen_dense": "v4"}
    assert gym_id("kettle") == "seal/FrankaKitchenDense-kettle-v4"
    record = collect(command=["seal", "run"], device="cpu")
    assert record["cpu"] == f"{cpu_model()}, {os.cpu_count()} CPUs"
    cpuinfo = Path("/proc/cpuinfo")  # on Linux (CI), the model name the kernel reports
    text = cpuinfo.read_text() if cpuinfo.exists() else ""
    name = re.search(r"^model name\s*:\s*(.+?)\s*$", text, re.M)
    assert cpu_model() == (name.group(1) if name else platform.processor() or platform.machine())
    assert record["reward_versions"] == {"franka_kitchen_dense": "v4"}


def test_a_runs_reward_version_option_is_recorded() -> None:
    v2 = EnvConfig(
        adapter="franka_kitchen_dense", tasks=["kettle"], options={"reward_version": "v2"}
    )
    assert reward_versions([v2]) == {"franka_kitchen_dense": "v2"}
    default = EnvConfig(adapter="franka_kitchen_dense", tasks=["kettle"])
    assert reward_versions([v2, default]) == {"franka_kitchen_dense": "v2+v4"}
    record = collect(command=["seal", "run"], device="cpu", envs=[v2])
    assert record["reward_versions"] == {"franka_kitchen_dense": "v2"}
