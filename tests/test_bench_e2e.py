"""`seal bench --only e2e_vs_sb3`: the two sides do the same work, read back from their counters
(no timing asserts: tiny sizes, only what is computed)."""

from __future__ import annotations

import pytest

from seal.bench.e2e import bench_e2e
from seal.bench.suite import format_table
from seal.run.state import LOOP_PARTS

pytest.importorskip("stable_baselines3")


def test_both_sides_do_the_same_work_on_reach() -> None:
    # 20-step episodes: two of warm-up, then three with one update per env step.
    # agent.compile=false: the shipped protocol compiles; a cold compile costs ~20-80 s a test.
    figure = bench_e2e(
        "reach-v3",
        steps=60,
        warmup=40,
        overrides=["envs.mw.episode_length=20", "agent.compile=false"],
    )
    seal, sb3 = figure["seal"], figure["sb3"]
    for side in (seal, sb3):
        assert side["env_steps"] == 60 and side["updates"] == 60
        assert side["samples_per_update"] == 256.0
        assert side["wall_s"] > 0
    assert set(seal["shares"]) == {*LOOP_PARTS, "other"}
    assert sum(seal["shares"].values()) == pytest.approx(1.0)
    assert seal["shares"]["evaluate"] == 0.0  # no evaluation inside the window
    assert figure["e2e_vs_sb3"] == pytest.approx(sb3["wall_s"] / seal["wall_s"])
    table = format_table(
        {
            "e2e_vs_sb3": {"reach-v3": figure["e2e_vs_sb3"]},
            "details": {"e2e_vs_sb3": {"reach-v3": figure, "sac_vs_sb3_256": {"sac_vs_sb3": 1.5}}},
            "load_before": {"loadavg_1m": 1.0, "cpus": 2, "torch_threads": 1},
            "load_after": {"loadavg_1m": 1.0},
        }
    )
    assert "e2e_vs_sb3 reach-v3" in table and ">=1.3" in table and "(256, 256) 1.50" in table
