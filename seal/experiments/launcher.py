"""Running the arms of a learning experiment on Ray: every (arm, seed) is one Ray task.

Every experiment of `seal.experiments` launches its arms (`seal.experiments.arms.Arm`) here.
`run_all` sends each (arm, seed) to Ray as one task of `seal.sweep.trials.execute_trial` (what a
`seal sweep` trial runs), which runs the protocol as `seal run` does into
`<out>/<protocol>/<group>/seed-<n>`: a seed gives the same metrics.csv rows either way. The
tasks share a private local Ray of `parallel` CPUs (`seal bench --jobs`) or the cluster at
`address` (`--address`; a Ray initialised otherwise in this process is an error). A run reserves
the CPUs its protocol.threads needs (`run_cpus`: one for every shipped bench protocol, so
--jobs 2 runs two at a time; the quickstart a whole node) and its [resources] GPUs.

An arm with a `pretrain` is sent once that arm's run of the same seed has finished (`ray.wait`),
with `transfer.checkpoint` set to that run's `last_checkpoint`, a path the task reads where it
runs. The nodes write the run directories under `out` and this process reads them, so on a
cluster every node must see `out` at the same path (a shared filesystem: NFS or similar;
nothing is copied between nodes), which `check_shared_out` checks before the first run. A task
whose worker or node is lost runs again (RETRIES) and continues its run directory from its last
checkpoint, as `execute_trial` continues a started one, or starts afresh where its checkpoints
hold no replay (`_on_node`); a run's "done" line names its node.

With `--reuse`, `run_or_reuse` takes the finished runs under `out` whose resolved config is
today's (`finished_run`) and continues the unfinished ones that saved a checkpoint
(`unfinished_run`). A SIGTERM, Ctrl-C or failed run stops the others as a stopped sweep does
(`Launcher.cancel`): gently (`ray.cancel(force=False)`, a SIGINT to the run, which saves its
last finished epoch), then by force after `grace_s` or a second signal; a signal ends in
`Preempted`. Which runs are reused, and what they were made with, is `seal.experiments.records`.
"""

from __future__ import annotations

import contextlib
import secrets
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

from seal.errors import SealError
from seal.experiments.arms import Arm
from seal.experiments.records import finished_run, last_checkpoint, unfinished_run
from seal.protocols.config import ProtocolConfig
from seal.run.preemption import Preempted, SignalStop
from seal.sweep.config_tables import Resources
from seal.sweep.grid import DEFAULT_GRACE_S
from seal.sweep.ray_session import (
    RaySession,
    alive_cpu_nodes,
    check_address,
    check_feasible,
    import_ray,
    parse_resources,
)
from seal.sweep.trials import TrialRecord, execute_trial, is_finished, is_started

if TYPE_CHECKING:  # Ray is imported only where it is used (`import_ray`)
    from ray import ObjectRef

    from seal.bench.timing import MachineLoad

Key = tuple[str, int]
"""(arm name, seed): one run of an experiment."""

RETRIES = 3
"""How often Ray runs a task again after its worker or node was lost (a run that raises is not
run again: that is its error, in error.txt)."""
WAKE_S = 0.5
"""How often the driver, waiting on its tasks, looks whether a signal asked it to stop."""
REUSE_HINT = (
    "run the same command with --reuse to take the finished runs and continue the others "
    "(those whose checkpoints hold no replay run again from the start)"
)
"""What a stopped bench's last line says to do."""

# ---------------------------------------------------------------- the commands runs stand for


def seal_run_command(arm: Arm, seed: int, out: Path, overrides: Sequence[str] = ()) -> list[str]:
    """The `seal run` command line that makes the same run alone (its provenance's command)."""
    cmd = ["seal", "run", str(arm.protocol), "--seeds", str(seed), "--out", str(out)]
    for item in overrides:
        cmd += ["--set", item]
    return cmd


def resume_command(arm: Arm, run_dir: Path) -> list[str]:
    """The `seal run --resume` command line that continues `run_dir` (its saved config)."""
    return ["seal", "run", str(arm.protocol), "--resume", str(run_dir)]


