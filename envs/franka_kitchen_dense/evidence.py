"""Evidence that each kitchen can be solved through `env.step`, and that its reward follows progress.

`expert_evidence` runs the scripted expert (`experts.policy`, which sees only observations) and a
uniform random policy over the same seeds, through the env that the adapter's `make` returns,
and reports:

- `scripted_success`: share of expert episodes with `info["success"]` 1 at some step (any-step,
  Meta-World's evaluation); `scripted_final_success`: share still successful at the last step;
  `scripted_flicks` / `random_flicks`: episodes successful at some step but not at the last one
  (an object flicked through its success band); `random_success_rate`: the random policy's any-step rate.
- `expert_reward_spearman`: Spearman's rho of step index against reward, from the first step up
  to the first success (the whole episode if none), averaged over episodes; under reward v4 the
  reward includes the approach term F, and `expert_reward_spearman_unshaped` is the same
  figure on the reward less F (v3's terms).
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
) -> tuple[list[float], list[float], list[float], list[float]]:
    """One full episode: rewards, successes, `info["distance"]` per step (reset's distance first)
    and the approach term per step (`info["approach"]`, 0 where the reward has none)."""
    obs, info = env.reset()
    rewards, successes, distances, approach = [], [], [float(info["distance"])], []
    truncated = terminated = False
    while not (truncated or terminated):
        obs, reward, terminated, truncated, info = env.step(act(obs))
        rewards.append(float(reward))
        successes.append(float(info["success"]))
        distances.append(float(info["distance"]))
        approach.append(float(info.get("approach", 0.0)))
    return rewards, successes, distances, approach


def _rank_rho(rewards: list[float]) -> float:
    """Spearman's rho of step index against `rewards` (1 for <= 2 steps, 0 for a constant reward)."""
    if len(rewards) <= 2:
        return 1.0  # solved at once: nothing to rank
    if np.ptp(rewards) == 0.0:
        return 0.0  # a constant reward has no rank correlation: a failure
    return float(spearmanr(np.arange(len(rewards)), rewards).statistic)


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
    from franka_kitchen_dense.tasks import SHAPED_VERSIONS, TASKS

    spec = TASKS[task]
    expert_returns, random_returns, rhos, flats, firsts = [], [], [], [], []
    unshaped_rhos, shaped = [], False
    any_success = final_success = random_any = random_flicks = 0
    for seed in seeds:
        env = make(seed)
        rewards, successes, distances, approach = _episode(
            env, lambda obs: policy(obs, task, gravity_compensation)
        )
        shaped = env.unwrapped.reward_version in SHAPED_VERSIONS
        expert_returns.append(sum(rewards))
        first = successes.index(1.0) if 1.0 in successes else None
        any_success += first is not None
        final_success += successes[-1] == 1.0
        end = len(rewards) if first is None else first + 1
        rhos.append(_rank_rho(rewards[:end]))
        unshaped_rhos.append(
            _rank_rho([r - f for r, f in zip(rewards[:end], approach[:end], strict=True)])
        )
        travel = distances[0] - spec.threshold
        flats.append(flat_stretch(rewards[:end], distances[: end + 1], travel))
        if first is not None:
            firsts.append(first + 1)
        env.close()
        env = make(seed)
        random_rewards, random_successes, _, _ = _episode(
            env, _uniform_policy(env.action_space, seed)
        )
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
        **(
            {"expert_reward_spearman_unshaped": round(float(np.mean(unshaped_rhos)), 4)}
            if shaped
            else {}
        ),
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


# ---- exploits -----------------------------------------------------------------------------------

EXPLOIT_RATIO_MAX = 0.5
"""A no-progress behaviour may earn at most this share of the expert's episode return."""
OSCILLATION_FRACTIONS = (0.0, 0.025, 0.05, 0.075, 0.1, 0.075, 0.05, 0.025)
"""One period of the oscillation: the object jiggled over the first 10% of its travel and back."""
OVERSHOOT_FRACTIONS = (0.25, 0.5, 0.75, 1.0)
"""Past the goal: these shares of the way from the goal to the joint's limit (the kettle: of its
travel again, beyond the goal)."""
PARKING_DISTANCES = (0.03, 0.06, 0.12)
"""Parking points: the gripper this far (m) from the handle along +-x, +-y, +-z."""
FINGER_ACTIONS = {"open": 1.0, "still": 0.0, "closing": -1.0}
"""Finger actions (a7 = a8) tried at every posed state; the arm action is zero."""
APPROACH_CYCLE = (0.12, 0.06, 0.03, 0.0, 0.03, 0.06)
"""One period of the approach cycle: the gripper this far (m) back from the untouched handle along
its approach direction, each step from the previous pose (reward v4's approach term paid in turn)."""


def _posed_step(
    env: gym.Env,
    seed: int,
    joint: np.ndarray,
    arm: np.ndarray,
    fingers: float,
    previous_potential: float | None = None,
) -> tuple[float, float, dict[str, Any]]:
    """(reward, success, info) of one `env.step` from the state with the task joint at `joint`,
    the arm at `arm` (fingers open, at rest) and the finger action `fingers` (arm action zero).

    The step's Phi(s) (reward v4) is the posed state's, never the reset state's; or
    `previous_potential`, so that the step pays the approach term of arriving at `arm` from a
    state of that potential (the approach cycle)."""
    from franka_kitchen_dense.posing import ARM_DOFS, FINGER_OPEN

    raw = env.unwrapped
    env.reset(seed=seed)
    raw.set_task_joint(joint)
    raw.data.qpos[:ARM_DOFS] = arm
    raw.data.qpos[ARM_DOFS : ARM_DOFS + 2] = FINGER_OPEN
    raw.data.qvel[: ARM_DOFS + 2] = 0.0
    raw.sync(previous_potential=previous_potential)
    action = np.zeros(env.action_space.shape, dtype=env.action_space.dtype)
    action[7:9] = fingers
    _, reward, _, _, info = env.step(action)
    return float(reward), float(info["success"]), info


def _posed_reward(
    env: gym.Env, seed: int, joint: np.ndarray, arm: np.ndarray, fingers: float
) -> tuple[float, float]:
    """(reward, success) per step of holding the posed state (`_posed_step`) still: the step is
    taken twice from the same pose, the second time with Phi(s) (reward v4) that of the state the
    first ended in, which the second ends in again, so it pays a still gripper's approach term
    F = (gamma - 1) * Phi(s) rather than one step of the unsupported arm's sag."""
    _, _, info = _posed_step(env, seed, joint, arm, fingers)
    reward, success, _ = _posed_step(env, seed, joint, arm, fingers, info.get("potential"))
    return reward, success


def _best_step(
    env: gym.Env, seed: int, joint: np.ndarray, offset: np.ndarray | None = None
) -> tuple[float, float]:
    """The gripper posed at the handle (+ `offset`) with the joint at `joint`: the best reward over
    the finger actions, and whether that state is a success."""
    arm = _arm_at(env, seed, joint, offset)
    steps = [_posed_reward(env, seed, joint, arm, f) for f in FINGER_ACTIONS.values()]
    return max(r for r, _ in steps), max(s for _, s in steps)


def _arm_at(
    env: gym.Env, seed: int, joint: np.ndarray, offset: np.ndarray | None = None
) -> np.ndarray:
    """The IK arm pose putting the gripper at the handle (+ `offset`) with the joint at `joint`."""
    from franka_kitchen_dense.posing import best_gripper_pose

    raw = env.unwrapped
    env.reset(seed=seed)
    raw.set_task_joint(joint)
    return best_gripper_pose(raw, offset=offset)[0]


def _approach_cycle(env: gym.Env, seed: int) -> tuple[float, list[np.ndarray]]:
    """Mean reward per step of `APPROACH_CYCLE` (the untouched handle, the best finger action at
    each pose), each step's Phi(s) (reward v4) that of the state the previous step ended in (one
    step of the arm's sag included, so its approach term telescopes over the period); the second
    of two laps counts. Also the cycle's arm poses."""
    raw = env.unwrapped
    start = raw.initial_task_joint()
    back = -np.asarray(raw.task.approach, dtype=np.float64)  # the gripper comes in along `approach`
    poses = {d: _arm_at(env, seed, start, d * back) for d in sorted(set(APPROACH_CYCLE))}
    previous: float | None = None  # the first step of the first lap: the posed state's
    rewards = []
    for lap in range(2):
        for d in APPROACH_CYCLE:
            steps = [
                _posed_step(env, seed, start, poses[d], f, previous)
                for f in FINGER_ACTIONS.values()
            ]
            reward, _, info = max(steps, key=lambda step: step[0])
            previous = info.get("potential", 0.0)
            if lap == 1:
                rewards.append(reward)
    return float(np.mean(rewards)), [poses[d] for d in sorted(poses)]


def _overshoot_joints(raw: Any) -> list[np.ndarray]:
    """Joint values past the goal, on the far side from the start."""
    start, goal = raw.initial_task_joint(), raw.task.goal_array
    if goal.shape == (7,):  # the kettle: carried past its goal position, goal orientation
        return [
            np.concatenate([goal[:3] + f * (goal[:3] - start[:3]), goal[3:]])
            for f in OVERSHOOT_FRACTIONS
        ]
    lo, hi = raw.model.jnt_range[raw.model.joint(raw.task.joint).id]
    limit = hi if goal[0] > start[0] else lo
    return [goal + f * (limit - goal) for f in OVERSHOOT_FRACTIONS]


def exploit_evidence(env: gym.Env, expert_return: float, seed: int = 0) -> dict[str, Any]:
    """Returns of five no-progress behaviours over an episode, each holding a posed state (or a
    cycle of them) for `episode_length` steps, read through `env.step`, against `expert_return`:

    - `hover`: the gripper at the handle, the object untouched;
    - `oscillate`: the gripper at the handle while the object is jiggled over the first 10% of its
      travel and back (`OSCILLATION_FRACTIONS`), mean over one period;
    - `past_goal`: the object pushed past its goal (`OVERSHOOT_FRACTIONS` of the way to the joint's
      limit) and out of the success band, gripper at the handle; the best such point (none when
      the joint's limit lies inside the band);
    - `parking`: the object untouched, the gripper at the best of the handle, 18 points around
      it (`PARKING_DISTANCES` along +-x, +-y, +-z) and the approach cycle's points: the reward's
      best no-progress point;
    - `approach_cycle`: the object untouched, the gripper posed in turn `APPROACH_CYCLE` back from
      the handle, each step's Phi(s) (reward v4) that of the state the previous pose's step ended
      in: one period's mean per step.

    A held state's step pays a still gripper's approach term, (gamma - 1) * Phi(s) (reward v4),
    and every posed step's Phi(s) comes after posing, never from the reset state. At every state
    the best of the finger actions counts. `exploit_ratio` = the best exploit's return / the
    expert's; `exploit_ok` when it is <= `EXPLOIT_RATIO_MAX` and the approach cycle earns no more
    than parking (`approach_cycle_ok`).
    """
    raw = env.unwrapped
    length = raw.episode_length
    start, goal = raw.initial_task_joint(), raw.task.goal_array
    hover, _ = _best_step(env, seed, start)
    wave = []
    for fraction in OSCILLATION_FRACTIONS:
        joint = start + fraction * (goal - start)
        if joint.shape == (7,):
            joint[3:] /= np.linalg.norm(joint[3:])
        wave.append(_best_step(env, seed, joint)[0])
    past = [_best_step(env, seed, joint) for joint in _overshoot_joints(raw)]
    past_rewards = [r for r, success in past if success == 0.0]
    parking = [hover]
    for distance in PARKING_DISTANCES:
        for axis in range(3):
            for sign in (1.0, -1.0):
                offset = np.zeros(3)
                offset[axis] = sign * distance
                parking.append(_best_step(env, seed, start, offset)[0])
    cycle, cycle_arms = _approach_cycle(env, seed)
    for arm in cycle_arms:
        parking.append(
            max(_posed_reward(env, seed, start, arm, f)[0] for f in FINGER_ACTIONS.values())
        )
    returns = {
        "hover": hover * length,
        "oscillate": float(np.mean(wave)) * length,
        "past_goal": max(past_rewards) * length if past_rewards else None,
        "parking": max(parking) * length,
        "approach_cycle": cycle * length,
    }
    best = max(v for v in returns.values() if v is not None)
    ratio = best / expert_return if expert_return > 0 else float("inf")
    cycle_ok = returns["approach_cycle"] <= returns["parking"]
    return {
        "exploit_returns": {k: None if v is None else round(v, 1) for k, v in returns.items()},
        "exploit_best": max((k for k, v in returns.items() if v is not None), key=returns.get),
        "exploit_ratio": round(ratio, 4),
        "approach_cycle_ok": bool(cycle_ok),
        "exploit_ok": bool(ratio <= EXPLOIT_RATIO_MAX and cycle_ok),
    }
