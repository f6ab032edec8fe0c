"""Protocol runners: the three kinds, checkpoints and resume (the epoch loop: `seal.run.loop`).

One seed of a protocol is one `Run` writing one run directory (`seal.run.rundir`). A run
has one or more phases: baseline and joint have the phase "train"; finetune has "pretrain" (on
the source env) then "finetune" (on the target env, starting from the best pre-trained
checkpoint with the policy's last layer re-initialised, SEAL Appendix D). A baseline or joint
run with a [transfer] table starts its "train" phase the same way from any `seal run` checkpoint
(issue 5: MT1 -> MT3, MT1 -> MT10), with the learning rates x transfer.lr_factor; with
transfer.map, one env also starts from another env of the checkpoint (`seal.run.mapped_start`).

The epoch (garage MTSAC convention, issue 4's table)::

    plan = scheduler.plan(progress)               # which tasks collect, batch composition
    collect one episode on every collecting task  # uniform random actions during warm-up
    take grad_steps gradient steps                # after every env finished its warm-up
    log losses (every logging.train_interval), evaluate (every evaluation.interval),
    checkpoint (every checkpoint.interval)

Exact resume: a checkpoint (written by the `Checkpointer` callback, `seal.run.checkpointing`)
holds the agent, the replay, the scheduler, the counters and the RNG states, and the CSV row
counts. Env instances continue their own RNG streams from episode to episode, which a checkpoint
cannot capture, so the collector's env instances are rebuilt with seeds derived from (seed,
phase, epoch) right after every checkpoint, in uninterrupted and in resumed runs alike: a resumed
run then replays exactly what the uninterrupted run did.
Evaluation runs on env instances of its own, several per task (`PhaseLoop._eval_collector`),
built once per phase: each evaluation episode resets with a seed derived from (phase, grad
steps, episode), so they need no rebuilding at checkpoints.

A resume starts from the newest intact checkpoint: one that does not read as a seal checkpoint
(torn, zero bytes) or whose CSV rows are no longer all there is skipped, named on stderr with the
reason and in provenance.json's "resumes"; none intact is a one-line refusal that changes nothing.

On SIGTERM or SIGINT (`checkpoint.on_signal`) a run stops at a safe point with the checkpoint of
its last finished epoch, records the stop in provenance.json's "preemptions" and raises
`seal.run.preemption.Preempted`, whose line ends with the --resume command. A checkpoint
written at a signal re-seeds the collectors from its epoch like any other, so the resumed run
repeats what an uninterrupted run that also checkpointed at that epoch does.

Before anything is created, a run checks its estimated memory (`seal.run.resources`) and
takes its directory's lock (`seal.run.rundir.DirLock`), which it holds until it ends; a
full disk (ENOSPC, EDQUOT) while it writes stops it with one line naming the file.
"""

from __future__ import annotations

import contextlib
import copy
import errno
import json
import math
import shutil
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypedDict

import torch

from seal import provenance
from seal.device import apply_matmul_precision
from seal.errors import ConfigError, SealError
from seal.learner.checkpoint import read_checkpoint
from seal.learner.sac import Agent, AgentState
from seal.learner.transfer import transfer_from
from seal.protocols import scheduling
from seal.protocols.config import ProtocolConfig
from seal.protocols.loader import (
    config_from_dict,
    config_to_dict,
    dumps_toml,
    read_toml,
    upgrade_saved,
)
from seal.run.checkpoint_fields import (
    EpochCheckpoint,
    RunCheckpoint,
    check_epoch_checkpoint,
    check_run_checkpoint,
    saved_config_table,
)
from seal.run.checkpointing import Checkpointer
from seal.run.loggers import ScalarLogger, open_loggers
from seal.run.loop import LoopCallback, PhaseLoop, ProgressBar
from seal.run.mapped_start import mapped_start
from seal.run.phase_model import (
    Phase,
    PhaseModel,
    build_adapters,
    build_alignment,
    plan_phases,
    run_agent_config,
)
from seal.run.preemption import Preempted, SignalStop
from seal.run.resources import check_resources, choose_update_threads
from seal.run.rundir import (
    CONFIG_LIMIT,
    DirLock,
    RunDir,
    new_group_id,
    parse_seed_dir,
    seed_dir,
)
from seal.run.state import LOOP_PARTS, PhaseState
from seal.seeding import derive_seed

