"""Evidence that each kitchen can be solved through `env.step`, and that its reward follows progress.

`expert_evidence` runs the scripted expert (`experts.policy`, which sees only observations) and a
uniform random policy over the same seeds, through the env that the adapter's `make` returns,
and reports:

- `scripted_success`: share of expert episodes with `info["success"]` 1 at some step (any-step,
  Meta-World's evaluation); `scripted_final_success`: share still successful at the last step;
  `scripted_flicks` / `random_flicks`: episodes successful at some step but not at the last one
  (an object flicked through its success band); `random_success_rate`: the random policy's any-step rate.
- `expert_reward_spearman`: Spearman's rho of step index against reward, from the first step up
  to the first success (the whole episode if none), averaged over episodes.
- `expert_mean_return`, `random_mean_return` over full episodes, and `return_ratio` = their ratio.
- `flat_stretch_share`: the longest run of consecutive steps in which the reward stays within a
  0.1 band, measured as the object progress made during it (the success measure's decrease)
  over the task's travel (initial distance - threshold); the worst episode's.

`reach_evidence` measures how near the gripper can get to the task's handle (position-only IK)
with the joint shut and at its goal: the measurement behind an "unsolvable" verdict.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
from scipy.stats import spearmanr

FLAT_BAND = 0.1  # reward change below which a stretch of progress counts as flat


def _episode(
    env: gym.Env, act: Callable[[np.ndarray], np.ndarray]
) -> tuple[list[float], list[float], list[float]]:
    """One full episode: rewards, successes and `info["distance"]` per step (reset's distance first)."""
    obs, info = env.reset()
    rewards, successes, distances = [], [], [float(info["distance"])]
    truncated = terminated = False
    while not (truncated or terminated):
        obs, reward, terminated, truncated, info = env.step(act(obs))
        rewards.append(float(reward))
        successes.append(float(info["success"]))
        distances.append(float(info["distance"]))
    return rewards, successes, distances


def flat_stretch(rewards: list[float], distances: list[float], travel: float) -> float:
    """Longest object progress (share of `travel`) over consecutive steps whose rewards lie within
    a FLAT_BAND band. `distances[t]` is the success measure after step t (index 0: at reset)."""
    longest = 0.0
    for i in range(len(rewards)):
        lo = hi = rewards[i]
        for j in range(i, len(rewards)):
            lo, hi = min(lo, rewards[j]), max(hi, rewards[j])
            if hi - lo >= FLAT_BAND:
                break
            # progress between the states that earned rewards i..j (distances[t + 1] is step t's)
            span = distances[i + 1 : j + 2]
            longest = max(longest, max(span) - min(span))
    return longest / travel


def _uniform_policy(space: gym.spaces.Box, seed: int) -> Callable[[np.ndarray], np.ndarray]:
    """Uniform random actions from a generator seeded with `seed` (the observation is ignored)."""
    rng = np.random.default_rng(seed)
    return lambda obs: rng.uniform(space.low, space.high).astype(space.dtype)


def expert_evidence(
    make: Callable[[int], gym.Env],
    task: str,
    seeds: list[int],
    gravity_compensation: bool = False,
) -> dict[str, Any]:
    """Expert and random episodes over `seeds` (`make(seed)` builds a seeded env, with gravity
    compensation when `gravity_compensation`, which the expert is told); figures above."""
    from franka_kitchen_dense.experts import policy
    from franka_kitchen_dense.tasks import TASKS

    spec = TASKS[task]
    expert_returns, random_returns, rhos, flats, firsts = [], [], [], [], []
    any_success = final_success = random_any = random_flicks = 0
    for seed in seeds:
        env = make(seed)
        rewards, successes, distances = _episode(
            env, lambda obs: policy(obs, task, gravity_compensation)
        )
        expert_returns.append(sum(rewards))
        first = successes.index(1.0) if 1.0 in successes else None
        any_success += first is not None
        final_success += successes[-1] == 1.0
        end = len(rewards) if first is None else first + 1
        if end <= 2:
            rho = 1.0  # solved at once: nothing to rank
        elif np.ptp(rewards[:end]) == 0.0:
            rho = 0.0  # a constant reward has no rank correlation: a failure
        else:
            rho = float(spearmanr(np.arange(end), rewards[:end]).statistic)
        rhos.append(rho)
        travel = distances[0] - spec.threshold
        flats.append(flat_stretch(rewards[:end], distances[: end + 1], travel))
        if first is not None:
            firsts.append(first + 1)
        env.close()
        env = make(seed)
        random_rewards, random_successes, _ = _episode(env, _uniform_policy(env.action_space, seed))
        random_returns.append(sum(random_rewards))
        random_any += 1.0 in random_successes
        random_flicks += 1.0 in random_successes and random_successes[-1] == 0.0
        env.close()
    n = len(seeds)
    random_mean = float(np.mean(random_returns))
    return {
        "scripted_success": any_success / n,
        "scripted_final_success": final_success / n,
        # flicks: a success at some step that the episode's last step no longer has
        "scripted_flicks": any_success - final_success,
        "random_success_rate": random_any / n,
        "random_flicks": random_flicks,
        "episodes": n,
        "mean_steps_to_success": float(np.mean(firsts)) if firsts else None,
        "expert_reward_spearman": round(float(np.mean(rhos)), 4),
        "expert_mean_return": round(float(np.mean(expert_returns)), 2),
        "random_mean_return": round(random_mean, 2),
        "return_ratio": round(float(np.mean(expert_returns)) / random_mean, 2)
        if random_mean > 0
        else None,
        "flat_stretch_share": round(float(np.max(flats)), 4),
    }


def reach_evidence(env: Any) -> dict[str, float]:
    """Nearest approach (m) of the gripper to the task site by position-only IK from several starts,
    with the task joint shut and at its goal. `env` is the raw `FrankaKitchenDenseEnv`."""
    from franka_kitchen_dense.posing import ARM_DOFS, solve_gripper_at_object

    home = env._init_qpos[:ARM_DOFS]
    out = {}
    for where, value in (("shut", env.initial_task_joint()), ("goal", env.task.goal_array)):
        env.set_task_joint(value)
        errors = [
            solve_gripper_at_object(
                env, home + np.array([turn, 0, 0, 0, 0, 0, 0]), rotation_weight=0.0
            )[1]
            for turn in np.linspace(-1.6, 1.6, 9)
        ]
        out[f"reach_gap_{where}_m"] = round(float(min(errors)), 4)
    return out
