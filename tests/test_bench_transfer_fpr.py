"""The transfer bench's false-positive rate (`--fpr`) and its seeds-until-the-MDE rule
(`--seeds-until-mde`), on finished runs and runs made up by hand."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from seal.errors import SealError
from seal.experiments.arms import ARMS, arms
from seal.protocols import load_protocol
from seal.protocols.loader import config_to_dict
from tests.test_bench_transfer import _metrics

# ---------------------------------------------------------------- the false-positive rate


def _finished_alone_runs(root: Path, steps: list[int]) -> None:
    """Finished runs of the alone arm under `root`, today's config, one per seed, whose target
    reaches 90% on every task at `steps[seed]` gradient steps."""
    from seal.protocols.toml_io import dumps_toml

    arm = next(a for a in ARMS if a.name == "alone")
    config = load_protocol(arm.protocol)
    for seed, reach in enumerate(steps):
        run = root / config.name / f"20261201-000000-{seed:06d}" / f"seed-{seed}"
        run.mkdir(parents=True)
        (run / "config.toml").write_text(dumps_toml(config_to_dict(config)))
        lines = [
            f"{seed},train,{epoch},target,{task},{1.0 if 50 * epoch >= reach else 0.0},-1.0,"
            f"{50 * epoch},{100 * epoch},{50 * epoch * 8e-6},1.0"
            for epoch in range(2, 101, 2)
            for task in ("t0", "t1", "t2", "t3")
        ]
        (run / "metrics.csv").write_text(
            "seed,phase,epoch,env,task,success,return,grad_steps,env_steps,updates,wall_s\n"
            + "\n".join(lines)
            + "\n"
        )
        (run / "provenance.json").write_text(
            json.dumps({"seed": seed, "git_sha": "abc", "end_time": "2026-12-01T00:10:00"})
        )


def test_fpr_bench_on_ten_finished_alone_runs(tmp_path) -> None:
    from seal.experiments.transfer import format_fpr, run_fpr_bench
    from seal.stats import binomial_ci

    steps = [2000, 2500, 3000, 2200, 2800, 2600, 2400, 3100, 1900, 2700]
    _finished_alone_runs(tmp_path, steps)
    result = run_fpr_bench(out=tmp_path, reuse=True, splits=200)
    assert len(result["reused"]) == 10  # nothing was run
    assert result["grad_steps_to_90_per_seed"] == steps
    rate = result["false_positive_rate"]
    assert (rate["splits"], rate["half"], rate["seeds"]) == (200, 5, 10)
    assert rate["rate"] == rate["excluding_0"] / 200
    assert rate["rate_ci95"] == pytest.approx(list(binomial_ci(rate["excluding_0"], 200)))
    assert result["goal"]["met"] is (rate["rate"] <= 0.10)
    text = format_fpr(result)
    assert "200 random 5/5 splits" in text and "percentile bootstrap (the arms" in text
    with pytest.raises(SealError, match="needs >= 10"):
        run_fpr_bench(seeds=9, out=tmp_path, reuse=True)


def test_cli_fpr_only_with_learn_transfer(capsys) -> None:
    from seal.cli.main import main

    assert main(["bench", "--learn", "table1", "--fpr"]) == 2
    assert "--fpr only applies to --learn transfer" in capsys.readouterr().err
    assert main(["bench", "--learn", "transfer", "--fpr", "--full"]) == 2


# ---------------------------------------------------------------- seeds until the MDE (issue 58 item 4)


def test_cli_seeds_until_mde_errors_are_one_line(capsys) -> None:
    from seal.cli.main import main

    cases = [
        (["--learn", "table1", "--seeds-until-mde", "0.1", "--max-seeds", "10"], "only apply to"),
        (["--seeds-until-mde", "0.1", "--max-seeds", "10"], "only apply to --learn transfer"),
        (["--learn", "transfer", "--seeds-until-mde", "0.1"], "go together"),
        (["--learn", "transfer", "--max-seeds", "10"], "go together"),
        (["--learn", "transfer", "--seeds-until-mde", "0.1", "--max-seeds", "4"], "expected >= 5"),
        (["--learn", "transfer", "--seeds-until-mde", "0", "--max-seeds", "10"], "MDE > 0"),
        (
            ["--learn", "transfer", "--seeds", "5", "--seeds-until-mde", "0.1", "--max-seeds", "9"],
            "give one of them",
        ),
        (
            ["--learn", "transfer", "--fpr", "--seeds", "40", "--seeds-until-mde", "0.1"]
            + ["--max-seeds", "20"],
            "give one of them",
        ),
    ]
    for argv, message in cases:
        assert main(["bench", *argv]) == 2, argv
        err = capsys.readouterr().err.strip()
        assert message in err and len(err.splitlines()) == 1, (argv, err)


def _reaching(reach: dict[str, int | None]) -> pd.DataFrame:
    """A run's target metrics: each task succeeds from its `reach` gradient step on (None: never),
    evaluated every 100 steps up to 5,000."""
    rows = [
        (epoch, "target", task, float(at is not None and 100 * epoch >= at), 100 * epoch, 1e-3)
        for epoch in range(1, 51)
        for task, at in reach.items()
    ]
    return _metrics(rows)


def _fake_runs(monkeypatch, reach_of) -> list[list[int]]:
    """The rule's loop on made-up runs: run_or_reuse returns a path per job, load_run a run whose
    metrics `reach_of(arm, seed)` makes; the report is skipped. Returns the seeds of each call."""
    import types

    import seal
    import seal.experiments.transfer as transfer

    calls: list[list[int]] = []

    def run_or_reuse(jobs, out, overrides, parallel, log, reuse, *, address=None):
        calls.append(sorted({s for _, s in jobs}))
        return {(a.name, s): Path(f"/made-up/{a.name}/{s}") for a, s in jobs}, {}

    def load_run(path):
        arm, seed = Path(path).parts[-2], int(Path(path).parts[-1])
        return types.SimpleNamespace(metrics=reach_of(arm, seed), provenance={})

    monkeypatch.setattr(transfer, "run_or_reuse", run_or_reuse)
    monkeypatch.setattr(seal, "load_run", load_run)
    monkeypatch.setattr(transfer, "_result", lambda chosen, seeds, *a, **k: {"seeds": seeds})
    return calls


def test_seeds_until_mde_stops_when_the_named_statistics_are_precise(monkeypatch) -> None:
    from seal.experiments.until_mde import format_until_mde, run_transfer_until_mde

    def reach_of(arm: str, seed: int) -> pd.DataFrame:
        alone = 2000 + 100 * (seed % 3)
        saves = 100 + 100 * (seed % 2)
        at = {"alone": alone, "high_source": alone - saves, "no_correspondence": alone}[arm]
        return _reaching({t: at for t in ("t0", "t1", "t2", "t3")})

    calls = _fake_runs(monkeypatch, reach_of)
    result = run_transfer_until_mde(
        0.10, 9, only=["high_source", "no_correspondence"], batch=2, log=print
    )
    rule = result["seeds_until_mde"]
    assert calls == [[0, 1, 2, 3, 4]] and result["seeds"] == rule["seeds_used"] == 5
    assert rule["stopped_because"] == "target reached" and rule["above_target"] == []
    assert rule["rule"] == {
        **rule["rule"],
        "target": 0.10,
        "max_seeds": 9,
        "batch": 2,
        "first": 5,
        "schedule": [5, 7, 9],
        "sd_bound_confidence": 0.8,
        "statistics": [
            "high_source/steps",
            "high_source/auc",
            "no_correspondence/steps",
            "no_correspondence/auc",
        ],
    }
    (look,) = rule["looks"]
    # high_source saves 100, 200, 100, 200, 100 steps of the alone arm's mean 2,080.
    assert look["statistics"]["high_source/steps"]["sd"] == pytest.approx(
        np.std([100, 200, 100, 200, 100], ddof=1) / 2080
    )
    assert look["statistics"]["no_correspondence/steps"]["sd"] == 0.0
    assert "stopped at 5 seeds, target reached" in format_until_mde(rule)


def test_seeds_until_mde_stops_at_max_seeds_and_ignores_arms_that_never_reach(monkeypatch) -> None:
    from seal.experiments.until_mde import format_until_mde, run_transfer_until_mde

    def reach_of(arm: str, seed: int) -> pd.DataFrame:
        at = {"alone": 2500, "high_source": 1500 if seed % 2 else 3500}.get(arm)
        return _reaching({t: at for t in ("t0", "t1", "t2", "t3")})  # the control never reaches

    calls = _fake_runs(monkeypatch, reach_of)
    result = run_transfer_until_mde(0.10, 9, only=["high_source", "no_correspondence"], batch=2)
    rule = result["seeds_until_mde"]
    assert calls == [[0, 1, 2, 3, 4], [5, 6], [7, 8]] and rule["seeds_used"] == 9
    assert [look["seeds"] for look in rule["looks"]] == [5, 7, 9]
    assert rule["stopped_because"] == "max seeds"
    assert "high_source/steps" in rule["above_target"]
    # The control never reaches but its alone arm does, so it counts: G is the budget, 5,000,
    # against 2,500 in every seed, a saving of -1 each time: SD 0, MDE 0.
    assert rule["looks"][-1]["statistics"]["no_correspondence/steps"]["sd"] == 0.0
    assert "still above 0.1: high_source/steps" in format_until_mde(rule)


def test_rule_differences_give_no_mde_where_arm_and_alone_never_reach() -> None:
    import types

    from seal.experiments.until_mde import rule_differences

    never = types.SimpleNamespace(metrics=_reaching({"t0": None, "t1": None}))
    loaded = {(a, s): never for a in ("alone", "no_correspondence") for s in range(3)}
    chosen = arms(only=["no_correspondence"])
    assert rule_differences(loaded, chosen, 3) == {
        "no_correspondence/steps": None,
        "no_correspondence/auc": None,
    }


def test_the_rule_batch_is_the_runs_that_go_at_once() -> None:
    from seal.experiments.until_mde import rule_batch

    chosen = arms(only=["high_source"])
    assert rule_batch(chosen, 2)["batch"] == 2  # one CPU a shipped testbed run
    assert rule_batch(chosen, 7)["batch"] == 7
    assert "node CPUs // 1 CPU(s) a run" in rule_batch(chosen, 2)["how"]
    assert rule_batch(chosen, 4, overrides=["protocol.threads=3"])["batch"] == 1


def test_fpr_under_the_rule_on_forty_finished_alone_runs(tmp_path) -> None:
    from seal.experiments.until_mde import format_fpr_until_mde, run_fpr_until_mde
    from seal.stats import binomial_ci

    steps = [int(s) for s in np.random.default_rng(5).integers(19, 32, 40) * 100]
    _finished_alone_runs(tmp_path, steps)
    result = run_fpr_until_mde(0.10, 20, out=tmp_path, reuse=True, splits=100)
    assert result["found_finished"] == 40 and len(result["reused"]) == 40  # nothing was run
    assert result["grad_steps_to_90_per_seed"] == steps
    assert result["rule"]["batch"] == 2 and result["rule"]["first"] == 5
    rate = result["false_positive_rate_under_rule"]
    assert rate["splits"] == 100 and rate["schedule"] == [5, 7, 9, 11, 13, 15, 17, 19, 20]
    assert rate["rate_ci95"] == pytest.approx(list(binomial_ci(rate["excluding_0"], 100)))
    assert result["false_positive_rate_fixed_max_seeds"]["half"] == 20
    text = format_fpr_until_mde(result)
    assert "False-positive rate under seeds-until-MDE <= 0.1" in text
    assert "40 found finished, 40 reused" in text


def test_fpr_under_the_rule_says_how_many_alone_seeds_it_has(tmp_path) -> None:
    from seal.experiments.until_mde import run_fpr_until_mde

    _finished_alone_runs(tmp_path, [2000 + 100 * (s % 7) for s in range(30)])
    said: list[str] = []

    class Said(Exception):
        pass

    def log(message: str) -> None:
        said.append(message)
        raise Said  # stop before any run

    with pytest.raises(Said):
        run_fpr_until_mde(0.10, 20, out=tmp_path, reuse=True, log=log)
    assert said[0].startswith("30 of the 40 alone seeds")
    assert "running the other 10" in said[0]


def test_cli_set_reaches_every_transfer_arm_but_not_fpr(capsys, monkeypatch) -> None:  # noqa: ANN001
    import seal.experiments.transfer as transfer
    from seal.cli.main import main

    seen = {}

    def fake(**kwargs):  # noqa: ANN003, ANN202
        seen.update(kwargs)
        return {"fake": True}

    monkeypatch.setattr(transfer, "run_transfer_bench", fake)
    args = ["bench", "--learn", "transfer", "--json", "--set", "agent.critic_sharing=shared"]
    assert main(args) == 0
    assert seen["overrides"] == ["agent.critic_sharing=shared"]
    assert main([*args, "--fpr"]) == 2
    assert "--set applies to --learn transfer's arms" in capsys.readouterr().err
    assert main([*args, "--seeds-until-mde", "0.1", "--max-seeds", "9"]) == 2
    assert "not to --fpr or --seeds-until-mde" in capsys.readouterr().err