DISK_FULL = (errno.ENOSPC, errno.EDQUOT)
"""OSError numbers a run reports in one line: the user frees space and resumes."""

# ---------------------------------------------------------------- results and phases


class PhaseTiming(TypedDict):
    """Where one phase's wall time went (`RunResult.timing`, `seal bench --protocol`)."""

    seconds: dict[str, float]
    """Part -> wall seconds: `seal.run.state.LOOP_PARTS`, demos, evaluate_worker_cpu."""
    calls: dict[str, int]
    """Part -> how many times it ran (update: gradient steps; evaluate: evaluations)."""
    epochs: int
    grad_steps: int


class TimeShares(TypedDict):
    """Where a run's wall time went (`time_shares`; provenance.json's "time_shares", `RunResult`).

    loop_s is the phases' epoch loops (across resumes); parts_s splits it into `LOOP_PARTS`
    and other_s is the rest (planning, the epoch's bookkeeping, a signal's rollback marks).
    startup_s is this process's wall outside the loops: building the run and each phase (agent,
    replay, demonstrations), then closing the phase's env instances and workers.
    """

    wall_s: float
    startup_s: float
    loop_s: float
    parts_s: dict[str, float]
    other_s: float
    evaluate_worker_cpu_s: float
    """evaluation.mode = "async": the evaluation worker's CPU seconds (parts_s's evaluate is then
    the loop's waiting on it); 0 for synchronous evaluation."""


def time_shares(states: Sequence[PhaseState], startup_s: float) -> TimeShares:
    """The phases' loop time by part (`PhaseState.seconds`), other and `startup_s` beside it."""
    loop_s = sum(s.wall_s for s in states)
    parts = {p: sum(s.seconds.get(p, 0.0) for s in states) for p in LOOP_PARTS}
    return {
        "wall_s": startup_s + loop_s,
        "startup_s": startup_s,
        "loop_s": loop_s,
        "parts_s": parts,
        "other_s": loop_s - sum(parts.values()),
        "evaluate_worker_cpu_s": sum(s.seconds.get("evaluate_worker_cpu", 0.0) for s in states),
    }


def time_line(shares: TimeShares) -> str:
    """`shares` in one line: start-up, then the loop's wall by part with its percentage."""
    loop = shares["loop_s"]

    def part(name: str, seconds: float) -> str:
        return f"{name} {seconds:.1f} s ({100 * seconds / loop if loop else 0.0:.0f}%)"

    parts = dict(shares["parts_s"])
    cpu = shares["evaluate_worker_cpu_s"]
    if cpu:
        parts["evaluate (waiting)"] = parts.pop("evaluate")
    text = (
        f"time: wall {shares['wall_s']:.1f} s = start-up {shares['startup_s']:.1f} s + loop "
        f"{loop:.1f} s: "
        + ", ".join(part(n, s) for n, s in [*parts.items(), ("other", shares["other_s"])])
    )
    if cpu:
        text += f"; evaluation worker CPU {cpu:.1f} s"
    return text


@dataclass(frozen=True)
class RunResult:
    """What one seed's run produced: its directory and the headline numbers (also `seal run --json`)."""

    run_dir: Path
    update_counts: dict[str, dict[str, float | None]]
    """env -> task -> millions of that task's transitions consumed by updates when it first reached the threshold (None, JSON null: never; 0 would be a task reached before any update)."""
    final_success: dict[str, dict[str, float]]
    """env -> task -> success rate at the last evaluation of the phase that trained on env."""
    timing: dict[str, PhaseTiming] = field(default_factory=dict)
    """phase -> {"seconds", "calls"} of its collect/update/evaluate/checkpoint parts, "epochs", "grad_steps" (`seal bench --protocol`)."""
    threads: str = ""
    """The updates' intra-op threads and what chose them (`seal.device.ThreadChoice.describe`)."""
    time_shares: TimeShares | None = None
    """Where the run's wall time went (`time_shares`)."""


