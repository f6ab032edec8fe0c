"""Pad-and-fine-tune alignment: index positions, Table 3 ids, overrides, actions, wrappers."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from seal.envs import EnvAdapter, ObsLayout
from seal.envs.alignment import PAPER_TABLE, Alignment, lone_entries
from seal.envs.metaworld import MetaWorldAdapter
from seal.envs.point import PointAdapter
from seal.errors import SealError, UnknownNameError

KITCHEN_TASKS = (
    "microwave",
    "right-hinge-door",
    "left-hinge-door",
    "light-switch",
    "top-right-burner",
    "top-left-burner",
    "bottom-right-burner",
    "bottom-left-burner",
    "slide-cabinet",
    "kettle",
)


class FakeKitchen(EnvAdapter):
    """The dense kitchen's shape only (59-d state, 3-d goal, 9-d action): alignment needs no physics."""

    name = "franka_kitchen_dense"
    all_tasks = KITCHEN_TASKS
    default_episode_length = 280

    observation_space = property(lambda self: gym.spaces.Box(-np.inf, np.inf, (62,), np.float64))
    action_space = property(lambda self: gym.spaces.Box(-1.0, 1.0, (9,), np.float32))
    obs_layout = property(
        lambda self: ObsLayout.from_slices([slice(0, 18)], [slice(18, 59)], [slice(59, 62)])
    )

    def make(self, task: str, seed: int) -> gym.Env:
        raise NotImplementedError


@pytest.fixture(scope="module")
def mw_fk() -> Alignment:
    return Alignment.build([MetaWorldAdapter(), FakeKitchen()])


def test_widths_and_index_positions(mw_fk: Alignment) -> None:
    # state block: max(36 MW, 59 kitchen) = 59; ids: 10 MT10 + 4 unaligned burners = 14; goal 3.
    assert (mw_fk.state_width, mw_fk.num_ids, mw_fk.goal_width) == (59, 14, 3)
    assert (mw_fk.onehot_start, mw_fk.goal_start, mw_fk.obs_dim) == (59, 73, 76)
    assert mw_fk.act_dim == 9


def test_table3_ids(mw_fk: Alignment) -> None:
    # MT10 in its order takes ids 0..9; kitchen tasks share their Table 3 partner's id, and the
    # four burners, first seen in kitchen order, take 10..13.
    assert mw_fk.task_ids("metaworld").tolist() == list(range(10))
    kitchen = dict(zip(KITCHEN_TASKS, mw_fk.task_ids("franka_kitchen_dense").tolist(), strict=True))
    assert kitchen == {
        "microwave": 3,  # door-open-v3
        "right-hinge-door": 3,
        "left-hinge-door": 3,
        "light-switch": 1,  # push-v3
        "top-right-burner": 10,
        "top-left-burner": 11,
        "bottom-right-burner": 12,
        "bottom-left-burner": 13,
        "slide-cabinet": 5,  # drawer-close-v3
        "kettle": 2,  # pick-place-v3
    }
    assert (
        mw_fk.task_id("franka_kitchen_dense", "kettle")
        == mw_fk.task_id("metaworld", "pick-place-v3")
        == 2
    )
    assert mw_fk.groups[10:] == (
        "top-right-burner",
        "top-left-burner",
        "bottom-right-burner",
        "bottom-left-burner",
    )


def test_metaworld_obs_transform(mw_fk: Alignment) -> None:
    obs = np.arange(39, dtype=np.float64)[None]  # value = index, so positions can be read off
    out = mw_fk.transform_obs("metaworld", obs, "door-open-v3")
    assert out.shape == (1, 76) and out.dtype == np.float32
    row = out[0]
    # state block = robot (0..3, 18..21) then objects (4..17, 22..35), padded with zeros to 59
    assert row[:8].tolist() == [0, 1, 2, 3, 18, 19, 20, 21]
    assert row[8:22].tolist() == list(range(4, 18))
    assert row[22:36].tolist() == list(range(22, 36))
    assert not row[36:59].any()
    onehot = np.zeros(14)
    onehot[3] = 1.0  # door-open-v3 is MT10's 4th task
    np.testing.assert_array_equal(row[59:73], onehot)
    assert row[73:76].tolist() == [36.0, 37.0, 38.0]


