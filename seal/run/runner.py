"""Protocol runners: the three kinds, checkpoints and resume (the epoch loop: `seal.run.loop`).

A seed's run is set up as a pipeline (`seal.run.setup`): `run_seed` plans the run (`plan_run`),
checks its resources (`check_resources`), builds it (`build`: the `Run`) and runs it.

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
Evaluation runs on env instances of its own, several per task (`seal.run.evaluation`),
built once per phase: each evaluation episode resets with a seed derived from (phase, grad
steps, episode), so they need no rebuilding at checkpoints.

A resume starts from the newest intact checkpoint (`seal.run.resume`).

On SIGTERM or SIGINT (`checkpoint.on_signal`) a run stops at a safe point with the checkpoint of
its last finished epoch, records the stop in provenance.json's "preemptions" and raises
`seal.run.preemption.Preempted`, whose line ends with the --resume command. A checkpoint
written at a signal re-seeds the collectors from its epoch like any other, so the resumed run
repeats what an uninterrupted run that also checkpointed at that epoch does.

Before anything is created, a run checks its estimated memory (`seal.run.resources`) and
takes its directory's lock (`seal.run.dirlock.DirLock`), which it holds until it ends; a
full disk (ENOSPC, EDQUOT) while it writes stops it with one line naming the file.
"""

from __future__ import annotations

import contextlib
import errno
import shutil
import sys
import time
import warnings
from collections.abc import Sequence
from pathlib import Path

from seal import provenance
from seal.device import ThreadChoice
from seal.errors import SealError, SealWarning
from seal.files import check_output_dir
from seal.learner.checkpoint import read_checkpoint
from seal.learner.sac import Agent
from seal.learner.transfer import transfer_from
from seal.protocols.config import ProtocolConfig
from seal.protocols.loader import config_to_dict
from seal.protocols.toml_io import dumps_toml
from seal.run.checkpoint_fields import EpochCheckpoint, check_run_checkpoint
from seal.run.checkpointing import Checkpointer
from seal.run.dirlock import DirLock
from seal.run.loggers import ScalarLogger, open_loggers
from seal.run.loop import LoopCallback, PhaseLoop, ProgressBar
from seal.run.phase_model import Phase, PhaseModel
from seal.run.preemption import Preempted, SignalStop
from seal.run.results import RunResult, run_result, time_line, time_shares
from seal.run.resume import resume_point
from seal.run.rundir import RunDir, new_group_id, parse_seed_dir, seed_dir
from seal.run.setup import (
    RunPlan,
    apply_transfer,
    check_resources,
    check_transfer,
    load_policy,
    plan_run,
    saved_config,
    transfer_source,
)
from seal.run.state import PhaseState
from seal.seeding import derive_seed

__all__ = ["Run", "RunResult", "build", "load_policy", "new_group_dir", "resume_run", "run_seed"]

DISK_FULL = (errno.ENOSPC, errno.EDQUOT)
"""OSError numbers a run reports in one line: the user frees space and resumes."""


class Run:
    """One seed of one protocol: owns the run directory, phases, checkpoints and resume (`build`)."""

    def __init__(
        self,
        plan: RunPlan,
        threads: ThreadChoice,
        path: Path,
        *,
        quiet: bool = True,
        resume: bool = False,
        command: list[str] | None = None,
        callbacks: Sequence[LoopCallback] = (),
    ) -> None:
        self.created = plan.started
        self.loop_s = 0.0
        """This process's wall in the phases' epoch loops (the rest of its wall is start-up)."""
        self.plan, self.config, self.seed, self.quiet = plan, plan.config, plan.seed, quiet
        self.callbacks = tuple(callbacks)
        """Called by every phase's loop, after the progress bar (e.g. a sweep's Ray Tune reporter)."""
        self.phases, self.device, self.adapters = plan.phases, plan.device, plan.adapters
        self.alignment, self.agent_cfg = plan.alignment, plan.agent_cfg
        self.threads = threads
        """The updates' intra-op threads and the inputs of the rule that chose them."""
        # [transfer]: read the source checkpoint now, so a bad path fails before anything is written
        # (a resumed run restores its own agent and does not need the source any more).
        self.transfer_state = None if resume else transfer_source(self.config)
        # [transfer]: the checkpoint applied to a throwaway agent now too (its widths, its map).
        if self.transfer_state is not None:
            check_transfer(plan, self.transfer_state)
        self._open(path, resume, command)
        self.results: dict[str, PhaseState] = {}
        self.loggers: list[ScalarLogger] = []
        """The run's TensorBoard and wandb loggers while it runs (`seal.run.loggers`)."""
        self.checkpointer = Checkpointer(self)
        """Writes best.pt and the epoch checkpoints (`seal.run.checkpointing`)."""
        self.stop = SignalStop(self.config.checkpoint.signal_budget_s)
        """SIGTERM and SIGINT while `run()` runs, with checkpoint.on_signal (`seal.run.preemption`)."""

    def _open(self, path: Path, resume: bool, command: list[str] | None) -> None:
        """Take the directory's lock (held to the end of `run()`: one writer per run directory)
        and open or create it; a failure leaves no half-made run directory."""
        self.lock = DirLock(path)
        if resume:
            RunDir.open(path)  # not a run directory: refuse before creating a lock file in it
        missing = [p for p in (Path(path), *Path(path).parents) if not p.exists()]
        created = missing[-1] if missing else None  # the top folder this run makes
        try:
            self.lock.acquire(command)
        except OSError as exc:
            # A folder that cannot be made there: under /proc, no permission, a name too long.
            if created is not None:
                shutil.rmtree(created, ignore_errors=True)
            raise SealError(
                f"{path}: cannot create the run directory ({exc.strerror or exc}: "
                f"{exc.filename or path}); give --out a folder you can write to"
            ) from None
        try:
            self._open_rundir(self.config, path, resume, command)
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
        resume_payload, finished = resume_point(self.plan, self.rundir, self.checkpointer)
        self.results.update(finished)
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
        return run_result(
            self.rundir.path,
            self.phases,
            self.results,
            self.adapters,
            self.threads.describe(),
            shares,
        )

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
            apply_transfer(self.config, self.adapters, agent, state)
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
        loop = PhaseLoop(self, phase, payload, callbacks, self.stop, self.plan.models[phase.name])
        wall_before = loop.state.wall_s
        try:
            return loop.run()
        finally:
            self.loop_s += loop.state.wall_s - wall_before


