"""`seal bench --learn reach_sb3`: both sides of `e2e_vs_sb3` learn the task they are timed on.

Issue 36 item 2: Meta-World reach-v3 must reach >= 90% success at some evaluation within 100,000
env steps in >= 2 of 3 seeds, under SEAL's loop and under stable-baselines3's `SAC.learn`.

- SEAL: `seal run`'s runner on the shipped `protocols/learn/reach.toml` (SAC 2 x 256, batch 256,
  one gradient step per env step after a 4,000-step warm-up, 200-step episodes, 500 epochs).
- SB3: `SAC` with the same widths, batch, learning rate, gamma, tau and warm-up
  (`seal.bench.e2e.sb3_sac`), on an env built by the same `adapter.make(task, seed)`.
- Both are evaluated by the same code, `seal.evaluation.evaluate`, on evaluation instances seeded
  as the runner seeds its own (`build_eval_collector`): 10 deterministic episodes every 2,000 env
  steps (the protocol's `evaluation.interval` x `episode_length`), success at any step of an
  episode, the episode set drawn by the gradient-step count. SB3 acts through
  `predict(deterministic=True)`. Each run stops at its first evaluation at >= 90%.

Each (side, seed) is one Ray task on one CPU at one torch thread (`seal.experiments.launcher`:
a local Ray of `parallel` CPUs, or the cluster at `address`): SEAL's a protocol run into
`<out>/reach/<group>/seed-<N>` as every bench's, SB3's a call of `run_sb3_side`. Each writes
`<out>/<side>-seed<N>.json`, which `reuse` takes instead of running it again.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, TypedDict

from seal.errors import SealError, UnknownNameError
from seal.experiments.arms import Arm
from seal.experiments.launcher import launching, run_failure, seal_run_command
from seal.run.rundir import atomic_write_text

PROTOCOL = Path(__file__).resolve().parents[2] / "protocols" / "learn" / "reach.toml"
REACH = Arm("reach", "reach-v3", None, directory=PROTOCOL.parent)
"""SEAL's side as an arm (its `seal run` command line)."""
SIDES = ("seal", "sb3")
GOAL_SEEDS = 2
"""Issue 36 item 2: at least 2 of 3 seeds reach the threshold on each side."""


class SideRun(TypedDict):
    """One (side, seed) run: its evaluations and its first crossing."""

    side: str
    seed: int
    evaluations: list[dict[str, float]]
    """Each evaluation: env_steps, grad_steps, success."""
    reached_at_env_steps: int | None
    """Env steps at the first evaluation at >= the threshold (None: never within the budget)."""
    wall_s: float


def _evaluations_of(metrics_csv: Path) -> list[dict[str, float]]:
    import pandas as pd

    rows = pd.read_csv(metrics_csv)
    return [
        {
            "env_steps": int(r.env_steps),
            "grad_steps": int(r.grad_steps),
            "success": float(r.success),
        }
        for r in rows.itertuples()
    ]


def _side_run(
    side: str, seed: int, evaluations: list[dict[str, float]], threshold: float, wall_s: float
) -> SideRun:
    """The record of a run that took `wall_s` and evaluated `evaluations`."""
    from seal.evaluation import reaches

    return {
        "side": side,
        "seed": seed,
        "evaluations": evaluations,
        "reached_at_env_steps": next(
            (int(e["env_steps"]) for e in evaluations if reaches(e["success"], threshold)), None
        ),
        "wall_s": wall_s,
    }


SEAL_THREADS = ["protocol.threads=1"]
"""SEAL's side runs at one torch thread, as SB3's does (`run_sb3_side`)."""


def seal_side(run_dir: Path, seed: int, threshold: float, wall_s: float) -> SideRun:
    """The record of SEAL's run of `protocols/learn/reach.toml` in `run_dir`."""
    return _side_run("seal", seed, _evaluations_of(run_dir / "metrics.csv"), threshold, wall_s)


def run_sb3_side(seed: int, overrides: Sequence[str] = ()) -> SideRun:
    """SB3's `SAC.learn` on the protocol's task, evaluated by SEAL's evaluation every
    `evaluation.interval` x `episode_length` env steps, stopped at the first crossing."""
    import torch
    from stable_baselines3.common.callbacks import BaseCallback

    from seal.bench.e2e import sb3_sac
    from seal.bench.sb3 import _require_sb3
    from seal.evaluation import evaluate, reaches
    from seal.protocols import load_protocol
    from seal.run.phase_model import (
        PhaseModel,
        build_adapters,
        build_eval_collector,
        plan_phases,
    )

    _require_sb3()
    torch.set_num_threads(1)
    config = load_protocol(PROTOCOL, list(overrides))
    ((env, env_cfg),) = config.envs.items()
    (task,) = env_cfg.tasks
    adapters = build_adapters(config)
    adapter = adapters[env]
    every = config.evaluation.interval * adapter.episode_length
    budget = config.protocol.epochs * adapter.episode_length
    model = sb3_sac(config, adapter.make(task, seed), seed, budget + 1)
    (phase,) = plan_phases(config)
    collector = build_eval_collector(config, PhaseModel(config, phase, adapters, None), seed)
    evaluations: list[dict[str, float]] = []

    def policy(name: str, obs: Any, task_ids: Any) -> Any:
        return model.predict(obs, deterministic=True)[0]

    class Evaluate(BaseCallback):  # type: ignore[misc]
        def _on_step(self) -> bool:
            if self.num_timesteps % every:
                return True
            success = evaluate(
                policy,
                adapters,
                episodes=config.evaluation.episodes,
                seed=seed,
                collector=collector,
                draw=model._n_updates,
            )[env][task]["success"]
            evaluations.append(
                {
                    "env_steps": self.num_timesteps,
                    "grad_steps": model._n_updates,
                    "success": success,
                }
            )
            return not reaches(success, config.evaluation.threshold)

    start = time.perf_counter()
    try:
        model.learn(total_timesteps=budget, callback=Evaluate())
    finally:
        collector.close()
    wall_s = time.perf_counter() - start
    return _side_run("sb3", seed, evaluations, config.evaluation.threshold, wall_s)


