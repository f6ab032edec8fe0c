"""Evaluation that stops a task once its verdict is settled (`evaluation.decide_early`) and
episodes that end at their first success (`evaluation.end_on_success`), on scripted envs whose
episode k succeeds or fails by a fixed pattern (issue 60)."""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
import pytest

from seal.envs.base import EnvAdapter, ObsLayout
from seal.evaluation import EarlyDecision, reaches
from seal.learner.collection import Collector
from seal.learner.critic_probe import CriticProbe
from seal.learner.evaluation_waves import episode_seed
from tests.learner.test_collection import adapters, half_policy

SEED, DRAW, LENGTH = 5, 7, 4


class PatternEnv(gym.Env):
    """Reward 1 every step; `info["success"]` is 1 at step 2 of an episode its pattern marks.

    The episode is known by its reset seed (`episode_seed`), so its outcome does not depend on
    the instance, replica or wave that runs it; every reset is recorded as (task, episode,
    replica), the replica being the instance's place among its task's (the order they are made).
    """

    def __init__(self, adapter: PatternAdapter, task: str, replica: int) -> None:
        self.adapter, self.task, self.replica = adapter, task, replica
        self.observation_space = adapter.observation_space
        self.action_space = adapter.action_space
        self.t, self.succeeds = 0, False

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict]:
        episode = self.adapter.episode_of[self.task][int(seed)]  # type: ignore[arg-type]
        self.adapter.resets.append((self.task, episode, self.replica))
        self.t, self.succeeds = 0, self.adapter.patterns[self.task][episode]
        return np.zeros(1), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        self.t += 1
        success = float(self.succeeds and self.t == 2)
        return np.array([self.t]), 1.0, False, self.t >= LENGTH, {"success": success}


class PatternAdapter(EnvAdapter):
    """Tasks "a" and "b" whose episodes succeed by `patterns` (one bool per episode)."""

    name: ClassVar[str] = "pat"
    all_tasks: ClassVar[tuple[str, ...]] = ("a", "b")
    default_episode_length: ClassVar[int] = LENGTH

    def __init__(self, patterns: dict[str, list[bool]]) -> None:
        super().__init__()
        self.patterns = patterns
        self.episode_of = {
            task: {episode_seed(SEED, self.name, task, DRAW, k): k for k in range(len(p))}
            for task, p in patterns.items()
        }
        self.resets: list[tuple[str, int, int]] = []
        self.made = dict.fromkeys(patterns, 0)

    @property
    def observation_space(self) -> gym.spaces.Box:
        return gym.spaces.Box(-np.inf, np.inf, (1,), np.float64)

    @property
    def action_space(self) -> gym.spaces.Box:
        return gym.spaces.Box(-1.0, 1.0, (1,), np.float32)

    @property
    def obs_layout(self) -> ObsLayout:
        return ObsLayout((0,), (), ())

    def make(self, task: str, seed: int) -> gym.Env:
        self.made[task] += 1
        return PatternEnv(self, task, self.made[task] - 1)


def zero_policy(env: str, obs: np.ndarray, task_ids: np.ndarray) -> np.ndarray:
    return np.zeros((len(obs), 1), dtype=np.float32)


def run(
    patterns: dict[str, list[bool]],
    replicas: int,
    decide: EarlyDecision | None,
    backend: str = "sync",
    end_on_success: bool = False,
) -> tuple[dict[str, dict[str, float]], PatternAdapter]:
    adapter = PatternAdapter(patterns)
    episodes = len(patterns["a"])
    with Collector(
        {"pat": adapter}, seed=SEED, backend=backend, replicas=replicas, num_workers=2
    ) as col:
        out = col.evaluate(
            zero_policy, episodes, draw=DRAW, decide=decide, end_on_success=end_on_success
        )
    return out["pat"], adapter


F, T = False, True
# Task "b" never settles before its last episode (5 failures first, then 45 successes), so it
# runs all 50 whatever "a" does.
UNSETTLED = [F] * 5 + [T] * 45

