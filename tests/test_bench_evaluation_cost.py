"""The floor projection's evaluation cost under decide_early and end_on_success, by hand."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from seal.bench.evaluation_cost import evaluation_share, success_steps
from seal.protocols import load_protocol


def _config(tmp_path, **evaluation: object):  # noqa: ANN001, ANN202
    text = (
        '[protocol]\nname = "c"\nkind = "baseline"\nepochs = 10\n'
        '[envs.pt]\nadapter = "point"\ntasks = ["east", "north"]\nepisode_length = 500\n'
        "[evaluation]\nepisodes = 50\nthreshold = 0.9\n"
        + "".join(f"{k} = {str(v).lower()}\n" for k, v in evaluation.items())
    )
    path = tmp_path / "c.toml"
    path.write_text(text)
    return load_protocol(path)


def test_the_share_of_full_evaluation_steps_by_hand(tmp_path) -> None:  # noqa: ANN001
    both = _config(tmp_path, decide_early=True, end_on_success=True, full_every=10)
    # n = 50, T = 500, needed = 45, 6 failures settle, L = 100, k = 10, 3 replicas:
    # before = (50*500 + 9 * 6*500) / 10 / 25000 = 0.208; after = (50*100 + 9 * 45*100) / 250000
    got = evaluation_share(both, "pt", 100.0, replicas=3)
    assert got["before"] == pytest.approx(0.208)
    assert got["after"] == pytest.approx(0.182)
    assert got["share"] == pytest.approx(0.208)
    # 4 replicas: 6 -> 8 episodes run, 45 -> 48.
    four = evaluation_share(both, "pt", 100.0, replicas=4)
    assert four["before"] == pytest.approx((25000 + 9 * 8 * 500) / 250000)
    assert four["after"] == pytest.approx((5000 + 9 * 48 * 100) / 250000)
    # decide_early alone: a succeeding task still runs 45 full-length episodes.
    early = _config(tmp_path, decide_early=True, full_every=10)
    assert evaluation_share(early, "pt", 100.0, 3)["after"] == pytest.approx(
        (25000 + 9 * 45 * 500) / 250000
    )
    # end_on_success alone: only successes are cut; failing tasks pay the full evaluation.
    cut = _config(tmp_path, end_on_success=True)
    assert evaluation_share(cut, "pt", 100.0, 3) == pytest.approx(
        {"share": 1.0, "before": 1.0, "after": 0.2}
    )
    assert evaluation_share(_config(tmp_path), "pt", 100.0, 3)["share"] == 1.0


class _Succeeds(gym.Env):
    """Succeeds at step `at` if every action so far was +1, else never."""

    observation_space = gym.spaces.Box(-1, 1, (1,))
    action_space = gym.spaces.Box(-1, 1, (1,))

    def __init__(self, at: int) -> None:
        self.at, self.t, self.good = at, 0, True

    def reset(self, *, seed=None, options=None):  # noqa: ANN001, ANN201
        self.t, self.good = 0, True
        return np.zeros(1, np.float32), {}

    def step(self, action):  # noqa: ANN001, ANN201
        self.t += 1
        self.good &= bool(action[0] > 0)
        return (
            np.zeros(1, np.float32),
            0.0,
            False,
            False,
            {"success": self.good and self.t >= self.at},
        )


class _Adapter:
    tasks = ("a", "b", "c")

    def make(self, task: str, seed: int) -> gym.Env:
        return _Succeeds({"a": 7, "b": 11, "c": 3}[task])

    def expert(self, task: str):  # noqa: ANN201
        return None if task == "c" else (lambda obs: np.ones(1, np.float32))


def test_expert_success_steps_are_the_first_success_or_the_episode_length(tmp_path) -> None:  # noqa: ANN001
    config = _config(tmp_path)
    # a at 7, b at 11, c has no expert: the episode length, 500.
    assert success_steps(config, {"pt": _Adapter()}) == {"pt": pytest.approx((7 + 11 + 500) / 3)}