# ---------------------------------------------------------------- checkpoint files


def transfer_source(config: ProtocolConfig) -> AgentState | None:
    """The agent state named by [transfer] checkpoint (None without [transfer]).

    ConfigError naming `transfer.checkpoint` and the path if it is empty, missing or not a
    `seal run` checkpoint.
    """
    transfer = config.transfer
    if transfer is None:
        return None
    where = f"{config.path}: transfer.checkpoint"
    if not transfer.checkpoint:
        raise ConfigError(
            f"{where} is empty; give a checkpoint written by `seal run`, e.g. "
            "--set transfer.checkpoint=reports/<protocol>/<group>/seed-0/checkpoints/best.pt"
        )
    try:
        data = check_run_checkpoint(read_checkpoint(transfer.checkpoint), transfer.checkpoint)
    except SealError as exc:
        raise ConfigError(f"{where} = {transfer.checkpoint!r}: {exc}") from None
    return data["agent"]


class Run:
    """One seed of one protocol: owns the run directory, phases, checkpoints and resume."""

    def __init__(
        self,
        config: ProtocolConfig,
        seed: int,
        path: Path,
        *,
        quiet: bool = True,
        resume: bool = False,
        command: list[str] | None = None,
        callbacks: Sequence[LoopCallback] = (),
        cores: int | None = None,
    ) -> None:
        self.created = time.perf_counter()
        self.loop_s = 0.0
        """This process's wall in the phases' epoch loops (the rest of its wall is start-up)."""
        self.config = config
        self.callbacks = tuple(callbacks)
        """Called by every phase's loop, after the progress bar (e.g. a sweep's Ray Tune reporter)."""
        self.seed = int(seed)
        self.quiet = quiet
        self.phases = plan_phases(config)
        self.device = provenance.resolve_device(config.protocol.device)
        self.adapters = build_adapters(config)
        self.alignment = (
            build_alignment(config, self.adapters) if config.kind == "finetune" else None
        )
        self.agent_cfg = run_agent_config(config, self.device)
        # Sizes the machine cannot hold fail here, in one line, before anything is allocated or written.
        estimate = check_resources(config, self.adapters, self.device)
        self.threads = choose_update_threads(config, estimate, cores)
        """The updates' intra-op threads and the inputs of the rule that chose them."""
        if self.threads.threads:
            torch.set_num_threads(self.threads.threads)
        apply_matmul_precision(torch.device(self.device), config.protocol.matmul_precision)
        # [transfer]: read the source checkpoint now, so a bad path fails before anything is written
        # (a resumed run restores its own agent and does not need the source any more).
        self.transfer_state = None if resume else transfer_source(config)
        # [transfer] map: which env starts from which, checked against the checkpoint now too.
        if self.transfer_state is not None:
            mapped_start(config, self.adapters, self.transfer_state)
        self.lock = DirLock(path)
        """Held from here to the end of `run()`: one writer per run directory."""
        if resume:
            RunDir.open(path)  # not a run directory: refuse before creating a lock file in it
        missing = [p for p in (Path(path), *Path(path).parents) if not p.exists()]
        created = missing[-1] if missing else None  # the top folder this run makes
        self.lock.acquire(command)
        try:
            self._open_rundir(config, path, resume, command)
        except OSError as exc:
            self.lock.release()
            if created is not None:
                shutil.rmtree(created, ignore_errors=True)  # leave no half-made run directory
            if exc.errno not in DISK_FULL:
                raise
            raise SealError(
                f"{path}: writing {exc.filename or 'a file'} failed: {exc.strerror}; free space and run again"
            ) from None
        except BaseException:
            self.lock.release()
            raise
        self.results: dict[str, PhaseState] = {}
        self.loggers: list[ScalarLogger] = []
        """The run's TensorBoard and wandb loggers while it runs (`seal.run.loggers`)."""
        self.checkpointer = Checkpointer(self)
        """Writes best.pt and the epoch checkpoints (`seal.run.checkpointing`)."""
        self.stop = SignalStop(config.checkpoint.signal_budget_s)
        """SIGTERM and SIGINT while `run()` runs, with checkpoint.on_signal (`seal.run.preemption`)."""

    def _open_rundir(
        self, config: ProtocolConfig, path: Path, resume: bool, command: list[str] | None
    ) -> None:
        if resume:
            self.rundir = RunDir.open(path)
        else:
            prov = provenance.collect(command, self.device, envs=config.envs.values())
            prov.update(
                seed=self.seed,
                start_time=provenance.utc_now(),
                end_time=None,
                protocol=config.name,
                kind=config.kind,
                group=Path(path).parent.name,
                phase_names=[p.name for p in self.phases],
                update_threads=self.threads.describe(),
            )
            self.rundir = RunDir.create(path, dumps_toml(config_to_dict(config)), prov)

    # ------------------------------------------------------------ driver
    def run(self) -> RunResult:
        """Run (or resume) every phase, holding the directory's lock; returns the headline numbers."""
        self.lock.acquire()  # a no-op unless run() is called again after it released the lock
        handling = self.stop.handling() if self.config.checkpoint.on_signal else None
        try:
            with handling or contextlib.nullcontext():
                return self._run()
        except Preempted as stop:
            raise self._preempted(stop) from None
        except OSError as exc:
            if exc.errno not in DISK_FULL:
                raise
            raise SealError(
                f"{self.rundir.path}: writing {exc.filename or 'a file'} failed: {exc.strerror}; "
                "the last checkpoint and the CSV rows up to it are intact: free space, then "
                f"resume with --resume {self.rundir.path}"
            ) from None
        finally:
            self.lock.release()

    def _run(self) -> RunResult:
        resume_payload = self._resume_point()
        start_phase = 0 if resume_payload is None else int(resume_payload["runner"]["phase_index"])
        purge = None
        if resume_payload is not None:
            # Hide TensorBoard events written after the checkpoint (they are written again): the
            # resumed phase's past its step, and all of any later phase's. Events at the
            # checkpoint's own step (its epoch's evaluation and train rows) came before it and are
            # not written again, so the resumed phase's purge starts one step later.
            step = int(resume_payload["runner"]["state"]["grad_steps"]) + 1
            purge = {
                p.name: step if p.index == start_phase else 0 for p in self.phases[start_phase:]
            }
        self.loggers = open_loggers(self.config, self.rundir.path, purge)
        try:
            for phase in self.phases[start_phase:]:
                payload = resume_payload if phase.index == start_phase else None
                self.results[phase.name] = self._run_phase(phase, payload)
                if self.stop.requested and phase is not self.phases[-1]:
                    later = self.phases[phase.index + 1].name
                    raise Preempted(
                        self.stop.signum or 0, f"{self.stop.note}; phase {later} did not start"
                    )
        finally:
            for logger in self.loggers:
                logger.close()
            self.loggers = []
        startup_s = time.perf_counter() - self.created - self.loop_s
        shares = time_shares([self.results[p.name] for p in self.phases], startup_s)
        self.rundir.update_provenance(end_time=provenance.utc_now(), time_shares=shares)
        print(f"[seal] {self.rundir.path}: {time_line(shares)}", file=sys.stderr)
        if self.stop.requested:
            raise Preempted(
                self.stop.signum or 0, f"{self.stop.note}; the run is complete", resumable=False
            )
        return self._result(shares)

    def _preempted(self, stop: Preempted) -> Preempted:
        """The stop recorded in provenance.json, its line ending with how to resume."""
        record = {"time": provenance.utc_now(), "signal": self.stop.name, "what": stop.line}
        with contextlib.suppress(
            OSError, ValueError
        ):  # the checkpoint is saved; this is a courtesy
            previous = self.rundir.read_provenance().get("preemptions", [])
            self.rundir.update_provenance(preemptions=[*previous, record])
        line = f"{stop.line} ({self.rundir.path})"
        if stop.resumable:
            line = (
                f"{stop.line}; resume with: seal run {self.config.path} --resume {self.rundir.path}"
            )
        return Preempted(stop.signum, line, resumable=stop.resumable, what=stop.line)

    def _resume_point(self) -> EpochCheckpoint | None:
        """The latest epoch checkpoint, with the CSVs cut back to it and the resume recorded; None: start over."""
        self.checkpointer.clear_torn()
        latest = self.rundir.latest_checkpoint()
        if latest is None:
            if (self.rundir.path / "metrics.csv").exists():
                # Killed before the first checkpoint: start over cleanly.
                self.rundir.truncate_to({})
            return None
        payload, latest, skipped = self._newest_intact()
        resumes = self.rundir.read_provenance().get("resumes", [])
        record = {"time": provenance.utc_now(), "from": latest.name}
        if skipped:
            record["skipped"] = skipped
        self.rundir.update_provenance(resumes=[*resumes, record])
        for name, state in payload["runner"].get("finished_phases", {}).items():
            self.results[name] = PhaseState(**state)
        return payload

    def _newest_intact(self) -> tuple[EpochCheckpoint, Path, list[dict[str, str]]]:
        """The newest checkpoint that reads and whose CSV rows are all there, with the CSVs cut
        back to it, and the newer ones it skipped (each named on stderr with the reason).

        A skipped file stays: the resumed run writes a checkpoint of the same name when it gets
        there again, and until then it is older than every new one, so `prune` drops it first.
        SealError if no checkpoint is intact.
        """
        skipped: list[dict[str, str]] = []
        phases = [p.name for p in self.phases]
        for path in reversed(self.rundir.epoch_checkpoints()):
            try:
                payload = check_epoch_checkpoint(read_checkpoint(path), path, phases, self.seed)
                self._check_scheduler_state(payload, path)
                self.rundir.truncate_to(payload["runner"]["rows"])
            except SealError as exc:
                skipped.append({"file": path.name, "why": str(exc)})
                continue
            for skip in skipped:
                print(
                    f"seal run --resume: skipping {self.rundir.checkpoints / skip['file']}: {skip['why']}",
                    file=sys.stderr,
                )
            if skipped:
                print(f"seal run --resume: resuming from {path}", file=sys.stderr)
            return payload, path, skipped
        why = "; ".join(s["why"] for s in skipped)
        raise SealError(
            f"--resume {self.rundir.path}: no intact checkpoint to resume from ({why}); "
            f"delete {self.rundir.checkpoints} to start the run over"
        )

    def _check_scheduler_state(self, payload: EpochCheckpoint, path: Path) -> None:
        """SealError if the checkpoint's scheduler state does not load into a fresh scheduler of
        its phase: its keys are each scheduler's own, which the checkpoint's TypedDicts leave
        untyped, so it is loaded into a throwaway one here, before the resume changes anything."""
        phase = self.phases[payload["runner"]["phase_index"]]
        model = PhaseModel(self.config, phase, self.adapters, self.alignment)
        scheduler = scheduling.build(
            self.config.scheduler,
            model.env_tasks,
            {e: self.config.envs[e].adapter for e in phase.envs},
            self.config.path,
            episode_lengths={e: self.adapters[e].episode_length for e in phase.envs},
        )
        try:
            scheduler.load_state_dict(copy.deepcopy(payload["scheduler"]))
        except (KeyError, TypeError, ValueError, IndexError, AttributeError) as exc:
            raise SealError(
                f"checkpoint {path}: field scheduler does not fit this run's {scheduler.kind or type(scheduler).__name__!r} "
                f"scheduler ({type(exc).__name__}: {str(exc)[:100]})"
            ) from None

    def _result(self, shares: TimeShares) -> RunResult:
        """The headline numbers and the per-part timing of the finished phases."""
        counts: dict[str, dict[str, float | None]] = {}
        final: dict[str, dict[str, float]] = {}
        for phase in self.phases:
            state = self.results[phase.name]
            for env in phase.envs:
                tasks = self.adapters[env].tasks
                reached = state.reached.get(env, {})
                counts[env] = {t: float(reached[t]) if t in reached else None for t in tasks}
                final[env] = {t: float(state.last_success.get(env, {}).get(t, 0.0)) for t in tasks}
        timing: dict[str, PhaseTiming] = {
            name: {
                "seconds": dict(state.seconds),
                "calls": dict(state.calls),
                "epochs": state.epoch,
                "grad_steps": state.grad_steps,
            }
            for name, state in self.results.items()
        }
        return RunResult(self.rundir.path, counts, final, timing, self.threads.describe(), shares)

    # ------------------------------------------------------------ building blocks
    def initial_agent(self, phase: Phase, model: PhaseModel, resuming: bool = False) -> Agent:
        """The phase's agent before its first update: transferred ([transfer]) or fine-tuned from pre-training's best."""
        agent = Agent(model.specs, self.agent_cfg, derive_seed(self.seed, "agent", phase.index))
        if resuming:
            return agent  # the checkpoint's agent state replaces everything (lr factor included)
        transfer = self.config.transfer
        if transfer is not None and phase.name == "train":
            state = self.transfer_state
            if state is None:
                state = transfer_source(self.config)
                assert state is not None  # None only without [transfer]
            try:
                transfer_from(agent, state, reinit_critic=transfer.reinit_critic)
                mapped = mapped_start(self.config, self.adapters, state)
                if mapped is not None:
                    mapped.apply(agent, state)
            except SealError as exc:
                raise ConfigError(
                    f"{self.config.path}: transfer.checkpoint = {transfer.checkpoint!r}: {exc}"
                ) from None
            agent.set_lr_factor(transfer.lr_factor)
        if phase.name == "finetune":
            ft = self.config.finetune
            assert ft is not None
            best = self.rundir.best_path("pretrain")
            if not best.is_file():
                raise SealError(
                    f"{self.rundir.path}: fine-tuning needs the pre-training's best checkpoint {best}, which is missing"
                )
            source = check_run_checkpoint(read_checkpoint(best), best)
            transfer_from(agent, source["agent"], reinit_critic=ft.reinit_critic)
            agent.set_lr_factor(ft.lr_factor)
        return agent

    # ------------------------------------------------------------ the epoch loop
    def _run_phase(self, phase: Phase, payload: EpochCheckpoint | None) -> PhaseState:
        """One phase's loop, with the progress bar, the loggers, the caller's callbacks and the checkpoints."""
        callbacks = [
            *([] if self.quiet else [ProgressBar()]),
            *self.loggers,
            *self.callbacks,
            self.checkpointer,
        ]
        loop = PhaseLoop(self, phase, payload, callbacks, self.stop)
        wall_before = loop.state.wall_s
        try:
            return loop.run()
        finally:
            self.loop_s += loop.state.wall_s - wall_before


