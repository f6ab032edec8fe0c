"""`seal bench --learn transfer --address`: the bench on a two-node Ray cluster on one machine.

A head and a worker node are started with `ray start` on loopback, each of one CPU, with its own
temp dir and ports (`loopback_cluster`), so two runs land one on each node (each run's "done"
line names its node); the bench runs in a subprocess (this process may hold the suite's local
Ray) and its table equals a local Ray's for the same seed. Then the worker node is killed (every
process of it, as a lost machine) once its run has saved its first checkpoint: Ray runs that task
again on the head, which continues the run directory from its checkpoint, or, where checkpoints
hold no replay, runs it afresh; the rows are those of a run never interrupted.

The cluster is this test's own: its processes are found by its temp dir and stopped by pid, never
by `ray stop` (which would stop every Ray on the machine, the suite's too). The only time limit is
HUNG_S, a step that never comes; the kill acts on an event (the checkpoint file).
docs/cluster.md is the recipe for a real cluster.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
import pytest

from tests.testbed_tiny import SMALL
from tests.waiting import HUNG_S, wait_until

pytest.importorskip("ray")

ARMS = ["alone", "pretrain_source"]
"""Two runs of one seed, independent of each other: one CPU each, so one on each node."""
OVERRIDES = ["protocol.epochs=30", "checkpoint.interval=2", *SMALL]
"""tests/testbed_tiny.py's SMALL, for 30 epochs (about 20 s) with a checkpoint every 2
(the kill's event)."""
WORKER_RESOURCE = "seal_test_worker"
"""A custom resource only the worker node has: how the test tells its node id."""


def free_ports(n: int) -> list[int]:
    """`n` distinct ports free on loopback now (the cluster's, so it clashes with no other Ray)."""
    sockets = [socket.socket() for _ in range(n)]
    try:
        for s in sockets:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in sockets]
    finally:
        for s in sockets:
            s.close()


def ray_env() -> dict[str, str]:
    """The environment of the cluster's processes and the benches: no token authentication (a
    loopback cluster; Ray 2.5x enables it on `ray start --head`), no usage stats, no RAY_ADDRESS."""
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    env.update(RAY_AUTH_MODE="disabled", RAY_USAGE_STATS_ENABLED="0")
    return env


def ray_cli() -> str:
    return str(Path(sys.executable).with_name("ray"))


@dataclass
class Cluster:
    root: Path
    """Every node's temp dir is under it: <root>/head, <root>/worker."""
    address: str
    """The head's GCS, HOST:PORT: what --address takes."""

    def pids(self, node: str | None = None) -> list[int]:
        """The live processes of one node ("head", "worker") or of all: those that name its temp
        dir or hold a file open in it (the agents rename themselves, "ray::DashboardAgent", but
        write their logs there)."""
        mark = f"{self.root / node if node else self.root}/"
        found = []
        for proc in Path("/proc").iterdir():
            if not proc.name.isdigit() or int(proc.name) == os.getpid():
                continue
            try:
                if (proc / "stat").read_text().rsplit(")", 1)[1].split()[0] == "Z":
                    continue  # a zombie: already ended
                args = (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode()
                files = [os.readlink(fd) for fd in (proc / "fd").iterdir()]
            except OSError:
                continue
            if mark in f"{args}/" or any(f.startswith(mark) for f in files):
                found.append(int(proc.name))
        return found

    def kill(self, node: str | None = None, sig: int = signal.SIGKILL) -> None:
        for pid in self.pids(node):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, sig)


def start_node(root: Path, name: str, ports: list[int], head_port: int) -> None:
    """`ray start` one node of one CPU on loopback, with its own temp dir and ports."""
    node_manager, object_manager, listen, grpc, metrics, runtime_env, dashboard, client = ports
    first_worker = 20000 + 200 * (head_port % 50) + (0 if name == "head" else 100)
    cmd = [
        ray_cli(),
        "start",
        "--node-ip-address=127.0.0.1",
        "--num-cpus=1",
        "--num-gpus=0",
        f"--temp-dir={root / name}",
        "--disable-usage-stats",
        f"--node-manager-port={node_manager}",
        f"--object-manager-port={object_manager}",
        f"--dashboard-agent-listen-port={listen}",
        f"--dashboard-agent-grpc-port={grpc}",
        f"--metrics-export-port={metrics}",
        f"--runtime-env-agent-port={runtime_env}",
        f"--min-worker-port={first_worker}",
        f"--max-worker-port={first_worker + 99}",
        "--object-store-memory=100000000",
    ]
    if name == "head":
        cmd += [
            "--head",
            f"--port={head_port}",
            "--include-dashboard=false",
            f"--dashboard-port={dashboard}",
            f"--ray-client-server-port={client}",
        ]
    else:
        cmd += [f"--address=127.0.0.1:{head_port}", f'--resources={{"{WORKER_RESOURCE}": 1}}']
    done = subprocess.run(
        cmd, env=ray_env(), capture_output=True, text=True, timeout=HUNG_S, check=False
    )
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{done.stdout}\n{done.stderr}")


