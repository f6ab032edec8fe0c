"""Shared fixtures: keep this file small; fixtures used by one test module live in that module."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest
import torch

from seal.envs.point import PointAdapter


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