def run_cpus(config: ProtocolConfig, node_cpus: int, whole_node: bool = False) -> int:
    """The CPUs one run of `config` reserves: the fewest on which its protocol.threads resolves
    as `seal run` resolves it on this machine, at most `node_cpus` (the biggest node's).

    A number N: N. "auto": one for a one-thread choice (every shipped bench protocol's), else
    `seal.device.CORES_PER_UPDATE_THREAD` per thread, the cores the rule keeps for its team
    (the task resolves "auto" again on the CPUs it got). 0 (torch's default, every core) and
    `whole_node` (the quickstart, whose shipped settings assume the machine to itself): the node.
    """
    setting = config.protocol.threads
    if whole_node or setting == 0:
        return node_cpus
    if setting != "auto":
        return max(1, min(int(setting), node_cpus))
    from seal.device import CORES_PER_UPDATE_THREAD
    from seal.run.phase_model import build_adapters
    from seal.run.resources import choose_update_threads, estimate_resources

    estimate = estimate_resources(config, build_adapters(config), "cpu")
    threads = choose_update_threads(config, estimate).threads
    return min(1 if threads <= 1 else CORES_PER_UPDATE_THREAD * threads, node_cpus)


# ---------------------------------------------------------------- Ray


class Launcher:
    """The Ray tasks of one bench (made by `launching`): protocol runs (`run`) and plain calls
    (`call`), each reserving its CPUs, collected as they end (`next`)."""

    def __init__(
        self, ray: ModuleType, stop: SignalStop, log: Callable[[str], None], grace_s: float
    ) -> None:
        self.ray = ray
        self.stop = stop
        self.log = log
        self.grace_s = grace_s
        self.hint = REUSE_HINT
        """The end of a stopped bench's line: how to continue."""
        self.pending: dict[ObjectRef[Any], tuple[Key, TrialRecord | None]] = {}
        """Each task not collected yet: its key, and its run's record (None for a call)."""
        nodes = alive_cpu_nodes(ray)
        if not nodes:
            raise SealError(
                "the Ray cluster has no alive node with a CPU (`ray status` lists its nodes)"
            )
        self.node_cpus = max(int(n["Resources"]["CPU"]) for n in nodes)
        """The CPUs of the biggest node: what a run that wants a node to itself reserves."""
        self.nodes: dict[Key, str] = {}  # where each collected run ran: "<ip> (<node id[:8]>)"
        self._execute = ray.remote(_on_node)
        self._trial = execute_trial  # as this module holds it now (a test may replace it)
        self._calls: dict[Callable[..., Any], Any] = {}
        self._checked: set[str] = set()

    def run(
        self, key: Key, config: ProtocolConfig, run_dir: Path, cpus: int, command: Sequence[str]
    ) -> None:
        """Queue one protocol run into `run_dir` (a started one continues from its checkpoint)."""
        record = TrialRecord(
            trial=f"{key[0]}/seed-{key[1]}", protocol=config.name, seed=key[1], run_dir=str(run_dir)
        )
        res = Resources(cpus=cpus, gpus=parse_resources(config).gpus)
        if config.name not in self._checked:
            check_feasible(self.ray, config, res)
            self._checked.add(config.name)
        task = self._execute.options(
            num_cpus=cpus, num_gpus=res.gpus, max_retries=RETRIES, name=f"seal-bench:{record.trial}"
        )
        ref = task.remote(self._trial, config, record, threads=cpus, command=list(command))
        self.pending[ref] = (key, record)

    def call(self, key: Key, fn: Callable[..., Any], *args: Any, cpus: int = 1) -> None:
        """Queue `fn(*args)` (a module-level function: each node imports it) on `cpus` CPUs."""
        if fn not in self._calls:
            self._calls[fn] = self.ray.remote(fn)
        task = self._calls[fn].options(
            num_cpus=cpus, max_retries=RETRIES, name=f"seal-bench:{key[0]}/seed-{key[1]}"
        )
        self.pending[task.remote(*args)] = (key, None)

    def next(self) -> tuple[Key, Any]:
        """The next task to end and what it returned (a run's `TrialRecord`, which says how the
        run ended). On a signal: the tasks left are stopped (`cancel`) and `Preempted` raised."""
        while not self.stop.requested:
            ready, _ = self.ray.wait(list(self.pending), num_returns=1, timeout=WAKE_S)
            if not ready:
                continue
            key, record = self.pending.pop(ready[0])
            try:
                if record is None:  # a call
                    return key, self.ray.get(ready[0])
                done, self.nodes[key] = self.ray.get(ready[0])
                return key, done
            except self.ray.exceptions.RayTaskError as exc:  # the function raised
                cause = exc.cause if exc.cause is not None else exc
                raise SealError(f"{key[0]} seed {key[1]} failed: {_first_line(cause)}") from None
            except Exception as exc:  # noqa: BLE001 - its worker or node lost RETRIES + 1 times
                raise SealError(
                    f"{key[0]} seed {key[1]}: its Ray task was lost ({RETRIES} retries): "
                    f"{_first_line(exc)}"
                ) from None
        assert self.stop.signum is not None
        ended = self.cancel(self.stop.name)
        raise Preempted(
            self.stop.signum, f"{self.stop.name}: stopped the bench ({ended}); {self.hint}"
        )

    def cancel(self, why: str) -> str:
        """Stop the tasks left as a sweep stops its trials: gently (`ray.cancel(force=False)`, a
        SIGINT to the run, which saves its last finished epoch), then, after `grace_s` or a
        second signal, by force. Returns what became of them, e.g. "2 stopped, 1 finished"."""
        if not self.pending:
            return "no run was left"
        self.log(
            f"{why}: stopping {len(self.pending)} runs; each saves its last finished epoch "
            f"(waiting up to {self.grace_s:g} s; a second signal stops waiting)"
        )
        for ref in self.pending:
            self.ray.cancel(ref, force=False)
        deadline = time.monotonic() + self.grace_s
        left = list(self.pending.values())
        while self.pending and self.stop.count < 2 and (wait := deadline - time.monotonic()) > 0:
            ready, _ = self.ray.wait(list(self.pending), num_returns=1, timeout=min(WAKE_S, wait))
            for ref in ready:
                self.pending.pop(ref)
        for ref in self.pending:
            self.ray.cancel(ref, force=True)  # its newest checkpoint stays
        self.pending.clear()
        return _outcomes(record for _, record in left)


