"""`seal eval CHECKPOINT [--episodes N] [--video DIR]`: evaluate a saved policy on its tasks."""

from __future__ import annotations

import argparse
import json
import os


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add `seal eval`."""
    p = subparsers.add_parser(
        "eval",
        help="evaluate a run checkpoint (deterministic policy, success at any step)",
        description=__doc__,
    )
    p.add_argument(
        "checkpoint",
        metavar="CHECKPOINT",
        help="a checkpoint of a run, e.g. reports/<protocol>/<group>/seed-0/checkpoints/best.pt",
    )
    p.add_argument(
        "--episodes",
        type=int,
        default=None,
        metavar="N",
        help="episodes per task (default: the run's [evaluation].episodes)",
    )
    p.add_argument(
        "--seed", type=int, default=12345, help="seed of the evaluation envs (default: 12345)"
    )
    p.add_argument("--device", default="auto", help="torch device (default: auto)")
    p.add_argument(
        "--video",
        default=None,
        metavar="DIR",
        help="also write one MP4 per task under DIR (needs offscreen MuJoCo rendering: EGL or OSMesa)",
    )
    p.add_argument(
        "--json",
        action="store_true",
        help='print one JSON line {"checkpoint", "phase", "epoch", "episodes", "success": {env: {task: s}}, "return": {...}, "videos": [paths]}',
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Load the checkpoint, evaluate, print a table or JSON, optionally record videos."""
    from seal.errors import SealError
    from seal.evaluation import evaluate, mean_success, record_videos, rendering_problem
    from seal.run.resources import check_evaluation_memory
    from seal.run.setup import load_policy

    if args.episodes is not None and args.episodes < 1:
        raise SealError(f"--episodes {args.episodes}: must be >= 1")
    if args.seed < 0:
        raise SealError(f"--seed {args.seed}: must be >= 0")
    if args.video and "MUJOCO_GL" not in os.environ:
        # MuJoCo's default (GLFW) needs a display; pick a headless backend that works here
        # before anything imports mujoco.
        for backend in ("egl", "osmesa"):
            os.environ["MUJOCO_GL"] = backend
            if rendering_problem() is None:
                break
        else:
            del os.environ["MUJOCO_GL"]
    config, model, agent, data = load_policy(args.checkpoint, args.device)
    episodes = args.episodes or config.evaluation.episodes
    tasks = sum(len(a.tasks) for a in model.adapters.values())
    check_evaluation_memory(
        episodes, tasks, "--episodes" if args.episodes else "evaluation.episodes"
    )
    policy = model.policy(agent, deterministic=True)
    if args.video:
        # Checked first: a machine that cannot render says so before minutes of evaluation.
        written = record_videos(policy, model.adapters, args.video, seed=args.seed)
    else:
        written = []
    results = evaluate(
        policy, model.adapters, episodes=episodes, seed=args.seed, backend=config.training.collector
    )
    if args.json:
        print(
            json.dumps(
                {
                    "checkpoint": str(args.checkpoint),
                    "phase": data["phase"],
                    "epoch": data["epoch"],
                    "episodes": episodes,
                    "success": {
                        e: {t: v["success"] for t, v in r.items()} for e, r in results.items()
                    },
                    "return": {
                        e: {t: v["return"] for t, v in r.items()} for e, r in results.items()
                    },
                    "videos": [str(p) for p in written],
                }
            )
        )
        return 0
    print(
        f"{args.checkpoint}: protocol {config.name!r}, phase {data['phase']!r}, epoch {data['epoch']}, {episodes} episodes per task"
    )
    width = max(len(t) for r in results.values() for t in r)
    for env, per_task in results.items():
        for task, v in per_task.items():
            print(
                f"  {env:<10} {task:<{width}}  success {v['success']:.2f}  return {v['return']:9.2f}"
            )
    print(f"  mean success {mean_success(results):.3f}")
    for path in written:
        print(f"  video: {path}")
    return 0
