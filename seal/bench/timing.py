"""Timing and load helpers every `seal bench` figure is measured with.

`_timeit` takes the best of several wall-time runs (the least-disturbed one on a shared machine),
and `machine_load` records the
load averages, CPU count and torch threads that are stored next to every figure.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Mapping
from typing import Any, TypedDict

import torch


def _timeit(fn: Callable[[], object], repeats: int) -> float:
    """Best-of-`repeats` wall time of fn(): the least-disturbed run on a shared machine."""
    best = math.inf
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def best_interleaved(
    runs: Mapping[str, Callable[[], object]], repeats: int, per: int = 1
) -> dict[str, float]:
    """Each run's best-of-`repeats` wall time / `per`, the runs timed in turn within each repeat
    so that machine load falls on all of them alike."""
    best = dict.fromkeys(runs, math.inf)
    for _ in range(repeats):
        for name, fn in runs.items():
            best[name] = min(best[name], _timeit(fn, 1) / per)
    return best


def updates_of(agent: Any, batches: object, updates: int) -> Callable[[], None]:
    """A callable that makes `updates` updates of `agent` on the same `batches`: what the update
    benches time with `best_interleaved`."""

    def run() -> None:
        for _ in range(updates):
            agent.update(batches)

    return run


class MachineLoad(TypedDict):
    """`machine_load`'s record."""

    loadavg_1m: float
    loadavg_5m: float
    loadavg_15m: float
    cpus: int | None
    torch_threads: int


def machine_load() -> MachineLoad:
    """Load averages and CPU count, recorded next to every figure."""
    one, five, fifteen = os.getloadavg()
    return {
        "loadavg_1m": round(one, 2),
        "loadavg_5m": round(five, 2),
        "loadavg_15m": round(fifteen, 2),
        "cpus": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
    }