def _on_node(
    run: Callable[..., TrialRecord], config: ProtocolConfig, record: TrialRecord, **kwargs: Any
) -> tuple[TrialRecord, str]:
    """On a node: `run`'s record, and the node: "<ip> (<id, first 8>)". (A retry of a run whose
    checkpoints hold no replay runs afresh: `seal.sweep.trials.set_aside`.)"""
    import ray

    node = f"{ray.util.get_node_ip_address()} ({ray.get_runtime_context().get_node_id()[:8]})"
    return run(config, record, **kwargs), node


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__


def _outcomes(records: Iterator[TrialRecord | None]) -> str:
    """ "2 stopped, 1 finished, 3 not started": what stopped tasks left in their run directories."""
    counts: dict[str, int] = {}
    for record in records:
        if record is None:
            how = "call stopped"
        elif is_finished(record.run_dir):
            how = "finished"
        elif is_started(record.run_dir):
            how = "stopped"
        else:
            how = "not started"
        counts[how] = counts.get(how, 0) + 1
    return ", ".join(f"{n} {how}" for how, n in counts.items())


@contextlib.contextmanager
def launching(
    out: Path,
    parallel: int,
    address: str | None,
    log: Callable[[str], None],
    grace_s: float = DEFAULT_GRACE_S,
) -> Iterator[Launcher]:
    """A `Launcher` on a private local Ray of `parallel` CPUs, or on the cluster at `address`
    (after `check_shared_out`), holding SIGTERM and SIGINT; leaving it by an exception (a failed
    run) stops the tasks left (`Launcher.cancel`)."""
    import_ray("seal bench --learn")
    if parallel < 1:
        raise SealError(f"--jobs must be >= 1, got {parallel}")
    check_address(address)
    with RaySession(address, parallel if address is None else None, strict=True) as ray:
        if address is not None:
            check_shared_out(ray, out)
        stop = SignalStop()
        with stop.handling():
            launcher = Launcher(ray, stop, log, grace_s)
            try:
                yield launcher
            finally:
                if launcher.pending:
                    launcher.cancel("the bench stops")


SHARED_CHECK_S = 300.0
"""How long `check_shared_out` waits for every node's answer (a busy node starts a worker)."""