# (pattern of "a", replicas, episodes counted, episodes run, success over those counted), 50
# episodes at 0.9. A task is counted up to the episode that settled it, whatever the replicas;
# it runs to the end of that episode's wave.
CASES = [
    # 6 failures first: settled (not reached) at the 6th failure.
    ([F] * 6 + [T] * 44, 1, 6, 6, 0.0),
    ([F] * 6 + [T] * 44, 4, 6, 8, 0.0),  # waves end at 4, 8
    ([F] * 6 + [T] * 44, 7, 6, 7, 0.0),
    # 5 failures first: never settled early; reaches 0.9 = 45/50 exactly.
    ([F] * 5 + [T] * 45, 1, 50, 50, 0.9),
    ([F] * 5 + [T] * 45, 4, 50, 50, 0.9),
    # 45 successes first: settled (reached) at the 45th success.
    ([T] * 45 + [F] * 5, 1, 45, 45, 1.0),
    ([T] * 45 + [F] * 5, 4, 45, 48, 1.0),  # waves end at ..., 44, 48
    ([T] * 45 + [F] * 5, 7, 45, 49, 1.0),  # waves end at ..., 42, 49
    # 44 successes first: the 6th failure is the last episode, so nothing is saved.
    ([T] * 44 + [F] * 6, 1, 50, 50, 0.88),
    ([T] * 44 + [F] * 6, 4, 50, 50, 0.88),
    # failures at 1, 3, ..., 11: the 6th is episode 11, in the wave ending at 12 (4) or 15 (5).
    ([k not in (1, 3, 5, 7, 9, 11) for k in range(50)], 4, 12, 12, 6 / 12),
    ([k not in (1, 3, 5, 7, 9, 11) for k in range(50)], 5, 12, 15, 6 / 12),
]


def test_the_rule_is_reaches_at_its_boundary() -> None:
    rule = EarlyDecision(50, 0.9)
    assert (rule.needed, rule.fewest_episodes) == (45, 6)
    assert EarlyDecision(50, 0.1 * 9).needed == 45  # 0.9000000000000001: SUCCESS_TOLERANCE
    assert EarlyDecision(10, 0.9).needed == 9 and EarlyDecision(100, 0.9).needed == 90
    assert EarlyDecision(4, 0.0).needed == 0 and EarlyDecision(4, 0.0).fewest_episodes == 1
    # 44 successes and 5 failures settle nothing; one more of either does.
    np.testing.assert_array_equal(rule([44, 44, 45, 0, 0], [5, 6, 0, 5, 6]), [F, T, T, F, T])


@pytest.mark.parametrize(("pattern", "replicas", "counted", "ran", "success"), CASES)
def test_an_early_decision_is_the_full_verdict(
    pattern: list[bool], replicas: int, counted: int, ran: int, success: float
) -> None:
    patterns = {"a": pattern, "b": UNSETTLED}
    full, _ = run(patterns, replicas, None)
    early, adapter = run(patterns, replicas, EarlyDecision(50, 0.9))
    a = early["a"]
    assert a["episodes"] == counted and a["decided_early"] == float(counted < 50)
    assert a["success_rate"] == pytest.approx(success)
    assert a["mean_return"] == LENGTH  # every episode runs its 4 steps, reward 1 each
    assert full["a"]["success_rate"] == pytest.approx(sum(pattern) / 50)
    assert reaches(a["success_rate"], 0.9) == reaches(full["a"]["success_rate"], 0.9)
    # "b" ran every episode and got what a full evaluation gets, bit for bit ...
    assert early["b"] == {**full["b"], "decided_early": 0.0}
    # ... and each task ran its first episodes in order, episode k on replica k % replicas as in
    # a full evaluation, so the k-th episode is the same whether or not the other task stopped.
    for task, count in (("a", ran), ("b", 50)):
        runs = [(k, r) for t, k, r in adapter.resets if t == task]
        assert runs == [(k, k % replicas) for k in range(count)]


def reference_count(pattern: list[bool], threshold: float) -> int:
    """Episodes counted, by a plain reading of the rule: up to the first at which the successes
    reach `needed`, or the failures pass what `needed` allows."""
    n = len(pattern)
    needed = min(s for s in range(n + 1) if s / n >= threshold - 1e-9)
    for k in range(1, n + 1):
        s = sum(pattern[:k])
        if s >= needed or k - s > n - needed:
            return k
    return n


