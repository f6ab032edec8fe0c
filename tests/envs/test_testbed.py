"""The transfer testbed's envs: `point_view` is `point` behind fixed maps, `point_diagonal` is `point` on diagonals."""

from __future__ import annotations

import numpy as np
import pytest

from seal.envs import make_adapter
from seal.envs.alignment import Alignment
from seal.envs.point import PointAdapter
from seal.envs.testbed import (
    TESTBED_TABLE,
    VIEW_MATRIX,
    PointDiagonalAdapter,
    PointViewAdapter,
    point_action,
    view_action,
)
from seal.errors import UnknownNameError


def test_built_in_names_and_spaces() -> None:
    view, diagonal = make_adapter("point_view"), make_adapter("point_diagonal")
    assert isinstance(view, PointViewAdapter) and isinstance(diagonal, PointDiagonalAdapter)
    assert (view.obs_dim, view.act_dim, view.tasks) == (6, 5, ("t0", "t1", "t2", "t3"))
    assert (diagonal.obs_dim, diagonal.act_dim) == (4, 2)
    assert diagonal.tasks == ("northeast", "northwest", "southwest", "southeast")


def test_view_matrix_keeps_all_information() -> None:
    # Orthonormal columns to 3 decimals: W^T W = I within rounding, so the map is invertible.
    np.testing.assert_allclose(VIEW_MATRIX.T @ VIEW_MATRIX, np.eye(4), atol=3e-3)


def test_view_is_point_through_the_maps() -> None:
    # t1 is paired with east (goal (1, 0)). Action entry 3 moves x, entry 1 moves -y; 0, 2, 4 are ignored.
    assert point_action(np.array([0.7, 0.5, -0.3, 1.0, 0.9])).tolist() == [1.0, -0.5]
    view = PointViewAdapter().make("t1", seed=3)
    point = PointAdapter().make("east", seed=3)
    obs_v, _ = view.reset(seed=3)
    obs_p, _ = point.reset(seed=3)
    np.testing.assert_allclose(obs_v, VIEW_MATRIX @ obs_p)
    # Entries 3 and 1 of this action make point's move (1.0, -(-0.5)) = (1.0, 0.5); 0, 2, 4 are noise.
    action = np.array([0.9, -0.5, 0.2, 1.0, -0.9], dtype=np.float32)
    out_v = view.step(action)
    out_p = point.step(np.array([1.0, 0.5], dtype=np.float32))
    np.testing.assert_allclose(out_v[0], VIEW_MATRIX @ out_p[0])
    assert out_v[1:4] == out_p[1:4]
    assert out_v[4]["success"] == out_p[4]["success"]
    assert view.observation_space.contains(out_v[0])


def test_view_action_inverts_point_action() -> None:
    move = np.array([[0.25, -1.0], [-0.5, 0.75]], dtype=np.float32)
    np.testing.assert_array_equal(point_action(view_action(move)), move)
    np.testing.assert_array_equal(view_action(move)[:, [0, 2, 4]], 0.0)


def test_tasks_share_goals_through_the_table() -> None:
    for key, point_task in TESTBED_TABLE.items():
        task = key.split(":")[1]
        goal = PointViewAdapter().make(task, seed=0).inner.goal
        np.testing.assert_array_equal(goal, PointAdapter().make(point_task, seed=0).goal)
    # The diagonal goals lie at radius 1, 45 degrees from point's: (1/sqrt 2, 1/sqrt 2) for northeast.
    goal = PointDiagonalAdapter().make("northeast", seed=0).goal
    np.testing.assert_allclose(goal, [0.7071067811865476, 0.7071067811865476])


def test_alignment_pairs_the_tasks() -> None:
    alignment = Alignment.build([PointAdapter(), PointViewAdapter()], TESTBED_TABLE)
    assert alignment.groups == ("east", "north", "west", "south")
    # t0 -> north (id 1), t1 -> east (0), t2 -> south (3), t3 -> west (2).
    assert alignment.task_ids("point_view").tolist() == [1, 0, 3, 2]
    assert (alignment.state_width, alignment.act_dim) == (6, 5)


@pytest.mark.parametrize("name", ["point_view", "point_diagonal"])
def test_semantic_check_passes(name: str) -> None:
    adapter = make_adapter(name)
    assert all(adapter.semantic_check(task)["ok"] for task in adapter.tasks)


def test_unknown_task_names_the_valid_ones() -> None:
    with pytest.raises(UnknownNameError, match="t0"):
        PointViewAdapter().make("east", seed=0)
    with pytest.raises(UnknownNameError, match="northeast"):
        PointDiagonalAdapter().make("east", seed=0)