def check_shared_out(ray: ModuleType, out: Path) -> None:
    """SealError unless every node with a CPU sees `out` at the same path: one task pinned to each
    node reads a file written here. The runs write their directories there, and a fine-tune reads
    its pre-training's checkpoint from there."""
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    out.mkdir(parents=True, exist_ok=True)
    token = secrets.token_hex(8)
    probe = out / f".seal-shared-{token}"
    probe.write_text(token)
    sees = ray.remote(_sees)
    nodes = alive_cpu_nodes(ray)
    try:
        refs = [
            sees.options(
                num_cpus=0,
                max_retries=0,
                scheduling_strategy=NodeAffinitySchedulingStrategy(n["NodeID"], soft=False),
            ).remote(str(probe), token)
            for n in nodes
        ]
        answers = ray.get(refs, timeout=SHARED_CHECK_S)
    except ray.exceptions.GetTimeoutError:
        raise SealError(
            f"--out {out}: not every node of the Ray cluster answered within {SHARED_CHECK_S:g} s "
            "whether it sees it (`ray status` shows the nodes)"
        ) from None
    except ray.exceptions.RayError as exc:  # a node or its worker died while it was asked
        raise SealError(
            f"--out {out}: a node of the Ray cluster failed while asked whether it sees it "
            f"({_first_line(exc)}); `ray status` shows the nodes, then run the bench again"
        ) from None
    finally:
        probe.unlink(missing_ok=True)
    blind = [n["NodeManagerAddress"] for n, seen in zip(nodes, answers, strict=True) if not seen]
    if blind:
        raise SealError(
            f"--out {out}: node{'s' if len(blind) > 1 else ''} {', '.join(blind)} of the Ray "
            "cluster do not see it at that path; a bench on a cluster writes its run directories "
            "there from every node and reads them here, so --out must be on a filesystem every "
            "node mounts at the same path (NFS or similar)"
        )


def _sees(path: str, token: str) -> bool:
    """On a node: whether the file at `path` holds `token`."""
    try:
        return Path(path).read_text() == token
    except OSError:
        return False


def describe_ray(parallel: int, address: str | None) -> str:
    """Where a bench ran, for its output: "a local Ray of 2 CPUs" or "the Ray cluster at X"."""
    return f"a local Ray of {parallel} CPUs" if address is None else f"the Ray cluster at {address}"


# ---------------------------------------------------------------- running arms


def bench_context(
    wall_s: float, parallel: int, address: str | None, load_before: MachineLoad
) -> dict[str, Any]:
    """Where and how a bench ran, for its JSON: its wall time, the Ray it ran on, the load before and after."""
    from seal.bench.timing import machine_load

    return {
        "wall_s": wall_s,
        "parallel": parallel,
        "ray": describe_ray(parallel, address),
        "load_before": load_before,
        "load_after": machine_load(),
    }


def run_failure(record: TrialRecord) -> str:
    """One line: how a run that did not finish ended, and what to do."""
    if record.status == "failed":
        return (
            f"{record.trial} ({record.protocol}) failed: {record.error} "
            f"(traceback: {record.run_dir}/error.txt)"
        )
    return (
        f"{record.trial} ({record.protocol}) was stopped ({record.note or 'a signal to its worker'});"
        f" {REUSE_HINT}"
    )


