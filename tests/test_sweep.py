"""`seal sweep` without Ray: search-space parsing, sampling, resources, ranking and resume
bookkeeping, and the one-line errors (the sweeps themselves: tests/test_sweep_ray.py)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from seal.errors import ConfigError
from seal.protocols import load_protocol
from seal.sweep.ray_session import parse_resources
from seal.sweep.samples import count_trials, parse_search, sample_overrides, with_overrides
from seal.sweep.tables import rank_trials
from seal.sweep.trials import TrialRecord, is_finished, read_evaluations
from tests.sweep_tiny import write_protocol


def test_search_table_parses_every_distribution(tmp_path: Path) -> None:
    extra = """
    [search]
    num_samples = 3
    seed = 7
    scheduler = "asha"
    grace_period = 2
    "agent.actor_lr" = {dist = "loguniform", low = 1e-5, high = 1e-3}
    "agent.tau" = {dist = "uniform", low = 0.001, high = 0.02}
    "training.batch_per_task" = {dist = "int", low = 16, high = 17}
    "agent.hidden" = {dist = "choice", values = [[32], [64, 64]]}
    "agent.gamma" = {dist = "grid", values = [0.9, 0.95]}
    """
    spec = parse_search(load_protocol(write_protocol(tmp_path, extra=extra)))
    assert [p.key for p in spec.params] == [
        "agent.actor_lr",
        "agent.tau",
        "training.batch_per_task",
        "agent.hidden",
        "agent.gamma",
    ]
    assert (spec.num_samples, spec.seed, spec.scheduler, spec.grace_period) == (3, 7, "asha", 2)
    assert [p.dist for p in spec.params] == ["loguniform", "uniform", "int", "choice", "grid"]
    assert spec.params[2].low == 16 and spec.params[3].values == ([32], [64, 64])
    # 3 draws for each of the 2 grid points; --samples wins over the file's num_samples.
    assert count_trials(spec) == 6
    spec = parse_search(load_protocol(write_protocol(tmp_path, extra=extra)), num_samples=1)
    assert count_trials(spec) == 2


def test_sample_becomes_overrides_of_the_resolved_config(tmp_path: Path) -> None:
    config = load_protocol(write_protocol(tmp_path))
    overrides = sample_overrides(
        {"agent.actor_lr": 1e-4, "agent.hidden": [64, 64], "protocol.device": "cpu"}
    )
    assert overrides == ["agent.actor_lr=0.0001", "agent.hidden=[64, 64]", 'protocol.device="cpu"']
    changed = with_overrides(config, overrides)
    assert (changed.agent.actor_lr, changed.agent.hidden) == (1e-4, (64, 64))
    assert changed.agent.critic_lr == 3e-3  # untouched values stay


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ('"agent.actor_lr" = {dist = "normal", low = 0, high = 1}', "dist = 'normal' is not valid"),
        (
            '"agent.actor_lr" = {dist = "loguniform", low = 0.0, high = 1e-3}',
            "expected a number > 0",
        ),
        ('"agent.actor_lr" = {dist = "uniform", low = 1e-3}', "high is missing"),
        ('"agent.actor_lr" = {dist = "choice", values = []}', "non-empty array"),
        ('"agent.actor_lr" = {dist = "uniform", low = 1, high = 1}', "must be below high"),
        ("samples = 4", "table.key"),
        (
            'scheduler = "hyperband"\n"agent.tau" = {dist = "uniform", low = 0.001, high = 0.01}',
            "valid: 'none', 'asha'",
        ),
    ],
)
def test_bad_search_entries_name_the_key_and_what_is_valid(
    tmp_path: Path, entry: str, message: str
) -> None:
    with pytest.raises(ConfigError, match="search") as info:
        load_protocol(write_protocol(tmp_path, extra=f"[search]\n{entry}\n"))
    assert message in str(info.value)
    assert str(tmp_path / "tiny.toml") in str(info.value)


def test_search_without_a_search_table_says_how_to_write_one(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"needs a \[search\] table"):
        parse_search(load_protocol(write_protocol(tmp_path)))


def test_resources_table(tmp_path: Path) -> None:
    res = parse_resources(
        load_protocol(write_protocol(tmp_path, extra="[resources]\ncpus = 2.5\ngpus = 0.25\n"))
    )
    assert (res.cpus, res.gpus, res.threads) == (2.5, 0.25, 2)
    assert parse_resources(load_protocol(write_protocol(tmp_path))).cpus == 1.0
    with pytest.raises(ConfigError, match=r"resources\.cpus = 0 is not valid"):
        parse_resources(load_protocol(write_protocol(tmp_path, extra="[resources]\ncpus = 0\n")))
    with pytest.raises(
        ConfigError, match=r"resources\.memory is not a valid key; valid keys: cpus, gpus"
    ):
        parse_resources(load_protocol(write_protocol(tmp_path, extra="[resources]\nmemory = 4\n")))


def test_evaluations_per_run_sets_ashas_horizon(tmp_path: Path) -> None:
    from seal.sweep.samples import evaluation_horizon, evaluations_per_run

    # 20 epochs, interval 10: evaluations at 10 and 20 -> 2; 25 epochs: 10, 20 and the last (25) -> 3.
    assert evaluations_per_run(load_protocol(write_protocol(tmp_path))) == 2
    assert evaluations_per_run(load_protocol(write_protocol(tmp_path), ["protocol.epochs=25"])) == 3
    # Tune draws the samples, so ASHA's horizon is a bound over the searched values' ends:
    # 35 epochs every 5 -> 7 evaluations (agent.tau does not change the count).
    extra = """
    [search]
    "protocol.epochs" = {dist = "int", low = 20, high = 35}
    "evaluation.interval" = {dist = "choice", values = [10, 5]}
    "agent.tau" = {dist = "uniform", low = 0.001, high = 0.01}
    """
    config = load_protocol(write_protocol(tmp_path, extra=extra))
    assert evaluation_horizon(config, parse_search(config)) == 7


def test_ranking_puts_finished_then_stopped_then_failed(tmp_path: Path) -> None:
    def rec(name: str, status: str, success: float | None, ret: float | None) -> TrialRecord:
        return TrialRecord(
            trial=name,
            protocol="p",
            seed=0,
            run_dir=str(tmp_path / name),
            status=status,
            mean_success=success,
            mean_return=ret,
        )

    trials = [
        rec("failed", "failed", None, None),
        rec("tie-low-return", "finished", 0.0, -16.0),
        rec("stopped-high", "stopped", 0.9, -5.0),
        rec("best", "finished", 0.5, -10.0),
        rec("tie-high-return", "finished", 0.0, -6.0),
    ]
    # Finished by success (0.5 first), equal success by return (-6 before -16); ASHA-stopped after
    # every finished trial even with higher success; failed last.
    assert [t.trial for t in rank_trials(trials)] == [
        "best",
        "tie-high-return",
        "tie-low-return",
        "stopped-high",
        "failed",
    ]


def test_read_evaluations_and_completion_marker(tmp_path: Path) -> None:
    run = tmp_path / "seed-0"
    run.mkdir()
    (run / "metrics.csv").write_text(
        "seed,phase,epoch,env,task,success,return,grad_steps,env_steps,updates,wall_s\n"
        "0,train,10,point,east,0.0,-10.0,100,150,0.001,1.0\n"
        "0,train,10,point,west,1.0,-4.0,100,150,0.001,1.0\n"
        "0,train,20,point,east,0.5,-8.0,200,300,0.002,2.0\n"
        "0,train,20,point,west,1.0,-2.0,200,300,0.002,2.0\n"
        "0,train,30,point,ea"  # a torn row from a kill: ignored
    )
    evals = read_evaluations(run)
    # Epoch 10: success (0 + 1) / 2 = 0.5, return (-10 - 4) / 2 = -7; epoch 20: 0.75 and -5.
    assert [(e.epoch, e.mean_success, e.mean_return, e.rows) for e in evals] == [
        (10, 0.5, -7.0, 2),
        (20, 0.75, -5.0, 2),
    ]
    assert not is_finished(run)
    (run / "provenance.json").write_text(json.dumps({"start_time": "x", "end_time": None}))
    assert not is_finished(run)
    (run / "provenance.json").write_text(
        json.dumps({"start_time": "x", "end_time": "2026-11-22T04:00:00+00:00"})
    )
    assert is_finished(run)


def test_seal_run_and_protocols_never_import_ray() -> None:
    code = "import sys, seal.cli.run_cmd, seal.protocols, seal.run.runner, seal.cli.sweep_cmd, seal.cli.main; seal.cli.main.build_parser(); print('ray' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--samples", "3"], "--samples is only used with --search"),
        (["--search", "--seeds", "0-1"], "a search runs one seed per sample"),
        (["--resume", "somewhere"], "give either protocol FILEs or --resume"),
        (["--address", "nohost"], "expected auto or HOST:PORT"),
        (["--address", "127.0.0.1:1"], "no Ray cluster answers there"),
        (["--num-cpus", "2", "--address", "auto"], "--num-cpus 2 sets the CPUs of a local Ray"),
        (["--jobs", "2", "--address", "auto"], "--num-cpus 2 sets the CPUs of a local Ray"),
        (["--num-cpus", "0"], "--num-cpus 0: expected an integer >= 1"),
        (["--num-cpus", "-1"], "--num-cpus -1: expected an integer >= 1"),
        # A trial would fail on it; the sweep refuses it before any directory or Ray work:
        (["--set", 'transfer.checkpoint="gone.pt"'], "transfer.checkpoint = 'gone.pt': checkpoint"),
    ],
)
def test_cli_mistakes_are_one_line_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    from seal.cli.main import main

    assert (
        main(["sweep", str(write_protocol(tmp_path)), "--out", str(tmp_path / "reports"), *args])
        == 2
    )
    err = capsys.readouterr().err
    assert err.startswith("seal sweep: error: ") and message in err
    assert not (tmp_path / "reports").exists()  # nothing written before the mistake was caught


def test_a_search_space_the_schema_rejects_fails_at_load_without_ray(tmp_path: Path) -> None:
    from seal.sweep.search import search

    # A learning rate of exactly 0 is not a valid Adam rate. The whole search space is checked
    # when the protocol loads (each searched value at the ends of its distribution), so the
    # search stops before any directory or Ray work; trials that fail while running (a NaN) are
    # still recorded without stopping the others (test_failing_trial_is_reported_...).
    extra = '[search]\nnum_samples = 1\n"agent.actor_lr" = {dist = "choice", values = [0.0]}\n'
    with pytest.raises(ConfigError, match=r"search\.agent\.actor_lr = 0\.0\).*agent\.actor_lr"):
        search(write_protocol(tmp_path, extra=extra), out=tmp_path / "reports")
    assert not (tmp_path / "reports").exists()


@pytest.mark.parametrize("search", [False, True])
def test_a_run_too_large_for_the_machine_is_refused_before_ray(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], search: bool
) -> None:
    """seal run's memory refusal, before any directory or Ray work: for a plain sweep's protocol,
    and for each [search] value alone (a replay of 10^12 failed inside every trial)."""
    from seal.cli.main import main

    huge = "100000000000"
    extra = (
        f'[search]\nnum_samples = 1\n"replay.capacity_per_env" = {{dist = "choice", values = [1000, {huge}]}}\n'
        if search
        else ""
    )
    args = ["--search"] if search else ["--set", f"replay.capacity_per_env={huge}"]
    path = write_protocol(tmp_path, extra=extra)
    assert main(["sweep", str(path), "--out", str(tmp_path / "reports"), *args]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and f"replay.capacity_per_env = {huge}: the run needs" in err[0], err
    assert ("[search] value" in err[0]) == search
    assert not (tmp_path / "reports").exists()
    # The control: the same protocol with values that fit passes the check (and goes on to Ray,
    # which this test does not start).
    from seal.sweep.manifest import _check_memory, _load_configs

    (tmp_path / "fits").mkdir()
    fits = write_protocol(tmp_path / "fits", extra=extra.replace(f", {huge}", ""))
    _check_memory(load_protocol(fits), search)
    # On a cluster (--address) the trials run on other nodes, whose memory is theirs to check.
    sets = [] if search else [f"replay.capacity_per_env={huge}"]
    with pytest.raises(ConfigError, match="the run needs"):
        _load_configs([path], sets, None, search=search, local=True)
    _load_configs([path], sets, None, search=search, local=False)
