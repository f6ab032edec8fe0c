"""Smoke tests of the `seal bench` functions (no timing asserts: only what they compute)."""

from __future__ import annotations

import pytest

from seal.bench.collection import bench_collection
from seal.bench.flops import UpdateShape, flop_formula_check, gemm_flops, ideal_update_gemms
from seal.bench.suite import format_table
from seal.cli.main import main
from seal.learner import env_backends


def _table_of(key: str, details: dict, **extra_details: object) -> str:
    """format_table of a result holding one key (its value from `details`) and its details."""
    return format_table(
        {
            key: details[key],
            "details": extra_details,
            "load_before": {"loadavg_1m": 1.0, "cpus": 2, "torch_threads": 2},
            "load_after": {"loadavg_1m": 1.5},
        }
    )


def test_ideal_flop_formula_by_hand() -> None:
    # obs 2, act 1, one task without one-hot, hidden (3,), batch 1:
    # actor dims [2, 3, 2] -> one forward = 2 * (2*3 + 3*2) = 24; critic dims [3, 3, 1] -> 2 * (9 + 3) = 24.
    # critic step: actor fwd 24 + 2 target fwd 48 + 2 x (fwd 24 + dW 24 + dX of the 3->1 layer 6) = 180
    # actor step: actor fwd 24 + 2 x (fwd 24 + dX 3->1 layer 6 + dX to the 1 action column 2*3*1 = 6)
    #             + actor dW 24 + actor dX of the 3->2 layer 2*2*3 = 12  -> 132.   Total 312.
    shape = UpdateShape(obs_dim=2, act_dim=1, num_tasks=1, hidden=(3,), batch=1, one_hot=False)
    assert gemm_flops(ideal_update_gemms(shape)) == 312


def test_flop_formula_equals_flop_counter_on_our_update() -> None:
    check = flop_formula_check()
    assert check["equal"], check
    # Computing all 3 policy heads and the full critic input gradient costs more than ideal.
    assert check["formula_ideal"] < check["flop_counter"]


def test_seal_update_flop_formula_by_hand() -> None:
    from seal.bench.flops import agent_update_gemms, agent_update_shapes
    from seal.learner import AgentConfig, EnvSpec

    # SEAL, obs 2, act 1, one task without one-hot, translator (3,) -> latent 3 -> trunk (3,),
    # per-env critic (3,), batch 1. Policy chain [2, 3, 3, 3, 2]: forward 2 * (6 + 9 + 9 + 6) = 60;
    # critic [3, 3, 1]: forward 2 * (9 + 3) = 24.
    # critic step: 60 + 2 x 24 + 2 x (24 + dW 24 + dX of 3->1 layer 6) = 216
    # actor step: 60 + 2 x (24 + 6 + dX to the action column 2*3*1 = 6) + dW 60
    #             + dX of the 3->3, 3->3, 3->2 layers 2 * (9 + 9 + 6) = 48  -> 240.   Per env 456.
    config = AgentConfig(
        architecture="seal",
        translator_hidden=(3,),
        latent_dim=3,
        trunk_hidden=(3,),
        critic_hidden=(3,),
        task_encoder="none",
    )
    shapes = agent_update_shapes([EnvSpec("a", 2, 1, 1), EnvSpec("b", 2, 1, 1)], config, 1)
    assert shapes[0].actor_dims == [2, 3, 3, 3, 2] and shapes[0].critic_dims == [3, 3, 1]
    assert gemm_flops(agent_update_gemms(shapes)) == 2 * 456


@pytest.mark.parametrize("critic_sharing", ["per_env", "shared"])
def test_seal_flop_formula_equals_flop_counter_on_a_seal_update(critic_sharing: str) -> None:
    from seal.bench.flops import agent_flop_formula_check
    from seal.learner import AgentConfig, EnvSpec

    config = AgentConfig(
        architecture="seal",
        translator_hidden=(16,),
        latent_dim=12,
        trunk_hidden=(16, 16),
        critic_hidden=(16, 8),
        critic_sharing=critic_sharing,
        device="cpu",
    )
    specs = [EnvSpec("mw", 39, 4, 2), EnvSpec("fk", 62, 9, 3)]
    check = agent_flop_formula_check(specs, config, per_task=4)
    assert check["equal"], check
    assert check["formula_ideal"] < check["flop_counter"]