@pytest.mark.parametrize("threshold", [0.9, 0.8, 0.5])
def test_random_patterns_keep_the_verdict(threshold: float) -> None:
    rng = np.random.default_rng(0)
    for trial in range(12):
        n = int(rng.choice([10, 20, 50]))
        replicas = int(rng.integers(2, 6))
        patterns = {task: list(rng.random(n) < rng.uniform(0.6, 1.0)) for task in "ab"}
        full, _ = run(patterns, replicas, None)
        early, _ = run(patterns, replicas, EarlyDecision(n, threshold))
        # What is recorded does not depend on the waves: one instance per task counts the same.
        assert early == run(patterns, 1, EarlyDecision(n, threshold))[0], trial
        for task, pattern in patterns.items():
            got, want = early[task], full[task]
            counted = reference_count(pattern, threshold)
            assert got["episodes"] == counted, (trial, task)
            assert got["success_rate"] == pytest.approx(np.mean(pattern[:counted]))
            assert reaches(got["success_rate"], threshold) == reaches(
                want["success_rate"], threshold
            )


def test_backends_decide_alike() -> None:
    patterns = {"a": [F] * 6 + [T] * 44, "b": [T] * 45 + [F] * 5}
    sync, _ = run(patterns, 4, EarlyDecision(50, 0.9))
    inline, _ = run(patterns, 4, EarlyDecision(50, 0.9), backend="inline-batched")
    assert sync == inline
    assert (sync["a"]["episodes"], sync["b"]["episodes"]) == (6, 45)


def test_an_episode_ends_at_its_first_success() -> None:
    # Pattern env: success at step 2 of a marked episode, reward 1 a step: its return is 2.
    patterns = {"a": [T, F, T], "b": [F, F, F]}
    out, _ = run(patterns, 2, None, end_on_success=True)
    assert out["a"]["mean_return"] == pytest.approx((2 + LENGTH + 2) / 3)
    assert out["a"]["success_rate"] == pytest.approx(2 / 3)
    assert out["b"]["mean_return"] == LENGTH


GAMMA = 0.9


def critic(env: str, obs: np.ndarray, task_ids: np.ndarray, actions: np.ndarray) -> np.ndarray:
    """tests/learner/test_critic_probe.py's hand-made critic: 10 x + 100 a + the task id."""
    return 10 * obs[:, 0] + 100 * actions[:, 0] + task_ids


def test_a_cut_return_and_its_probe_are_hand_computed() -> None:
    # The toy envs (tests/learner/test_collection.py): x += 0.5 a step, reward = x after it;
    # "a" succeeds at step 2, "c" at step 4 (its last), "b" never; toy2's "stop" terminates at 3.
    policy = half_policy([])
    with Collector(adapters(), seed=0, backend="sync") as col:
        out = col.evaluate(policy, 2, probe=CriticProbe(critic, policy, GAMMA), end_on_success=True)
        # "a" steps twice per episode, the others run to their end.
        np.testing.assert_array_equal(col.env_steps["toy"], [2 * 2, 2 * 4, 2 * 4])
        np.testing.assert_array_equal(col.env_steps["toy2"], [2 * 2, 2 * 3])
    toy, toy2 = out["toy"], out["toy2"]
    # Cut at step 2: return 0.5 + 1.0 (the success step's reward included) ...
    assert toy["a"]["mean_return"] == toy2["a"]["mean_return"] == pytest.approx(1.5)
    # ... and earned bootstraps at the cut as at a time limit: 0.5 + 0.9 * 1.0 + 0.9^2 Q(x = 1,
    # a = 0.5) with Q = 10 + 50 + task id.
    assert toy["a"]["earned"] == pytest.approx(0.5 + 0.9 * 1.0 + 0.81 * 60)
    assert toy2["a"]["earned"] == pytest.approx(0.5 + 0.9 * 1.0 + 0.81 * 60)
    assert toy["b"]["mean_return"] == toy["c"]["mean_return"] == pytest.approx(5.0)
    assert toy2["stop"]["mean_return"] == pytest.approx(3.0)  # terminated, no success
    assert [toy[t]["success_rate"] for t in "abc"] == [1.0, 0.0, 1.0]