def test_kitchen_obs_transform_batched_with_mixed_tasks(mw_fk: Alignment) -> None:
    obs = np.tile(np.arange(62, dtype=np.float64), (3, 1)) + np.array([[0.0], [100.0], [200.0]])
    # rows: microwave (local 0, id 3), kettle (local 9, id 2), top-right-burner (local 4, id 10)
    out = mw_fk.transform_obs("franka_kitchen_dense", obs, np.array([0, 9, 4]))
    assert out.shape == (3, 76)
    np.testing.assert_array_equal(out[1, :59], np.arange(59) + 100.0)
    assert np.flatnonzero(out[:, 59:73]).tolist() == [
        0 * 14 + 3,
        1 * 14 + 2,
        2 * 14 + 10,
    ]  # row*14 + id
    np.testing.assert_array_equal(out[2, 73:76], [259.0, 260.0, 261.0])
    by_name = mw_fk.transform_obs(
        "franka_kitchen_dense", obs, ["microwave", "kettle", "top-right-burner"]
    )
    np.testing.assert_array_equal(out, by_name)
    # a single 1-D observation gives a single aligned observation
    np.testing.assert_array_equal(
        mw_fk.transform_obs("franka_kitchen_dense", obs[1], "kettle"), out[1]
    )


def test_point_has_no_goal_and_gets_zeros_there() -> None:
    align = Alignment.build([MetaWorldAdapter(tasks="mt3"), PointAdapter()])
    # state max(36, 4) = 36; ids 3 + 4 = 7; goal 3 (point has none: zeros)
    assert (align.state_width, align.num_ids, align.goal_width, align.obs_dim) == (36, 7, 3, 46)
    out = align.transform_obs("point", np.array([[0.5, -0.5, 0.1, 0.0]]), "west")
    expected = np.zeros(46, dtype=np.float32)
    expected[:4] = [0.5, -0.5, 0.1, 0.0]
    expected[36 + 3 + 2] = 1.0  # west is point's 3rd task, after 3 Meta-World ids
    np.testing.assert_array_equal(out[0], expected)


def test_actions_pad_and_unpad(mw_fk: Alignment) -> None:
    actions = np.array([[0.1, 0.2, 0.3, 0.4], [-1.0, -0.5, 0.5, 1.0]], dtype=np.float32)
    padded = mw_fk.pad_action("metaworld", actions)
    assert padded.shape == (2, 9) and padded.dtype == np.float32
    np.testing.assert_array_equal(padded[:, 4:], 0.0)
    np.testing.assert_array_equal(mw_fk.unpad_action("metaworld", padded), actions)
    assert mw_fk.unpad_action("franka_kitchen_dense", padded).shape == (2, 9)


def test_table_override_replaces_the_default() -> None:
    table = {"reach-v3": "reaching", "metaworld:push-v3": "reaching", "kettle": "reaching"}
    align = Alignment.build([MetaWorldAdapter(), FakeKitchen()], table=table)
    # "reaching" is id 0 (reach-v3 first); push joins it, so MT10 uses 9 ids; no Table 3 rows
    # apply, so the kitchen adds its 9 other tasks: 18 ids.
    assert align.num_ids == 18
    assert (
        align.task_id("metaworld", "push-v3")
        == 0
        == align.task_id("franka_kitchen_dense", "kettle")
    )
    assert align.task_id("metaworld", "pick-place-v3") == 1
    assert align.task_id("franka_kitchen_dense", "microwave") == 9  # not aligned any more


