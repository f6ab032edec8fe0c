"""`seal bench --learn learner`: issue 54's Meta-World rule, seed-paired new - old env steps."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import scipy.stats

import seal.experiments.learner as learner
from seal.cli.main import main
from seal.errors import SealError
from seal.experiments.arms import Arm
from tests.faults.point_protocol import point_protocol


def test_the_paired_change_and_its_verdict_by_hand() -> None:
    # diffs -10, +10, -20: mean -6.67, sd 15.275, sem 8.819, t(0.975, 2) = 4.3027 -> half 37.95
    change = learner.paired_change([100, 200, 300], [90, 210, 280])
    assert change["differences"] == [-10.0, 10.0, -20.0]
    assert change["mean"] == pytest.approx(-20 / 3)
    assert change["ci95"] == pytest.approx([-20 / 3 - 37.9458, -20 / 3 + 37.9458], abs=1e-3)
    assert change["no_slower"] is True
    # Every seed slower by 100-120: the CI lies above 0.
    slower = learner.paired_change([100, 200, 300], [200, 310, 420])
    assert slower["ci95"][0] > 0 and slower["no_slower"] is False
    # One seed: no CI, no verdict.
    assert learner.paired_change([100], [90])["no_slower"] is None
    with pytest.raises(SealError, match="2 old seeds against 1 new"):
        learner.paired_change([1, 2], [1])


def test_a_crossing_is_the_first_evaluation_at_90_percent_else_the_run_total() -> None:
    rows = [
        # epoch, task, success, env_steps
        (1, "a", 0.5, 100),
        (1, "b", 0.0, 100),
        (2, "a", 0.9, 200),
        (2, "b", 0.8, 200),
        (3, "a", 1.0, 300),
        (3, "b", 0.2, 300),
    ]
    metrics = pd.DataFrame(
        [
            {"seed": 0, "phase": "train", "epoch": e, "env": "mw", "task": t, "success": s,
             "return": 0.0, "grad_steps": e * 10, "env_steps": n, "updates": e / 100, "batch": 8}
            for e, t, s, n in rows
        ]
    )  # fmt: skip
    assert learner.crossing(metrics, "mw", "a") == {"env_steps": 200, "reached": True}
    assert learner.crossing(metrics, "mw", "b") == {"env_steps": 300, "reached": False}
    with pytest.raises(SealError, match="no evaluation of mw/c"):
        learner.crossing(metrics, "mw", "c")


def test_the_bench_needs_a_change_to_compare(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "--learn", "learner"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--set agent.critic_layer_norm=true" in err
    assert main(["bench", "--learn", "learner", "--arms", "nope", "--set", "a.b=1"]) == 2
    assert "quickstart, table1_single_mw, reach" in capsys.readouterr().err
    assert main(["bench", "--learn", "kitchen", "--baseline", "a.b=1"]) == 2
    assert "--baseline only applies to --learn learner" in capsys.readouterr().err
    same = ["--learn", "learner", "--baseline", "agent.critic_layer_norm=true"]
    assert main(["bench", *same, "--set", "agent.critic_layer_norm=true", "--no-run"]) == 2
    assert "is the change itself" in capsys.readouterr().err


@pytest.mark.slow  # four point runs on two local Rays: ~25 s idle
def test_both_learners_run_seed_for_seed_and_no_run_reads_them_back(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "pt.toml").write_text(point_protocol("pt", 3))
    arm = Arm("pt", "point", None, directory=tmp_path)
    monkeypatch.setattr(learner, "CHECKS", (learner.Check("point", arm, 2, "pt", "east"),))
    out = tmp_path / "out"
    change = ["agent.critic_layer_norm=true"]
    plain = ["agent.critic_layer_norm=false"]  # the old side whatever the default is
    result = learner.run_learner_bench(seeds=5, out=str(out), overrides=change, baseline=plain)
    (check,) = result["checks"]
    assert check["seeds"] == 2 and check["paired_seeds"] == [0, 1]  # the check's own 2 seeds
    # Four runs: each seed as shipped and with the change, told apart by their agent tables.
    configs = sorted(p.read_text() for p in out.glob("pt/*/seed-*/config.toml"))
    assert len(configs) == 4
    assert sum("critic_layer_norm = true" in c for c in configs) == 2
    for side in ("old", "new"):
        for seed in ("0", "1"):
            run = check[side][seed]
            assert f"seed-{seed}" in run["run_dir"]
            steps = pd.read_csv(Path(run["run_dir"]) / "metrics.csv")
            assert run["env_steps"] in set(steps["env_steps"])
    diffs = [check["new"][s]["env_steps"] - check["old"][s]["env_steps"] for s in ("0", "1")]
    assert check["change"]["differences"] == diffs
    # The rule by hand: no slower when the 95% t CI's low end, mean - t(0.975, 1) SD / sqrt(2),
    # is <= 0.
    low = np.mean(diffs) - scipy.stats.t.ppf(0.975, 1) * np.std(diffs, ddof=1) / np.sqrt(2)
    assert check["change"]["ci95"][0] == pytest.approx(low)
    assert check["change"]["no_slower"] == bool(low <= 0)
    assert result["complete"] and result["no_slower"] == check["change"]["no_slower"]
    again = learner.run_learner_bench(
        seeds=5, out=str(out), overrides=change, run=False, baseline=plain
    )
    assert again["checks"] == result["checks"]
    text = learner.format_result(again)
    assert re.search(r"point \(pt/east\), env steps to 90% old -> new: s0 ", text)
    assert "rule (every check no slower)" in text
    assert "against the protocols with agent.critic_layer_norm=false (old)" in text
    # The sides swapped: the same four runs, each seed's change negated.
    swapped = learner.run_learner_bench(
        seeds=5, out=str(out), overrides=plain, run=False, baseline=change
    )
    assert swapped["checks"][0]["change"]["differences"] == [-d for d in diffs]
    # A run missing on one side: the rule is not decided.
    missing = learner.run_learner_bench(
        seeds=5, out=str(tmp_path / "empty"), overrides=change, run=False, baseline=plain
    )
    assert missing["no_slower"] is None and not missing["complete"]
    assert math.isnan(missing["checks"][0]["change"]["mean"])


def test_the_quickstart_check_reads_rule_2s_committed_v3_records_though_the_quickstart_moved_to_v4() -> (
    None
):
    (quickstart,) = learner.arms(["quickstart"])
    assert quickstart.pins == ("envs.fk.options={reward_version='v3'}",)
    out = Path(__file__).resolve().parents[1] / "results" / "learner_check"
    result = learner.run_learner_bench(
        out=str(out),
        overrides=["agent.critic_layer_norm=true"],
        baseline=["agent.critic_layer_norm=false"],
        only=["quickstart"],
        run=False,
    )
    (check,) = result["checks"]
    assert check["paired_seeds"] == list(range(10))
    # Seed 0's drawer-close, read by hand from the two records' metrics.csv.
    assert (check["old"]["0"]["env_steps"], check["new"]["0"]["env_steps"]) == (8_000, 4_000)
    assert "(mw/drawer-close-v3; both sides envs.fk.options={reward_version='v3'})" in (
        learner.format_result(result)
    )
