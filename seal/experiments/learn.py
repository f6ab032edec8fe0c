"""`seal bench --learn`: the learning evidence, slow and not part of CI.

MTMHSAC on `point` with and without the one-hot next to uniform random actions, and SAC on
Meta-World reach-v3, each an ordinary protocol under `protocols/learn/` run by the runner in this
process; what is measured is the env steps and gradient updates a run took, its wall time, its last
evaluation's success per task and which tasks ever reached the threshold.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np
import pandas as pd

if TYPE_CHECKING:
    from seal.envs.base import EnvAdapter


LEARN = Path(__file__).resolve().parents[2] / "protocols" / "learn"
"""The learning-evidence protocols (point with and without the one-hot, reach-v3)."""


class LearnResult(TypedDict):
    """`learn_protocol`'s record of one run."""

    env_steps: int
    gradient_updates: int
    epochs: int
    wall_s: float
    success: dict[str, float]
    reached: dict[str, bool]


def learn_protocol(
    name: str, seed: int = 0, overrides: Sequence[str] = (), out: Path | None = None
) -> LearnResult:
    """Run `protocols/learn/<name>.toml` (one seed, this process, the runner's phase loop).

    Into `out` (default: a temporary directory, removed after). Returns the env steps and
    gradient steps the run took (it may stop early: `evaluation.stop_when_reached`), its epochs,
    wall time, the last evaluation's success per task and which tasks ever reached the threshold.
    """
    import tempfile

    from seal.protocols import load_protocol
    from seal.run.runner import run_seed

    config = load_protocol(LEARN / f"{name}.toml", list(overrides))
    (env,) = config.envs
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        result = run_seed(config, seed, (out or Path(tmp)) / name)
        metrics = pd.read_csv(result.run_dir / "metrics.csv")
    (timing,) = result.timing.values()
    last = metrics[metrics["epoch"] == metrics["epoch"].max()]
    return {
        "env_steps": int(last["env_steps"].sum()),
        "gradient_updates": int(timing["grad_steps"]),
        "epochs": int(timing["epochs"]),
        "wall_s": time.perf_counter() - start,
        "success": result.final_success[env],
        "reached": {t: v is not None for t, v in result.update_counts[env].items()},
    }


def random_success(adapter: EnvAdapter, episodes: int = 20, seed: int = 0) -> dict[str, float]:
    """Success rate per task of uniform random actions."""
    from seal.learner.collection import Collector

    with Collector({adapter.name: adapter}, seed=seed, backend="sync") as col:
        runs = [col.collect_episodes(None, random_actions=True) for _ in range(episodes)]
    return {
        task: float(np.mean([r.successes[adapter.name][i] for r in runs]))
        for i, task in enumerate(adapter.tasks)
    }


def point_evidence(seed: int = 0) -> dict[str, Any]:
    """Random baseline, `protocols/learn/point.toml`, and its no-one-hot control for as many epochs."""
    from seal.envs.point import PointAdapter

    random = random_success(PointAdapter(), seed=seed)
    with_one_hot = learn_protocol("point", seed)
    epochs = f"protocol.epochs={with_one_hot['epochs']}"
    without = learn_protocol("point_no_one_hot", seed, [epochs])
    return {
        "random": random,
        "one_hot": with_one_hot,
        "no_one_hot": without,
        "checks": {
            "one_hot_all_tasks_100pct": all(with_one_hot["reached"].values()),
            "random_le_20pct": all(v <= 0.2 for v in random.values()),
            "no_one_hot_fails_a_task": any(v < 1.0 for v in without["success"].values()),
        },
    }


def run_learn(log: Callable[[str], None] = lambda _: None) -> dict[str, Any]:
    """The learning evidence: point with and without one-hot and a random baseline, then reach-v3."""
    log("learn: point (random, MTMHSAC, MTMHSAC without one-hot): protocols/learn/point*.toml")
    point = point_evidence()
    log("learn: reach-v3 SAC: protocols/learn/reach.toml")
    reach = learn_protocol("reach")
    return {
        "point_random": point["random"],
        "point_mtmhsac": point["one_hot"],
        "point_no_one_hot": point["no_one_hot"],
        "reach_v3_sac": reach,
        "checks": {**point["checks"], "reach_v3_ge_90pct": reach["reached"]["reach-v3"]},
    }
