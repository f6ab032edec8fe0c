"""Which torch device to run on (`"auto"` picks CUDA when present, else CPU), and with how many CPU threads."""

from __future__ import annotations

import contextlib
import os
import re
from collections.abc import Iterator
from dataclasses import dataclass

import torch

from seal.errors import SealError

DEVICE_NAMES = "auto, cpu, cuda, cuda:<index>"
"""The device names a config may give, as an error lists them."""


def is_device_name(name: object) -> bool:
    """Whether `name` is one of `DEVICE_NAMES` (any case, spaces around allowed); whether this
    machine has that device is `resolve_device`'s question, asked when a run starts."""
    return (
        isinstance(name, str)
        and re.fullmatch(r"auto|cpu|cuda(:\d+)?", name.strip().lower()) is not None
    )


def resolve_device(name: str | torch.device = "auto") -> torch.device:
    """The torch device for a config value: "auto", "cpu", "cuda" or "cuda:<index>".

    Raises SealError for an unknown name or a CUDA device that this machine does not have, so a
    config written on a GPU machine fails before the run starts rather than inside torch.
    """
    if isinstance(name, torch.device):
        name = str(name)
    text = str(name).strip().lower()
    if text == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(text)
    except RuntimeError as exc:
        raise SealError(f"unknown device {name!r}; valid: {DEVICE_NAMES}") from exc
    if device.type == "cpu":
        return torch.device("cpu")
    if device.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        index = 0 if device.index is None else device.index
        if index >= count:
            raise SealError(
                f'device {name!r} requested but this machine has {count} CUDA device(s); use device = "auto" or "cpu"'
            )
        return device
    raise SealError(f"unsupported device {name!r}; valid: {DEVICE_NAMES}")


def apply_matmul_precision(device: torch.device, precision: str) -> None:
    """torch.set_float32_matmul_precision(`precision`) when `device` is CUDA; CPU runs keep
    "highest", since "high" there may mean a bfloat16-based algorithm where the CPU has one."""
    if device.type == "cuda":
        torch.set_float32_matmul_precision(precision)


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


# ---------------------------------------------------------------- threads for the updates

CORES_PER_UPDATE_THREAD = 2
"""Usable cores per intra-op thread "auto" gives the updates: half the cores stay free.

torch's OpenMP threads wait at every op's barrier for the slowest of them, spinning: a thread
whose core another process holds leaves its peer spinning on the core it needs, so a team that
fills every core collapses as soon as anything else runs. On 2 cores beside about one core of
other work, 2 threads ran the quickstart's update 11-17x slower than 1, and MT10-size and
paper-scale updates 2-7x slower (docs/benchmarks.md, "Threads under load"). Half the cores keep
a team on cores of its own beside one other job of its size (a second seed, a sweep's trial)."""

WORK_PER_UPDATE_THREAD = 2e8
"""Parameters x batch (about one forward pass's multiply-adds) per intra-op thread "auto" gives.

At the quickstart's 8.0e7, 4e7 a thread in a team of two, a second thread did not pay on an
AVX-512 EPYC even idle (61.6 updates/s, against 71.6-83.5 for one thread beside other jobs) and
paid 1.14x on an AVX2 one; 2e8 asks five times that share of each thread. Teams on more than 2
cores were not measured (docs/benchmarks.md, "Threads under load")."""


def usable_cores() -> int:
    """The cores this process may run on (`os.sched_getaffinity`: a container's or `taskset`'s
    share, not the machine's count)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


@dataclass(frozen=True)
class ThreadChoice:
    """The intra-op threads the updates run on, and what chose them."""

    threads: int
    """torch intra-op threads for the gradient updates (0: torch's default, untouched)."""
    setting: int | str
    """protocol.threads as configured: "auto", 0 or a number."""
    parameters: int
    """Trainable parameters of the update (actor and critic)."""
    batch: int
    """Transitions per gradient step, over every (env, task)."""
    cores: int
    """Cores the run may use: usable_cores(), or a sweep trial's share."""

    def describe(self) -> str:
        """One line: the number and the rule's inputs."""
        inputs = f"{self.parameters:,} parameters x batch {self.batch:,}, {self.cores} usable cores"
        if self.setting == "auto":
            return (
                f"{self.threads} (auto: {inputs}; one thread per {WORK_PER_UPDATE_THREAD:,.0f} "
                f"of parameters x batch, at most one per {CORES_PER_UPDATE_THREAD} cores)"
            )
        if self.threads == 0:
            return f"torch's default, {torch.get_num_threads()} (protocol.threads = 0; {inputs})"
        plural = "s" if self.cores != 1 else ""
        capped = (
            f", capped at {self.cores} core{plural}" if self.threads < int(self.setting) else ""
        )
        return f"{self.threads} (protocol.threads = {self.setting}{capped}; {inputs})"


def update_threads(parameters: int, batch: int, cores: int) -> int:
    """The "auto" rule: threads for an update of `parameters` x `batch` on `cores` usable cores.

    min(work / WORK_PER_UPDATE_THREAD, cores / CORES_PER_UPDATE_THREAD), rounded down, at least 1.
    """
    by_work = int(parameters * batch // WORK_PER_UPDATE_THREAD)
    by_cores = cores // CORES_PER_UPDATE_THREAD
    return max(1, min(by_work, by_cores))


def choose_threads(
    setting: int | str, parameters: int, batch: int, cores: int | None = None
) -> ThreadChoice:
    """protocol.threads resolved: "auto" by `update_threads`, N capped at `cores`, 0 kept (torch's).

    `cores` defaults to `usable_cores()`; a sweep passes its trial's share.
    """
    cores = usable_cores() if cores is None else max(1, int(cores))
    if setting == "auto":
        threads = update_threads(parameters, batch, cores)
    elif isinstance(setting, int) and not isinstance(setting, bool) and setting >= 0:
        threads = min(setting, cores)
    else:
        raise SealError(f'protocol.threads = {setting!r}: expected "auto" or a whole number >= 0')
    return ThreadChoice(threads, setting, int(parameters), int(batch), cores)
