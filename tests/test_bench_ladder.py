"""`seal bench --learn transfer --ladder` on tiny runs read with --no-run: the eight arms, the
factorial's effects from their per-seed figures, each piece's end drift, and the files."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from seal.cli.main import main
from seal.experiments import ladder_bench
from seal.experiments.arms import LADDER_ARMS, arms
from seal.experiments.ladder import effects_per_seed
from seal.experiments.records import last_checkpoint
from seal.protocols import load_protocol
from seal.run.runner import run_seed
from tests.testbed_tiny import TINY

SEEDS = 2


@pytest.fixture(scope="module")
def out(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Seeds 0-1 of every arm the ladder needs, laid out as the bench lays them out."""
    root = tmp_path_factory.mktemp("bench")
    for seed in range(SEEDS):
        checkpoint = None
        for arm in arms(only=LADDER_ARMS):  # the pre-training comes before the arms it starts
            extra = [] if arm.pretrain is None else [f"transfer.checkpoint={checkpoint}"]
            config = load_protocol(arm.protocol, [*TINY, *extra])
            run = run_seed(config, seed, root / config.name / "g").run_dir
            if not arm.has_target:
                checkpoint = last_checkpoint(run)
    return root


@pytest.fixture(scope="module")
def result(out: Path) -> dict[str, Any]:
    return ladder_bench.run_ladder_bench(seeds=3, out=out, run=False, overrides=TINY)


@pytest.mark.slow
def test_the_ladder_reads_its_arms_and_names_the_missing_seed(result: dict[str, Any]) -> None:
    ladder = result["ladder"]
    assert list(ladder["arms"]) == list(LADDER_ARMS)
    assert result["seeds"] == SEEDS  # seed 2 has no run: the seeds 0-1 that have every arm
    assert result["missing"] == [f"{a.name}/seed-2" for a in arms(only=LADDER_ARMS)]
    assert ladder["arms"]["oracle_translator"]["pieces"] == []
    assert ladder["arms"]["ladder_critic_temperature"]["pieces"] == ["critic", "temperature"]
    assert ladder["arms"]["oracle_policy"]["pieces"] == ["head", "critic", "temperature"]
    for name, arm in ladder["arms"].items():
        assert arm["auc_per_seed"] == result["arms"][name]["auc_per_seed"]
        assert len(arm["steps_saved_per_seed"]) == SEEDS


@pytest.mark.slow
def test_the_effects_are_the_factorials_of_the_arms_figures(result: dict[str, Any]) -> None:
    ladder = result["ladder"]
    cells = {name: a["pieces"] for name, a in ladder["arms"].items()}
    for stat, key in (("auc", "auc_per_seed"), ("steps", "steps_saved_per_seed")):
        per_seed = effects_per_seed({a: result["arms"][a][key] for a in cells}, cells)
        effects = ladder["effects"][stat]
        assert list(effects) == list(per_seed)
        for name, values in per_seed.items():
            assert effects[name]["per_seed"] == pytest.approx(values), (stat, name)
            assert {"mean", "ci95", "sd_paired", "mde", "seeds_for_mde_0p10"} <= set(effects[name])
    # By hand, seed 0: the head's main effect on AUC = mean of the 4 arms with it - the 4 without.
    auc = {a: result["arms"][a]["auc_per_seed"][0] for a in cells}
    with_head = np.mean([auc[a] for a in cells if "head" in cells[a]])
    without = np.mean([auc[a] for a in cells if "head" not in cells[a]])
    assert ladder["effects"]["auc"]["head"]["per_seed"][0] == pytest.approx(with_head - without)


@pytest.mark.slow
def test_each_pieces_end_drift_is_read_from_the_runs(result: dict[str, Any], out: Path) -> None:
    drift = result["ladder"]["drift"]
    assert set(drift["per_arm"]) == {*LADDER_ARMS, "alone"}
    run = Path(result["run_dirs"]["ladder_head/seed-1"])
    train = pd.read_csv(run / "train.csv")
    last = train[(train["env"] == "target") & (train["key"] == "drift/head")].iloc[-1]
    assert drift["per_arm"]["ladder_head"]["head"]["per_seed"][1] == pytest.approx(last["value"])
    head = drift["per_piece"]["head"]
    mapped = [a for a in LADDER_ARMS if "head" in result["ladder"]["arms"][a]["pieces"]]
    assert head["mapped"] == pytest.approx(
        np.mean([v for a in mapped for v in drift["per_arm"][a]["head"]["per_seed"]])
    )
    assert drift["per_piece"]["translator"]["fresh"] is None  # mapped in every arm
    assert drift["per_piece"]["translator"]["alone"] > 0


@pytest.mark.slow
def test_the_files_and_the_output(result: dict[str, Any]) -> None:
    files = result["ladder"]["files"]
    assert json.loads(Path(files["json"]).read_text())["effects"].keys() == {"auc", "steps"}
    assert Path(files["plot"]).is_file()
    assert sorted(Path(p).name for p in files["tables"]) == ["ladder.md", "ladder.tex"]
    assert all(Path(p).is_file() for p in files["tables"])
    text = ladder_bench.format_ladder_result(result)
    ladder_part = text[text.index("# Ladder") : text.index("Ladder figures:")]
    assert "head x critic x temperature" in ladder_part and "oracle_policy" in ladder_part
    assert max(len(line) for line in ladder_part.splitlines()) <= 100
    assert "--no-run: seeds 0-1 have a finished run of every arm" in text


def test_the_cli_wires_ladder_no_run_and_reuse(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    called: list[dict[str, Any]] = []

    def fake(**kwargs: Any) -> dict[str, Any]:
        called.append(kwargs)
        return {"ladder": {"arms": {}}}

    monkeypatch.setattr(ladder_bench, "run_ladder_bench", fake)
    monkeypatch.setattr(ladder_bench, "format_ladder_result", lambda result: "the ladder's text")
    assert main(["bench", "--learn", "transfer", "--ladder", "--no-run", "--out", "D"]) == 0
    assert capsys.readouterr().out == "the ladder's text\n"
    assert (
        main(["bench", "--learn", "transfer", "--ladder", "--reuse", "--seeds", "3", "--json"]) == 0
    )
    assert json.loads(capsys.readouterr().out) == {"ladder": {"arms": {}}}
    assert [(c["run"], c["reuse"], c["seeds"], c["out"], c["parallel"]) for c in called] == [
        (False, False, 5, "D", 2),
        (True, True, 3, "reports/bench_transfer", 2),
    ]
    for bad in (["--full"], ["--fpr"], ["--arms", "alone"], ["--seeds-until-mde", "0.1"]):
        args = ["bench", "--learn", "transfer", "--ladder", *bad]
        if bad[0] == "--seeds-until-mde":
            args += ["--max-seeds", "6"]
        assert main(args) == 2, bad
        assert "--ladder only applies to --learn transfer" in capsys.readouterr().err
    assert main(["bench", "--learn", "kitchen", "--ladder"]) == 2
    assert "--ladder only applies to --learn transfer" in capsys.readouterr().err
    assert main(["bench", "--learn", "transfer", "--fpr", "--no-run"]) == 2
    assert (
        "--no-run only applies to --learn kitchen, learner, mtrl and transfer"
        in capsys.readouterr().err
    )
