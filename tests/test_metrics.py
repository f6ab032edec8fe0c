"""The update-count metric (Appendix B) against hand-worked cases."""

from __future__ import annotations

import io
import math

import numpy as np
import pandas as pd
import pytest

from seal.errors import SealError
from seal.metrics import (
    add_percent_change,
    aggregate_seeds,
    batch_share,
    decompose_first_reach,
    env_totals,
    first_reach,
    format_ci,
    format_count,
    format_number,
    format_percent,
    format_total,
    percent_change,
)


def _csv(text: str) -> pd.DataFrame:
    return pd.read_csv(io.StringIO(text), dtype={"phase": str, "env": str, "task": str})


# Constant batch: 10 tasks, 128 transitions per task per gradient step, 500 gradient steps per
# epoch (one 500-step episode per task, evaluated every epoch). Per epoch each task consumes
# 500 * 128 = 64,000 transitions = 0.064 M, so `updates` = epoch * 0.064.
# drawer-close first reaches 0.9 at epoch 3: 3 * 500 * 128 = 192,000 transitions = 0.192 M,
# with 3 * 500 = 1500 gradient steps and 3 * 500 = 1500 env steps (one episode per epoch).
# The dip to 0.88 at epoch 4 does not matter: it is the first evaluation that counts.
# Only 2 of the 10 tasks are written out; the other 8 change nothing about these rows.
CONSTANT_BATCH = """seed,phase,epoch,env,task,success,return,grad_steps,env_steps,updates,wall_s
0,train,1,mw,drawer-close-v3,0.20,10,500,500,0.064,1
0,train,1,mw,reach-v3,0.00,5,500,500,0.064,1
0,train,2,mw,drawer-close-v3,0.50,20,1000,1000,0.128,2
0,train,2,mw,reach-v3,0.10,6,1000,1000,0.128,2
0,train,3,mw,drawer-close-v3,0.92,30,1500,1500,0.192,3
0,train,3,mw,reach-v3,0.30,7,1500,1500,0.192,3
0,train,4,mw,drawer-close-v3,0.88,30,2000,2000,0.256,4
0,train,4,mw,reach-v3,0.50,8,2000,2000,0.256,4
0,train,5,mw,drawer-close-v3,0.95,31,2500,2500,0.320,5
0,train,5,mw,reach-v3,0.60,9,2500,2500,0.320,5
"""


def test_constant_batch_equals_c_gs_bs() -> None:
    reach = first_reach(_csv(CONSTANT_BATCH), threshold=0.9)
    dc = reach[reach["task"] == "drawer-close-v3"].iloc[0]
    assert bool(dc["reached"]) is True
    assert dc["epoch"] == 3
    # C x GS x BS = 3 * 500 * 128 = 192,000 transitions.
    assert dc["updates"] == pytest.approx(3 * 500 * 128 / 1e6) == pytest.approx(0.192)
    assert dc["grad_steps"] == 1500
    assert dc["env_steps"] == 1500


def test_never_reached_is_zero_and_rendered_as_dash() -> None:
    # reach-v3 peaks at 0.60 < 0.9: not learned, all numbers 0 (Tables 4-7 write 0).
    reach = first_reach(_csv(CONSTANT_BATCH), threshold=0.9)
    r = reach[reach["task"] == "reach-v3"].iloc[0]
    assert bool(r["reached"]) is False
    assert (r["updates"], r["grad_steps"], r["env_steps"], r["epoch"]) == (0.0, 0, 0, 0)
    agg = aggregate_seeds(reach)
    row = agg[agg["task"] == "reach-v3"].iloc[0]
    assert row["updates_mean"] == 0.0 and row["reached"] == 0 and row["seeds"] == 1
    assert format_count(row["updates_mean"], row["updates_std"], 0, 1) == "— [0/1]"
    assert format_count(0.0, math.nan, 0, 2, style="latex") == "--- [0/2]"


