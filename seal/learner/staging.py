"""Compile staging: each update stage run eager or torch.compiled, CUDA graphs on CUDA.

A stage (`seal.learner.update.critic_stage`, `actor_stage`) computes its losses and their
gradients as one function of pre-drawn policy noise, so compiling it puts forward, backward and
gradient clipping in one graph, as LeanRL compiles CleanRL's update; the optimiser steps stay
eager. On CUDA each compiled stage is replayed as a CUDA graph (`compile_mode`).
"""

from __future__ import annotations

import os
import re
import time
import warnings
from collections.abc import Callable, Hashable, Sequence
from typing import TypeVar, cast

import torch

R = TypeVar("R")


def compile_mode(device: torch.device) -> str | None:
    """torch.compile's mode for the update stages: on CUDA "reduce-overhead", which replays each
    compiled stage as a CUDA graph (one launch for its forward and backward kernels); elsewhere
    the default, since CPU has no graphs. Measured on an H200: docs/benchmarks.md."""
    return "reduce-overhead" if device.type == "cuda" else None


KERNEL_CAPS = ("ATEN_CPU_CAPABILITY", "DNNL_MAX_CPU_ISA", "MKL_ENABLE_INSTRUCTIONS")
"""Environment variables that cap the CPU kernels torch and its libraries pick."""


def isolate_inductor_cache() -> None:
    """Give compiled code made under capped CPU kernels its own inductor cache directory.

    torch 2.13's FX graph cache key omits these caps, so code compiled under one cap is loaded
    under another and crashes (measured: `ATEN_CPU_CAPABILITY=avx2 MKL_ENABLE_INSTRUCTIONS=AVX2
    DNNL_MAX_CPU_ISA=AVX2` reading a native run's cache segfaults, and a native run reading the
    capped cache aborts). With a cap set and no TORCHINDUCTOR_CACHE_DIR of the user's (torch
    writes its default there once it has used it), the cache goes to the default directory
    suffixed with the caps; otherwise nothing changes.
    """
    from torch._inductor.runtime.cache_dir_utils import default_cache_dir

    caps = [f"{k}={os.environ[k]}" for k in KERNEL_CAPS if os.environ.get(k)]
    chosen = os.environ.get("TORCHINDUCTOR_CACHE_DIR")
    if not caps or (chosen and os.path.abspath(chosen) != os.path.abspath(default_cache_dir())):
        return
    suffix = re.sub(r"[^A-Za-z0-9_.=-]", "_", "-".join(caps))
    os.environ["TORCHINDUCTOR_CACHE_DIR"] = f"{default_cache_dir()}-{suffix}"


class Stages:
    """The update's stages by name, eager or compiled (`compile`), with a permanent eager fallback.

    torch.compile fails lazily (no C++ compiler, unsupported op or torch version): the first
    failure warns once and switches every stage to eager for good; a real error then re-raises
    from eager. A stage has no side effects (its noise is drawn before), so a failed compiled
    call is simply run again eagerly. A call that compiles adds its seconds to `compile_seconds`.
    A deep copy (the ratio lever's clones) runs eager.
    """

    def __init__(self, stages: Sequence[Callable[..., object]]) -> None:
        self.eager = tuple(stages)
        self._compiled: dict[Callable[..., object], Callable[..., object]] = {}
        self._keys: set[Hashable] = set()
        self.compile_seconds = 0.0
        """Wall seconds of the compiled stage calls that compiled; 0 when eager."""

    def compile(self, device: torch.device) -> None:
        """torch.compile every stage (compilation itself happens at the first call of a key)."""
        isolate_inductor_cache()
        # The run chose its float32 matmul precision (protocol.matmul_precision): no advice needed.
        warnings.filterwarnings("ignore", "TensorFloat32 tensor cores", UserWarning)
        mode = compile_mode(device)
        self._compiled = {
            fn: torch.compile(fn, fullgraph=True, dynamic=False, mode=mode) for fn in self.eager
        }

    @property
    def compiled(self) -> bool:
        """Whether stages run compiled (compile was asked for and has not failed)."""
        return bool(self._compiled)

    def forget_keys(self) -> None:
        """New parameters or optimiser states may fail the compiled guards: trace again."""
        self._keys = set()

    def run(self, stage: Callable[..., R], key: Hashable, *args: object) -> R:
        """`stage` (one of this object's) on `args`; `key` names what its compiled graph is
        specialised to."""
        compiled = self._compiled.get(stage)
        if compiled is not None:
            key = (stage.__name__, key)
            start = time.perf_counter()
            try:
                if key in self._keys:
                    out = cast(R, compiled(*args))  # compiled for this key: no tracing, no patch
                else:
                    # Tracing autograd.grad needs this flag; patching costs ~50 us, so only here.
                    with torch._dynamo.config.patch(trace_autograd_ops=True):
                        out = cast(R, compiled(*args))
            except Exception as exc:  # any compiler failure means: run eager
                warnings.warn(
                    f"torch.compile failed ({type(exc).__name__}: {exc}); running eager",
                    stacklevel=4,
                )
                self._compiled = {}
            else:
                if key not in self._keys:
                    self._keys.add(key)
                    self.compile_seconds += time.perf_counter() - start
                return out
        return stage(*args)

    def __deepcopy__(self, memo: dict[int, object]) -> Stages:
        return Stages(self.eager)


def mark_step(compiled: bool, device: torch.device) -> None:
    """Before an update's compiled stages on CUDA: a stage's outputs live until the next update
    replays it (cudagraph trees); every one is consumed within its update (steps, stacked scalars)."""
    if compiled and device.type == "cuda":
        torch.compiler.cudagraph_mark_step_begin()