# ---------------------------------------------------------------- public API


def new_group_dir(config: ProtocolConfig, out: str | Path = "reports") -> Path:
    """reports/<protocol>/<timestamp>-<config hash>; not created yet."""
    return Path(out) / config.name / new_group_id(dumps_toml(config_to_dict(config)))


def run_seed(
    config: ProtocolConfig,
    seed: int,
    group_dir: str | Path,
    *,
    quiet: bool = True,
    resume: bool = False,
    command: list[str] | None = None,
    callbacks: Sequence[LoopCallback] = (),
    cores: int | None = None,
) -> RunResult:
    """Run one seed of `config` into `group_dir/seed-<seed>` (`callbacks`: see `LoopCallback`;
    `cores`: the cores the run shares, a sweep trial's, which bound its update threads).

    With `resume=True` an existing run directory continues from its last checkpoint with the
    config saved in it (a finished run returns at once); a missing one starts fresh, so a sweep
    can call this again for every trial after an interruption.
    """
    path = seed_dir(Path(group_dir), seed)
    if resume and (path / "config.toml").is_file():
        saved = _saved_config(path)
        run = Run(
            saved,
            seed,
            path,
            quiet=quiet,
            resume=True,
            command=command,
            callbacks=callbacks,
            cores=cores,
        )
    else:
        run = Run(
            config, seed, path, quiet=quiet, command=command, callbacks=callbacks, cores=cores
        )
    return run.run()