def test_collection_bench_on_point_ends_on_identical_observations(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # auto's probe is injected (10 us a step, what a point step costs), so the choice does not
    # depend on this machine's speed: 4 x 10 us is far below the 1 ms threshold for workers.
    monkeypatch.setattr(env_backends, "_probe_step_seconds", lambda instance, steps=10: 1e-5)
    result = bench_collection(
        "point", episodes=1, episode_length=10, backends=("sync", "subproc-batched"), num_workers=2
    )
    assert result["env_steps"] == 4 * 10  # 4 point tasks x 10 steps
    assert all(b["same_final_obs"] for b in result["backends"].values())
    assert result["auto_backend"] == "sync"
    assert result["speedup"] == result["backends"]["sync"]["speedup"] > 0


def test_table_lists_each_key_with_its_goal() -> None:
    result = {
        "sac_vs_sb3": 1.5,
        "details": {
            "sac_vs_sb3": {"ours_updates_per_s": 30.0, "sb3_updates_per_s": 20.0},
            "collect_fk_speedup": {"skipped": "no kitchen"},
        },
        "collect_fk_speedup": None,
        "load_before": {"loadavg_1m": 1.0, "cpus": 2, "torch_threads": 2},
        "load_after": {"loadavg_1m": 1.5},
    }
    table = format_table(result)
    assert "sac_vs_sb3" in table and "1.50" in table and ">=1.3" in table
    assert "collect_fk_speedup" in table and "skipped: no kitchen" in table


def test_update_rate_bench_times_eager_and_compiled_on_the_protocols_shapes(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The paper_update_rate plumbing on the quickstart's agent (two envs of one task each, 128
    per task): a stand-in torch.compile that returns the stage itself makes the "compiled" path
    run the eager stages, so its losses must equal eager's exactly and its rate be the headline."""
    import torch

    from seal.bench.flops import QUICKSTART, bench_update_rate

    monkeypatch.setattr(torch, "compile", lambda fn, **_: fn)
    d = bench_update_rate(QUICKSTART, updates=2, repeats=1, device="cpu")
    assert d["batch"] == 2 * 128 and d["device"] == "cpu"
    assert {n: (e["obs_dim"], e["act_dim"]) for n, e in d["envs"].items()} == {
        "mw": (39, 4),
        "fk": (62, 9),
    }
    compiled = d["paths"]["compiled"]
    assert compiled["compiled"] and compiled["loss_max_rel_diff"] == {
        "update_1": 0.0,
        "update_5": 0.0,
    }
    assert d["headline_path"] == "compiled"
    assert d["paper_update_rate"] == compiled["updates_per_s"] == 1 / compiled["update_s"]
    assert d["paths"]["eager"]["updates_per_s"] > 0
    assert "paper_update_rate_tf32" not in d  # TF32 is timed on CUDA only
    table = _table_of("paper_update_rate", d, paper_update_rate=d)
    assert "paper_update_rate" in table and ">=1000" in table and "batch 256" in table
    assert "TF32" not in table
    on_gpu = {**d, "paper_update_rate_tf32": 576.54}  # as a CUDA run adds it
    assert "; with TF32 matmuls 576.5/s;" in _table_of(
        "paper_update_rate", d, paper_update_rate=on_gpu
    )


def test_mt10_flops_bench_reports_eager_and_compiled_paths(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """As above for mt10_update_flops_fraction: identity "compilation", so equal losses; the
    headline is the compiled path's, and each path's fraction is matmul time / its update time."""
    import torch

    from seal.bench.flops import bench_mt10_flops

    monkeypatch.setattr(torch, "compile", lambda fn, **_: fn)
    d = bench_mt10_flops(updates=1, repeats=1)
    eager, compiled = d["paths"]["eager"], d["paths"]["compiled"]
    assert compiled["loss_max_rel_diff"] == {"update_1": 0.0, "update_5": 0.0}
    assert d["mt10_update_flops_fraction"] == compiled["mt10_update_flops_fraction"]
    t_mm = eager["mt10_update_flops_fraction"] * eager["update_s"]
    assert compiled["mt10_update_flops_fraction"] == pytest.approx(t_mm / compiled["update_s"])
    # every GEMM of the ideal update, by hand in test_ideal_flop_formula_by_hand's terms
    assert d["ideal_flops_per_update"] == gemm_flops(ideal_update_gemms(UpdateShape()))
    assert d["flop_counter_per_update"] > d["ideal_flops_per_update"]  # all 10 heads computed
    table = _table_of(
        "mt10_update_flops_fraction", d, mt10_update_flops=d, flop_formula_check={"equal": True}
    )
    assert "compiled shown; eager" in table and "formula==FlopCounter: True" in table


def test_unknown_benchmark_key_is_a_one_line_user_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "--only", "nope"]) == 2
    err = capsys.readouterr().err
    assert "unknown benchmark 'nope'" in err and "sac_vs_sb3" in err
    assert "paper_update_rate" in err  # opt-in keys are valid too


