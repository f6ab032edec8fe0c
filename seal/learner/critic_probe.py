"""How far a critic overestimates: its Q at an evaluation episode's first state against what the
episode earned from there (issue 54; the kitchen's traces first measured it by hand).

Per episode, as `scripts/trace_kitchen_policy.py` computes it:
- `q_start`: the lower twin critic's Q of the first observation and the action the policy took there;
- `earned`: the discounted return from there, sum_t gamma^t r_t, plus gamma^T * Q(s_T, pi(s_T)) when
  the episode was cut at its time limit (a truncation, not an end: the critic's target bootstraps
  there too), nothing after a termination.
A critic that overestimates says more than its policy earns: `q_start / earned` well above 1.

A `CriticProbe` watches the episodes of one `Collector._run` (each instance runs one episode) and
turns them into those two numbers per instance.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Protocol

import numpy as np


class Critic(Protocol):
    """The lower twin critic's Q (N,) of raw observations (N, obs_dim), task ids (N,) and env actions."""

    def __call__(
        self, env: str, obs: np.ndarray, task_ids: np.ndarray, actions: np.ndarray
    ) -> np.ndarray: ...


class ActFn(Protocol):
    """The policy whose episodes are probed: (env, obs, task_ids) -> env actions."""

    def __call__(self, env: str, obs: np.ndarray, task_ids: np.ndarray) -> np.ndarray: ...


class CriticProbe:
    """`q_start` and `earned` (see the module) of every instance's episode in one collector round."""

    def __init__(self, critic: Critic, policy: ActFn, gamma: float) -> None:
        self.critic, self.policy, self.gamma = critic, policy, float(gamma)
        self._state: dict[str, dict[str, np.ndarray]] = {}

    def start(self, sizes: Mapping[str, int]) -> None:
        """A new round over `sizes[env]` instances per environment."""
        self._state = {
            env: {
                "discounted": np.zeros(n),
                "steps": np.zeros(n, dtype=np.int64),
                "terminated": np.zeros(n, dtype=bool),
                "q_start": np.full(n, np.nan),
                "last_obs": np.zeros(0),
            }
            for env, n in sizes.items()
        }

    def first(
        self, env: str, run: np.ndarray, task_ids: np.ndarray, obs: np.ndarray, actions: np.ndarray
    ) -> None:
        """The instances `run` start their episodes at `obs` with `actions`."""
        self._state[env]["q_start"][run] = self.critic(env, obs, task_ids, actions)

    def step(
        self,
        env: str,
        run: np.ndarray,
        rewards: np.ndarray,
        next_obs: np.ndarray,
        terminated: np.ndarray,
    ) -> None:
        """One step of the instances `run`."""
        s = self._state[env]
        s["discounted"][run] += self.gamma ** s["steps"][run] * np.asarray(rewards, dtype=float)
        s["steps"][run] += 1
        s["terminated"][run] = terminated
        if s["last_obs"].shape[:1] != s["steps"].shape:
            s["last_obs"] = np.zeros((len(s["steps"]), *np.shape(next_obs)[1:]), dtype=np.float32)
        s["last_obs"][run] = next_obs

    def finish(
        self, env: str, run: np.ndarray, task_ids: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(q_start, earned) of the instances `run`, whose episodes have ended."""
        s = self._state[env]
        last = s["last_obs"][run]
        boot = self.critic(env, last, task_ids, self.policy(env, last, task_ids))
        tail = np.where(s["terminated"][run], 0.0, self.gamma ** s["steps"][run] * boot)
        return s["q_start"][run].copy(), s["discounted"][run] + tail


def overestimation(q_start: float, earned: float) -> float:
    """`q_start / earned`, NaN where the episodes earned nothing positive (no ratio has meaning)."""
    return q_start / earned if earned > 0 else float("nan")
