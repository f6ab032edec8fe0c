"""`seal.experiments.launcher`: every run of `seal bench --learn` is a Ray task.

What a run reserves, the one-line errors (no Ray, --jobs with --address, a Ray initialised
otherwise, an --out a node does not see), and on a local Ray how a stopped bench stops its runs
(each saves its last finished epoch; one that ignores the gentle cancel is cut off at a second
signal) and how a run whose worker is lost runs again from its last checkpoint. The stop and
retry tests act on events (a run's first evaluation, its first checkpoint, the driver's
"stopping" line), never on how long something took: their only time limit, HUNG_S, calls a
step that never comes hung. The runs are a tiny `point` protocol, a few seconds each.
"""

from __future__ import annotations

import _thread
import contextlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pandas as pd
import pytest

import seal.experiments.launcher as launcher
import seal.sweep.ray_session as ray_session_module
from seal.errors import SealError
from seal.experiments.arms import ARMS, Arm
from seal.experiments.launcher import check_shared_out, run_all, run_cpus, run_or_reuse
from seal.protocols import load_protocol
from seal.run.preemption import Preempted, SignalStop, hearing_cancel
from seal.run.runner import run_seed
from seal.sweep.ray_session import RaySession
from seal.sweep.trials import is_finished, last_preemption, read_evaluations
from tests.faults.point_protocol import point_protocol
from tests.waiting import HUNG_S, wait_until


def tiny_arm(tmp_path: Path, epochs: int, interval: int = 5) -> Arm:
    """An arm whose protocol is the fault tests' small point protocol, written to
    tmp_path/protocols/tiny.toml."""
    directory = tmp_path / "protocols"
    directory.mkdir(exist_ok=True)
    text = point_protocol("tiny", epochs, interval=interval, train_interval=None)
    (directory / "tiny.toml").write_text(text)
    return Arm("tiny", "Tiny", None, directory=directory)


def run_dirs(out: Path) -> list[Path]:
    return list(out.glob("tiny/*/seed-0"))


def worker_pid(out: Path) -> int:
    """The pid of the Ray worker that runs seed 0 (its run directory's lock file says it)."""
    (run,) = run_dirs(out)
    return int(json.loads((run / ".seal.lock").read_text())["pid"])


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


@contextlib.contextmanager
def in_background(steps: Callable[[], None]) -> Iterator[None]:
    """Run `steps` in a thread while the test's body runs; re-raise its failure after, also when
    the body raised (as the tests expect Preempted to), so no failure of `steps` is lost."""
    failed: list[BaseException] = []

    def target() -> None:
        try:
            steps()
        except BaseException as exc:  # noqa: BLE001 - reported by the test
            failed.append(exc)

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    try:
        yield
    finally:
        thread.join(HUNG_S)
        assert not thread.is_alive(), f"the background steps still run after {HUNG_S} s"
        if failed:
            raise failed[0]


# ---------------------------------------------------------------- without a Ray


def _interrupted() -> bool:
    """Whether Ray's gentle cancel, `_thread.interrupt_main()`, interrupts this (main) thread."""
    try:
        _thread.interrupt_main()
        for _ in range(10**6):  # the interrupt is taken between bytecodes
            pass
    except KeyboardInterrupt:
        return True
    return False


def test_a_trial_hears_the_gentle_cancel_where_its_worker_ignores_sigint() -> None:
    # A Ray worker started under a background driver (`nohup seal bench ... &`) ignores SIGINT,
    # and there Ray's gentle cancel does nothing: the run never saved (issue 54's runs, 2026-12-06).
    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        assert not _interrupted()
        with hearing_cancel():
            assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
            assert _interrupted()
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
        signal.signal(signal.SIGINT, handler := lambda *_: None)  # a process's own handler: kept
        with hearing_cancel():
            assert signal.getsignal(signal.SIGINT) is handler
    finally:
        signal.signal(signal.SIGINT, before)


