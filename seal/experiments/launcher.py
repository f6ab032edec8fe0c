"""Running the arms of a learning experiment as `seal run` processes, two at a time on 2 cores.

Every experiment of `seal.experiments` launches its arms (`seal.experiments.arms.Arm`) here: each
(arm, seed) is its own `seal run` process in its own session (`run_all`), and an arm with a
`pretrain` starts from that arm's last checkpoint of the same seed (`last_checkpoint`). With
`--reuse`, `run_or_reuse` takes the finished runs under the output directory whose resolved config
is today's (`finished_run`) and resumes the unfinished ones that saved a checkpoint
(`unfinished_run`). A stopped launcher (SIGTERM within `terminate_as_exit`, Ctrl-C, a failed run)
gives each of its runs one SIGTERM, so that it saves a checkpoint, and kills a run still going
after STOP_WAIT_S (`_stop_runs`). Runs set against each other should share their code and agent:
`code_versions` and `versions_note` name the commits the runs were made with, `agent_mismatches`
the agent keys that differ.
"""

from __future__ import annotations

import contextlib
import json
import signal
import subprocess
import sys
import threading
import time
import tomllib
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from seal.errors import SealError
from seal.experiments.arms import Arm

# ---------------------------------------------------------------- launching


def seal_run_command(arm: Arm, seed: int, out: Path, overrides: Sequence[str] = ()) -> list[str]:
    """The `seal run` command line of one seed of one arm."""
    cmd = [sys.executable, "-m", "seal.cli.main", "run", str(arm.protocol), "--seeds", str(seed)]
    cmd += ["--out", str(out), "--quiet", "--no-report", "--json"]
    for item in overrides:
        cmd += ["--set", item]
    return cmd


def last_checkpoint(run_dir: Path) -> Path:
    """The newest epoch checkpoint (ckpt-<epoch>.pt) of a finished run: what a pre-training hands on."""
    found = sorted(
        (run_dir / "checkpoints").glob("ckpt-*.pt"), key=lambda p: int(p.stem.rsplit("-", 1)[1])
    )
    if not found:
        raise SealError(f"{run_dir}: no checkpoints/ckpt-<epoch>.pt to start the next arm from")
    return found[-1]


def resume_command(arm: Arm, run_dir: Path) -> list[str]:
    """The `seal run --resume` command line that continues `run_dir` (its saved config)."""
    run = [sys.executable, "-m", "seal.cli.main", "run", str(arm.protocol)]
    return [*run, "--resume", str(run_dir), "--quiet", "--no-report", "--json"]


def run_all(
    jobs: list[tuple[Arm, int]],
    out: Path,
    overrides: Sequence[str] = (),
    parallel: int = 2,
    log: Callable[[str], None] = lambda _: None,
    done: Mapping[tuple[str, int], Path] | None = None,
    resume: Mapping[tuple[str, int], Path] | None = None,
) -> dict[tuple[str, int], Path]:
    """Run every (arm, seed) as its own `seal run` process, `parallel` at a time; their run directories.

    A job whose arm has a `pretrain` starts once that arm's run of the same seed is in `done`
    (given, e.g. reused, or finished here), from its last checkpoint. A job in `resume` continues
    that run directory from its last checkpoint instead of starting afresh. Stopped (SIGTERM,
    Ctrl-C, a failed run), it stops its runs with SIGTERM so that each saves a checkpoint.
    """
    resume = resume or {}
    pending = list(jobs)
    running: list[tuple[Arm, int, subprocess.Popen[str], float]] = []
    finished: dict[tuple[str, int], Path] = dict(done or {})

    def ready(job: tuple[Arm, int]) -> bool:
        arm, seed = job
        return arm.pretrain is None or (arm.pretrain, seed) in finished

    with terminate_as_exit(), _stopped_at_exit(running):
        while pending or running:
            while len(running) < parallel and any(ready(j) for j in pending):
                arm, seed = pending.pop(next(i for i, j in enumerate(pending) if ready(j)))
                if (arm.name, seed) in resume:
                    cmd = resume_command(arm, resume[(arm.name, seed)])
                else:
                    extra = list(overrides)
                    if arm.pretrain is not None:
                        start = last_checkpoint(finished[(arm.pretrain, seed)])
                        extra.append(f"transfer.checkpoint={start}")
                    cmd = seal_run_command(arm, seed, out, extra)
                log(f"start {arm.name} seed {seed}: {' '.join(cmd[1:])}")
                # Its own session: a Ctrl-C at the terminal reaches the launcher alone, which
                # then stops each run with one SIGTERM (a second signal would abort its save).
                proc = subprocess.Popen(
                    cmd,
                    stdout=subprocess.PIPE,
                    stderr=subprocess.PIPE,
                    text=True,
                    start_new_session=True,
                )
                running.append((arm, seed, proc, time.monotonic()))
            if not running:  # pending jobs wait on arms that are neither given nor run
                missing = sorted({f"{a.pretrain} seed {s}" for a, s in pending})
                raise SealError(f"testbed jobs wait on runs that are not scheduled: {missing}")
            time.sleep(0.2)
            for item in list(running):
                arm, seed, proc, started = item
                if proc.poll() is None:
                    continue
                running.remove(item)
                stdout, stderr = proc.communicate()
                if proc.returncode != 0:
                    tail = (stderr or stdout).strip().splitlines()[-1:] or ["(no output)"]
                    raise SealError(
                        f"seal run {arm.protocol} --seeds {seed} failed (exit {proc.returncode}): {tail[0]}"
                    )
                run_dir = Path(json.loads(stdout.strip().splitlines()[-1])["run_dir"])
                finished[(arm.name, seed)] = run_dir
                log(f"done {arm.name} seed {seed} in {time.monotonic() - started:.0f} s: {run_dir}")
    return {job: finished[job] for job in finished if done is None or job not in done}


