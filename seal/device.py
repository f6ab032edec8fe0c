"""Which torch device to run on (`"auto"` picks CUDA when present, else CPU), and with how many CPU threads."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch

from seal.errors import SealError


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
        raise SealError(f"unknown device {name!r}; valid: auto, cpu, cuda, cuda:<index>") from exc
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
    raise SealError(f"unsupported device {name!r}; valid: auto, cpu, cuda, cuda:<index>")


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