def test_lower_threshold_reads_an_earlier_evaluation() -> None:
    # At 0.5, reach-v3 first gets there at epoch 4 (0.256 M), drawer-close at epoch 2 (0.128 M).
    reach = first_reach(_csv(CONSTANT_BATCH), threshold=0.5).set_index("task")
    assert reach.loc["reach-v3", "updates"] == pytest.approx(0.256)
    assert reach.loc["drawer-close-v3", "updates"] == pytest.approx(0.128)


def test_success_equal_to_threshold_counts_despite_rounding() -> None:
    # 45 successes of 50 episodes is exactly 90%; a float sum in another order may land at
    # 0.8999999999999999, which must still count.
    outcomes = np.array([1.0] * 45 + [0.0] * 5)
    rounded_down = 0.8999999999999999
    assert rounded_down < 0.9
    text = (
        "seed,phase,epoch,env,task,success,return,grad_steps,env_steps,updates,wall_s\n"
        f"0,train,1,mw,a,{float(outcomes.mean())!r},0,10,10,0.001,0\n"
        f"0,train,1,mw,b,{rounded_down!r},0,10,10,0.001,0\n"
        "0,train,1,mw,c,0.88,0,10,10,0.001,0\n"
    )
    reached = first_reach(_csv(text)).set_index("task")["reached"]
    assert reached.to_dict() == {"a": True, "b": True, "c": False}


# A changing ratio: a stepped data-ratio schedule gives drawer-close a shrinking share of each
# batch, so its `updates` grows unevenly: +0.100, +0.080, +0.050, +0.020 M per epoch (500 steps).
# It reaches 0.9 at epoch 3, where the column reads 0.100 + 0.080 + 0.050 = 0.230 M. A formula
# C x GS x BS with the first epoch's 200 per task per step would say 3 * 500 * 200 = 0.300 M.
CHANGING_RATIO = """seed,phase,epoch,env,task,success,return,grad_steps,env_steps,updates,wall_s
0,train,1,mw,drawer-close-v3,0.10,1,500,500,0.100,1
0,train,2,mw,drawer-close-v3,0.40,1,1000,1000,0.180,2
0,train,3,mw,drawer-close-v3,0.90,1,1500,1500,0.230,3
0,train,4,mw,drawer-close-v3,1.00,1,2000,2000,0.250,4
"""


def test_changing_ratio_reads_the_updates_column() -> None:
    dc = first_reach(_csv(CHANGING_RATIO)).iloc[0]
    assert dc["updates"] == pytest.approx(0.230)
    assert dc["updates"] != pytest.approx(3 * 500 * 200 / 1e6)
    assert dc["grad_steps"] == 1500


def test_rows_out_of_order_still_find_the_first_evaluation() -> None:
    # Same data, rows reversed (e.g. a resumed run appended out of order): still epoch 3.
    shuffled = _csv(CHANGING_RATIO).iloc[::-1].reset_index(drop=True)
    assert first_reach(shuffled).iloc[0]["updates"] == pytest.approx(0.230)


# Several seeds of one task (constant batch, 0.064 M per epoch):
#   seed 0 reaches at epoch 3 -> 0.192; seed 1 at epoch 4 -> 0.256; seed 2 never.
# Over the 2 seeds that reached it: mean (0.192 + 0.256) / 2 = 0.224,
# sample std sqrt(((0.192-0.224)^2 + (0.256-0.224)^2) / (2-1)) = 0.032 * sqrt(2) = 0.045254834;
# "2/3 seeds reached". Mean gradient steps (1500 + 2000) / 2 = 1750.
SEEDS = """seed,phase,epoch,env,task,success,return,grad_steps,env_steps,updates,wall_s
0,train,3,mw,drawer-close-v3,0.91,1,1500,1500,0.192,1
0,train,4,mw,drawer-close-v3,0.95,1,2000,2000,0.256,1
1,train,3,mw,drawer-close-v3,0.70,1,1500,1500,0.192,1
1,train,4,mw,drawer-close-v3,0.93,1,2000,2000,0.256,1
2,train,3,mw,drawer-close-v3,0.10,1,1500,1500,0.192,1
2,train,4,mw,drawer-close-v3,0.20,1,2000,2000,0.256,1
"""