def test_a_run_reserves_the_cpus_its_threads_resolve_to(monkeypatch: pytest.MonkeyPatch) -> None:
    alone = next(a for a in ARMS if a.name == "alone")
    # Every shipped bench protocol resolves to one thread: one CPU, so --jobs 2 runs two.
    assert run_cpus(load_protocol(alone.protocol), node_cpus=2) == 1
    assert run_cpus(load_protocol(alone.protocol, ["protocol.threads=3"]), node_cpus=8) == 3
    assert run_cpus(load_protocol(alone.protocol, ["protocol.threads=3"]), node_cpus=2) == 2
    # torch's default (every core) and the quickstart's rule take the whole node.
    assert run_cpus(load_protocol(alone.protocol, ["protocol.threads=0"]), node_cpus=6) == 6
    assert run_cpus(load_protocol(alone.protocol), node_cpus=6, whole_node=True) == 6
    # "auto" with a team of t threads (on a 16-core machine here): the 2 t cores the rule keeps
    # for it, on which the task resolves "auto" to t again.
    import seal.device

    monkeypatch.setattr(seal.device, "usable_cores", lambda: 16)
    wide = ["agent.trunk_hidden=[1024, 1024]", "agent.critic_hidden=[1024, 1024]"]
    big = load_protocol(alone.protocol, [*wide, "training.batch_per_task=4000"])
    from seal.run.phase_model import build_adapters
    from seal.run.resources import choose_update_threads, estimate_resources

    estimate = estimate_resources(big, build_adapters(big), "cpu")
    threads = choose_update_threads(big, estimate).threads
    assert threads >= 2
    assert run_cpus(big, node_cpus=64) == 2 * threads
    assert choose_update_threads(big, estimate, cores=2 * threads).threads == threads
    assert run_cpus(big, node_cpus=3) == 3


