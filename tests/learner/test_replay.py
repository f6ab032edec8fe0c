"""Multi-task replay: storage per (env, task), ring wrap, per-task sampling, consumed counters, memory check."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from seal.errors import SealError, UnknownNameError
from seal.learner import EnvSpec, MultiTaskReplay
from seal.learner import replay as replay_module
from seal.schedulers.base import counts_from_ratio


def _add_tagged(replay: MultiTaskReplay, env: str, task_ids: list[int], step: int) -> None:
    """Add one transition per task id whose obs is [task, step, ...] so rows can be traced."""
    spec = replay.specs[env]
    n = len(task_ids)
    obs = np.zeros((n, spec.obs_dim), np.float32)
    obs[:, 0] = task_ids
    obs[:, 1] = step
    replay.add(
        env,
        np.array(task_ids),
        obs,
        np.full((n, spec.act_dim), step, np.float32),
        np.full(n, step),
        obs + 100,
        np.zeros(n),
    )


def test_add_and_sample_keep_tasks_apart_and_count_consumed() -> None:
    replay = MultiTaskReplay([EnvSpec("mw", 3, 2, 4)], capacity=40)
    assert replay.capacity_per_task == {"mw": 10}  # 40 per env split evenly over 4 tasks
    for step in range(3):
        _add_tagged(replay, "mw", [0, 1, 2, 3], step)
    np.testing.assert_array_equal(replay.size["mw"], [3, 3, 3, 3])
    batch = replay.sample({"mw": np.array([5, 0, 2, 1])})["mw"]
    assert batch.obs.dtype == torch.float32 and batch.task_ids.dtype == torch.int64
    assert batch.task_ids.tolist() == [0] * 5 + [2] * 2 + [3]
    # every row comes from its own task's buffer, and its fields belong to one transition
    torch.testing.assert_close(batch.obs[:, 0], batch.task_ids.float())
    torch.testing.assert_close(batch.rewards, batch.obs[:, 1])
    torch.testing.assert_close(batch.next_obs, batch.obs + 100)
    assert set(batch.obs[:, 1].tolist()) <= {0.0, 1.0, 2.0}
    replay.sample({"mw": np.array([1, 1, 1, 1])})
    np.testing.assert_array_equal(replay.consumed["mw"], [6, 1, 3, 2])
    assert replay.consumed["mw"].dtype == np.int64


def test_ring_buffer_wraps_per_task_and_repeated_task_ids_get_their_own_slots() -> None:
    replay = MultiTaskReplay([EnvSpec("mw", 2, 1, 2)], capacity=6)  # 3 slots per task
    _add_tagged(replay, "mw", [0, 0, 1], step=0)  # two instances of task 0 in one add
    _add_tagged(replay, "mw", [0, 0], step=1)  # task 0 now wrote 4 rows into 3 slots: wraps
    np.testing.assert_array_equal(replay.size["mw"], [3, 1])
    np.testing.assert_array_equal(replay.position["mw"], [1, 1])
    # slot 0 was overwritten by step 1's second instance: slots hold steps [1, 0, 1]
    np.testing.assert_array_equal(replay.storage["mw"]["obs"][0, :, 1], [1, 0, 1])
    assert replay.storage["mw"]["obs"][1, 0, 0] == 1.0


def test_sampling_errors_name_env_and_task() -> None:
    replay = MultiTaskReplay([EnvSpec("mw", 2, 1, 3)], capacity=30)
    _add_tagged(replay, "mw", [0], 0)
    with pytest.raises(SealError, match=r"'mw' task\(s\) \[1\] have no transitions"):
        replay.sample({"mw": np.array([1, 1, 0])})
    with pytest.raises(SealError, match="one per task"):
        replay.sample({"mw": np.array([1, 1])})
    with pytest.raises(UnknownNameError):
        replay.sample({"fk": np.array([1])})
    with pytest.raises(SealError, match=r"task ids must be in \[0, 3\)"):
        _add_tagged(replay, "mw", [3], 0)
    assert replay.sample({"mw": np.zeros(3, np.int64)}) == {}


def test_counts_from_ratio_splits_exactly() -> None:
    mt10 = counts_from_ratio({"mw": 1.0}, {"mw": 10}, batch_per_task=128)
    np.testing.assert_array_equal(mt10["mw"], [128] * 10)
    # two envs of 10 tasks: total 128 * 20 = 2560; 75/25 -> 1920 and 640 -> 192 and 64 per task
    both = counts_from_ratio({"mw": 0.75, "fk": 0.25}, {"mw": 10, "fk": 10}, batch_per_task=128)
    np.testing.assert_array_equal(both["mw"], [192] * 10)
    np.testing.assert_array_equal(both["fk"], [64] * 10)
    # total 1 * 5 = 5 at 50/50, per task a: 2.5 / 3 = 0.83, b: 2.5 / 2 = 1.25; floors 0 and 1, and
    # the 3 left over go to the largest remainders (a's 0.83 each) -> 1 each everywhere
    odd = counts_from_ratio({"a": 1, "b": 1}, {"a": 3, "b": 2}, batch_per_task=1)
    np.testing.assert_array_equal(odd["a"], [1, 1, 1])
    np.testing.assert_array_equal(odd["b"], [1, 1])
    # 10 over 4 tasks: 2 each + 2 leftover, to the lowest indices without rng, random with one
    uneven = counts_from_ratio({"a": 1.0, "b": 0.0}, {"a": 4, "b": 1}, batch_per_task=2)
    np.testing.assert_array_equal(uneven["a"], [3, 3, 2, 2])
    np.testing.assert_array_equal(uneven["b"], [0])
    drawn = counts_from_ratio(
        {"a": 1.0}, {"a": 4, "b": 1}, batch_per_task=2, rng=np.random.default_rng(0)
    )
    assert drawn["a"].sum() == 10 and sorted(drawn["a"].tolist()) == [2, 2, 3, 3]
    with pytest.raises(SealError, match="data ratios"):
        counts_from_ratio({"a": 0.0}, {"a": 2}, 4)
    with pytest.raises(UnknownNameError):
        counts_from_ratio({"c": 1.0}, {"a": 2}, 4)


def test_memory_check_refuses_before_allocating(monkeypatch: pytest.MonkeyPatch) -> None:
    spec = EnvSpec("metaworld", 39, 4, 10)
    # 10 tasks x 100,000 rows x (39 + 39 + 4 + 1 + 1) floats x 4 bytes = 336,000,000 bytes
    assert replay_module.replay_bytes([spec]) == 336_000_000
    monkeypatch.setattr(replay_module, "available_memory_bytes", lambda: 100_000_000)
    with pytest.raises(SealError, match=r"needs 0\.31 GiB .*only 0\.09 GiB"):
        MultiTaskReplay([spec])
    MultiTaskReplay([spec], capacity=1000)  # small enough


def test_available_memory_reads_proc_meminfo_without_psutil() -> None:
    available = replay_module.available_memory_bytes()
    assert available is not None and available > 10 * 2**20


def test_state_dict_round_trip() -> None:
    spec = EnvSpec("mw", 3, 2, 2)
    replay = MultiTaskReplay([spec], capacity=20)
    for step in range(4):
        _add_tagged(replay, "mw", [0, 1], step)
    replay.sample({"mw": np.array([3, 1])})
    other = MultiTaskReplay([spec], capacity=20)
    other.load_state_dict(replay.state_dict())
    for field, array in replay.storage["mw"].items():
        np.testing.assert_array_equal(other.storage["mw"][field], array)
    np.testing.assert_array_equal(other.consumed["mw"], [3, 1])
    np.testing.assert_array_equal(other.size["mw"], [4, 4])
    with pytest.raises(SealError, match="capacities per task"):
        MultiTaskReplay([spec], capacity=10).load_state_dict(replay.state_dict())


def test_rows_are_uniform_over_each_tasks_filled_rows() -> None:
    replay = MultiTaskReplay([EnvSpec("mw", 2, 1, 2)], capacity=20, seed=3)  # 10 slots per task
    for step in range(3):
        _add_tagged(replay, "mw", [0], step)
    for step in range(7):
        _add_tagged(replay, "mw", [1], step)
    batch = replay.sample({"mw": np.array([6000, 7000])})["mw"]
    steps = batch.obs[:, 1].long()
    # task 0 holds steps 0-2, task 1 steps 0-6: each row drawn 2000 and 1000 times in expectation
    # (binomial sd ~37 and ~30); none of the 7 unfilled rows of task 0 or 3 of task 1 ever.
    counts0 = torch.bincount(steps[:6000], minlength=10).tolist()
    counts1 = torch.bincount(steps[6000:], minlength=10).tolist()
    assert all(abs(c - 2000) < 200 for c in counts0[:3]) and counts0[3:] == [0] * 7
    assert all(abs(c - 1000) < 150 for c in counts1[:7]) and counts1[7:] == [0] * 3


def test_state_dict_carries_the_sampling_stream() -> None:
    spec = EnvSpec("mw", 3, 2, 2)
    replay = MultiTaskReplay([spec], capacity=20, seed=1)
    for step in range(5):
        _add_tagged(replay, "mw", [0, 1], step)
    replay.sample({"mw": np.array([4, 4])})
    other = MultiTaskReplay([spec], capacity=20, seed=2)
    other.load_state_dict(replay.state_dict())
    expected = replay.sample({"mw": np.array([8, 8])})["mw"]
    got = other.sample({"mw": np.array([8, 8])})["mw"]
    assert torch.equal(got.obs, expected.obs) and torch.equal(got.task_ids, expected.task_ids)
    # a fresh replay with the other seed draws other rows from the same contents
    fresh = MultiTaskReplay([spec], capacity=20, seed=2)
    fresh.load_state_dict({k: v for k, v in replay.state_dict().items() if k != "generator"})
    assert not torch.equal(fresh.sample({"mw": np.array([8, 8])})["mw"].obs, expected.obs)