def test_several_seeds_mean_std_over_reaching_seeds() -> None:
    per_seed = first_reach(_csv(SEEDS))
    assert per_seed["reached"].tolist() == [True, True, False]
    agg = aggregate_seeds(per_seed).iloc[0]
    assert agg["updates_mean"] == pytest.approx(0.224)
    assert agg["updates_std"] == pytest.approx(0.032 * math.sqrt(2))
    assert agg["grad_steps_mean"] == pytest.approx(1750)
    assert (agg["reached"], agg["seeds"]) == (2, 3)
    cell = format_count(
        agg["updates_mean"], agg["updates_std"], int(agg["reached"]), int(agg["seeds"])
    )
    assert cell == "0.224 ± 0.04525 [2/3]"


def test_one_reaching_seed_has_no_std() -> None:
    # Only seed 0 reaches at 0.94 -> its number alone, std undefined (not a misleading "± 0").
    per_seed = first_reach(_csv(SEEDS), threshold=0.94)
    agg = aggregate_seeds(per_seed).iloc[0]
    assert agg["updates_mean"] == pytest.approx(0.256) and math.isnan(agg["updates_std"])
    assert format_count(agg["updates_mean"], agg["updates_std"], 1, 3) == "0.256 [1/3]"


# Pad-and-fine-tune: update counts restart at the fine-tune phase. The same task name in both
# phases (point env pre-trained and fine-tuned on itself) must give two separate numbers:
# pretrain reaches at epoch 2 (0.2 M), finetune at its own epoch 1 (0.05 M, not 0.25 M).
PHASES = """seed,phase,epoch,env,task,success,return,grad_steps,env_steps,updates,wall_s
0,pretrain,1,point,reach,0.50,1,100,100,0.10,1
0,pretrain,2,point,reach,0.95,1,200,200,0.20,2
0,finetune,1,point,reach,0.90,1,100,100,0.05,3
0,finetune,2,point,reach,1.00,1,200,200,0.10,4
"""


def test_update_counts_restart_per_phase() -> None:
    per_seed = first_reach(_csv(PHASES)).set_index("phase")
    assert per_seed.loc["pretrain", "updates"] == pytest.approx(0.20)
    assert per_seed.loc["finetune", "updates"] == pytest.approx(0.05)
    assert per_seed.loc["finetune", "grad_steps"] == 100


def test_env_totals_count_never_reached_as_zero_under_the_zero_rule() -> None:
    # drawer-close 0.192 + reach-v3 0 (never) = 0.192 total; 1 of 2 tasks reached.
    totals = env_totals(aggregate_seeds(first_reach(_csv(CONSTANT_BATCH))), censored="zero")
    row = totals.iloc[0]
    assert (row["phase"], row["env"]) == ("train", "mw")
    assert row["updates_total"] == pytest.approx(0.192)
    assert (row["tasks_reached"], row["tasks"], row["censored_tasks"]) == (1, 2, 1)