def run_all(
    jobs: list[tuple[Arm, int]],
    out: Path,
    overrides: Sequence[str] = (),
    parallel: int = 2,
    log: Callable[[str], None] = lambda _: None,
    done: Mapping[Key, Path] | None = None,
    resume: Mapping[Key, Path] | None = None,
    *,
    address: str | None = None,
    whole_node: bool = False,
    grace_s: float = DEFAULT_GRACE_S,
) -> dict[Key, Path]:
    """Run every (arm, seed) as a Ray task (`launching`); the run directories of those run here.

    A job whose arm has a `pretrain` is sent once that arm's run of the same seed is in `done`
    (given, e.g. reused, or finished here), from its last checkpoint. A job in `resume` continues
    that run directory from its last checkpoint instead of starting afresh. `whole_node`: each
    run reserves a whole node (`run_cpus`). A run that fails stops the others (SealError); a
    SIGTERM or SIGINT stops them all (`Preempted`), each saving its last finished epoch.
    """
    from seal.protocols import load_protocol
    from seal.protocols.loader import config_to_dict
    from seal.protocols.toml_io import dumps_toml
    from seal.run.rundir import seed_dir
    from seal.run.runner import new_group_dir

    resume = resume or {}
    finished: dict[Key, Path] = dict(done or {})
    scheduled = {(a.name, s) for a, s in jobs} | set(finished)
    unscheduled = sorted(
        {
            f"{a.pretrain} seed {s}"
            for a, s in jobs
            if a.pretrain and (a.pretrain, s) not in scheduled
        }
    )
    if unscheduled:
        raise SealError(f"jobs wait on runs that are not scheduled: {unscheduled}")
    if not jobs:
        return {}
    root = Path(out).absolute()
    waiting = list(jobs)
    cpus: dict[str, int] = {}
    groups: dict[str, Path] = {}  # one group per resolved config, as `seal run --seeds` makes

    with launching(root, parallel, address, log, grace_s) as launch:

        def send(arm: Arm, seed: int) -> None:
            base = load_protocol(arm.protocol, overrides)
            if arm.name not in cpus:
                cpus[arm.name] = run_cpus(base, launch.node_cpus, whole_node)
            if (arm.name, seed) in resume:
                run_dir, config = Path(resume[(arm.name, seed)]), base
                command = resume_command(arm, run_dir)
            else:
                extra = list(overrides)
                if arm.pretrain is not None:
                    start = last_checkpoint(finished[(arm.pretrain, seed)]).absolute()
                    extra.append(f"transfer.checkpoint={start}")
                config = load_protocol(arm.protocol, extra) if arm.pretrain else base
                text = dumps_toml(config_to_dict(config))
                group = groups.setdefault(text, new_group_dir(config, root))
                run_dir, command = seed_dir(group, seed), seal_run_command(arm, seed, root, extra)
            log(f"queue {arm.name} seed {seed} on {cpus[arm.name]} CPU(s): {' '.join(command)}")
            launch.run((arm.name, seed), config, run_dir, cpus[arm.name], command)

        def send_ready() -> None:
            for job in [
                j for j in waiting if j[0].pretrain is None or (j[0].pretrain, j[1]) in finished
            ]:
                waiting.remove(job)
                send(*job)

        send_ready()
        while launch.pending:
            key, record = launch.next()
            if record.status != "finished":
                raise SealError(run_failure(record))
            finished[key] = Path(record.run_dir)
            where = f"in {record.wall_s:.0f} s on node {launch.nodes[key]}"
            log(f"done {key[0]} seed {key[1]} {where}: {finished[key]}")
            send_ready()
    return {job: finished[job] for job in finished if done is None or job not in done}


def run_or_reuse(
    jobs: list[tuple[Arm, int]],
    out: Path,
    overrides: Sequence[str],
    parallel: int,
    log: Callable[[str], None],
    reuse: bool,
    *,
    address: str | None = None,
    whole_node: bool = False,
) -> tuple[dict[Key, Path], dict[Key, Path]]:
    """(every job's run directory, the reused ones): with `reuse`, finished runs under `out`
    whose resolved config is today's (`finished_run`) are taken, unfinished ones with a
    checkpoint (`unfinished_run`: a session that ended mid-run) are continued, and the rest are
    run (`run_all`, on a local Ray of `parallel` CPUs or the cluster at `address`)."""
    reused: dict[Key, Path] = {}
    resumed: dict[Key, Path] = {}
    if reuse:
        for arm, seed in jobs:
            found = finished_run(arm, seed, out, overrides)
            if found is not None:
                reused[(arm.name, seed)] = found
                log(f"reuse {arm.name} seed {seed}: {found}")
                continue
            partial = unfinished_run(arm, seed, out, overrides)
            if partial is not None:
                resumed[(arm.name, seed)] = partial
                log(f"resume {arm.name} seed {seed}: {partial}")
        jobs = [(a, s) for a, s in jobs if (a.name, s) not in reused]
    ran = run_all(
        jobs,
        out,
        overrides,
        parallel,
        log,
        done=reused,
        resume=resumed,
        address=address,
        whole_node=whole_node,
    )
    return {**reused, **ran}, reused