# ---------------------------------------------------------------- public API


def build(
    plan: RunPlan,
    threads: ThreadChoice,
    path: Path,
    *,
    quiet: bool = True,
    resume: bool = False,
    command: list[str] | None = None,
    callbacks: Sequence[LoopCallback] = (),
) -> Run:
    """The planned run, ready to `run()`: its transfer source read and checked, its directory
    locked and opened (`resume`) or created. Each phase's agent, replay and workers are built
    when its loop starts (`seal.run.phase_parts`)."""
    return Run(
        plan, threads, path, quiet=quiet, resume=resume, command=command, callbacks=callbacks
    )


def new_group_dir(config: ProtocolConfig, out: str | Path = "reports") -> Path:
    """reports/<protocol>/<timestamp>-<config hash>; not created yet (`out` is checked: a
    directory name, not a path through a file)."""
    root = check_output_dir(out)
    return root / config.name / new_group_id(dumps_toml(config_to_dict(config)))


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
    resume = resume and (path / "config.toml").is_file()
    if resume:
        config = saved_config(path)  # the run directory's own config
    plan = plan_run(config, seed)  # phases, adapters, alignment, each phase's model
    threads = check_resources(plan, cores)  # refused here, before anything is allocated
    run = build(
        plan, threads, path, quiet=quiet, resume=resume, command=command, callbacks=callbacks
    )
    return run.run()


def _warn_differences(path: Path, saved: ProtocolConfig, given: ProtocolConfig) -> None:
    """A SealWarning naming the keys where the FILE given with --resume differs from the saved
    config (an edit made after the run started, or the run's own --set), which the run keeps."""
    from seal.sweep.config_tables import flatten

    mine, theirs = (flatten(config_to_dict(c)) for c in (saved, given))
    keys = sorted(k for k in mine.keys() | theirs.keys() if mine.get(k) != theirs.get(k))
    if keys:
        shown = ", ".join(f"{k} ({mine.get(k)!r} saved, {theirs.get(k)!r} in it)" for k in keys[:4])
        more = f" and {len(keys) - 4} more" if len(keys) > 4 else ""
        warnings.warn(
            SealWarning(
                f"--resume {path}: {given.path} differs from the run's saved config in {shown}"
                f"{more}; the run goes on with its saved config (start a new run to use the file's)"
            ),
            stacklevel=2,
        )


def resume_run(
    run_dir: str | Path, *, quiet: bool = True, protocol: ProtocolConfig | None = None
) -> RunResult:
    """Continue a run directory from its last checkpoint, with the config it saved; `protocol`
    (the FILE given with --resume) must be of the same protocol, and a SealWarning names the
    keys where it differs from the saved config, which the run keeps."""
    path = Path(run_dir)
    seed = parse_seed_dir(path)
    if seed is None:
        raise SealError(
            f"--resume {path}: expected a seed directory named seed-<n> (reports/<protocol>/<group>/seed-<n>)"
        )
    config = saved_config(path)
    if protocol is not None:
        if config.name != protocol.name:
            raise SealError(
                f"--resume {path}: this run is of protocol {config.name!r}, not {protocol.name!r}"
            )
        _warn_differences(path, config, protocol)
    plan = plan_run(config, seed)
    return build(plan, check_resources(plan), path, quiet=quiet, resume=True).run()
