"""`seal sweep` on a local Ray: sweeps and a search of the tiny `point` protocol
(tests/sweep_tiny.py), their tables, failures, resume and SIGTERM. The tests share one local Ray
session (module fixture)."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from seal.errors import SealError
from seal.protocols import load_protocol
from seal.sweep.samples import count_trials, parse_search
from seal.sweep.trials import TrialRecord, is_finished, read_evaluations
from tests.sweep_tiny import write_protocol
from tests.waiting import HUNG_S, wait_until


@pytest.fixture(scope="module")
def ray_session():  # noqa: ANN201 - yields the ray module
    """One local Ray for every test below (startup costs seconds), started as `seal sweep` starts
    one; sweeps reuse an initialised Ray. The dev extra installs Ray: a missing one fails these
    tests rather than skipping them."""
    from seal.sweep.ray_session import RaySession

    with RaySession(num_cpus=2) as ray:  # an initialised Ray (another module's) is used, kept
        yield ray


def test_trials_run_at_the_priority_of_the_sweep(ray_session) -> None:  # noqa: ANN001
    # Ray's default worker niceness, 15, starves a trial beside any busy process: a search of 16 s
    # alone was still running after 8 min beside two learning runs on 2 cores (23 s at 0).
    @ray_session.remote
    def niceness() -> int:
        return os.nice(0)

    assert ray_session.get(niceness.remote()) == os.nice(0)


SEARCH_SPACE = """
[search]
num_samples = 3
seed = {seed}
"agent.actor_lr" = {{dist = "loguniform", low = 1e-5, high = 1e-3}}
"agent.tau" = {{dist = "uniform", low = 0.001, high = 0.02}}
"training.batch_per_task" = {{dist = "int", low = 16, high = 17}}
"agent.hidden" = {{dist = "choice", values = [[32], [64, 64]]}}
"agent.gamma" = {{dist = "grid", values = [0.9, 0.95]}}
"""


def tune_draws(tmp_path: Path, seed: int) -> list[dict[str, object]]:
    """The configs Ray Tune draws for SEARCH_SPACE with `seed`, by sample index (a trial that only reports)."""
    from ray import tune

    from seal.sweep.samples import plain_sample, search_algorithm, search_space, trial_index

    spec = parse_search(
        load_protocol(
            write_protocol(tmp_path, f"draws{seed}", extra=SEARCH_SPACE.format(seed=seed))
        )
    )
    tuner = tune.Tuner(
        lambda config: tune.report({"done_once": 1}),
        param_space=search_space(spec),
        tune_config=tune.TuneConfig(
            num_samples=spec.num_samples, search_alg=search_algorithm(spec), reuse_actors=True
        ),
        run_config=tune.RunConfig(storage_path=str(tmp_path / f"tune{seed}"), verbose=0),
    )
    results = tuner.fit()
    assert len(results) == count_trials(spec) == 6 and not results.errors
    by_index = {trial_index(r.metrics["trial_id"]): plain_sample(r.config) for r in results}
    return [by_index[i] for i in range(len(by_index))]


@pytest.mark.slow
def test_tune_draws_the_same_samples_for_the_same_seed(ray_session, tmp_path: Path) -> None:  # noqa: ANN001
    samples = tune_draws(tmp_path, seed=7)
    # Tune's grid semantics: each of the 3 draws is made for every grid point, in grid order.
    assert [s["agent.gamma"] for s in samples] == [0.9, 0.95] * 3
    for s in samples:
        assert list(s) == [
            "agent.actor_lr",
            "agent.tau",
            "training.batch_per_task",
            "agent.hidden",
            "agent.gamma",
        ]
        assert 1e-5 <= s["agent.actor_lr"] <= 1e-3
        assert 0.001 <= s["agent.tau"] <= 0.02
        assert s["training.batch_per_task"] in (16, 17)  # int: both ends included
        assert s["agent.hidden"] in ([32], [64, 64])
    assert len({s["agent.actor_lr"] for s in samples}) == 6  # a fresh draw per trial
    assert (
        tune_draws(tmp_path, seed=7) == samples
    )  # same seed, same configs (what resume relies on)
    other = tune_draws(tmp_path, seed=8)
    assert [s["agent.actor_lr"] for s in other] != [s["agent.actor_lr"] for s in samples]


def test_two_seeds_give_two_run_dirs_and_one_table(
    ray_session, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:  # noqa: ANN001
    from seal.cli.main import main

    protocol = write_protocol(tmp_path)
    code = main(
        ["sweep", str(protocol), "--seeds", "0-1", "--out", str(tmp_path / "reports"), "--json"]
    )
    assert code == 0
    data = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    runs = [Path(p) for p in data["run_dirs"]]
    assert [r.name for r in runs] == ["seed-0", "seed-1"]
    assert runs[0].parent == runs[1].parent == Path(data["sweep_dir"])  # one group
    assert runs[0].parent.parent == (tmp_path / "reports" / "tiny").resolve()
    for run in runs:
        # The run directory `seal run` writes, finished.
        assert {"config.toml", "provenance.json", "metrics.csv", "train.csv", "checkpoints"} <= {
            p.name for p in run.iterdir()
        }
        assert is_finished(run)
        assert len(read_evaluations(run)) == 2  # epochs 10 and 20
    table = Path(data["table"])
    assert table.name == "update_counts.md" and table.is_file()
    text = table.read_text()
    assert "Single Env" in text and "east (point)" in text
    assert data["failed"] == []


@pytest.mark.slow
def test_search_ranks_the_config_that_cannot_learn_last(ray_session, tmp_path: Path) -> None:  # noqa: ANN001
    from seal.sweep.search import search

    extra = """
    [search]
    num_samples = 2
    seed = 0
    "agent.lr_factor" = {dist = "grid", values = [1.0, 1e-9]}
    "agent.tau" = {dist = "uniform", low = 0.004, high = 0.01}
    """
    result = search(write_protocol(tmp_path, extra=extra, epochs=40), out=tmp_path / "reports")
    assert len(result.trials) == 4
    assert all(t.status == "finished" for t in result.trials)
    # Ranked: the two learning configs (success > 0 at 40 epochs, see the module docstring) first,
    # the two with a learning rate of ~0 (success 0) last.
    assert [t.sample["agent.lr_factor"] for t in result.trials] == [1.0, 1.0, 1e-9, 1e-9]
    assert result.trials[1].mean_success > 0.0
    assert [t.mean_success for t in result.trials[2:]] == [0.0, 0.0]
    csv_rows = (result.sweep_dir / "search.csv").read_text().splitlines()
    assert csv_rows[0].startswith("rank,trial,status,agent.lr_factor,agent.tau,mean_success")
    best = load_protocol(result.best_config)
    assert best.agent.lr_factor == 1.0 and best.search == {}
    assert best.agent.tau == result.trials[0].sample["agent.tau"]

    # Resuming a finished search runs nothing again: every trial is kept, the ranking unchanged.
    metrics = Path(result.trials[0].run_dir) / "metrics.csv"
    before = metrics.stat().st_mtime_ns
    again = search(resume=result.sweep_dir)
    assert [t.start for t in again.trials] == ["kept"] * 4
    assert [t.trial for t in again.trials] == [t.trial for t in result.trials]
    assert metrics.stat().st_mtime_ns == before


@pytest.mark.slow
def test_resume_runs_the_pending_samples_as_drawn_and_keeps_finished_ones(
    ray_session, tmp_path: Path
) -> None:  # noqa: ANN001
    from seal.sweep.search import search

    extra = """
    [search]
    num_samples = 3
    seed = 5
    "agent.tau" = {dist = "uniform", low = 0.004, high = 0.01}
    """
    first = search(write_protocol(tmp_path, extra=extra), out=tmp_path / "reports")
    drawn = {t.trial: t.sample for t in first.trials}
    assert sorted(drawn) == ["sample-000", "sample-001", "sample-002"]
    assert all(t.status == "finished" and t.start == "new" for t in first.trials)
    # An interrupted search: sample-001 was running (pending in sweep.json, its run directory
    # unfinished) and sample-002 was never drawn (not in sweep.json, no run directory).
    manifest_path = first.sweep_dir / "sweep.json"
    manifest = json.loads(manifest_path.read_text())
    manifest["trials"] = [t for t in manifest["trials"] if t["trial"] != "sample-002"]
    for t in manifest["trials"]:
        if t["trial"] == "sample-001":
            t["status"] = "pending"
    manifest_path.write_text(json.dumps(manifest))
    by_name = {t.trial: Path(t.run_dir) for t in first.trials}
    shutil.rmtree(by_name["sample-001"])
    shutil.rmtree(by_name["sample-002"].parent)
    metrics = by_name["sample-000"] / "metrics.csv"
    before = (metrics.stat().st_mtime_ns, metrics.read_text())

    again = search(resume=first.sweep_dir)
    by_name = {t.trial: t for t in again.trials}
    assert by_name["sample-000"].start == "kept" and by_name["sample-000"].status == "finished"
    assert (metrics.stat().st_mtime_ns, metrics.read_text()) == before  # not run again
    for name in ("sample-001", "sample-002"):
        assert by_name[name].start == "new" and by_name[name].status == "finished"
        assert is_finished(by_name[name].run_dir)
    # Tune drew the same values again (seed 5): each sample is what the first search ran.
    assert {t.trial: t.sample for t in again.trials} == drawn
    resumed = load_protocol(Path(by_name["sample-002"].run_dir) / "config.toml")
    assert resumed.agent.tau == drawn["sample-002"]["agent.tau"]


def test_failing_sample_is_recorded_while_the_others_finish(ray_session, tmp_path: Path) -> None:  # noqa: ANN001
    from seal.sweep.search import search

    # init_alpha = 1e300 makes the first update's losses inf/NaN: "training diverged".
    extra = """
    [search]
    num_samples = 1
    "agent.init_alpha" = {dist = "grid", values = [1e300, 0.01]}
    """
    result = search(write_protocol(tmp_path, extra=extra), out=tmp_path / "reports")
    assert [(t.trial, t.status) for t in result.trials] == [
        ("sample-001", "finished"),
        ("sample-000", "failed"),
    ]
    failed = result.trials[1]
    assert "training diverged" in failed.error
    assert (Path(failed.run_dir) / "error.txt").is_file()
    assert result.to_json()["failed"] == [
        {"trial": "sample-000", "run_dir": failed.run_dir, "error": failed.error}
    ]
    assert load_protocol(result.best_config).agent.init_alpha == 0.01
    rows = (result.sweep_dir / "search.csv").read_text().splitlines()
    assert rows[2].startswith("2,sample-000,failed,") and "training diverged" in rows[2]


def test_failing_trial_is_reported_others_complete_and_resume_keeps_finished(
    ray_session, tmp_path: Path
) -> None:  # noqa: ANN001
    from seal.sweep.grid import sweep

    good = write_protocol(tmp_path, "good")
    # init_alpha = 1e300 makes the entropy term infinite: the first update's losses are inf/NaN
    # and the runner raises "training diverged" inside the trial.
    bad = write_protocol(tmp_path, "diverges", init_alpha=1e300)
    result = sweep([good, bad], seeds=[0], out=tmp_path / "reports")
    by_name = {t.protocol: t for t in result.trials}
    assert by_name["good"].status == "finished" and is_finished(by_name["good"].run_dir)
    failed = by_name["diverges"]
    assert failed.status == "failed" and "training diverged" in failed.error
    assert (Path(failed.run_dir) / "error.txt").is_file()
    assert result.to_json()["failed"] == [
        {"trial": "diverges/seed-0", "run_dir": failed.run_dir, "error": failed.error}
    ]
    assert result.to_json()["run_dirs"] == [by_name["good"].run_dir]
    assert result.table is not None and result.table.name == "update_counts.md"
    assert "diverges/seed-0" in (result.sweep_dir / "trials.md").read_text()

    metrics = Path(by_name["good"].run_dir) / "metrics.csv"
    before = (metrics.stat().st_mtime_ns, metrics.read_text())
    again = sweep(resume=result.sweep_dir)
    by_name = {t.protocol: t for t in again.trials}
    assert by_name["good"].start == "kept" and by_name["good"].status == "finished"
    assert (metrics.stat().st_mtime_ns, metrics.read_text()) == before  # not run again
    assert by_name["diverges"].start == "continued" and by_name["diverges"].status == "failed"


def test_resume_of_a_missing_sweep_dir_is_a_user_error(tmp_path: Path) -> None:
    from seal.sweep.grid import sweep

    with pytest.raises(SealError, match="not a sweep directory"):
        sweep(resume=tmp_path)


@pytest.mark.slow
@pytest.mark.timeout(3 * HUNG_S)  # its own waits give up at HUNG_S each
def test_sigterm_stops_a_sweep_with_every_trial_saved_and_resume_finishes_them(
    ray_session, tmp_path: Path
) -> None:  # noqa: ANN001
    """One trial's worker gets SIGTERM itself, then the driver does: both trials save their last
    finished epoch as `seal run` would, sweep.json marks them preempted, the driver exits 143
    with the resume command, and `--resume` finishes them with the rows of uninterrupted runs
    that also checkpointed where they stopped."""
    from seal.run.loop import PhaseLoop
    from seal.run.runner import run_seed
    from seal.sweep.grid import sweep

    protocol = write_protocol(tmp_path, "stop")
    sets = ["checkpoint.save_replay=true", "protocol.epochs=40", "evaluation.interval=2"]
    args = ["sweep", str(protocol), "--seeds", "0-1", "--out", str(tmp_path / "out")]
    args += ["--num-cpus", "2"] + [a for s in sets for a in ("--set", s)]
    stderr = tmp_path / "driver.err"
    with stderr.open("w") as err_file:
        driver = subprocess.Popen(
            [sys.executable, "-m", "seal.cli.main", *args],
            env={**os.environ, "OMP_NUM_THREADS": "1"},
            stdout=subprocess.DEVNULL,
            stderr=err_file,
            text=True,
        )
    runs = tmp_path / "out" / "stop"

    def evaluated(seed: int) -> bool:
        return any(len(read_evaluations(r)) >= 1 for r in runs.glob(f"*/seed-{seed}"))

    def worker(seed: int) -> int:
        (run,) = runs.glob(f"*/seed-{seed}")
        return json.loads((run / ".seal.lock").read_text())["pid"]

    # Seed 0 must still be running when the driver's SIGTERM comes, whatever the machine's speed:
    # its worker is held (SIGSTOP) from its first evaluation until the driver has begun stopping
    # the sweep, so its 40 epochs cannot finish first (issue 55: they did on a loaded machine).
    held = None
    try:
        wait_until(lambda: evaluated(0), "seed 0 evaluated", child=driver, why=stderr.read_text)
        held = worker(0)
        os.kill(held, signal.SIGSTOP)
        wait_until(lambda: evaluated(1), "seed 1 evaluated", child=driver, why=stderr.read_text)
        (group,) = runs.iterdir()
        os.kill(worker(1), signal.SIGTERM)  # a trial's worker gets the signal itself

        def seed_1_preempted() -> bool:
            trials = json.loads((group / "sweep.json").read_text())["trials"]
            return trials[1]["status"] == "preempted"

        wait_until(
            seed_1_preempted, "seed 1 was recorded preempted", child=driver, why=stderr.read_text
        )
        driver.send_signal(signal.SIGTERM)
        wait_until(
            lambda: "SIGTERM: stopping" in stderr.read_text(),
            "the driver stopping",
            child=driver,
            why=stderr.read_text,
        )
        os.kill(held, signal.SIGCONT)  # now the driver's gentle cancel reaches it mid-run
        held = None
        driver.wait(timeout=HUNG_S)
    finally:
        if held is not None:
            os.kill(held, signal.SIGCONT)
        if driver.poll() is None:
            driver.kill()
            driver.wait()
    err = stderr.read_text()
    assert driver.returncode == 143, err
    assert err.strip().splitlines()[-1] == (
        f"seal sweep: SIGTERM: stopped the sweep (2 preempted); resume with: seal sweep --resume {group}"
    )
    trials = json.loads((group / "sweep.json").read_text())["trials"]
    # A failure here once went unexplained (its output lost): each assert now says what it saw.
    assert [t["status"] for t in trials] == ["preempted", "preempted"], (trials, err)
    # seed 1 got SIGTERM; seed 0 the driver's gentle ray.cancel, which a trial sees as SIGINT.
    assert trials[0]["note"].startswith("SIGINT "), (trials, err)
    assert trials[1]["note"].startswith("SIGTERM "), (trials, err)
    stopped = {}
    for t in trials:
        run = Path(t["run_dir"])
        newest = max((run / "checkpoints").glob("ckpt-*.pt"), key=lambda p: p.stat().st_mtime_ns)
        stopped[t["seed"]] = int(newest.stem.split("-")[1])
        assert (
            f"epoch {stopped[t['seed']]} " in t["note"]
            or f"epoch {stopped[t['seed']]}'s" in t["note"]
        ), (stopped, t, err)
        assert not is_finished(run), (t, err)

    again = sweep(resume=group)
    assert [(t.start, t.status) for t in again.trials] == [("continued", "finished")] * 2, again
    real_close = PhaseLoop._close_epoch
    for t in again.trials:
        epoch = stopped[t.seed]

        def close(loop: PhaseLoop, last: bool, epoch: int = epoch) -> None:
            real_close(loop, last)
            if loop.state.epoch == epoch and loop.saved_epoch != epoch:
                loop._checkpoint(reseed=True)  # the reference checkpoints where the trial stopped

        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(PhaseLoop, "_close_epoch", close)
            # One torch thread, as the trial's (execute_trial sets [resources]'s threads).
            config = load_protocol(protocol, [*sets, "protocol.threads=1"])
            ref = run_seed(config, t.seed, tmp_path / f"ref{t.seed}").run_dir
        for name in ("metrics.csv", "train.csv"):
            got, want = ((Path(d) / name).read_text().splitlines() for d in (t.run_dir, ref))
            if name == "metrics.csv":  # the wall-clock column aside
                got, want = ([r.rsplit(",", 1)[0] for r in rows] for rows in (got, want))
            assert got == want


def test_a_started_trial_without_a_saved_replay_is_set_aside_and_runs_afresh(
    tmp_path: Path,
) -> None:
    """`seal sweep --resume` (and a bench task's retry) cannot continue a run whose checkpoints
    hold no replay: execute_trial moves it to <group>/.lost/ and runs the seed from the start,
    giving the rows a run that was never interrupted gives."""
    import pandas as pd

    from seal.protocols import load_protocol
    from seal.sweep.trials import execute_trial
    from tests.faults.point_protocol import point_protocol

    path = tmp_path / "p.toml"
    path.write_text(point_protocol("noreplay", 2))
    config = load_protocol(path, ["checkpoint.save_replay=false"])

    def trial(group: str) -> tuple[TrialRecord, Path]:
        run_dir = tmp_path / "out" / "noreplay" / group / "seed-0"
        return TrialRecord(trial="t", protocol="noreplay", seed=0, run_dir=str(run_dir)), run_dir

    clean, clean_dir = trial("clean")
    assert execute_trial(config, clean).status == "finished"
    record, run_dir = trial("partial")
    (run_dir / "checkpoints").mkdir(parents=True)
    (run_dir / "config.toml").write_text("# a run stopped before its end\n")
    (run_dir / "checkpoints" / "ckpt-0000001.pt").write_bytes(b"an epoch checkpoint, no replay")
    record = execute_trial(config, record)
    assert (record.status, record.start) == ("finished", "new")
    (moved,) = (run_dir.parent / ".lost").iterdir()
    assert moved.name.startswith("seed-0-")
    assert (moved / "config.toml").read_text() == "# a run stopped before its end\n"
    drop = ["wall_s"]
    pd.testing.assert_frame_equal(
        pd.read_csv(run_dir / "metrics.csv").drop(columns=drop),
        pd.read_csv(clean_dir / "metrics.csv").drop(columns=drop),
    )