@contextlib.contextmanager
def loopback_cluster() -> Iterator[Cluster]:
    """A head and a worker node of one CPU each on this machine, torn down on exit (by pid).

    The temp dirs are short paths under /tmp: Ray's Unix sockets live there (108 bytes at most)."""
    root = Path(tempfile.mkdtemp(prefix="sealc-", dir="/tmp"))
    head_port, *ports = free_ports(17)
    cluster = Cluster(root, f"127.0.0.1:{head_port}")
    try:
        start_node(root, "head", ports[:8], head_port)
        start_node(root, "worker", ports[8:], head_port)
        yield cluster
    finally:
        cluster.kill(sig=signal.SIGTERM)
        deadline = time.monotonic() + 10
        while cluster.pids() and time.monotonic() < deadline:
            time.sleep(0.1)
        cluster.kill()
        shutil.rmtree(root, ignore_errors=True)


def worker_node_id(cluster: Cluster) -> str:
    """The Ray node id of the worker node (the one with WORKER_RESOURCE), asked in a subprocess."""
    script = """
import json, sys, ray
ray.init(address=sys.argv[1], logging_level="error", log_to_driver=False)
print(json.dumps([n["NodeID"] for n in ray.nodes() if n["Alive"] and sys.argv[2] in n["Resources"]]))
"""
    done = subprocess.run(
        [sys.executable, "-c", script, cluster.address, WORKER_RESOURCE],
        env=ray_env(),
        capture_output=True,
        text=True,
        timeout=HUNG_S,
        check=True,
    )
    (node,) = json.loads(done.stdout.strip().splitlines()[-1])
    return node


BENCH = """
import json, sys
from seal.experiments.transfer import run_transfer_bench
out, address, only, overrides = json.loads(sys.argv[1])
log = lambda line: print(f"[bench] {line}", file=sys.stderr, flush=True)
result = run_transfer_bench(
    seeds=1, out=out, parallel=2, overrides=overrides, log=log, only=only, address=address
)
print(json.dumps(result, default=float))
"""
"""`seal bench --learn transfer --arms ... --seeds 1 --json [--address A]` with OVERRIDES (which
the command line takes for the other sets, not this one): its function, as the command calls it."""


