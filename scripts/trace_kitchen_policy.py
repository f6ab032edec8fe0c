"""Trace a trained single-kitchen-task policy: where its gripper goes and what the reward pays.

    python scripts/trace_kitchen_policy.py reports/bench_kitchen/<protocol>/<group>/seed-0/checkpoints/ckpt-0000535.pt
    python scripts/trace_kitchen_policy.py --expert bottom-right-burner   # the scripted expert, reward v3

Runs 3 deterministic episodes (env seeds 12345-12347, `seal eval`'s default) of the checkpoint's
policy on its one dense-kitchen task and prints, per episode: return, success, the task joint at
the start and end, the gripper-to-handle distance over the last 100 steps, the share of steps
with a closing finger effort, the reward's grasp/reach term over the last 100 steps and the
largest in-place term, the arm joints that end the episode at a limit and the arm's joint angles
at reset and at the first successful step; for a checkpoint also the critic's Q at reset (the lower
twin, of the action taken) beside what the episode earned from there, discounted at the agent's
gamma with the critic's own Q of the last state carried past the 280-step limit (a critic that
overestimates says more than the episode earns). The kitchen README's traces of the learned and
failed policies read these.
"""

from __future__ import annotations

import sys
from collections.abc import Callable

import mujoco
import numpy as np

from seal.envs import EnvAdapter, make_adapter
from seal.evaluation import AgentPolicy
from seal.run.setup import load_policy

ARM_JOINTS = 7
"""The Franka's arm joints (robot:panda0_joint1-7) are the model's first seven."""
AT_LIMIT = 0.01
"""A joint within this of an end of its range (rad) counts as at its limit."""


def pinned(model: mujoco.MjModel, data: mujoco.MjData) -> str:
    """The arm joints at a limit, as 'joint2 lower, joint6 upper' (or 'none')."""
    names = []
    for j in range(ARM_JOINTS):
        low, high = model.jnt_range[j]
        q = data.qpos[model.jnt_qposadr[j]]
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j).split("_")[-1]
        if q - low < AT_LIMIT:
            names.append(f"{name} lower")
        elif high - q < AT_LIMIT:
            names.append(f"{name} upper")
    return ", ".join(names) or "none"


def arm_angles(model: mujoco.MjModel, data: mujoco.MjData) -> str:
    """The arm joints' angles, as 'joint1 +0.15 joint2 -1.77 ...'."""
    return " ".join(
        f"joint{j + 1} {data.qpos[model.jnt_qposadr[j]]:+.2f}" for j in range(ARM_JOINTS)
    )


Critic = tuple[Callable[[np.ndarray, np.ndarray], float], float]
"""(the lower twin's Q of one observation and action, the discount) of a checkpoint's agent."""


def trace(
    adapter: EnvAdapter,
    act: Callable[[np.ndarray], np.ndarray],
    episodes: int = 3,
    critic: Critic | None = None,
) -> None:
    """Print one line per deterministic episode of `act` on the adapter's one task."""
    (task,) = adapter.tasks
    for episode in range(episodes):
        env = adapter.make(task, 12345 + episode)
        obs, info = env.reset(seed=12345 + episode)
        inner = env.unwrapped
        start = float(inner.task_joint()[0])
        if episode == 0:
            print(f"arm at reset: {arm_angles(inner.model, inner.data)}")
        effort, grasp, in_place, rewards, gap, success = [], [], [], [], [], []
        at_success = None
        q_reset = critic[0](obs, act(obs)) if critic else None
        for _ in range(adapter.episode_length):
            action = act(obs)
            obs, reward, terminated, truncated, info = env.step(action)
            reading = inner.reading(action)
            effort.append(reading.effort)
            grasp.append(info["grasp_reward"])
            in_place.append(info["in_place_reward"])
            rewards.append(reward)
            gap.append(float(np.linalg.norm(reading.tcp - reading.obj)))
            success.append(bool(info["success"]))
            if success[-1] and at_success is None:
                at_success = arm_angles(inner.model, inner.data)
            if terminated or truncated:
                break
        print(
            f"episode {episode}: return {sum(rewards):.1f}, success at the end {info['success']}, "
            # an evaluation counts an episode successful if any step is (Meta-World's rule)
            f"first success at step {success.index(True) + 1 if any(success) else None} "
            f"(successful steps {sum(success)}), "
            f"joint {start:.3f} -> {float(inner.task_joint()[0]):.3f} (goal {inner.task.goal[0]}), "
            f"gripper-handle last 100 steps {np.mean(gap[-100:]) * 100:.1f} cm, "
            f"closing effort share {np.mean(np.array(effort) > 0):.2f}, "
            f"grasp/reach term last 100 {np.mean(grasp[-100:]):.3f}, in_place max {max(in_place):.3f}, "
            f"arm joints at a limit at the end: {pinned(inner.model, inner.data)}, "
            f"arm at the first success: {at_success}"
            + (f", {_q_against_earned(critic, q_reset, rewards, obs, act(obs))}" if critic else "")
        )


def _q_against_earned(
    critic: Critic, q_reset: float, rewards: list[float], last_obs: np.ndarray, action: np.ndarray
) -> str:
    q, gamma = critic
    earned = sum(gamma**t * r for t, r in enumerate(rewards))
    earned += gamma ** len(rewards) * q(last_obs, action)  # the limit is a truncation: bootstrapped
    return f"critic's Q at reset {q_reset:.0f} against {earned:.0f} earned (discounted)"


def main(argv: list[str]) -> None:
    if argv[0] == "--expert":
        adapter = make_adapter("franka_kitchen_dense", tasks=[argv[1]])
        act = adapter.expert(argv[1])
        if act is None:
            sys.exit(f"no scripted expert for kitchen task {argv[1]!r}")
        trace(adapter, act)
        return
    config, _, agent, _ = load_policy(argv[0], "cpu")
    (env_name,) = list(config.envs)
    env_config = config.envs[env_name]
    # the run's own options (its reward version, episode length), not today's defaults
    adapter = make_adapter(env_config.adapter, tasks=list(env_config.tasks), **env_config.options)
    policy = AgentPolicy(agent, deterministic=True)

    def q(obs: np.ndarray, action: np.ndarray) -> float:
        return float(agent.q_values(env_name, obs[None], action[None], np.array([0])).min())

    trace(
        adapter,
        lambda obs: policy(env_name, obs[None], np.array([0]))[0],
        3,
        (q, config.agent.gamma),
    )


if __name__ == "__main__":
    main(sys.argv[1:])