def test_an_entry_whose_group_no_other_task_shares_is_found() -> None:
    adapters = [MetaWorldAdapter(), FakeKitchen()]
    # A typo of a shared group ("door-opne-v3"), and a qualified key with a made-up lone name.
    table = {
        "microwave": "door-opne-v3",
        "left-hinge-door": "door-open-v3",
        "franka_kitchen_dense:kettle": "kettles",
    }
    assert lone_entries(adapters, table) == [
        ("microwave", "door-opne-v3"),
        ("franka_kitchen_dense:kettle", "kettles"),
    ]
    # A shared group, even under a new name, and a task named as its own group, are not lone.
    shared = {"microwave": "doors", "left-hinge-door": "doors", "kettle": "kettle"}
    assert lone_entries(adapters, shared) == []
    assert lone_entries(adapters, {k: v for k, v in PAPER_TABLE.items()}) == []


def test_bad_tables_and_names() -> None:
    with pytest.raises(UnknownNameError, match="unknown task in alignment table 'kettel'"):
        Alignment.build([MetaWorldAdapter(), FakeKitchen()], table={"kettel": "pick-place-v3"})
    align = Alignment.build([PointAdapter()])
    with pytest.raises(
        UnknownNameError, match=r"unknown aligned environment 'metaworld'; valid: point"
    ):
        align.task_id("metaworld", "reach-v3")
    with pytest.raises(UnknownNameError, match=r"unknown point task 'up'"):
        align.transform_obs("point", np.zeros((1, 4)), "up")
    with pytest.raises(SealError, match="4 observations but tasks of shape"):
        align.transform_obs("point", np.zeros((4, 4)), [0, 1])
    with pytest.raises(SealError, match="repeat"):
        Alignment.build([PointAdapter(), PointAdapter()])
    assert set(PAPER_TABLE.values()) == {
        "drawer-close-v3",
        "pick-place-v3",
        "door-open-v3",
        "push-v3",
    }


def test_gymnasium_wrapper() -> None:
    align = Alignment.build([MetaWorldAdapter(tasks="mt3"), PointAdapter()])
    env = align.wrap(PointAdapter().make("north", seed=0), "point", "north")
    assert env.observation_space.shape == (46,) and env.action_space.shape == (4,)
    obs, _ = env.reset(seed=0)
    assert obs[36 + 3 + 1] == 1.0 and obs.shape == (46,)
    # the padded entries 2..3 are ignored: the point moves by 0.1 * (0, 1)
    obs2, reward, *_ = env.step(np.array([0.0, 1.0, 0.7, -0.7], dtype=np.float32))
    np.testing.assert_allclose(obs2[:2] - obs[:2], [0.0, 0.1], atol=1e-6)


def test_the_real_kitchen_aligns_like_the_fake(mw_fk: Alignment) -> None:
    from seal.envs import make_adapter

    kitchen = make_adapter("franka_kitchen_dense")
    fake = FakeKitchen()
    assert kitchen.tasks == fake.tasks and (kitchen.obs_dim, kitchen.act_dim) == (62, 9)
    assert kitchen.obs_layout.state == fake.obs_layout.state and kitchen.obs_layout.goal == (
        59,
        60,
        61,
    )
    real = Alignment.build([MetaWorldAdapter(), kitchen])
    assert (real.obs_dim, real.num_ids, real.act_dim) == (76, 14, 9)
    assert (
        real.task_ids("franka_kitchen_dense").tolist()
        == mw_fk.task_ids("franka_kitchen_dense").tolist()
    )


def test_protocol_check_warns_of_a_lone_group_and_names_the_close_one(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from pathlib import Path

    from seal.cli.main import main

    path = Path(__file__).parents[2] / "protocols" / "finetune_fk_to_mw.toml"
    table = 'finetune.alignment={microwave="door-opne-v3", kettle="pick-place-v3"}'
    assert main(["protocol", "check", str(path), "--set", table]) == 0
    err = capsys.readouterr().err
    assert (
        "finetune.alignment: 'microwave' = 'door-opne-v3' shares its id with no other task" in err
    )
    assert "did you mean 'door-open-v3'?" in err and "kettle" not in err
    # The control: the same table spelled right says nothing.
    assert main(["protocol", "check", str(path), "--set", table.replace("opne", "open")]) == 0
    assert "warning" not in capsys.readouterr().err