def bench(out: Path, address: str | None = None, *extra: str) -> subprocess.Popen[str]:
    """The bench of ARMS, one seed, on the cluster at `address` or a local Ray of 2 CPUs, in a
    subprocess, with OVERRIDES and `extra`: its JSON on stdout, its [bench] lines on stderr."""
    args = json.dumps([str(out), address, ARMS, [*OVERRIDES, *extra]])
    return subprocess.Popen(
        [sys.executable, "-c", BENCH, args],
        env=ray_env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def finish(proc: subprocess.Popen[str]) -> tuple[dict, str]:
    """The bench's JSON (its last line of stdout) and its stderr (the [bench] lines), once it
    exits 0."""
    stdout, stderr = proc.communicate(timeout=HUNG_S)
    assert proc.returncode == 0, stderr[-4000:]
    # The last line: Ray prints to stdout that a task of a lost node will be retried.
    return json.loads(stdout.strip().splitlines()[-1]), stderr


def done_nodes(stderr: str) -> dict[str, str]:
    """Each run's node id prefix, from its "[bench] done <arm> seed 0 ... on node IP (ID):" line."""
    found = re.findall(r"done (\w+) seed 0 in \d+ s on node \S+ \((\w+)\)", stderr)
    return dict(found)


COMPARED = ("arms", "pretrain", "table", "transfer_updates_saved", "target_curve_distance", "goal")
"""The bench's JSON keys a cluster must give as a local Ray does (wall clock, load, paths aside)."""


def table(result: dict) -> dict:
    """The bench's per-arm numbers and its table, without what depends on the machine or on
    where the runs are (wall clock, load, --out)."""
    assert {"arms", "pretrain", "table"} <= set(result), sorted(result)
    return {k: v for k, v in result.items() if k in COMPARED}


def run_dir(out: Path, arm: str) -> Path:
    (run,) = out.glob(f"testbed_{arm}/*/seed-0")
    return run


def rows(out: Path, arm: str) -> pd.DataFrame:
    """The arm's metrics.csv rows, the wall-clock column aside."""
    return pd.read_csv(run_dir(out, arm) / "metrics.csv").drop(columns="wall_s")


@pytest.fixture(scope="module")
def local_reference(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, Path]:
    """The bench's table and its --out on a private local Ray (no --address)."""
    out = tmp_path_factory.mktemp("local")
    result, _ = finish(bench(out))
    return table(result), out


def assert_same_runs(out: Path, reference: Path) -> None:
    """Each arm's rows are the local Ray's, and no (phase, epoch, env, task) row is twice."""
    for arm in ARMS:
        got = rows(out, arm)
        assert not got.duplicated(["phase", "epoch", "env", "task"]).any(), arm
        pd.testing.assert_frame_equal(got, rows(reference, arm))


@pytest.mark.slow
@pytest.mark.timeout(3 * HUNG_S)
def test_the_bench_on_a_two_node_cluster_gives_the_local_table(
    local_reference: tuple[dict, Path], tmp_path: Path
) -> None:
    want, reference = local_reference
    out = tmp_path / "out"
    with loopback_cluster() as cluster:
        worker = worker_node_id(cluster)
        result, stderr = finish(bench(out, cluster.address))
    assert result["ray"] == f"the Ray cluster at {cluster.address}"
    nodes = done_nodes(stderr)
    assert set(nodes) == set(ARMS), stderr
    # One CPU a node, two runs at once: one ran on each node.
    assert len(set(nodes.values())) == 2
    assert sum(worker.startswith(node) for node in nodes.values()) == 1
    assert table(result) == want
    assert_same_runs(out, reference)


@pytest.mark.slow
@pytest.mark.timeout(3 * HUNG_S)
@pytest.mark.parametrize("replay", [True, False], ids=["continues", "starts-afresh"])
def test_a_run_whose_node_is_lost_runs_again_on_the_other_node(
    local_reference: tuple[dict, Path], tmp_path: Path, replay: bool
) -> None:
    """The worker node dies (every process of it, SIGKILL) once its run has saved a checkpoint;
    Ray runs the task again on the head. With its replay in the checkpoint it continues the run
    directory from there; without (checkpoint.save_replay = false, most bench protocols: such a
    run cannot resume exactly) the partial run is moved to <group>/.lost/ and runs afresh. Either
    way the bench ends with the local Ray's table and rows, none twice."""
    want, reference = local_reference
    out = tmp_path / "out"
    with loopback_cluster() as cluster:
        worker = worker_node_id(cluster)
        proc = bench(out, cluster.address, f"checkpoint.save_replay={str(replay).lower()}")
        try:
            lost: list[Path] = []

            def checkpointed_on_the_worker() -> bool:
                assert proc.poll() is None, "the bench ended before the worker node was lost"
                on_worker = set(cluster.pids("worker"))
                for run in out.glob("testbed_*/*/seed-0"):
                    try:
                        pid = int(json.loads((run / ".seal.lock").read_text())["pid"])
                    except (OSError, ValueError, KeyError):
                        continue  # not written yet
                    if pid in on_worker and any((run / "checkpoints").glob("ckpt-*.pt")):
                        lost.append(run)
                        return True
                return False

            wait_until(checkpointed_on_the_worker, "checkpointed on the worker node")
            cluster.kill("worker")
            result, stderr = finish(proc)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    (run,) = lost
    nodes = done_nodes(stderr)
    assert set(nodes) == set(ARMS), stderr
    # Both finished on the head: the lost one ran again there.
    assert len(set(nodes.values())) == 1 and not worker.startswith(nodes[ARMS[0]])
    resumes = json.loads((run / "provenance.json").read_text()).get("resumes", [])
    if replay:
        assert len(resumes) == 1 and resumes[0]["from"].startswith("ckpt-"), resumes
    else:
        assert resumes == []
        (moved,) = (run.parent / ".lost").iterdir()
        assert moved.name.startswith("seed-0-") and any((moved / "checkpoints").glob("ckpt-*.pt"))
    assert table(result) == want
    assert_same_runs(out, reference)