def test_ratio_lever_bench_reports_every_mode_with_gradient_norm_ratios() -> None:
    from seal.bench.lever import bench_ratio_lever

    # Smoke size (2 warm-up updates, 4 per task): what is reported, not the figure itself.
    small = {
        "translator_hidden": (16,),
        "latent_dim": 16,
        "trunk_hidden": (16,),
        "critic_hidden": (16,),
    }
    result = bench_ratio_lever(warmup_updates=2, batch_per_task=4, episodes=1, draws=2, agent=small)
    # point (4 tasks) and point_view at 90/10 of 4 x 8 tasks' samples, rounded per task as the
    # runner rounds a plan (split_counts): a's tasks 7.2 -> 7, b's 0.8 -> 0, and the 4 left over go
    # to the largest remainders, b's 0.8 each: 28 and 4 (env-level rounding would give 29 and 3)
    assert result["batch"] == {"a": 28, "b": 4}
    assert list(result["modes"]) == ["weighted", "sequential", "per_env"]
    for mode in result["modes"].values():
        assert mode["env"] == "a" and 0.0 < mode["lever"] < 1.0
        g = mode["grad_norm"]
        assert mode["grad_norm_ratio_a_over_b"] == g["a"] / g["b"]
        expected = mode["expected"]
        assert expected["env"] == "a" and expected["draws"] == 2 and 0.0 < expected["lever"] < 1.0
    assert result["ratio_lever"] == result["modes"]["weighted"]["lever"]
    assert result["ratio_lever_expected"] == result["modes"]["weighted"]["expected"]["lever"]
    assert result["draws"] == 2
    # raw-gradient share of A under "weighted": 28 |g_a| / (28 |g_a| + 4 |g_b|)
    g = result["modes"]["weighted"]["grad_norm"]
    assert result["gradient_lever"] == pytest.approx(28 * g["a"] / (28 * g["a"] + 4 * g["b"]))
    # pure-noise ceiling: sqrt(28) / (sqrt(28) + sqrt(4)) = 5.2915 / 7.2915 = 0.72571
    assert result["noise_ceiling"] == pytest.approx(0.72571, abs=1e-5)
    table = _table_of("ratio_lever", result, ratio_lever=result)
    assert "ratio_lever" in table and ">=0.8" in table and "per_env" in table
    assert "pure-noise ceiling 0.73" in table
    table = _table_of("ratio_lever_expected", result, ratio_lever=result)
    assert "ratio_lever_expected" in table and "expected steps over 2 batches" in table


def test_paco_update_speedup_times_two_agents_that_compute_the_same_update() -> None:
    """The two sides differ only in PaCo's path: after five updates their losses agree, and the
    figure is the sets side's seconds over the composed side's (no verdict on the speed)."""
    from seal.bench.paco import bench_paco_update

    d = bench_paco_update(updates=2, repeats=1)
    assert d["loss_max_rel_diff"] < 1e-4
    assert d["batch"] == 2 * 128 and d["sets"] == 5 and d["hidden"] == [256, 256]
    assert d["paco_update_speedup"] == pytest.approx(d["sets_update_s"] / d["per_task_update_s"])
    table = _table_of("paco_update_speedup", {"paco_update_speedup": 2.5}, paco_update=d)
    assert "paco_update_speedup" in table and ">=2.0" in table and "K 5" in table


def test_bench_help_names_every_speed_key_and_every_learning_bench() -> None:
    """`seal bench --help` lists each key of the default run and the opt-in ones, and gives each
    `--learn` bench its own line: a bench added without a line in the help fails here."""
    from seal.bench.suite import OPT_IN_KEYS, SPEED_KEYS
    from seal.cli.bench_cmd import DESCRIPTION, LEARN_SETS

    words = set(DESCRIPTION.replace(",", " ").split())
    assert set(SPEED_KEYS + OPT_IN_KEYS) <= words
    lines = DESCRIPTION.splitlines()
    for name in LEARN_SETS:
        assert any(line.startswith(f"  {name} ") for line in lines), name
    assert all(len(line) <= 100 for line in lines)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--learn", "kitchen", "--quick"], "--quick only applies to the speed benches"),
        (["--protocol", "p.toml", "--only", "sac_vs_sb3"], "--only only applies to the speed"),
        (["--learn", "mtrl", "--repeats", "3"], "--repeats only applies to the speed benches"),
        (["--seeds", "3"], "--seeds only applies to a named --learn bench"),
        (["--learn", "--reuse"], "--reuse only applies to a named --learn bench"),
        (["--out", "d"], "--out only applies to a named --learn bench"),
        (["--epochs", "3"], "--epochs only applies to --protocol FILE"),
        (["--learn", "kitchen", "--floor-only"], "--floor-only only applies to --protocol FILE"),
        (["--cores", "8"], "--cores only applies to --protocol FILE"),
    ],
)
def test_an_option_the_chosen_bench_would_ignore_is_a_one_line_error(
    argv: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    from seal.cli.main import main

    assert main(["bench", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