# Censoring, by hand. One env, three tasks, two seeds, 0.1 M of each task's transitions per epoch
# (100 gradient steps); seed 0 runs 5 epochs (run total 0.5 M), seed 1 runs 4 (0.4 M).
#   a: seed 0 reaches at epoch 2 (0.2), seed 1 at epoch 3 (0.3)  -> mean 0.25 [2/2], not censored
#   b: seed 0 never (run total 0.5), seed 1 at epoch 4 (0.4)    -> mean over reaching 0.4 [1/2];
#      censored: (0.5 + 0.4) / 2 = 0.45
#   c: never in either seed (run totals 0.5 and 0.4)            -> "— [0/2]"; censored: 0.45
# run-total rule: 0.25 + 0.45 + 0.45 = 1.15, a lower bound, 2 censored tasks, 2/3 tasks reached.
# zero rule (the paper's): 0.25 + 0.4 + 0 = 0.65.
CENSORED = """seed,phase,epoch,env,task,success,return,grad_steps,env_steps,updates,wall_s
0,train,1,mw,a,0.50,0,100,100,0.1,0
0,train,1,mw,b,0.50,0,100,100,0.1,0
0,train,1,mw,c,0.50,0,100,100,0.1,0
0,train,2,mw,a,0.95,0,200,200,0.2,0
0,train,2,mw,b,0.50,0,200,200,0.2,0
0,train,2,mw,c,0.50,0,200,200,0.2,0
0,train,3,mw,a,0.95,0,300,300,0.3,0
0,train,3,mw,b,0.50,0,300,300,0.3,0
0,train,3,mw,c,0.50,0,300,300,0.3,0
0,train,4,mw,a,0.95,0,400,400,0.4,0
0,train,4,mw,b,0.50,0,400,400,0.4,0
0,train,4,mw,c,0.50,0,400,400,0.4,0
0,train,5,mw,a,0.95,0,500,500,0.5,0
0,train,5,mw,b,0.50,0,500,500,0.5,0
0,train,5,mw,c,0.50,0,500,500,0.5,0
1,train,1,mw,a,0.50,0,100,100,0.1,0
1,train,1,mw,b,0.50,0,100,100,0.1,0
1,train,1,mw,c,0.50,0,100,100,0.1,0
1,train,2,mw,a,0.50,0,200,200,0.2,0
1,train,2,mw,b,0.50,0,200,200,0.2,0
1,train,2,mw,c,0.50,0,200,200,0.2,0
1,train,3,mw,a,0.95,0,300,300,0.3,0
1,train,3,mw,b,0.50,0,300,300,0.3,0
1,train,3,mw,c,0.50,0,300,300,0.3,0
1,train,4,mw,a,0.95,0,400,400,0.4,0
1,train,4,mw,b,0.95,0,400,400,0.4,0
1,train,4,mw,c,0.50,0,400,400,0.4,0
"""


def test_censored_tasks_count_at_their_run_totals() -> None:
    per_seed = first_reach(_csv(CENSORED)).set_index(["seed", "task"])
    assert per_seed.loc[(0, "b"), "run_updates"] == pytest.approx(0.5)
    assert per_seed.loc[(1, "c"), "run_updates"] == pytest.approx(0.4)
    assert per_seed.loc[(1, "c"), "run_grad_steps"] == 400
    agg = aggregate_seeds(per_seed.reset_index()).set_index("task")
    assert agg.loc["a", "updates_mean"] == pytest.approx(0.25)
    assert agg.loc["a", "updates_bound"] == pytest.approx(0.25)
    assert agg.loc["b", "updates_mean"] == pytest.approx(0.4)
    assert agg.loc["b", "updates_bound"] == pytest.approx(0.45)
    assert agg.loc["c", "updates_mean"] == 0.0
    assert agg.loc["c", "updates_bound"] == pytest.approx(0.45)

    (row,) = env_totals(agg.reset_index()).itertuples(index=False)
    assert row.updates_total == pytest.approx(1.15)
    assert (row.tasks_reached, row.tasks, row.censored_tasks) == (2, 3, 2)
    assert format_total(row.updates_total, row.censored_tasks > 0) == "≥ 1.15"
    assert format_total(row.updates_total, True, "latex") == r"$\geq$ 1.15"
    assert format_total(0.25, False) == "0.25"

    (zero,) = env_totals(agg.reset_index(), censored="zero").itertuples(index=False)
    assert zero.updates_total == pytest.approx(0.65)
    with pytest.raises(
        SealError, match="censored rule 'max' is not valid; expected one of run-total, zero"
    ):
        env_totals(agg.reset_index(), censored="max")  # type: ignore[arg-type]


def test_a_censored_seed_without_a_run_total_leaves_the_bound_unknown() -> None:
    # A per-seed table written by hand without run totals: the bound of a censored task is NaN,
    # and so is the total it is part of (never a silent 0).
    per_seed = first_reach(_csv(CENSORED)).drop(columns=["run_updates"])
    agg = aggregate_seeds(per_seed).set_index("task")
    assert agg.loc["a", "updates_bound"] == pytest.approx(0.25)
    assert math.isnan(agg.loc["b", "updates_bound"])
    assert math.isnan(env_totals(agg.reset_index())["updates_total"].iloc[0])


