"""`seal bench --learn reach_sb3`: both sides evaluated on one grid by SEAL's evaluation, each
stopped at its first crossing (tiny sizes: only what is computed, no learning asserted)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from seal.experiments.reach_sb3 import (
    PROTOCOL,
    SEAL_THREADS,
    SideRun,
    format_result,
    run_reach_sb3_bench,
    run_sb3_side,
    seal_side,
)

pytest.importorskip("stable_baselines3")

# 5-step episodes: the hand moves at most a few cm, and reach-v3's goal is >= 20 cm away, so no
# episode can succeed; 10 warm-up steps; an evaluation every 2 epochs = 10 env steps; 50 in all.
TINY = [
    "envs.mw.episode_length=5",
    "training.warmup_steps=10",
    "protocol.epochs=10",
    "evaluation.interval=2",
    "evaluation.episodes=2",
    "training.batch_per_task=16",
    "agent.hidden=[16,16]",
    "agent.compile=false",  # the shipped protocol compiles; a cold compile costs ~20-80 s a test
]


def run_seal_side(seed: int, out: Path, overrides: list[str]) -> SideRun:
    """SEAL's side as the bench's Ray task runs it (`run_seed` at one thread), in this process."""
    from seal.protocols import load_protocol
    from seal.run.runner import run_seed

    config = load_protocol(PROTOCOL, [*SEAL_THREADS, *overrides])
    result = run_seed(config, seed, out)
    return seal_side(result.run_dir, seed, config.evaluation.threshold, 0.0)


def test_both_sides_evaluate_on_the_same_env_step_grid(tmp_path: Path) -> None:
    sb3 = run_sb3_side(0, TINY)
    seal = run_seal_side(0, tmp_path, TINY)
    for run in (sb3, seal):
        assert [e["env_steps"] for e in run["evaluations"]] == [10, 20, 30, 40, 50]
        assert all(e["success"] == 0.0 for e in run["evaluations"])
        assert run["reached_at_env_steps"] is None
    # SB3 updates once per env step after `learning_starts` (from step 11); SEAL's epoch loop
    # updates once per env step of each epoch from the one that completes the warm-up (5 steps
    # of updates at env step 10).
    assert [e["grad_steps"] for e in sb3["evaluations"]] == [0, 9, 19, 29, 39]
    assert [e["grad_steps"] for e in seal["evaluations"]] == [5, 15, 25, 35, 45]


def test_each_run_stops_at_its_first_crossing(tmp_path: Path) -> None:
    # At threshold 0 every evaluation crosses: both runs stop at their first, env step 10.
    at_zero = [*TINY, "evaluation.threshold=0.0"]
    for run in (run_sb3_side(1, at_zero), run_seal_side(1, tmp_path, at_zero)):
        assert run["reached_at_env_steps"] == 10
        assert len(run["evaluations"]) == 1


@pytest.mark.slow  # two local Rays start (~1 min beside two learning runs on 2 cores)
def test_bench_counts_seeds_and_reuses_finished_runs(tmp_path: Path) -> None:
    # Both sides as Ray tasks: SEAL's a protocol run, SB3's a call of run_sb3_side.
    logs: list[str] = []
    kwargs = dict(seeds=1, out=tmp_path, parallel=2, overrides=[*TINY, "evaluation.threshold=0.0"])
    result = run_reach_sb3_bench(log=logs.append, **kwargs)  # type: ignore[arg-type]
    goal = {"reached": 1, "seeds": 1, "goal_met": False}
    assert result["summary"] == {"seal": goal, "sb3": goal}
    for side in ("seal", "sb3"):
        saved = json.loads((tmp_path / f"{side}-seed0.json").read_text())
        assert saved["reached_at_env_steps"] == 10, side
    (run,) = tmp_path.glob("*/*/seed-0")  # SEAL's run directory, as `seal run` writes it
    assert (run / "metrics.csv").is_file()
    again = run_reach_sb3_bench(log=logs.append, reuse=True, **kwargs)  # type: ignore[arg-type]
    assert again["runs"] == result["runs"]
    assert any(line.startswith("reuse sb3 seed 0") for line in logs)
    assert any(line.startswith("reuse seal seed 0") for line in logs)
    assert "sb3: 1 of 1 seeds reach 90% (goal >= 2: not met)" in format_result(again)
    # A record made under other overrides is run again, not taken.
    logs.clear()
    other = {**kwargs, "overrides": [*kwargs["overrides"], "evaluation.episodes=1"]}  # type: ignore[dict-item]
    run_reach_sb3_bench(log=logs.append, reuse=True, only=["sb3"], **other)  # type: ignore[arg-type]
    assert not any(line.startswith("reuse") for line in logs)
