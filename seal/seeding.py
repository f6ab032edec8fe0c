"""Seeds of named random streams: common random numbers across runs with different env sets.

Every stream is keyed by (seed, labels), the labels naming the environment and the purpose, never
by the set of environments in the run, so a target env's initial weights, exploration noise, update
noise and replay draws are the same alone and in any joint run of the same seed.
"""

from __future__ import annotations

import zlib

import numpy as np
import torch


def derive_seed(*parts: int | str) -> int:
    """A 32-bit seed from a run seed and labels, stable across processes (crc32, not hash())."""
    ints = [p if isinstance(p, int) else zlib.crc32(p.encode()) for p in parts]
    return int(np.random.SeedSequence(ints).generate_state(1, np.uint32)[0])


def stream(*parts: int | str, device: torch.device | str = "cpu") -> torch.Generator:
    """A torch generator on `device` seeded by `derive_seed(*parts)`."""
    return torch.Generator(device).manual_seed(derive_seed(*parts))
