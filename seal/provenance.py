"""Where a result came from: git commit, package versions, device and command line.

Every run directory's `provenance.json` is built from these helpers, so a number in a table can be
traced to the code and libraries that produced it.
"""

from __future__ import annotations

import datetime as _dt
import importlib.metadata
import os
import subprocess
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

# The libraries whose versions change results; others are recorded only if asked for.
TRACKED_PACKAGES: tuple[str, ...] = (
    "seal",
    "torch",
    "numpy",
    "gymnasium",
    "gymnasium-robotics",
    "metaworld",
    "mujoco",
    "pandas",
    "scipy",
)


def git_sha(path: str | Path | None = None) -> str | None:
    """The commit of the git work tree holding `path` (default: the seal package), "+dirty" if modified.

    Returns None outside a git checkout (e.g. an installed wheel), never raises.
    """
    where = Path(path) if path is not None else Path(__file__).resolve().parent
    try:
        sha = subprocess.run(
            ["git", "-C", str(where), "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            timeout=10,
        )
        if sha.returncode != 0:
            return None
        dirty = subprocess.run(
            ["git", "-C", str(where), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=10,
        )
        return sha.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return None


def package_versions(names: tuple[str, ...] = TRACKED_PACKAGES) -> dict[str, str | None]:
    """Installed version of each named distribution (None when it is not installed)."""
    out: dict[str, str | None] = {"python": sys.version.split()[0]}
    for name in names:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = None
    return out


def reward_versions(envs: Iterable[Any] = ()) -> dict[str, str]:
    """Reward version of each installed environment package whose rewards are versioned (the
    dense kitchens': the suffix of their gymnasium ids). `envs`: a run's env configs; a kitchen
    env's `options.reward_version` is the version it runs (several joined by "+"); without one,
    the package's default `REWARD_VERSION`."""
    out: dict[str, str] = {}
    try:
        from franka_kitchen_dense import REWARD_VERSION
    except ImportError:
        return out
    used = {
        str(env.options.get("reward_version", REWARD_VERSION))
        for env in envs
        if env.adapter == "franka_kitchen_dense"
    }
    out["franka_kitchen_dense"] = "+".join(sorted(used)) or REWARD_VERSION
    return out


def resolve_device(device: str = "auto") -> str:
    """The device name a config value resolves to ("auto" -> "cuda" if present, else "cpu"); SealError if absent."""
    from seal.device import resolve_device as _resolve

    return str(_resolve(device))


def device_description(device: str) -> str:
    """A human-readable name of the device, e.g. "cpu (2 threads)" or "cuda:0 (NVIDIA A100)"."""
    import torch

    if device.startswith("cuda") and torch.cuda.is_available():
        index = torch.device(device).index or 0
        return f"{device} ({torch.cuda.get_device_name(index)})"
    return f"{device} ({torch.get_num_threads()} threads)"


def cpu_model() -> str:
    """The CPU's model name (/proc/cpuinfo on Linux), else what `platform` knows: a seed's outcome
    holds on one CPU, so every run records the one it ran on."""
    import platform

    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        for line in cpuinfo.read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine()


def utc_now() -> str:
    """The current UTC time as an ISO-8601 string with seconds."""
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")


def collect(
    command: list[str] | None = None, device: str = "auto", envs: Iterable[Any] = (), **extra: Any
) -> dict[str, Any]:
    """The provenance record: git SHA, package and reward versions (of `envs`, a run's env
    configs), command line, device, plus `extra`."""
    resolved = resolve_device(device)
    return {
        "git_sha": git_sha(),
        "packages": package_versions(),
        "reward_versions": reward_versions(envs),
        "command": " ".join(command if command is not None else sys.argv),
        "device": resolved,
        "device_name": device_description(resolved),
        "cpu": f"{cpu_model()}, {os.cpu_count()} CPUs",
        **extra,
    }