def run_reach_sb3_bench(
    *,
    seeds: int = 3,
    out: str | Path = "reports/bench_reach_sb3",
    parallel: int = 2,
    log: Callable[[str], None] = print,
    only: Sequence[str] | None = None,
    reuse: bool = False,
    overrides: Sequence[str] = (),
    address: str | None = None,
) -> dict[str, Any]:
    """Run seeds 0..seeds-1 on each side (`only`: the sides to run) as Ray tasks of one CPU each,
    on a local Ray of `parallel` CPUs or the cluster at `address`, and return the per-run records
    and each side's k of n within the budget. Each record is written as it finishes, with the
    overrides it ran under; `reuse` takes only a record of the same overrides."""
    from seal.protocols import load_protocol
    from seal.run.rundir import seed_dir
    from seal.run.runner import new_group_dir

    for side in only or ():
        if side not in SIDES:
            raise UnknownNameError("reach_sb3 side", side, list(SIDES))
    sides = [s for s in SIDES if not only or s in only]
    root = Path(out).absolute()
    root.mkdir(parents=True, exist_ok=True)
    runs: dict[tuple[str, int], dict[str, Any]] = {}
    todo = []
    for side in sides:
        for seed in range(seeds):
            path = root / f"{side}-seed{seed}.json"
            saved = json.loads(path.read_text()) if reuse and path.exists() else None
            if saved is not None and saved.get("overrides") == list(overrides):
                runs[side, seed] = saved
                log(f"reuse {side} seed {seed}: {path}")
            else:
                todo.append((side, seed))
    start = time.perf_counter()
    if todo:
        log(f"{len(todo)} runs: " + ", ".join(f"{s} seed {n}" for s, n in todo))
        config = load_protocol(PROTOCOL, [*SEAL_THREADS, *overrides])
        group = new_group_dir(config, root)
        with launching(root, parallel, address, log) as launch:
            launch.hint = "run the same command with --reuse to take the finished runs' records"
            for side, seed in todo:
                if side == "seal":
                    command = seal_run_command(REACH, seed, root, [*SEAL_THREADS, *overrides])
                    launch.run((side, seed), config, seed_dir(group, seed), 1, command)
                else:
                    launch.call((side, seed), run_sb3_side, seed, list(overrides))
            while launch.pending:
                (side, seed), got = launch.next()
                if side == "seal":
                    if got.status != "finished":
                        raise SealError(run_failure(got))
                    threshold = config.evaluation.threshold
                    got = seal_side(Path(got.run_dir), seed, threshold, got.wall_s)
                record = {**got, "overrides": list(overrides)}
                atomic_write_text(root / f"{side}-seed{seed}.json", json.dumps(record, indent=2))
                log(
                    f"done {side} seed {seed} in {got['wall_s']:.0f} s: "
                    f"reached at {got['reached_at_env_steps']} env steps"
                )
                runs[side, seed] = record
    summary = {
        side: {
            "reached": sum(runs[side, s]["reached_at_env_steps"] is not None for s in range(seeds)),
            "seeds": seeds,
            "goal_met": sum(runs[side, s]["reached_at_env_steps"] is not None for s in range(seeds))
            >= GOAL_SEEDS,
        }
        for side in sides
    }
    return {
        "protocol": str(PROTOCOL),
        "wall_s": time.perf_counter() - start,
        "runs": [runs[side, s] for side in sides for s in range(seeds)],
        "summary": summary,
    }


def format_result(result: Mapping[str, Any]) -> str:
    """One line per run and one per side: k of n seeds at >= 90% within the budget."""
    lines = ["side  seed  first evaluation >= 90% (env steps)  evaluations  wall"]
    for run in result["runs"]:
        at = run["reached_at_env_steps"]
        lines.append(
            f"{run['side']:<5} {run['seed']:>4}  {'never' if at is None else f'{at:,}':>34}"
            f"  {len(run['evaluations']):>11}  {run['wall_s']:.0f} s"
        )
    for side, s in result["summary"].items():
        lines.append(
            f"{side}: {s['reached']} of {s['seeds']} seeds reach 90% "
            f"(goal >= {GOAL_SEEDS}: {'met' if s['goal_met'] else 'not met'})"
        )
    return "\n".join(lines)