@contextlib.contextmanager
def _stopped_at_exit(
    running: list[tuple[Arm, int, subprocess.Popen[str], float]],
) -> Iterator[None]:
    """On leaving (normally, or by an exception), stop the runs still in `running` (`_stop_runs`)."""
    try:
        yield
    finally:
        _stop_runs([proc for _, _, proc, _ in running])


STOP_WAIT_S = 60.0
"""How long a stopped launcher waits for each run to save its checkpoint after SIGTERM
(`checkpoint.signal_budget_s`, 10 s by default, plus the save) before killing it."""


def _stop_runs(procs: Sequence[subprocess.Popen[str]]) -> None:
    """Stop the runs still going: SIGTERM, so that each finishes its epoch and saves a checkpoint
    that `--reuse` then resumes from; SIGKILL for one that has not exited within STOP_WAIT_S."""
    for proc in procs:
        if proc.poll() is None:
            proc.terminate()
    for proc in procs:
        try:
            proc.wait(timeout=STOP_WAIT_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@contextlib.contextmanager
def terminate_as_exit() -> Iterator[None]:
    """Within it, SIGTERM raises SystemExit (143) in the main thread, so a launcher's `finally`
    stops its runs cleanly; by default SIGTERM ends the process at once and orphans them."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, _frame: object) -> None:
        raise SystemExit(128 + signum)

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def run_or_reuse(
    jobs: list[tuple[Arm, int]],
    out: Path,
    overrides: Sequence[str],
    parallel: int,
    log: Callable[[str], None],
    reuse: bool,
) -> tuple[dict[tuple[str, int], Path], dict[tuple[str, int], Path]]:
    """(every job's run directory, the reused ones): with `reuse`, finished runs under `out`
    whose resolved config is today's (`finished_run`) are taken, unfinished ones with a
    checkpoint (`unfinished_run`: a session that ended mid-run) are resumed, and the rest are
    run (`run_all`)."""
    reused: dict[tuple[str, int], Path] = {}
    resumed: dict[tuple[str, int], Path] = {}
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
    ran = run_all(jobs, out, overrides, parallel, log, done=reused, resume=resumed)
    return {**reused, **ran}, reused


# ---------------------------------------------------------------- reuse and consistency

COMPARED_TABLES = ("envs", "agent", "replay", "training", "evaluation", "scheduler")
"""The resolved tables a reused run must share with the protocol as it resolves now."""


def _tables(resolved: Mapping[str, Any]) -> dict[str, Any]:
    out = {t: resolved.get(t, {}) for t in COMPARED_TABLES}
    out["epochs"] = resolved["protocol"]["epochs"]
    return out


def _same_tables(saved: Mapping[str, Any], want: Mapping[str, Any]) -> bool:
    """Whether a run's saved tables are today's: a key of [agent], [replay], [training] or
    [evaluation] that the run predates counts as the same when today's value is that key's default
    (a key added since, which keeps the old behaviour)."""
    from seal.learner.config import AgentConfig
    from seal.protocols.config import EvaluationConfig, ReplayConfig, TrainingConfig

    filled = dict(saved)
    for table, cls in (
        ("agent", AgentConfig),
        ("replay", ReplayConfig),
        ("training", TrainingConfig),
        ("evaluation", EvaluationConfig),
    ):
        if table not in saved:
            continue
        defaults = _defaults(cls)
        old = AgentConfig.upgrade(saved[table]) if table == "agent" else dict(saved[table])
        for key, value in want.get(table, {}).items():
            if key not in old and key in defaults:
                old[key] = defaults[key]
                if old[key] != value:
                    return False
        filled[table] = old
    return filled == want


def _defaults(cls: type) -> dict[str, Any]:
    """A config dataclass's field defaults as config.toml holds them (tuples as lists)."""
    import dataclasses

    out = {}
    for f in dataclasses.fields(cls):
        if f.default is not dataclasses.MISSING:
            value = f.default
        elif f.default_factory is not dataclasses.MISSING:
            value = f.default_factory()
        else:
            continue
        out[f.name] = list(value) if isinstance(value, tuple) else value
    return out


def resolved_tables(arm: Arm, overrides: Sequence[str] = ()) -> tuple[str, dict[str, Any]]:
    """(protocol name, the tables a run of `arm` saves in its config.toml), as the code resolves them now."""
    from seal.protocols import load_protocol
    from seal.protocols.loader import config_to_dict, dumps_toml

    config = load_protocol(arm.protocol, overrides)
    # Through TOML, as the runner writes config.toml, so that both sides compare alike.
    return config.name, _tables(tomllib.loads(dumps_toml(config_to_dict(config))))


def finished_run(arm: Arm, seed: int, out: Path, overrides: Sequence[str] = ()) -> Path | None:
    """The newest finished run of (arm, seed) under `out` whose saved config equals today's resolution, else None.

    Defaults of the learner can change between two runs (a new default init, say); a run is
    reused only if every resolved key of COMPARED_TABLES is the same, so arms never mix them.
    """
    from seal import load_run

    name, want = resolved_tables(arm, overrides)
    # Group directories start with their creation time, so the newest sorts last.
    for run in sorted(out.glob(f"{name}/*/seed-{seed}"), reverse=True):
        if not (run / "metrics.csv").is_file() or not (run / "config.toml").is_file():
            continue
        if not _same_tables(_tables(tomllib.loads((run / "config.toml").read_text())), want):
            continue
        loaded = load_run(run)
        epochs = loaded.metrics["epoch"]
        # Finished: all its epochs, or ended early (evaluation.stop_when_reached) with an end time.
        if loaded.provenance.get("end_time") or (
            not epochs.empty and int(epochs.max()) >= want["epochs"]
        ):
            return run
    return None


def unfinished_run(arm: Arm, seed: int, out: Path, overrides: Sequence[str] = ()) -> Path | None:
    """The newest run of (arm, seed) under `out` with today's resolved config that did not finish
    but saved an epoch checkpoint to go on from (`seal run --resume`), else None."""
    name, want = resolved_tables(arm, overrides)
    for run in sorted(out.glob(f"{name}/*/seed-{seed}"), reverse=True):
        if not (run / "config.toml").is_file() or not any((run / "checkpoints").glob("ckpt-*.pt")):
            continue
        if _same_tables(_tables(tomllib.loads((run / "config.toml").read_text())), want):
            return run
    return None


def agent_mismatches(
    agents: Mapping[tuple[str, int], Mapping[str, Any]], chosen: Sequence[Arm]
) -> list[str]:
    """Agent keys, other than shared_update, that differ between runs set against each other."""
    problems = []
    for arm in chosen:
        base = arm.alone or arm.name
        for (name, seed), agent in agents.items():
            if name != arm.name:
                continue
            ref = agents[(base, 0)]
            keys = sorted(
                k
                for k in set(agent) | set(ref)
                if k != "shared_update" and agent.get(k) != ref.get(k)
            )
            problems += [
                f"{name} seed {seed} vs {base} seed 0: agent.{k} = {agent.get(k)!r} vs {ref.get(k)!r}"
                for k in keys
            ]
    return problems


def code_versions(shas: Mapping[tuple[str, int], str | None]) -> dict[str, list[str]]:
    """The code versions (provenance git_sha) the runs were made with, each with its runs; one key when consistent.

    A learner change without a config key (a loss's scale, say) is invisible to
    `finished_run`; runs of different commits should not be set against each other.
    """
    out: dict[str, list[str]] = {}
    for (arm, seed), sha in sorted(shas.items()):
        out.setdefault(sha or "unknown", []).append(f"{arm}/seed-{seed}")
    return out


def versions_note(versions: Mapping[str, Sequence[str]]) -> str | None:
    """ "runs made with N code versions: <sha>: <runs>; ..." when `code_versions` found several, else None."""
    if len(versions) <= 1:
        return None
    listed = "; ".join(f"{sha}: {', '.join(runs)}" for sha, runs in versions.items())
    return f"runs made with {len(versions)} code versions: {listed}"
