"""Shared fixtures: keep this file small; fixtures used by one test module live in that module."""

from __future__ import annotations

import pytest

from seal.envs.point import PointAdapter


@pytest.fixture
def point_adapter() -> PointAdapter:
    """The four-task point-mass adapter with its default 50-step episodes: the fast test env."""
    return PointAdapter()