def test_percent_change_literal_values() -> None:
    # Table 1, Drawer Close: single env 6.4, High FK 2.4 -> (2.4 - 6.4) / 6.4 = -62.5%.
    assert percent_change(2.4, 6.4) == pytest.approx(-62.5)
    # Reach: 17.1 -> 12.7: -4.4 / 17.1 = -25.7309...%.
    assert percent_change(12.7, 17.1) == pytest.approx(-25.730994, abs=1e-6)
    # Drawer Open, 50/50: 42.7 -> 211.2: 168.5 / 42.7 = +394.6135...%.
    assert percent_change(211.2, 42.7) == pytest.approx(394.613583, abs=1e-6)
    assert format_percent(percent_change(211.2, 42.7)) == "+394.6%"
    assert format_percent(percent_change(12.7, 17.1)) == "-25.7%"
    # Baseline never reached (0 updates, not reached) -> n/a; variant never reached -> n/a too.
    assert percent_change(2.4, 0.0, baseline_reached=False) is None
    assert percent_change(0.0, 6.4, value_reached=False) is None
    assert format_percent(None) == "n/a"


def test_percent_change_cells_bold_when_fewer_updates() -> None:
    assert format_count(2.4, 0.1, 2, 2, -62.5, True, "markdown") == "**2.4 ± 0.1 (-62.5%)** [2/2]"
    assert (
        format_count(2.4, 0.1, 2, 2, -62.5, True, "latex")
        == r"\textbf{2.4 $\pm$ 0.1 (-62.5\%)} [2/2]"
    )
    assert (
        format_count(211.2, math.nan, 1, 2, 394.6135, True, "markdown") == "211.2 (+394.6%) [1/2]"
    )
    assert format_count(2.4, math.nan, 1, 2, None, True, "markdown") == "2.4 (n/a) [1/2]"
    # The baseline column shows no percent.
    assert format_count(6.4, math.nan, 2, 2, None, False, "markdown") == "6.4 [2/2]"


def test_add_percent_change_matches_env_and_task() -> None:
    agg = pd.DataFrame(
        {
            "column": ["Single Env", "Single Env", "High FK", "High FK", "High FK"],
            "env": ["mw", "fk", "mw", "fk", "fk"],
            "task": ["drawer-close", "kettle", "drawer-close", "kettle", "microwave"],
            "updates_mean": [6.4, 0.0, 2.4, 3.0, 4.0],
            "reached": [2, 0, 2, 1, 1],
        }
    )
    out = add_percent_change(agg, "Single Env").set_index(["column", "env", "task"])["pct_change"]
    assert out[("High FK", "mw", "drawer-close")] == pytest.approx(-62.5)
    assert math.isnan(out[("High FK", "fk", "kettle")])  # baseline never reached -> n/a
    assert math.isnan(out[("High FK", "fk", "microwave")])  # no baseline row at all
    assert math.isnan(out[("Single Env", "mw", "drawer-close")])  # the baseline itself


def test_format_number_four_significant_digits() -> None:
    assert [format_number(v) for v in (0.192, 6.4, 42.7, 211.2, 0.0192, 1536.0)] == [
        "0.192",
        "6.4",
        "42.7",
        "211.2",
        "0.0192",
        "1536",
    ]


def test_missing_column_is_a_seal_error() -> None:
    with pytest.raises(SealError, match=r"lacks column\(s\) \['updates'\]"):
        first_reach(_csv(CONSTANT_BATCH).drop(columns=["updates"]))


def test_one_rule_for_reaching_the_threshold() -> None:
    from seal.evaluation import reaches

    # np.mean of 0/1 outcomes can land a rounding error below 0.9: 0.1 * 9 = 0.9000000000000000222,
    # but sum([0.1] * 9) = 0.8999999999999999. Both count, in the runner and in the report.
    below = sum([0.1] * 9)
    assert below < 0.9 and reaches(below, 0.9) and not reaches(0.89, 0.9)
    frame = _csv(
        "seed,phase,epoch,env,task,success,return,grad_steps,env_steps,updates,wall_s\n"
        f"0,train,1,mw,a,{below!r},1,10,10,0.001,1\n"
    )
    assert bool(first_reach(frame, 0.9)["reached"].iloc[0])