def test_without_ray_the_bench_says_how_to_install_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from seal.cli.main import main

    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` fails as if not installed
    args = ["bench", "--learn", "transfer", "--arms", "alone", "--seeds", "1"]
    assert main([*args, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err == (
        "seal bench: error: seal bench --learn needs Ray: pip install 'seal[ray]' "
        "(or pip install 'ray[tune]')\n"
    )


def test_jobs_and_address_mistakes_are_one_line_errors(capsys: pytest.CaptureFixture[str]) -> None:
    from seal.cli.main import main

    assert main(["bench", "--learn", "transfer", "--jobs", "2", "--address", "auto"]) == 2
    assert "--jobs sets the CPUs of a local Ray" in capsys.readouterr().err
    # `seal sweep`'s name for it is the same option here.
    assert main(["bench", "--learn", "transfer", "--num-cpus", "2", "--address", "auto"]) == 2
    assert "--jobs sets the CPUs of a local Ray" in capsys.readouterr().err
    assert main(["bench", "--jobs", "2"]) == 2
    assert (
        "--jobs only applies to a named --learn bench (transfer, kitchen" in capsys.readouterr().err
    )
    assert main(["bench", "--learn", "transfer", "--address", "127.0.0.1:1"]) == 2
    assert "no Ray cluster answers there" in capsys.readouterr().err


def test_a_run_that_waits_on_an_unscheduled_pretraining_is_an_error(tmp_path: Path) -> None:
    rung = next(a for a in ARMS if a.name == "pretrained_trunk")
    with pytest.raises(SealError, match=r"not scheduled: \['pretrain_source seed 0'\]"):
        run_all([(rung, 0)], tmp_path)
    assert not any(tmp_path.iterdir())


# ---------------------------------------------------------------- on a local Ray


@pytest.fixture(scope="module")
def ray_session():  # noqa: ANN201 - yields the ray module
    """One local Ray of 2 CPUs for every test below, which `run_all(parallel=2)` takes."""
    with RaySession(num_cpus=2) as ray:
        if RaySession.opened != (None, 2):
            pytest.skip("another module's Ray is initialised in this process")
        yield ray


def test_a_ray_initialised_otherwise_is_an_error_for_the_bench(
    ray_session, monkeypatch: pytest.MonkeyPatch
) -> None:  # noqa: ANN001
    # The bench takes only the Ray it asks for: the same local Ray, or the cluster at its GCS.
    with RaySession(None, 2, strict=True) as ray:
        assert ray is ray_session
    gcs = ray_session.get_runtime_context().gcs_address
    with RaySession(gcs, strict=True):
        pass
    with pytest.raises(
        SealError, match=r"already initialised in this process \(a local Ray with 2 CPUs"
    ):
        RaySession(None, 3, strict=True).__enter__()
    with pytest.raises(SealError, match=r"not as asked \(the Ray cluster at --address auto\)"):
        RaySession("auto", strict=True).__enter__()
    # A Ray this process joined otherwise (a notebook's ray.init("auto")): --address auto takes
    # it when "auto" resolves to its GCS here, and refuses it when it names another cluster.
    monkeypatch.setattr(RaySession, "opened", None)
    monkeypatch.setattr(ray_session_module, "_auto_address", lambda: gcs)
    with RaySession("auto", strict=True) as ray:
        assert ray is ray_session
    monkeypatch.setattr(ray_session_module, "_auto_address", lambda: "10.9.9.9:6379")
    with pytest.raises(SealError, match=r"the Ray whose GCS is at .*--address auto"):
        RaySession("auto", strict=True).__enter__()
    monkeypatch.undo()
    # `seal sweep` (not strict) still uses whatever Ray is initialised, as its tests rely on.
    with RaySession(None, 3) as ray:
        assert ray is ray_session
    assert ray_session.is_initialized()


def test_address_auto_never_joins_a_private_ray(
    ray_session, monkeypatch: pytest.MonkeyPatch
) -> None:  # noqa: ANN001
    # This module's private Ray runs on this machine; Ray's own "auto" would join it (or any
    # other seal command's). seal's "auto" joins only RAY_ADDRESS or what `ray start` left here.
    from ray._private import services

    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    monkeypatch.setattr(services, "find_bootstrap_address", lambda temp_dir: None)
    assert services.canonicalize_bootstrap_address("auto") is not None  # Ray's fallback
    assert ray_session_module._auto_address() is None
    with pytest.raises(SealError, match=r"--address auto: no Ray cluster to join"):
        ray_session_module.check_address("auto")
    monkeypatch.setenv("RAY_ADDRESS", "local")  # would start a Ray, not join one
    assert ray_session_module._auto_address() is None
    monkeypatch.setattr(services, "find_bootstrap_address", lambda temp_dir: "127.0.0.1:1")
    with pytest.raises(
        SealError,
        match=r"--address auto, from the cluster `ray start` last left on this machine: "
        r"--address [\d.]+:1: no Ray cluster answers there",
    ):
        ray_session_module.check_address("auto")  # a `ray start` cluster since stopped
    monkeypatch.setenv("RAY_ADDRESS", "10.0.0.7:6379")
    assert ray_session_module._auto_address() == "10.0.0.7:6379"
    monkeypatch.setenv("RAY_ADDRESS", "localhost:6379")  # as Ray reads it: this node's IP
    assert ray_session_module._auto_address() == services.canonicalize_bootstrap_address(
        "localhost:6379"
    )
    monkeypatch.setenv("RAY_ADDRESS", "myhost")
    with pytest.raises(SealError, match=r"--address auto, from RAY_ADDRESS=myhost: --address"):
        ray_session_module.check_address("auto")


def test_the_shared_filesystem_check(
    ray_session, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:  # noqa: ANN001
    out = tmp_path / "out"
    check_shared_out(ray_session, out)  # one machine: its node sees it
    assert list(out.iterdir()) == []  # the probe is gone

    def blind(path: str, token: str) -> bool:
        return False

    monkeypatch.setattr(launcher, "_sees", blind)  # a node without the shared filesystem
    (node,) = [n["NodeManagerAddress"] for n in ray_session.nodes() if n["Alive"]]
    with pytest.raises(SealError, match=f"node {node} of the Ray cluster do not see it"):
        check_shared_out(ray_session, out)
    assert list(out.iterdir()) == []

    def dies(path: str, token: str) -> bool:
        raise ray_session.exceptions.WorkerCrashedError()  # as when the node dies mid-question

    monkeypatch.setattr(launcher, "_sees", dies)
    with pytest.raises(SealError, match=r"a node of the Ray cluster failed while asked"):
        check_shared_out(ray_session, out)
    assert list(out.iterdir()) == []


def test_a_cluster_without_a_live_cpu_node_is_a_one_line_error() -> None:
    class NoNodes:  # what ray.nodes() says once every worker node has died
        @staticmethod
        def nodes() -> list[dict]:
            return [{"Alive": False, "Resources": {"CPU": 2.0}}, {"Alive": True, "Resources": {}}]

    with pytest.raises(SealError, match="no alive node with a CPU"):
        launcher.Launcher(NoNodes, SignalStop(), print, 1.0)


@pytest.mark.slow
@pytest.mark.timeout(3 * HUNG_S)
def test_a_stopped_bench_lets_its_run_save_and_reuse_continues_it(
    ray_session, tmp_path: Path
) -> None:  # noqa: ANN001
    """A SIGTERM to the bench cancels its run gently: the run saves its last finished epoch (as
    `seal run` on SIGINT), the bench raises Preempted (exit 143), and `--reuse` continues the
    run in its own directory from that checkpoint to the end."""
    arm, out = tiny_arm(tmp_path, epochs=200), tmp_path / "out"
    stopping = threading.Event()

    def log(line: str) -> None:
        if "SIGTERM: stopping 1 runs" in line:
            stopping.set()

    def stop_the_bench() -> None:
        # The run is held (SIGSTOP) from its first evaluation until the bench is stopping, so it
        # cannot finish first however fast the machine is.
        wait_until(lambda: any(read_evaluations(r) for r in run_dirs(out)), "evaluated")
        held = worker_pid(out)
        os.kill(held, signal.SIGSTOP)
        try:
            os.kill(os.getpid(), signal.SIGTERM)  # the bench's own SignalStop takes it
            assert stopping.wait(HUNG_S), "the bench never began stopping"
        finally:
            os.kill(held, signal.SIGCONT)  # now the gentle cancel reaches it mid-run

    with pytest.raises(Preempted) as stopped, in_background(stop_the_bench):
        run_all([(arm, 0)], out, parallel=2, log=log, grace_s=HUNG_S)
    assert stopped.value.exit_code == 143
    assert str(stopped.value).startswith("SIGTERM: stopped the bench (1 stopped); run the same")
    (run,) = run_dirs(out)
    assert not is_finished(run)
    assert last_preemption(run).startswith("SIGINT ")  # Ray's gentle cancel is a SIGINT
    saved = max(int(p.stem.split("-")[1]) for p in (run / "checkpoints").glob("ckpt-*.pt"))
    assert saved >= 1

    dirs, reused = run_or_reuse([(arm, 0)], out, (), 2, lambda _: None, reuse=True)
    assert dirs == {("tiny", 0): run} and reused == {}
    assert is_finished(run)
    resumes = json.loads((run / "provenance.json").read_text())["resumes"]
    assert [r["from"] for r in resumes] == [f"ckpt-{saved:07d}.pt"]
    assert pd.read_csv(run / "metrics.csv")["epoch"].max() == 200


@pytest.mark.slow
@pytest.mark.timeout(3 * HUNG_S)
def test_a_run_that_ignores_the_gentle_cancel_is_cut_off_at_a_second_signal(
    ray_session, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:  # noqa: ANN001
    """The bench waits for a stopped run to save, however long (grace_s is an hour here); a
    run that never ends is force-cancelled once a second signal says to stop waiting, and its
    worker is gone: no run outlives the bench."""
    flags = tmp_path / "flags"
    flags.mkdir()

    def ignores_cancel(config, record, *, threads=1, command=None):  # noqa: ANN001, ANN202
        (flags / "pid").write_text(str(os.getpid()))
        while True:
            try:
                time.sleep(0.05)
            except KeyboardInterrupt:
                (flags / "interrupted").touch()

    monkeypatch.setattr(launcher, "execute_trial", ignores_cancel)

    def signal_twice() -> None:
        wait_until((flags / "pid").exists, "started")
        os.kill(os.getpid(), signal.SIGTERM)
        wait_until((flags / "interrupted").exists, "cancelled gently")
        os.kill(os.getpid(), signal.SIGTERM)  # the second: stop waiting

    arm = tiny_arm(tmp_path, epochs=2)
    with pytest.raises(Preempted) as stopped, in_background(signal_twice):
        run_all([(arm, 0)], tmp_path / "out", parallel=2, grace_s=3600.0)
    assert stopped.value.exit_code == 143
    pid = int((flags / "pid").read_text())
    wait_until(lambda: not alive(pid), "force-cancelled")


@pytest.mark.slow
@pytest.mark.timeout(3 * HUNG_S)
def test_a_run_whose_worker_is_lost_runs_again_from_its_last_checkpoint(
    ray_session, tmp_path: Path
) -> None:  # noqa: ANN001
    """A worker killed mid-run (as a lost node loses it) is retried by Ray (RETRIES); the task
    continues the run directory from its last checkpoint, and the rows are those of a run
    never interrupted."""
    arm, out = tiny_arm(tmp_path, epochs=100), tmp_path / "out"
    killed: list[int] = []

    def kill_the_worker() -> None:
        def checkpointed() -> bool:
            return any(any((r / "checkpoints").glob("ckpt-*.pt")) for r in run_dirs(out))

        wait_until(checkpointed, "checkpointed")
        killed.append(worker_pid(out))
        os.kill(killed[0], signal.SIGKILL)

    with in_background(kill_the_worker):
        dirs = run_all([(arm, 0)], out, parallel=2)
    run = dirs[("tiny", 0)]
    assert killed and worker_pid(out) != killed[0]  # another worker finished it
    assert is_finished(run)
    resumes = json.loads((run / "provenance.json").read_text())["resumes"]
    assert len(resumes) == 1 and resumes[0]["from"].startswith("ckpt-")
    ref = run_seed(load_protocol(arm.protocol), 0, tmp_path / "ref").run_dir
    got, want = (pd.read_csv(Path(d) / "metrics.csv") for d in (run, ref))
    pd.testing.assert_frame_equal(got.drop(columns="wall_s"), want.drop(columns="wall_s"))


DRIVER = """
import sys
from pathlib import Path
from seal.experiments.arms import Arm
from seal.experiments.launcher import run_all
from seal.run.preemption import Preempted
arm = Arm("tiny", "Tiny", None, directory=Path(sys.argv[1]))
try:
    run_all([(arm, 0)], Path(sys.argv[2]), parallel=1, log=lambda line: print(line, flush=True))
except Preempted as stop:
    print(stop, flush=True)
    sys.exit(stop.exit_code)
"""


@pytest.mark.slow
@pytest.mark.timeout(3 * HUNG_S)
def test_a_bench_started_in_the_background_still_lets_its_run_save(tmp_path: Path) -> None:
    """A bench whose shell ignores SIGINT (a background job: `nohup seal bench ... &`) gives its
    Ray workers an ignored SIGINT; stopped with SIGTERM, its run still saves its last finished
    epoch (`hearing_cancel`), where before the fix it was cut off after the grace period."""
    arm, out = tiny_arm(tmp_path, epochs=200), tmp_path / "out"
    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), str(root / "envs")])}
    driver = subprocess.Popen(
        [sys.executable, "-c", DRIVER, str(arm.directory), str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )
    lines: list[str] = []
    stopping = threading.Event()

    def read() -> None:
        assert driver.stdout is not None
        for line in driver.stdout:
            lines.append(line)
            if "SIGTERM: stopping 1 runs" in line:
                stopping.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        wait_until(lambda: any(read_evaluations(r) for r in run_dirs(out)), "evaluated")
        held = worker_pid(out)
        os.kill(held, signal.SIGSTOP)  # it cannot finish before the bench stops
        try:
            driver.send_signal(signal.SIGTERM)
            assert stopping.wait(HUNG_S), "".join(lines)[-3000:]
        finally:
            os.kill(held, signal.SIGCONT)
        assert driver.wait(HUNG_S) == 143, "".join(lines)[-3000:]
    finally:
        if driver.poll() is None:
            driver.kill()
    reader.join(HUNG_S)
    (run,) = run_dirs(out)
    assert last_preemption(run).startswith("SIGINT "), "".join(lines)[-3000:]
    assert any((run / "checkpoints").glob("ckpt-*.pt"))
