"""scripts/evaluation_exactness.py: each side of the comparison runs into its own directory."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from tests.script_module import load_script

QUICKSTART = Path(__file__).resolve().parents[1] / "protocols" / "quickstart.toml"


def test_overrides_of_both_sides_keep_the_full_side_full(monkeypatch, tmp_path) -> None:
    # --base overrides go to both sides; the full run must still land under full/ and run
    # without the cheap options (a full side under cheap/ compared the cheap run with itself).
    script = load_script("evaluation_exactness")
    runs: list[tuple[Path, bool, bool]] = []

    def run_seed(config, seed, group, quiet):
        runs.append((group, config.evaluation.decide_early, config.evaluation.end_on_success))

    monkeypatch.setattr(script, "run_seed", run_seed)
    monkeypatch.setattr(script, "crossings", lambda run_dir, threshold: pd.DataFrame())
    monkeypatch.setattr(script, "training_rows", lambda run_dir: pd.DataFrame())
    monkeypatch.setattr(script, "timing", lambda run_dir: (1.0, 0.0, 0.0))
    base = ["--base", "protocol.epochs=20", "--seeds", "0", "--out", str(tmp_path)]
    assert script.main([str(QUICKSTART), *base]) == 0
    assert runs == [
        (tmp_path / "full" / "quickstart", False, False),
        (tmp_path / "cheap" / "quickstart", True, True),
    ]
