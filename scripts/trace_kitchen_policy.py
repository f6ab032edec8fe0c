"""Trace a trained single-kitchen-task policy: where its gripper goes and what the reward pays.

    python scripts/trace_kitchen_policy.py reports/bench_kitchen/<protocol>/<group>/seed-0/checkpoints/ckpt-0000535.pt

Runs 3 deterministic episodes (env seeds 12345-12347, `seal eval`'s default) of the checkpoint's
policy on its one dense-kitchen task and prints, per episode: return, success, the task joint at
the start and end, the gripper-to-handle distance over the last 100 steps, the share of steps
with a closing finger effort, the reward's grasp/reach term over the last 100 steps and the
largest in-place term. The kitchen README's "why the burner is not learned" reads these.
"""

from __future__ import annotations

import sys

import numpy as np

from seal.envs import make_adapter
from seal.evaluation import AgentPolicy
from seal.protocols.runner import load_policy


def trace(checkpoint: str, episodes: int = 3) -> None:
    config, _, agent, _ = load_policy(checkpoint, "cpu")
    (env_name,) = list(config.envs)
    env_config = config.envs[env_name]
    # the run's own options (its reward version, episode length), not today's defaults
    adapter = make_adapter(env_config.adapter, tasks=list(env_config.tasks), **env_config.options)
    (task,) = adapter.tasks
    policy = AgentPolicy(agent, deterministic=True)
    for episode in range(episodes):
        env = adapter.make(task, 12345 + episode)
        obs, info = env.reset(seed=12345 + episode)
        inner = env.unwrapped
        start = float(inner.task_joint()[0])
        effort, grasp, in_place, rewards, gap, success = [], [], [], [], [], []
        for _ in range(adapter.episode_length):
            action = policy(env_name, obs[None], np.array([0]))[0]
            obs, reward, terminated, truncated, info = env.step(action)
            reading = inner.reading(action)
            effort.append(reading.effort)
            grasp.append(info["grasp_reward"])
            in_place.append(info["in_place_reward"])
            rewards.append(reward)
            gap.append(float(np.linalg.norm(reading.tcp - reading.obj)))
            success.append(bool(info["success"]))
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
            f"grasp/reach term last 100 {np.mean(grasp[-100:]):.3f}, in_place max {max(in_place):.3f}"
        )


if __name__ == "__main__":
    trace(sys.argv[1])