# ---- the robust criterion: K successive evaluations >= 90%, the first of them reported.
# drawer-close (CONSTANT_BATCH) hits at epochs 3 (0.92) and 5 (0.95), missing at 4 (0.88): with
# K = 2 it never has two in a row. A second task hits at 2, misses at 3, hits at 4 and 5: K = 2
# reports epoch 4 (the first of the pair 4, 5), K = 3 finds no run of three.
ROBUST = """seed,phase,epoch,env,task,success,return,grad_steps,env_steps,updates,wall_s
0,train,1,mw,door-open-v3,0.50,1,500,500,0.064,1
0,train,2,mw,door-open-v3,0.90,1,1000,1000,0.128,2
0,train,3,mw,door-open-v3,0.70,1,1500,1500,0.192,3
0,train,4,mw,door-open-v3,0.95,1,2000,2000,0.256,4
0,train,5,mw,door-open-v3,1.00,1,2500,2500,0.320,5
"""


def test_consecutive_evaluations_report_the_first_of_the_run() -> None:
    frame = pd.concat([_csv(CONSTANT_BATCH), _csv(ROBUST)], ignore_index=True)
    one = first_reach(frame).set_index("task")
    assert one.loc["door-open-v3", "epoch"] == 2 and one.loc["drawer-close-v3", "epoch"] == 3
    pd.testing.assert_frame_equal(first_reach(frame, consecutive=1), first_reach(frame))
    two = first_reach(frame, consecutive=2).set_index("task")
    assert two.loc["door-open-v3", "epoch"] == 4
    assert two.loc["door-open-v3", "updates"] == pytest.approx(0.256)
    assert two.loc["door-open-v3", "grad_steps"] == 2000
    assert not two.loc["drawer-close-v3", "reached"]  # 3 and 5 hit, 4 does not
    assert not two.loc["reach-v3", "reached"]
    three = first_reach(frame, consecutive=3).set_index("task")
    assert not three["reached"].any()


def test_consecutive_keeps_seeds_apart() -> None:
    # Seed 0's last evaluation hits and seed 1's first does: not two in a row of one run.
    rows = """seed,phase,epoch,env,task,success,return,grad_steps,env_steps,updates,wall_s
0,train,1,mw,t,0.10,1,500,500,0.064,1
0,train,2,mw,t,0.95,1,1000,1000,0.128,2
1,train,1,mw,t,0.95,1,500,500,0.064,1
1,train,2,mw,t,0.20,1,1000,1000,0.128,2
"""
    assert not first_reach(_csv(rows), consecutive=2)["reached"].any()


# Streaks, by run (rows shuffled below, so the training order comes from epoch, not the file):
#   seed 0, train, a: miss, hit, hit, miss, hit, hit, hit  (epochs 1-7)
#   seed 0, train, b: hit x 4                              (epochs 1-4)
#   seed 0, tune,  a: hit, hit                             (epochs 1-2; phases are kept apart)
#   seed 1, train, a: hit, miss, hit, hit                  (epochs 1-4)
STREAKS = {
    (0, "train", "a"): [0.1, 0.95, 0.9, 0.5, 1.0, 0.92, 0.97],
    (0, "train", "b"): [0.9, 0.91, 0.93, 1.0],
    (0, "tune", "a"): [1.0, 0.95],
    (1, "train", "a"): [0.99, 0.2, 0.9, 0.96],
}
# The epoch each run reports for K = 1..5 (0: never reached).
STREAK_EPOCHS = {
    (0, "train", "a"): [2, 2, 5, 0, 0],
    (0, "train", "b"): [1, 1, 1, 1, 0],
    (0, "tune", "a"): [1, 1, 0, 0, 0],
    (1, "train", "a"): [1, 3, 0, 0, 0],
}


