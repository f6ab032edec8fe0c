"""Shared fixtures: keep this file small; fixtures used by one test module live in that module."""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import torch

from seal.envs.point import PointAdapter

_INDUCTOR_CACHE = "TORCHINDUCTOR_CACHE_DIR"
_OWN_CACHE = pytest.StashKey[str]()


def pytest_configure(config: pytest.Config) -> None:
    """One inductor cache for the whole test run (issue 55), unless the caller chose one: the
    compile tests share their kernels, and a cache another run filled (under other kernel caps:
    DEVELOPERS.md, "Things learnt") is never read. Subprocesses inherit it."""
    if _INDUCTOR_CACHE not in os.environ:
        os.environ[_INDUCTOR_CACHE] = tempfile.mkdtemp(prefix="seal-test-inductor-")
        config.stash[_OWN_CACHE] = os.environ[_INDUCTOR_CACHE]


SLOW_TIMEOUT_S = 900
"""pytest-timeout's limit for a slow test (pyproject's `timeout`, 300 s, is the fast tier's): the
slowest, the compiled checkpoint round trip, took 157 s beside two kitchen runs (issue 55)."""


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """A slow test without a timeout of its own gets `SLOW_TIMEOUT_S`."""
    for item in items:
        if item.get_closest_marker("slow") and not item.get_closest_marker("timeout"):
            item.add_marker(pytest.mark.timeout(SLOW_TIMEOUT_S))


def pytest_unconfigure(config: pytest.Config) -> None:
    own = config.stash.get(_OWN_CACHE, None)
    if own is not None:
        shutil.rmtree(own, ignore_errors=True)
        del os.environ[_INDUCTOR_CACHE]


@pytest.fixture(autouse=True)
def _fresh_dynamo_caches() -> Iterator[None]:
    """Each test compiles from empty in-memory dynamo caches. Dynamo allows 8 compilations of one
    function per process, and every compiled agent of the process counts (each brings its own
    inductor backend): a whole slow-tier pass compiled `critic_stage` for 8 agents before
    test_cuda_mode_compiles_wherever_the_cpu_mode_does_and_agrees, which then fell back to eager
    and failed (issue 55, a flake of test order). The inductor cache on disk stays shared."""
    yield
    torch._dynamo.reset()


@pytest.fixture
def point_adapter() -> PointAdapter:
    """The four-task point-mass adapter with its default 50-step episodes: the fast test env."""
    return PointAdapter()


class _RunsCode:
    """Unpickling this calls Path.touch(target): the shape of a shared file that would run a command."""

    def __init__(self, target: Path) -> None:
        self.target = target

    def __reduce__(self) -> tuple[object, tuple[object, ...]]:
        return (Path.touch, (self.target,))


@pytest.fixture
def code_running_checkpoint() -> Callable[[Path, Path], Path]:
    """write(path, target): a seal-looking checkpoint at `path` whose unpickling would create `target`."""

    def write(path: Path, target: Path) -> Path:
        torch.save({"seal_checkpoint": 2, "agent": {"w": _RunsCode(target)}}, path)
        return path

    return write
