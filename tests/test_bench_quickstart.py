"""`seal bench --learn quickstart`: the README's table, curve and k-of-n line from the shipped file."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from seal.errors import SealError
from seal.experiments.quickstart import (
    arms,
    format_result,
    k_of_n_line,
    run_quickstart_bench,
    where_run,
)
from seal.provenance import cpu_model
from tests.test_bench_table1 import TINY


def test_k_of_n_counts_a_seed_only_when_every_task_reached() -> None:
    reached = {
        0: {"drawer-close-v3 (mw)": True, "slide-cabinet (fk)": True},
        1: {"drawer-close-v3 (mw)": True, "slide-cabinet (fk)": False},
        2: {"drawer-close-v3 (mw)": False, "slide-cabinet (fk)": False},
        3: {"drawer-close-v3 (mw)": True, "slide-cabinet (fk)": True},
    }
    line = k_of_n_line(reached, "this CPU")
    assert "in **2 of 4 seeds** (seeds 0-3; this CPU)" in line
    assert "Seed 1 did not reach: slide-cabinet (fk)." in line
    assert "Seed 2 did not reach: drawer-close-v3 (mw), slide-cabinet (fk)." in line
    assert "Seed 0 did not" not in line and "Seed 3 did not" not in line


def test_where_names_each_runs_recorded_cpu() -> None:
    """The line names the CPUs the runs recorded, not the machine that reads them."""
    one = where_run(dict.fromkeys(range(10), "CPU A, 2 CPUs"), None)
    assert one == "CPU A, 2 CPUs; protocol.threads = as shipped"
    b = dict.fromkeys((7, 8, 9), "CPU B, 16 CPUs")
    mixed = where_run({**dict.fromkeys(range(7), "CPU A, 2 CPUs"), **b}, "1")
    assert (
        mixed == "CPU A, 2 CPUs for seeds 0-6; CPU B, 16 CPUs for seeds 7-9; protocol.threads = 1"
    )
    old = where_run({0: None, 2: None, 3: "CPU B, 16 CPUs"}, None)
    here = f"this machine: {cpu_model()}, {os.cpu_count()} CPUs"
    assert old == (
        f"CPU not recorded ({here}) for seeds 0, 2; CPU B, 16 CPUs for seeds 3; "
        "protocol.threads = as shipped"
    )


def test_only_the_quickstart_arm() -> None:
    assert [a.name for a in arms()] == ["quickstart"]
    with pytest.raises(SealError, match="unknown quickstart arm 'nope'"):
        arms(["nope"])


@pytest.mark.slow
def test_tiny_end_to_end_writes_the_readme_pieces(tmp_path: Path) -> None:
    # Two seeds of the shipped file at tiny sizes (2 epochs of 2 updates): the plumbing only.
    docs = tmp_path / "docs"
    docs.mkdir()
    result = run_quickstart_bench(
        seeds=2, out=tmp_path / "runs", overrides=TINY, docs=docs, parallel=2
    )
    assert sorted(result["run_dirs"]) == ["seed-0", "seed-1"] and result["n"] == 2
    assert set(result["reached"]) == {"0", "1"}
    assert all(len(tasks) == 2 for tasks in result["reached"].values())
    assert result["goal"]["met"] is None  # fewer than 10 seeds are not judged
    page = (docs / "quickstart_table.md").read_text()
    assert f"in **{result['k']} of 2 seeds**" in page
    assert "Seed 0 alone (what README command 1 prints)" in page
    assert "slide-cabinet (FK)" in page and "drawer-close-v3 (MW)" in page
    assert (docs / "quickstart_success_fk.png").stat().st_size > 0
    assert "Goal: >= 9 of 10 seeds: not judged" in format_result(result)