def _streak_frame() -> pd.DataFrame:
    rows = [
        f"{seed},{phase},{epoch},mw,{task},{success},0,{100 * epoch},{100 * epoch},"
        f"{epoch / 1000},{epoch}"
        for (seed, phase, task), curve in STREAKS.items()
        for epoch, success in enumerate(curve, start=1)
    ]
    order = np.random.default_rng(0).permutation(len(rows))
    text = "seed,phase,epoch,env,task,success,return,grad_steps,env_steps,updates,wall_s\n"
    return _csv(text + "\n".join(rows[i] for i in order) + "\n")


def _epochs(reach: pd.DataFrame) -> dict[tuple[int, str, str], int]:
    return {
        (int(r.seed), r.phase, r.task): int(r.epoch) if r.reached else 0
        for r in reach.itertuples(index=False)
    }


@pytest.mark.parametrize("consecutive", [1, 2, 3, 4, 5])
def test_consecutive_reports_the_first_of_each_run_of_k_hits(consecutive: int) -> None:
    reach = first_reach(_streak_frame(), consecutive=consecutive)
    want = {run: epochs[consecutive - 1] for run, epochs in STREAK_EPOCHS.items()}
    assert _epochs(reach) == want
    # The row reported is that evaluation's: updates, steps of the first of the K hits.
    for r in reach[reach["reached"]].itertuples(index=False):
        assert (r.grad_steps, r.env_steps) == (100 * r.epoch, 100 * r.epoch)
        assert r.updates == pytest.approx(r.epoch / 1000)


@pytest.mark.parametrize("consecutive", [8, 100_000, 99_999_999_999_999_999_999])
def test_a_k_longer_than_every_run_is_never_reached(consecutive: int) -> None:
    # The longest run has 7 evaluations: no K above that can be met, however large (a K of
    # 10^20 once looped 10^20 times over the frame); the run totals are still reported.
    frame = _streak_frame()
    reach = first_reach(frame, consecutive=consecutive)
    never = first_reach(frame, threshold=1.0 + 1e-3)  # a threshold no evaluation reaches
    assert not reach["reached"].any()
    assert _epochs(reach) == dict.fromkeys(STREAKS, 0)
    pd.testing.assert_frame_equal(reach, never)
    totals = reach.set_index(["seed", "phase", "task"])["run_grad_steps"].to_dict()
    assert totals == {run: 100 * len(curve) for run, curve in STREAKS.items()}


@pytest.mark.parametrize("bad", [0, -1, 1.5, True])
def test_consecutive_must_be_a_positive_count(bad: object) -> None:
    with pytest.raises(SealError, match="consecutive"):
        first_reach(_csv(CONSTANT_BATCH), consecutive=bad)  # type: ignore[arg-type]


# ---- steps x per-step batch. Two arms of one 2-task env, one seed each, hand-computed:
#   base (alone, 64 per task per step, 500 steps/epoch): task a reaches at epoch 3 -> 1500 steps,
#     1500 x 64 = 96,000 transitions; task b at epoch 2 -> 1000 steps, 64,000 transitions.
#   arm (joint, the env's tasks draw 16 per step, 500 steps/epoch): task a reaches at epoch 4 ->
#     2000 steps, 2000 x 16 = 32,000 transitions; task b never.
DECOMPOSE_BASE = """seed,phase,epoch,env,task,success,return,grad_steps,env_steps,updates,wall_s
0,train,1,mw,a,0.10,1,500,500,0.032,1
0,train,1,mw,b,0.50,1,500,500,0.032,1
0,train,2,mw,a,0.50,1,1000,1000,0.064,2
0,train,2,mw,b,0.90,1,1000,1000,0.064,2
0,train,3,mw,a,0.91,1,1500,1500,0.096,3
0,train,3,mw,b,1.00,1,1500,1500,0.096,3
"""
DECOMPOSE_ARM = """seed,phase,epoch,env,task,success,return,grad_steps,env_steps,updates,wall_s
0,train,2,mw,a,0.30,1,1000,1000,0.016,2
0,train,2,mw,b,0.30,1,1000,1000,0.016,2
0,train,4,mw,a,0.92,1,2000,2000,0.032,4
0,train,4,mw,b,0.40,1,2000,2000,0.032,4
"""


