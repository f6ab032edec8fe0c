"""Timing and load helpers every `seal bench` figure is measured with.

`_timeit` takes the best of several wall-time runs (the least-disturbed one on a shared machine),
`torch_threads` pins torch's intra-op threads for a measurement, and `machine_load` records the
load averages, CPU count and torch threads that are stored next to every figure.
"""

from __future__ import annotations

import contextlib
import math
import os
import time
from collections.abc import Callable, Iterator
from typing import TypedDict

import torch


def _timeit(fn: Callable[[], object], repeats: int) -> float:
    """Best-of-`repeats` wall time of fn(): the least-disturbed run on a shared machine."""
    best = math.inf
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


@contextlib.contextmanager
def torch_threads(n: int | None) -> Iterator[None]:
    """Run with `n` torch intra-op threads (None: unchanged), restoring the previous count."""
    before = torch.get_num_threads()
    if n is not None:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(before)


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