def resume_run(
    run_dir: str | Path, *, quiet: bool = True, protocol_name: str | None = None
) -> RunResult:
    """Continue a run directory from its last checkpoint, with the config it saved."""
    path = Path(run_dir)
    seed = parse_seed_dir(path)
    if seed is None:
        raise SealError(
            f"--resume {path}: expected a seed directory named seed-<n> (reports/<protocol>/<group>/seed-<n>)"
        )
    saved = _saved_config(path)
    if protocol_name is not None and saved.name != protocol_name:
        raise SealError(
            f"--resume {path}: this run is of protocol {saved.name!r}, not {protocol_name!r}"
        )
    return Run(saved, seed, path, quiet=quiet, resume=True).run()


def load_policy(
    checkpoint: str | Path, device: str = "auto"
) -> tuple[ProtocolConfig, PhaseModel, Agent, RunCheckpoint]:
    """(config, phase model, agent with the saved weights, raw checkpoint) of a run checkpoint.

    SealError naming the file and the field when a field is missing, of the wrong type, or does
    not fit the rest (a phase its saved config has not, an agent state its networks refuse).
    """
    data = check_run_checkpoint(read_checkpoint(checkpoint), checkpoint)
    table = saved_config_table(data, checkpoint)
    config = config_from_dict(upgrade_saved(table), f"checkpoint {checkpoint}: field config_toml")
    phases = {p.name: p for p in plan_phases(config)}
    if data["phase"] not in phases:
        raise SealError(
            f"checkpoint {checkpoint}: field phase = {data['phase']!r}; expected a phase of its "
            f"saved config (kind {config.kind!r}): {', '.join(phases)}"
        )
    phase = phases[data["phase"]]
    adapters = build_adapters(config)
    alignment = build_alignment(config, adapters) if config.kind == "finetune" else None
    model = PhaseModel(config, phase, adapters, alignment)
    agent = Agent(model.specs, run_agent_config(config, provenance.resolve_device(device)), 0)
    try:
        agent.load_state_dict(data["agent"])
    except (SealError, RuntimeError, ValueError, KeyError, TypeError, IndexError) as exc:
        # The fields have their types; their values (shapes, optimiser slots) must also fit.
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:300]
        raise SealError(
            f"checkpoint {checkpoint}: field agent does not fit the agent its saved config "
            f"builds: {first}"
        ) from None
    return config, model, agent, data


def _saved_config(path: Path) -> ProtocolConfig:
    """The config a run directory saved, read as data (`seal.files`): a regular file inside it,
    at most CONFIG_LIMIT bytes, valid TOML and a valid protocol; ConfigError naming the file."""
    RunDir.open(path)
    config_path = path / "config.toml"
    raw = read_toml(config_path, what="run config", within=path, limit=CONFIG_LIMIT)
    return config_from_dict(upgrade_saved(raw), str(config_path))


def result_json(results: Sequence[RunResult]) -> str:
    """The one-line JSON that `seal run --json` ends with."""
    last = results[-1]
    data: dict[str, Any] = {
        "run_dir": str(last.run_dir),
        "update_counts": last.update_counts,
        "final_success": last.final_success,
    }
    if len(results) > 1:
        data["run_dirs"] = [str(r.run_dir) for r in results]
    return json.dumps(
        data,
        allow_nan=False,
        default=lambda o: None if isinstance(o, float) and not math.isfinite(o) else str(o),
    )