def test_transitions_are_steps_times_per_step_batch() -> None:
    base = decompose_first_reach(first_reach(_csv(DECOMPOSE_BASE))).set_index("task")
    arm = decompose_first_reach(first_reach(_csv(DECOMPOSE_ARM))).set_index("task")
    assert base.loc["a", "transitions"] == 96_000 and base.loc["a", "steps"] == 1500
    assert base.loc["a", "per_step"] == 64.0
    assert base.loc["b", "transitions"] == 64_000 and base.loc["b", "per_step"] == 64.0
    assert arm.loc["a", "transitions"] == 32_000 and arm.loc["a", "steps"] == 2000
    assert arm.loc["a", "per_step"] == 16.0
    # Never reached: 0 transitions over 0 steps, no per-step batch.
    assert arm.loc["b", "steps"] == 0 and math.isnan(arm.loc["b", "per_step"])
    for frame in (base, arm.loc[["a"]]):
        assert (frame["transitions"] == frame["steps"] * frame["per_step"]).all()
    # Task a: 1/3 of the transitions = 4/3 of the steps x 1/4 of the per-step batch.
    ratio_transitions = arm.loc["a", "transitions"] / base.loc["a", "transitions"]
    ratio_steps = arm.loc["a", "steps"] / base.loc["a", "steps"]
    ratio_per_step = arm.loc["a", "per_step"] / base.loc["a", "per_step"]
    assert ratio_transitions == pytest.approx(1 / 3)
    assert ratio_steps == pytest.approx(4 / 3) and ratio_per_step == pytest.approx(1 / 4)
    assert ratio_transitions == pytest.approx(ratio_steps * ratio_per_step, rel=1e-15)
    # 16 of a 128-transition update (8 tasks x 16): an eighth of the batch.
    assert batch_share(arm.loc["a", "per_step"], 128) == 0.125
    with pytest.raises(SealError, match="total_batch"):
        batch_share(16.0, 0)


def test_aggregate_per_step_mean_keeps_the_identity() -> None:
    # Two seeds of task a: (1500 steps, 96,000) and (1000 steps, 48,000): means 1250 and 72,000,
    # per-step batch 72,000 / 1250 = 57.6 (the ratio of the means, not the mean of 64 and 48).
    per_seed = pd.DataFrame(
        {
            "phase": "train",
            "env": "mw",
            "task": "a",
            "seed": [0, 1],
            "reached": True,
            "updates": [0.096, 0.048],
            "grad_steps": [1500, 1000],
            "env_steps": [1500, 1000],
        }
    )
    row = aggregate_seeds(per_seed).iloc[0]
    assert row["per_step_mean"] == pytest.approx(57.6)
    assert row["updates_mean"] * 1e6 == pytest.approx(row["grad_steps_mean"] * row["per_step_mean"])


def test_bold_follows_the_resolution_when_given() -> None:
    # The old rule (pct < 0) without `bold`; a report passes bold=False for an unresolved change.
    assert format_count(0.1, 0.01, 3, 3, -20.0, True, "markdown") == "**0.1 ± 0.01 (-20.0%)** [3/3]"
    unresolved = format_count(0.1, 0.01, 3, 3, -20.0, True, "markdown", bold=False, ci=(-0.4, 0.05))
    assert unresolved == "0.1 ± 0.01 (-20.0% [-40.0, +5.0]) [3/3]"
    resolved_cell = format_count(0.1, 0.01, 3, 3, -20.0, True, "latex", bold=True, ci=(-0.4, -0.05))
    assert resolved_cell == r"\textbf{0.1 $\pm$ 0.01 (-20.0\% [-40.0, -5.0])} [3/3]"
    assert format_ci((math.nan, 0.1)) == "[n/a]"
