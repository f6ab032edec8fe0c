"""`seal bench --learn transfer`: the fast cross-environment transfer testbed (docs/transfer_testbed.md).

Every arm is an ordinary protocol under `protocols/testbed/`, run by `seal run` in its own
process (two at a time on a 2-core machine); this module only launches them and reads their run
directories. The figure is

    transfer_updates_saved = 1 - C(high-source) / C(target alone),

where C is the target's consumed transitions (the `updates` column of metrics.csv, which counts
exactly what the replay handed to gradient updates) until each of its tasks first reaches 90%
evaluated success, summed over its tasks. A task that never reaches it counts as the run's total
for that task and is reported as censored. The mean over seeds is of the per-seed figures; seed
s of an arm is set against seed s of its target-alone arm.

Each arm's three paired statistics against its alone arm, seed for seed: `steps` (steps_saved,
1 - G(arm) / G(alone), G = gradient steps until every target task first reaches 90%),
`robust_steps` (the same with 2 evaluations in a row) and `auc` (AUC(arm) - AUC(alone), the area
under each target task's evaluated success over gradient steps 0..budget, over the budget,
averaged over the tasks; `target_auc`), each with its 95% CI and what the seeds can resolve
(`seal.stats.paired_power`: sd_paired_<stat>, mde_<stat>, seeds_for_mde_0p10_<stat>).
`false_positive_rate` runs the CI method on two halves of the alone arm, where no effect exists.
The tables (counts, steps x batch, changes: one thing a cell) and plots (each arm's statistics
with CI and MDE, the target's success with a bootstrap band) go to `<out>/transfer/`.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
import tomllib
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from seal.errors import SealError, UnknownNameError
from seal.metrics import AT_LEAST, DEFAULT_THRESHOLD, first_reach, format_count, format_number

TESTBED = Path(__file__).resolve().parents[2] / "protocols" / "testbed"
"""The testbed's protocol files."""
TARGET_ENV = "target"
"""The [envs.<name>] of the target in every testbed protocol."""
GOAL = 0.25
"""transfer_updates_saved the default shared_update must reach (issue 10)."""
POSITIVE_GOAL = 0.30
"""steps_saved at least one positive control must reach, with a 95% CI above 0 (issue 22)."""


@dataclass(frozen=True)
class Arm:
    """One run of the testbed: a protocol file, the target-alone arm it is set against, and what it starts from."""

    name: str
    label: str
    """Column heading of the table."""
    alone: str | None
    """The target-alone arm with the same per-step batch schedule; None for an alone arm itself."""
    full: bool = False
    """Only with --full."""
    directory: Path = TESTBED
    """Where the arm's protocol file lies."""
    pretrain: str | None = None
    """The arm whose last checkpoint starts this one (`--set transfer.checkpoint=...`), seed for seed."""
    has_target: bool = True
    """False for a source-only run (the pre-training): it is no column of the table."""

    @property
    def protocol(self) -> Path:
        """The arm's protocol file."""
        return self.directory / f"{self.name}.toml"


ARMS: tuple[Arm, ...] = (
    Arm("alone", "Single Env", None),
    Arm("high_source", "High Src", "alone"),
    Arm("no_correspondence", "No corr.", "alone"),
    Arm("pretrain_source", "Source pre-training", None, has_target=False),
    # The ladder of positive controls (docs/transfer_testbed.md, round 5), each from the seed's
    # pre-training: only the trunk pre-trained; the target's translator mapped too; its whole
    # policy, critic and temperatures mapped (transfer by construction).
    Arm("pretrained_trunk", "Pretrained trunk", "alone", pretrain="pretrain_source"),
    Arm("oracle_translator", "Oracle translator", "alone", pretrain="pretrain_source"),
    Arm("oracle_policy", "Oracle policy", "alone", pretrain="pretrain_source"),
    Arm("oracle_policy_clamp", "Oracle policy, clamp", "alone", pretrain="pretrain_source"),
    Arm("alone_sparse", "Single Env (sparse tgt)", None),
    Arm("positive_sparse_target", "Pos: sparse tgt", "alone_sparse", pretrain="pretrain_source"),
    Arm("high_source_per_env", "High Src per_env", "alone", full=True),
    Arm("alone_50_50", "Single Env (50/50 batch)", None, full=True),
    Arm("joint_50_50", "50/50", "alone_50_50", full=True),
    Arm("alone_high_target", "Single Env (High Tgt batch)", None, full=True),
    Arm("high_target", "High Tgt", "alone_high_target", full=True),
    # A diagnostic added after the first round-4 measurement, not a positive control: does the
    # target gain once its critic shares a pre-trained trunk too? (docs/transfer_testbed.md)
    Arm(
        "pretrain_source_shared_critic",
        "Source pre-training (shared critic)",
        None,
        full=True,
        has_target=False,
    ),
    Arm("alone_shared_critic", "Single Env (shared critic)", None, full=True),
    Arm(
        "diag_shared_critic",
        "Diag: shared critic",
        "alone_shared_critic",
        full=True,
        pretrain="pretrain_source_shared_critic",
    ),
)
"""The minimum set (docs/transfer_testbed.md, rounds 4 and 5), then the --full arms; the default-mode
high-source arm gives the round-3 headline, `POSITIVE_CONTROLS` round 4's positive controls."""

ARM_ALIASES: dict[str, str] = {"positive_pretrained": "pretrained_trunk"}
"""Old arm names `--arms` still takes (round 4's results keep theirs)."""
ORACLE_GOAL = 0.80
"""steps_saved oracle_policy must reach, with a 95% CI above 0, at >= 5 seeds (issue 34)."""
MDE_GOAL = 0.15
"""The smaller of an arm's steps and robust_steps MDEs at 5 seeds (from their paired SDs) must
be at most this, a fraction of the paired alone arm's steps (issue 34)."""
MIN_SEEDS_FOR_GOALS = 5


def _finite_number(value: Any) -> bool:
    return isinstance(value, int | float) and math.isfinite(value)


POSITIVE_CONTROLS = ("pretrained_trunk", "positive_sparse_target")
"""Round 4's positive controls, whose goal is POSITIVE_GOAL (SEAL's own mechanism must carry them)."""


def arms(full: bool = False, only: Sequence[str] | None = None) -> list[Arm]:
    """The arms run by `seal bench --learn transfer` (with `--full`: all of them; `only`: these and the arms they need)."""
    if not only:
        return [a for a in ARMS if full or not a.full]
    by_name = {a.name: a for a in ARMS}
    only = [ARM_ALIASES.get(name, name) for name in only]
    for name in only:
        if name not in by_name:
            raise UnknownNameError("testbed arm", name, [*by_name, *ARM_ALIASES])
    needed = {by_name[n].alone for n in only} | {by_name[n].pretrain for n in only}
    wanted = set(only) | (needed - {None})
    return [a for a in ARMS if a.name in wanted]


# ---------------------------------------------------------------- reading one run


@dataclass(frozen=True)
class TargetCost:
    """What one run's target env consumed until its tasks first reached the threshold."""

    consumed: float
    """Transitions consumed by updates until first >= threshold, summed over tasks (censored tasks: their total)."""
    grad_steps: int
    """Gradient steps until every task had first reached the threshold (censored: the run's total)."""
    censored: int
    """Tasks that never reached the threshold."""
    tasks: int
    per_task: dict[str, float]
    """Transitions per task (the summands of `consumed`)."""
    reached: tuple[str, ...]
    """The tasks that reached the threshold."""
    per_task_steps: dict[str, int] = field(default_factory=dict)
    """Gradient steps per task until it first reached the threshold (censored: the run's total)."""

    @property
    def task_steps(self) -> int:
        """Gradient steps summed over the tasks: `consumed` = task_steps x `per_step`, exactly."""
        return int(sum(self.per_task_steps.values()))

    @property
    def per_step(self) -> float:
        """The target's mean per-step batch per task over the spans to 90% (transitions / task-steps)."""
        return self.consumed / self.task_steps if self.task_steps else math.nan


def target_cost(
    metrics: pd.DataFrame,
    env: str = TARGET_ENV,
    threshold: float = DEFAULT_THRESHOLD,
    consecutive: int = 1,
) -> TargetCost:
    """The target's `TargetCost` from one run's metrics table (metrics.csv, one seed, one phase).

    Steps and transitions count from the run's first update: the target's first update in
    every testbed arm (a pre-training is a run of its own). `consecutive` > 1 is the robust
    criterion of `seal.metrics.first_reach`.
    """
    rows = metrics[metrics["env"] == env]
    if rows.empty:
        raise SealError(
            f"metrics table has no rows of env {env!r}; envs: {sorted(set(metrics['env']))}"
        )
    first = (
        first_reach(rows, threshold)
        if consecutive == 1
        else first_reach(rows, threshold, consecutive=consecutive)
    )
    # A task never reached counts as all it consumed, at the run's last evaluation.
    per_task: dict[str, float] = {}
    per_task_steps: dict[str, int] = {}
    for row in first.itertuples(index=False):
        millions = float(row.updates) if row.reached else float(row.run_updates)
        per_task[str(row.task)] = millions * 1e6
        per_task_steps[str(row.task)] = int(row.grad_steps if row.reached else row.run_grad_steps)
    return TargetCost(
        consumed=float(sum(per_task.values())),
        grad_steps=max(per_task_steps.values()),
        censored=int((~first["reached"]).sum()),
        tasks=len(first),
        per_task=per_task,
        reached=tuple(str(t) for t in first.loc[first["reached"], "task"]),
        per_task_steps=per_task_steps,
    )


def target_budget(metrics: pd.DataFrame, env: str = TARGET_ENV) -> int:
    """The gradient step of a run's last evaluation of `env` (its budget, unless it stopped early)."""
    return int(metrics.loc[metrics["env"] == env, "grad_steps"].max())


def target_auc(
    metrics: pd.DataFrame, budget: int | None = None, env: str = TARGET_ENV
) -> dict[str, float]:
    """Per task of `env`: the area under its evaluated success over gradient steps 0..budget, / budget.

    Trapezoids between evaluations. The curve starts at the run's evaluation at step 0 where it
    made one (the testbed's first evaluations fall in the warm-up), else at success 0 at step 0
    (an untrained policy succeeds in about 0.6% of point_view's episodes); after its last
    evaluation it holds that value up to `budget` (default: the run's own last evaluated step),
    and evaluations past `budget` are cut there.
    """
    rows = metrics[metrics["env"] == env]
    if rows.empty:
        raise SealError(
            f"metrics table has no rows of env {env!r}; envs: {sorted(set(metrics['env']))}"
        )
    budget = target_budget(metrics, env) if budget is None else int(budget)
    if budget <= 0:
        raise SealError(f"AUC budget {budget} gradient steps: expected > 0")
    out: dict[str, float] = {}
    for task, frame in rows.sort_values(["epoch", "grad_steps"], kind="stable").groupby(
        "task", sort=False
    ):
        steps = frame["grad_steps"].to_numpy(dtype=float)
        success = frame["success"].to_numpy(dtype=float)
        if steps[0] > 0:
            steps, success = np.r_[0.0, steps], np.r_[0.0, success]
        inside = steps < budget
        x = np.r_[steps[inside], budget]
        y = np.r_[success[inside], np.interp(budget, steps, success)]  # holds the last value
        out[str(task)] = float(np.trapezoid(y, x) / budget)
    return out


def saved(arm: Sequence[float], alone: Sequence[float]) -> list[float]:
    """Per seed: 1 - arm / alone (seed i against seed i); nan where the alone figure is 0."""
    if len(arm) != len(alone):
        raise SealError(f"{len(arm)} seeds of the arm but {len(alone)} of its target-alone arm")
    return [1.0 - a / b if b > 0 else math.nan for a, b in zip(arm, alone, strict=True)]


def updates_saved(arm: Sequence[TargetCost], alone: Sequence[TargetCost]) -> list[float]:
    """Per seed: 1 - arm's consumed / alone's consumed (seed i against seed i)."""
    return saved([a.consumed for a in arm], [b.consumed for b in alone])


def steps_saved(arm: Sequence[TargetCost], alone: Sequence[TargetCost]) -> list[float]:
    """Per seed: 1 - arm's gradient steps to 90% / alone's (seed i against seed i)."""
    return saved([a.grad_steps for a in arm], [b.grad_steps for b in alone])


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


# ---------------------------------------------------------------- the table


def ARM_CI(values: Sequence[float]) -> tuple[float, float]:  # noqa: N802 - a named constant
    """The arms' 95% CI of a mean paired statistic over seeds: Student's t. Measured
    (`seal bench --learn transfer --fpr`, alone seeds 0-9, 1,000 random 5/5 splits): the
    percentile bootstrap the arms used called 17.2% [14.9, 19.7] of no-effect splits resolved, t
    5.3% [4.0, 6.9]; over 5 pairs the bootstrap's interval is too narrow."""
    from seal.stats import t_ci

    return t_ci(values)


ROBUST_CONSECUTIVE = 2
"""The robust criterion reported beside the paper's: 2 successive evaluations >= 90%."""


def _saving(
    runs: Sequence[TargetCost], alone: Sequence[TargetCost], prefix: str = ""
) -> dict[str, Any]:
    """steps_saved and transfer_updates_saved per seed, their means, their 95% CIs (`ARM_CI`),
    and what the seeds resolve of steps_saved (`paired_power` as `steps`, or `robust_steps`)."""
    from seal.stats import paired_power, probability_of_improvement

    steps, updates = steps_saved(runs, alone), updates_saved(runs, alone)
    return {
        **paired_power(steps, f"{prefix}steps"),
        f"{prefix}steps_saved_per_seed": steps,
        f"{prefix}steps_saved": float(np.nanmean(steps)),
        f"{prefix}ci95": list(ARM_CI(steps)),
        f"{prefix}transfer_updates_saved_per_seed": updates,
        f"{prefix}transfer_updates_saved": float(np.nanmean(updates)),
        f"{prefix}transfer_updates_saved_ci95": list(ARM_CI(updates)),
        # P(a run of the arm needs fewer target steps than a run of its alone arm), ties 1/2.
        f"{prefix}probability_of_improvement": probability_of_improvement(
            [c.grad_steps for c in runs], [c.grad_steps for c in alone]
        ),
    }


def _auc_summary(
    runs: Sequence[Mapping[str, float]], alone: Sequence[Mapping[str, float]] | None
) -> dict[str, Any]:
    """An arm's target AUC (`target_auc`, per seed and task): per seed (the tasks' mean), mean and
    IQM over (seed, task); against its alone arm the paired gain AUC(arm) - AUC(alone) per seed,
    its mean, CI and `paired_power` (as `auc`), and the IQM over (seed, task) of the gains."""
    from seal.stats import interquartile_mean, iqm_ci, paired_power

    tasks = list(runs[0])
    own = np.array([[run[t] for t in tasks] for run in runs])
    out: dict[str, Any] = {
        "auc_per_seed": own.mean(axis=1).tolist(),
        "auc_mean": float(own.mean()),
        "auc_iqm": interquartile_mean(own.ravel()),
    }
    if alone is not None:
        gains = own - np.array([[run[t] for t in tasks] for run in alone])
        per_seed = gains.mean(axis=1).tolist()
        out.update(
            auc_gain_per_seed=per_seed,
            auc_gain=float(np.mean(per_seed)),
            auc_gain_ci95=list(ARM_CI(per_seed)),
            auc_gain_iqm=interquartile_mean(gains.ravel()),
            auc_gain_iqm_ci95=list(iqm_ci(gains)),
            **paired_power(per_seed, "auc"),
        )
    return out


def summarise(
    costs: Mapping[str, Sequence[TargetCost]],
    chosen: Sequence[Arm],
    robust: Mapping[str, Sequence[TargetCost]] | None = None,
    cka: Mapping[str, Sequence[Mapping[str, float]]] | None = None,
    pretrain: Mapping[str, Any] | None = None,
    auc: Mapping[str, Sequence[Mapping[str, float]]] | None = None,
) -> dict[str, Any]:
    """Per target arm: the target's transitions, gradient steps and per-step batch to 90%, censored tasks,
    and against its alone arm steps_saved and transfer_updates_saved with 95% CIs, under the paper's
    criterion and (`robust`, `robust_` keys) under ROBUST_CONSECUTIVE, with what the seeds resolve
    of each; `alignment_cka` from `cka`; the AUC statistics (`_auc_summary`) from `auc`, per arm
    and seed the target's `target_auc` over its alone arm's budget."""
    out: dict[str, Any] = {}
    for arm in chosen:
        if not arm.has_target:
            continue
        runs = costs[arm.name]
        entry: dict[str, Any] = {
            "label": arm.label,
            "protocol": str(arm.protocol.relative_to(TESTBED.parents[1])),
            "consumed_per_seed": [c.consumed for c in runs],
            "consumed_mean": float(np.mean([c.consumed for c in runs])),
            "grad_steps_to_90_per_seed": [c.grad_steps for c in runs],
            "grad_steps_to_90_mean": float(np.mean([c.grad_steps for c in runs])),
            "task_steps_per_seed": [c.task_steps for c in runs],
            "per_step_batch_per_seed": [c.per_step for c in runs],
            "per_step_batch_mean": float(np.mean([c.per_step for c in runs])),
            "censored_per_seed": [c.censored for c in runs],
            "censored": int(sum(c.censored for c in runs)),
            "task_runs": int(sum(c.tasks for c in runs)),
        }
        # An alone arm is its own reference: its savings are None (the JSON keys of every arm).
        entry.update(steps_saved=None, ci95=None, transfer_updates_saved=None, alignment_cka=None)
        if arm.alone is not None:
            entry["against"] = arm.alone
            entry.update(_saving(runs, costs[arm.alone]))
            base = float(np.mean([c.consumed for c in costs[arm.alone]]))
            # Beside it, the ratio of the seed means (less sensitive to one slow alone seed).
            entry["saved_of_means"] = 1.0 - entry["consumed_mean"] / base if base > 0 else math.nan
            if robust is not None:
                entry.update(_saving(robust[arm.name], robust[arm.alone], prefix="robust_"))
        if robust is not None:
            entry["robust_grad_steps_to_90_per_seed"] = [c.grad_steps for c in robust[arm.name]]
            entry["robust_censored"] = int(sum(c.censored for c in robust[arm.name]))
        if auc is not None and arm.name in auc:
            entry.update(_auc_summary(auc[arm.name], auc.get(arm.alone) if arm.alone else None))
        if cka is not None and arm.name in cka:
            per_seed = cka[arm.name]
            entry["alignment_cka_per_seed"] = [dict(v) for v in per_seed]
            entry["alignment_cka"] = {
                key: float(np.mean([v[key] for v in per_seed])) for key in per_seed[0]
            }
        if arm.pretrain is not None and pretrain is not None:
            entry["pretrain"] = pretrain[arm.pretrain]
        out[arm.name] = entry
    return out


def pretrain_cost(metrics: pd.DataFrame, threshold: float = DEFAULT_THRESHOLD) -> dict[str, Any]:
    """A source-only pre-training run: its gradient steps, the source's transitions, and whether every task reached."""
    env = str(metrics["env"].iloc[0])
    cost = target_cost(metrics, env=env, threshold=threshold)
    return {
        "grad_steps": int(metrics["grad_steps"].max()),
        "consumed": float(metrics.groupby("task")["updates"].max().sum() * 1e6),
        "reached_all": cost.censored == 0,
    }


TASK_LABEL = "point_view"
"""How the tables name the target's env ("t0 (point_view)")."""


def _values(runs: Sequence[TargetCost], task: str) -> list[float]:
    """Per seed: the target's transitions to 90% of `task` ("Total": all tasks; censored: totals)."""
    return [c.consumed if task == "Total" else c.per_task[task] for c in runs]


def _reached(runs: Sequence[TargetCost], task: str) -> int:
    return sum(1 for c in runs if (c.censored == 0 if task == "Total" else task in c.reached))


def _counts_display(
    costs: Mapping[str, Sequence[TargetCost]], chosen: Sequence[Arm], tasks: Sequence[str]
) -> pd.DataFrame:
    """Task rows (and Total), arm columns: M transitions to 90% as mean ± std [reached/seeds]."""
    records = []
    for task in [*tasks, "Total"]:
        record = {"Task": f"{task} ({TASK_LABEL})"}
        for arm in chosen:
            values = _values(costs[arm.name], task)
            std = float(np.std(values, ddof=1)) / 1e6 if len(values) > 1 else math.nan
            # Censored seeds count their total, so every cell has a mean, a lower bound ("≥") where
            # a seed is censored; [k/n] says how many reached.
            cell = format_count(float(np.mean(values)) / 1e6, std, 1, len(values))
            reached = _reached(costs[arm.name], task)
            bound = f"{AT_LEAST} " if reached < len(values) else ""
            record[arm.label] = bound + cell.rsplit(" [", 1)[0] + f" [{reached}/{len(values)}]"
        records.append(record)
    return pd.DataFrame.from_records(records)


def _steps_display(
    costs: Mapping[str, Sequence[TargetCost]], chosen: Sequence[Arm], tasks: Sequence[str]
) -> pd.DataFrame:
    """Per (task, arm): gradient steps to 90% x mean per-step batch = the transitions (means over seeds)."""
    records = []
    for task in tasks:
        record = {"Task": f"{task} ({TASK_LABEL})"}
        for arm in chosen:
            runs = costs[arm.name]
            steps = float(np.mean([c.per_task_steps[task] for c in runs]))
            per_step = float(
                np.mean([c.per_task[task] / max(c.per_task_steps[task], 1) for c in runs])
            )
            record[arm.label] = f"{format_number(steps)} × {per_step:.1f}"
        records.append(record)
    return pd.DataFrame.from_records(records)


def _change_rows(
    costs: Mapping[str, Sequence[TargetCost]], chosen: Sequence[Arm], tasks: Sequence[str]
) -> pd.DataFrame:
    """Per (task or Total, arm with an alone arm): the change of the mean transitions to 90%
    against the alone arm, with its paired 95% Fieller CI over seeds, as
    `seal.reports.changes.change_rows` lays changes out (censored seeds count their totals)."""
    from seal.reports.changes import CHANGE_ROW_COLUMNS
    from seal.stats import MIN_SEEDS_RESOLVED, change_ci, resolved

    labels = {a.name: a.label for a in ARMS}
    records = []
    for task in [*tasks, "Total"]:
        for arm in chosen:
            if arm.alone is None:
                continue
            mine, base = _values(costs[arm.name], task), _values(costs[arm.alone], task)
            low, high = change_ci(mine, base, paired=True)
            base_mean = float(np.mean(base))
            n = len(mine)
            records.append(
                {
                    "env": TARGET_ENV,
                    "task": task,
                    "column": arm.label,
                    "reference": labels[arm.alone],
                    "vs": labels[arm.alone],
                    "pct_change": 100 * (float(np.mean(mine)) / base_mean - 1)
                    if base_mean > 0
                    else math.nan,
                    "pct_ci_low": 100 * low,
                    "pct_ci_high": 100 * high,
                    "n_column": n,
                    "n_reference": len(base),
                    "paired": True,
                    "resolved": n >= MIN_SEEDS_RESOLVED and resolved((low, high)),
                    "shared_tasks": len(tasks) if task == "Total" else 0,
                    "sd_paired_pct": math.nan,
                    "mde_pct": math.nan,
                }
            )
    return pd.DataFrame.from_records(records, columns=list(CHANGE_ROW_COLUMNS))


STATISTICS: tuple[tuple[str, str, str, str], ...] = (
    ("steps", "steps_saved", "ci95", "steps_saved = 1 - G(arm) / G(alone)"),
    ("robust_steps", "robust_steps_saved", "robust_ci95", "the same, 2 evaluations in a row"),
    ("auc", "auc_gain", "auc_gain_ci95", "AUC(arm) - AUC(alone) of the target's success"),
)
"""The paired statistics: (name in the sd_/mde_ keys, its key, its CI's key, what it is)."""


def _statistic_note(label: str, name: str, key: str, ci_key: str, s: Mapping[str, Any]) -> str:
    """ "steps +0.115* [-0.27, +0.45] (+0.20, ...), sd_paired_steps 0.440, mde_steps 0.546,
    seeds_for_mde_0p10_steps 154": a statistic's mean (* resolved), CI, per-seed values and power."""
    from seal.stats import resolved

    low, high = s[ci_key]
    per_seed = ", ".join(f"{v:+.3f}" for v in s[f"{key}_per_seed"])
    seeds = s[f"seeds_for_mde_0p10_{name}"]
    text = (
        f"{name} {s[key]:+.3f}{'*' if resolved((low, high)) else ''} [{low:+.3f}, {high:+.3f}] "
        f"({per_seed}), sd_paired_{name} {s[f'sd_paired_{name}']:.3f}, "
        f"mde_{name} {s[f'mde_{name}']:.3f}, seeds_for_mde_0p10_{name} "
        f"{'n/a' if seeds is None else seeds}"
    )
    if name == "auc":
        iqm_low, iqm_high = s["auc_gain_iqm_ci95"]
        text += (
            f"; IQM over (seed, task) {s['auc_gain_iqm']:+.3f} [{iqm_low:+.3f}, {iqm_high:+.3f}]"
        )
    return f"{label}: {text}"


def _statistics_notes(chosen: Sequence[Arm], summary: Mapping[str, Any]) -> list[str]:
    """What the paired statistics are, then one note per (arm, statistic) with its keys."""
    notes = [
        "Paired statistics, arm seed s against its alone arm's seed s: "
        + "; ".join(f"{name}: {what}" for name, _, _, what in STATISTICS)
        + ". G = gradient steps until every target task first evaluates >= 90% (censored: the "
        "run's total); AUC = per task the area under the evaluated success over gradient steps "
        "0..the alone arm's budget (success 0 at step 0 unless evaluated there), over the budget, "
        "mean over the tasks.",
        "[lo, hi] = 95% Student's t CI of the mean over seeds (the percentile bootstrap called "
        "17% of no-effect 5/5 splits resolved: --fpr); * = it excludes 0. sd_paired_<stat> = SD of the per-seed "
        "values; mde_<stat> = (t(0.975, n-1) + t(0.80, n-1)) sd / sqrt(n), the effect found with "
        "power 0.8 at these n seeds; seeds_for_mde_0p10_<stat> = the seeds an MDE <= 0.10 needs "
        "at that SD (seal.stats). IQM = rliable's interquartile mean, stratified bootstrap CI.",
    ]
    for arm in chosen:
        s = summary[arm.name]
        if arm.alone is None or s["steps_saved"] is None:
            continue
        label = f"{arm.label} vs {summary[arm.alone]['label']}"
        for name, key, ci_key, _ in STATISTICS:
            if key in s:
                notes.append(_statistic_note(label, name, key, ci_key, s))
    return notes


def _arm_notes(chosen: Sequence[Arm], summary: Mapping[str, Any]) -> list[str]:
    """One note per arm: steps to 90% per seed, censored tasks, transfer_updates_saved, CKA, pre-training."""
    notes = []
    for arm in chosen:
        s = summary[arm.name]
        text = (
            f"{arm.label}: steps to 90% {format_number(s['grad_steps_to_90_mean'])} "
            f"{s['grad_steps_to_90_per_seed']}; censored {s['censored']}/{s['task_runs']}"
        )
        if s["steps_saved"] is not None:
            low, high = s["transfer_updates_saved_ci95"]
            text += (
                f"; transfer_updates_saved {s['transfer_updates_saved']:+.3f} "
                f"[{low:+.2f}, {high:+.2f}]; P(fewer steps) {s['probability_of_improvement']:.2f}"
            )
        if s["alignment_cka"] is not None:
            cka = s["alignment_cka"]
            text += f"; CKA translator {cka['translator']:.2f}, trunk {cka['trunk']:.2f}"
        if "pretrain" in s:
            pre = s["pretrain"]
            text += (
                f"; source pre-training {format_number(pre['grad_steps_mean'])} steps, "
                f"{format_number(pre['consumed_mean'] / 1e6)} M transitions, "
                f"all tasks reached in {pre['reached_all']}/{len(pre['grad_steps_per_seed'])} seeds"
            )
        notes.append(text)
    return notes


def transfer_documents(
    costs: Mapping[str, Sequence[TargetCost]], chosen: Sequence[Arm], summary: Mapping[str, Any]
) -> dict[str, tuple[str, list[Any], list[str]]]:
    """The bench's tables as `seal.reports.tables` documents, stem -> (title, sections, notes):
    `counts` (M transitions to 90%, arms as columns, then gradient steps x per-step batch) and
    `changes` (one row per (task, arm, alone arm), then the paired statistics in the notes)."""
    from seal.reports.tables import change_sections, changes_display

    chosen = [a for a in chosen if a.has_target]
    tasks = list(next(iter(costs.values()))[0].per_task)
    counts = (
        "M transitions of the target consumed by updates until first >= 90% success",
        [
            ("", _counts_display(costs, chosen, tasks), None),
            ("Gradient steps × per-step batch", _steps_display(costs, chosen, tasks), None),
        ],
        [
            "Mean ± sample std over seeds [seeds that reached / seeds]; a task never reached counts "
            "its run's total. Total = the sum over the target's tasks.",
            "Gradient steps to first >= 90% × the task's mean per-step batch over them "
            "(transitions per step), means over seeds: the transitions above are steps × batch, so "
            "a change in them is a change in steps times a change in batch share. Steps count from "
            "the target's first update.",
            *_arm_notes(chosen, summary),
        ],
    )
    rows = _change_rows(costs, chosen, tasks)
    labels = {TARGET_ENV: TASK_LABEL}
    changes = (
        "Changes against each arm's alone arm",
        change_sections(
            changes_display(rows, labels, "markdown"), changes_display(rows, labels, "latex")
        )
        if len(rows)
        else [],
        [
            "Change = mean(arm) / mean(alone) - 1 of the target's transitions to 90% (censored "
            "seeds at their totals), 95% CI = paired Fieller interval (t quantiles) in percent; "
            "bold = it excludes 0 with >= 3 seeds; n = seed pairs; tasks = the tasks in a total.",
            *_statistics_notes(chosen, summary),
        ],
    )
    return {"counts": counts, "changes": changes}


def format_table(
    costs: Mapping[str, Sequence[TargetCost]], chosen: Sequence[Arm], summary: Mapping[str, Any]
) -> str:
    """`transfer_documents` as Markdown: the counts (and steps x batch), then the changes and the
    paired statistics; no line longer than 100 characters (`seal.reports.tables.LINE_LIMIT`)."""
    from seal.reports.tables import markdown_document

    return "\n".join(
        markdown_document(title, sections, notes)
        for title, sections, notes in transfer_documents(costs, chosen, summary).values()
    )


def write_transfer_report(
    directory: Path,
    costs: Mapping[str, Sequence[TargetCost]],
    chosen: Sequence[Arm],
    summary: Mapping[str, Any],
    metrics: Mapping[tuple[str, int], pd.DataFrame],
) -> dict[str, list[str]]:
    """`directory`/tables/{counts,changes}.{md,tex} and `directory`/plots/: changes.png (each
    arm's paired statistics with their CIs and MDEs) and success_target.png (the target's mean
    success per arm, 95% bootstrap band over seeds). Returns the paths written."""
    from seal.reports.plots import (
        Interval,
        column_colours,
        plot_intervals,
        plot_success,
    )
    from seal.reports.tables import write_document
    from seal.stats import MIN_SEEDS_RESOLVED, resolved

    tables_dir, plots_dir = directory / "tables", directory / "plots"
    tables_dir.mkdir(parents=True, exist_ok=True)
    plots_dir.mkdir(parents=True, exist_ok=True)
    written: dict[str, list[str]] = {"tables": [], "plots": []}
    for stem, (title, sections, notes) in transfer_documents(costs, chosen, summary).items():
        if sections:
            paths = write_document(tables_dir / stem, title, sections, notes)
            written["tables"] += [str(p) for p in paths.values()]
    targets = [a for a in chosen if a.has_target]
    compared = [
        a for a in targets if a.alone is not None and summary[a.name]["steps_saved"] is not None
    ]
    if compared:
        panels = []
        for name, key, ci_key, what in STATISTICS:
            rows = []
            for arm in compared:
                s = summary[arm.name]
                if key not in s:
                    continue
                ci = (float(s[ci_key][0]), float(s[ci_key][1]))
                enough = len(s[f"{key}_per_seed"]) >= MIN_SEEDS_RESOLVED
                rows.append(
                    Interval(
                        f"{arm.label} vs {summary[arm.alone]['label']}",
                        float(s[key]),
                        *ci,
                        float(s[f"mde_{name}"]),
                        enough and resolved(ci),
                    )
                )
            if rows:
                panels.append((f"{name}: {what}", rows))
        path = plot_intervals(
            panels,
            plots_dir / "changes.png",
            "paired statistic (positive = the arm needs less / learns more than its alone arm)",
            "Target: each arm against its alone arm, mean over seeds, 95% CI, ±MDE",
        )
        written["plots"].append(str(path))
    frames = [
        frame[frame["env"] == TARGET_ENV].assign(column=arm.label, env_label=TASK_LABEL)
        for (name, _), frame in metrics.items()
        for arm in targets
        if arm.name == name
    ]
    if frames:
        labels = [a.label for a in targets]
        success = plot_success(
            pd.concat(frames, ignore_index=True),
            "grad_steps",
            column_colours(labels),
            {TARGET_ENV: f"{TASK_LABEL} (target)"},
            plots_dir,
            DEFAULT_THRESHOLD,
        )
        written["plots"] += [str(p) for p in success]
    return written


# ---------------------------------------------------------------- the command


def alignment(
    run_dirs: Mapping[tuple[str, int], Path], chosen: Sequence[Arm], seeds: int
) -> dict[str, list[dict[str, float]]]:
    """Per target arm and seed: linear CKA of the source's and the target's translator (and trunk) outputs on shared states.

    A joint arm: its own two envs, from its last checkpoint. An alone arm: its target against
    the source of the pre-training run of the same seed, two runs that never met (the baseline).
    """
    from seal.learner.probes import cka_from_checkpoints

    # An alone arm's source: the pre-training of the arms set against it, else the first one run.
    first = next((a.name for a in chosen if not a.has_target), None)
    partner = {a.alone: a.pretrain for a in chosen if a.pretrain is not None}
    out: dict[str, list[dict[str, float]]] = {}
    for arm in chosen:
        pre = partner.get(arm.name, first)
        if not arm.has_target or (arm.alone is None and pre is None):
            continue
        out[arm.name] = []
        for seed in range(seeds):
            target = last_checkpoint(run_dirs[(arm.name, seed)])
            source = target if arm.alone is not None else last_checkpoint(run_dirs[(pre, seed)])
            out[arm.name].append(cka_from_checkpoints(source, "source", target, TARGET_ENV))
    return out


def curve_distance(a: pd.DataFrame, b: pd.DataFrame, env: str = TARGET_ENV) -> float:
    """Mean |success difference| of `env`'s tasks between two runs, over the evaluations both made."""
    curves = [
        m[m["env"] == env].pivot_table(index="grad_steps", columns="task", values="success")
        for m in (a, b)
    ]
    left, right = curves[0].align(curves[1], join="inner")
    return float(np.abs(left.to_numpy() - right.to_numpy()).mean())


def source_sensitivity(
    metrics: Mapping[tuple[str, int], pd.DataFrame], chosen: Sequence[Arm], seeds: int
) -> dict[str, float] | None:
    """How much the target's success curve moves when only its source changes, against seed noise.

    Every joint arm shares high_source's target (its init and random streams: same seed, same
    source shapes), so `curve_distance` to high_source's run of the same seed measures what the
    source's goals or pre-training change for the target; `between_seeds` (high_source seed s
    against seed s + 1) is the scale of a change that matters. None without high_source.
    """
    names = {a.name for a in chosen}
    if "high_source" not in names or seeds < 2:
        return None
    out = {
        arm.name: float(
            np.mean(
                [
                    curve_distance(metrics[(arm.name, s)], metrics[("high_source", s)])
                    for s in range(seeds)
                ]
            )
        )
        for arm in chosen
        if arm.alone == "alone" and arm.name != "high_source"
    }
    out["between_seeds"] = float(
        np.mean(
            [
                curve_distance(
                    metrics[("high_source", s)], metrics[("high_source", (s + 1) % seeds)]
                )
                for s in range(seeds)
            ]
        )
    )
    return out


def _all_censored(arm: Mapping[str, Any]) -> bool:
    """Whether no target task of the arm reached the threshold in any seed."""
    return bool(arm.get("task_runs")) and arm.get("censored") == arm.get("task_runs")


def arm_mdes(summary: Mapping[str, Mapping[str, Any]]) -> dict[str, float | None]:
    """Each compared arm's MDE at the goal's 5 seeds, the smaller of steps' and robust_steps'.

    From each statistic's paired SD, whatever --seeds was. None where there is no SD, and where
    the arm and its alone arm never reached in any seed: every pair then sits at the run's budget,
    and an SD of 0 measures the budget, not the instrument.
    """
    from seal.stats import mde

    return {
        name: None
        if _all_censored(s) and _all_censored(summary[s["against"]])
        else min(
            (
                mde(s[k], MIN_SEEDS_FOR_GOALS)
                for k in ("sd_paired_steps", "sd_paired_robust_steps")
                if _finite_number(s.get(k))
            ),
            default=None,
        )
        for name, s in summary.items()
        if s.get("steps_saved") is not None
    }


def run_transfer_bench(
    full: bool = False,
    seeds: int = 5,
    out: str | os.PathLike[str] = "reports/bench_transfer",
    parallel: int = 2,
    overrides: Sequence[str] = (),
    log: Callable[[str], None] = lambda _: None,
    only: Sequence[str] | None = None,
    reuse: bool = False,
) -> dict[str, Any]:
    """Run every arm's seeds with `seal run`, read their run directories, and return the result as JSON-able dict.

    `only` runs just the named arms (with the arms they need), e.g. the `--full` arms after the
    minimum set; the headline figures are then None where not run. `reuse` takes finished runs
    under `out` whose resolved config is today's (`finished_run`).
    """
    from seal import load_run
    from seal.bench.timing import machine_load

    if seeds < 1:
        raise SealError(f"--seeds must be >= 1, got {seeds}")
    if parallel < 1:
        raise SealError(f"--jobs must be >= 1, got {parallel}")
    chosen = arms(full, only)
    load_before = machine_load()
    started = time.monotonic()
    # Pre-training first (the positive controls wait on it), then the longest arms, so the last
    # process does not run alone while a core idles.
    jobs = sorted(
        ((arm, seed) for seed in range(seeds) for arm in chosen),
        key=lambda job: (job[0].has_target, job[0].alone is None),
    )
    run_dirs, reused = run_or_reuse(jobs, Path(out), overrides, parallel, log, reuse)
    wall = time.monotonic() - started
    loaded = {key: load_run(path) for key, path in run_dirs.items()}
    targets = [a for a in chosen if a.has_target]

    def costs_of(consecutive: int) -> dict[str, list[TargetCost]]:
        return {
            arm.name: [
                target_cost(loaded[(arm.name, s)].metrics, consecutive=consecutive)
                for s in range(seeds)
            ]
            for arm in targets
        }

    costs = costs_of(1)
    pretrain = {}
    for arm in chosen:
        if not arm.has_target:
            runs = [pretrain_cost(loaded[(arm.name, s)].metrics) for s in range(seeds)]
            pretrain[arm.name] = {
                "grad_steps_per_seed": [r["grad_steps"] for r in runs],
                "grad_steps_mean": float(np.mean([r["grad_steps"] for r in runs])),
                "consumed_per_seed": [r["consumed"] for r in runs],
                "consumed_mean": float(np.mean([r["consumed"] for r in runs])),
                "reached_all": int(sum(r["reached_all"] for r in runs)),
            }
    mismatches = agent_mismatches({k: r.config.get("agent", {}) for k, r in loaded.items()}, chosen)
    versions = code_versions({k: r.provenance.get("git_sha") for k, r in loaded.items()})
    # Each arm's target AUC over its alone arm's budget, so that a pair shares one window.
    auc = {
        arm.name: [
            target_auc(
                loaded[(arm.name, s)].metrics,
                target_budget(loaded[(arm.alone or arm.name, s)].metrics),
            )
            for s in range(seeds)
        ]
        for arm in targets
    }
    summary = summarise(
        costs,
        chosen,
        robust=costs_of(ROBUST_CONSECUTIVE),
        cka=alignment(run_dirs, chosen, seeds),
        pretrain=pretrain,
        auc=auc,
    )
    report_dir = Path(out) / "transfer"
    written = write_transfer_report(
        report_dir, costs, chosen, summary, {k: r.metrics for k, r in loaded.items()}
    )

    def figure(name: str, key: str = "transfer_updates_saved") -> Any:
        return summary[name][key] if name in summary else None

    positives = {
        name: {key: s[key] for key in ("steps_saved", "ci95")}
        for name, s in summary.items()
        if name in POSITIVE_CONTROLS
    }
    # Issue 22: a positive control saves >= 30% of the target's steps with a CI above 0, and the
    # no-correspondence control's CI includes 0 or lies below it.
    positive_met = any(
        p["steps_saved"] >= POSITIVE_GOAL and p["ci95"][0] > 0 for p in positives.values()
    )
    control_ci = figure("no_correspondence", "ci95")
    # Issue 34: transfer by construction must be seen (oracle_policy >= 80% with a CI above 0 at
    # >= 5 seeds), and the instrument must resolve 15% of the alone arm's steps at 5 seeds.
    oracle = summary.get("oracle_policy")
    oracle_goal = None
    if oracle is not None and oracle.get("steps_saved") is not None:
        oracle_goal = {
            "steps_saved_ge": ORACLE_GOAL,
            "seeds_ge": MIN_SEEDS_FOR_GOALS,
            "steps_saved": oracle["steps_saved"],
            "ci95": oracle["ci95"],
            "met": bool(
                seeds >= MIN_SEEDS_FOR_GOALS
                and oracle["steps_saved"] >= ORACLE_GOAL
                and oracle["ci95"][0] > 0
            ),
        }
    mdes = arm_mdes(summary)
    return {
        "transfer_updates_saved": figure("high_source"),
        "goal": {
            "transfer_updates_saved_ge": GOAL,
            "met": None if figure("high_source") is None else bool(figure("high_source") >= GOAL),
            "per_env": figure("high_source_per_env"),
            "no_correspondence": figure("no_correspondence"),
            "positive_steps_saved_ge": POSITIVE_GOAL,
            "positive": positives,
            "positive_met": positive_met if positives else None,
            "no_correspondence_ci95": control_ci,
            "no_correspondence_ci_not_above_0": None if control_ci is None else control_ci[0] <= 0,
            "oracle_policy": oracle_goal,
            "mde": {
                "mde_le": MDE_GOAL,
                "at_seeds": MIN_SEEDS_FOR_GOALS,
                "per_arm": mdes,
                "met": {n: None if v is None else bool(v <= MDE_GOAL) for n, v in mdes.items()},
            },
        },
        "arms": summary,
        "pretrain": pretrain,
        "target_curve_distance": source_sensitivity(
            {k: r.metrics for k, r in loaded.items()}, chosen, seeds
        ),
        "table": format_table(costs, chosen, summary),
        "report_dir": str(report_dir),
        "tables": written["tables"],
        "plots": written["plots"],
        "seeds": seeds,
        "full": full,
        "overrides": list(overrides),
        "run_dirs": {f"{a}/seed-{s}": str(p) for (a, s), p in run_dirs.items()},
        "commands": {f"{a}/seed-{s}": r.provenance.get("command") for (a, s), r in loaded.items()},
        "reused": sorted(f"{a}/seed-{s}" for a, s in reused),
        "agent_mismatches": mismatches,
        "code_versions": versions,
        "wall_s": wall,
        "parallel": parallel,
        "load_before": load_before,
        "load_after": machine_load(),
    }


# ---------------------------------------------------------------- the false-positive rate

FPR_SEEDS = 10
"""Seeds of the alone arm the false-positive rate splits (two halves of FPR_HALF)."""
FPR_HALF = 5
"""Seeds a half: the bench's 5 seeds an arm."""
FPR_SPLITS = 1_000
FPR_GOAL = 0.10
"""The share of CIs that may exclude 0 where there is no effect; above it, change the CI method."""


def false_positive_rate(
    run_dirs: Sequence[Path], splits: int = FPR_SPLITS, half: int = FPR_HALF, seed: int = 0
) -> dict[str, Any]:
    """The arms' CI method on two halves of one arm's seeds, where there is no effect to find.

    `run_dirs` are runs of one arm (the alone arm, seeds 0-9); G = the target's gradient steps
    until every task first reaches 90% (`target_cost`, censored at the run's total).
    `seal.stats.split_false_positive_rate` draws `splits` random half/half splits, pairs the halves'
    seeds at random, and applies the arms' CI (`ARM_CI`: Student's t) and, for comparison, the
    percentile bootstrap it replaced, to the mean of 1 - G(a) / G(b); and `seal report`'s CI of a
    change (`seal.stats.change_ci`, paired) to mean(G(a)) / mean(G(b)) - 1 on the same splits.
    """
    from functools import partial

    from seal import load_run
    from seal.stats import bootstrap_ci, change_ci, split_false_positive_rate

    costs = [target_cost(load_run(path).metrics) for path in run_dirs]
    steps = [c.grad_steps for c in costs]
    split = partial(split_false_positive_rate, steps, half=half, splits=splits, seed=seed)
    rate = split(ci=ARM_CI)
    return {
        "grad_steps_to_90_per_seed": steps,
        "censored_per_seed": [c.censored for c in costs],
        "ci_method": "Student's t CI of the mean saving (the arms' ci95)",
        "false_positive_rate": rate,
        "false_positive_rate_bootstrap": split(ci=bootstrap_ci),
        # `seal report`'s CI of a change of the mean (Fieller's, paired), on the same splits
        "false_positive_rate_report": split(change=partial(change_ci, paired=True)),
        "goal": {"rate_le": FPR_GOAL, "met": rate["rate"] <= FPR_GOAL},
    }


def run_fpr_bench(
    seeds: int = FPR_SEEDS,
    out: str | os.PathLike[str] = "reports/bench_transfer",
    parallel: int = 2,
    log: Callable[[str], None] = lambda _: None,
    reuse: bool = False,
    splits: int = FPR_SPLITS,
) -> dict[str, Any]:
    """`seal bench --learn transfer --fpr`: run (or, with `reuse`, take) the alone arm's seeds
    0..seeds-1 under `out`, then `false_positive_rate` on them; a JSON-able dict."""
    from seal import load_run
    from seal.bench.timing import machine_load

    if seeds < 2 * FPR_HALF:
        raise SealError(f"--seeds {seeds}: the false-positive rate needs >= {2 * FPR_HALF}")
    (alone,) = arms(only=["alone"])
    load_before = machine_load()
    started = time.monotonic()
    jobs = [(alone, seed) for seed in range(seeds)]
    run_dirs, reused = run_or_reuse(jobs, Path(out), (), parallel, log, reuse)
    wall = time.monotonic() - started
    paths = [run_dirs[(alone.name, s)] for s in range(seeds)]
    shas = {(alone.name, s): load_run(p).provenance.get("git_sha") for s, p in enumerate(paths)}
    return {
        "arm": alone.name,
        "seeds": seeds,
        **false_positive_rate(paths, splits=splits),
        "run_dirs": {f"{alone.name}/seed-{s}": str(p) for s, p in enumerate(paths)},
        "reused": sorted(f"{a}/seed-{s}" for a, s in reused),
        "code_versions": code_versions(shas),
        "wall_s": wall,
        "parallel": parallel,
        "load_before": load_before,
        "load_after": machine_load(),
    }


def format_fpr(result: Mapping[str, Any]) -> str:
    """The human-readable output of `run_fpr_bench`."""
    rate, other = result["false_positive_rate"], result["false_positive_rate_bootstrap"]

    def share(r: Mapping[str, Any]) -> str:
        low, high = r["rate_ci95"]
        return (
            f"{r['excluding_0']}/{r['splits']} = {r['rate']:.3f} (95% CI [{low:.3f}, {high:.3f}])"
        )

    verdict = "met" if result["goal"]["met"] else "not met: change the CI method and say so"
    lines = [
        f"False-positive rate: {result['arm']} seeds 0-{result['seeds'] - 1}, G = target steps to "
        f"90% {result['grad_steps_to_90_per_seed']} (censored tasks per seed "
        f"{result['censored_per_seed']})",
        f"{rate['splits']} random {rate['half']}/{rate['half']} splits, halves paired at random, "
        "CI of the mean of 1 - G(a) / G(b) excluding 0:",
        f"  {result['ci_method']}: {share(rate)}; goal <= {result['goal']['rate_le']}: {verdict}",
        f"  percentile bootstrap (the arms' CI until measured here), for comparison: {share(other)}",
    ]
    if "false_positive_rate_report" in result:
        lines.append(
            "  seal report's CI of mean(G(a)) / mean(G(b)) - 1 (Fieller's, paired by seed): "
            f"{share(result['false_positive_rate_report'])}"
        )
    note = versions_note(result["code_versions"])
    if note:
        lines.append(f"WARNING, {note}")
    reused = f" ({len(result['reused'])} runs reused)" if result["reused"] else ""
    lines.append(
        f"{result['seeds']} seeds, {result['parallel']} runs at a time, {result['wall_s']:.0f} s "
        f"wall{reused}; load before {result['load_before']['loadavg_1m']} (1 min), after "
        f"{result['load_after']['loadavg_1m']}"
    )
    return "\n".join(lines)


def format_result(result: Mapping[str, Any]) -> str:
    """The human-readable output of `run_transfer_bench`."""
    goal = result["goal"]
    load = result["load_before"]

    def shown(value: float | None) -> str:
        return "not run" if value is None else f"{value:+.3f}"

    verdict = {None: "not run", True: "met", False: "not met"}[goal["met"]]
    lines = [
        result["table"],
        "",
        f"transfer_updates_saved (high-source, default shared_update) = {shown(result['transfer_updates_saved'])} "
        f"(goal >= {goal['transfer_updates_saved_ge']}: {verdict}); "
        f"per_env {shown(goal['per_env'])}, no correspondence {shown(goal['no_correspondence'])}",
    ]
    if goal["positive"]:
        verdict = {True: "met", False: "not met"}[goal["positive_met"]]
        shown_positive = "; ".join(
            f"{name} {p['steps_saved']:+.3f} [{p['ci95'][0]:+.2f}, {p['ci95'][1]:+.2f}]"
            for name, p in goal["positive"].items()
        )
        lines.append(
            f"positive controls, steps_saved with 95% CI: {shown_positive} "
            f"(goal >= {goal['positive_steps_saved_ge']} with the CI above 0: {verdict})"
        )
    if goal["no_correspondence_ci95"] is not None:
        low, high = goal["no_correspondence_ci95"]
        lines.append(
            f"no-correspondence control steps_saved 95% CI [{low:+.2f}, {high:+.2f}] "
            f"(goal: includes 0 or lies below it: {'met' if goal['no_correspondence_ci_not_above_0'] else 'not met'})"
        )
    oracle = goal.get("oracle_policy")
    if oracle is not None:
        low, high = oracle["ci95"]
        lines.append(
            f"oracle_policy steps_saved {oracle['steps_saved']:+.3f} [{low:+.2f}, {high:+.2f}] "
            f"(goal >= {oracle['steps_saved_ge']} with the CI above 0 at >= {oracle['seeds_ge']} "
            f"seeds: {'met' if oracle['met'] else 'not met'})"
        )
    mdes = goal.get("mde", {}).get("per_arm", {})
    if mdes:
        shown_mde = ", ".join(f"{n} {v:.2f}" for n, v in mdes.items() if v is not None)
        met = [n for n, ok in goal["mde"]["met"].items() if ok]
        lines.append(
            f"MDE at {goal['mde']['at_seeds']} seeds, min(steps, robust_steps): {shown_mde} "
            f"(goal <= {goal['mde']['mde_le']}: met by {', '.join(met) or 'no arm'})"
        )
    distance = result["target_curve_distance"]
    if distance is not None:
        moved = ", ".join(f"{k} {v:.3f}" for k, v in distance.items() if k != "between_seeds")
        lines.append(
            f"target success curve vs high_source's, same seed, mean |difference|: {moved}; "
            f"between seeds of high_source {distance['between_seeds']:.3f}"
        )
    if result["seeds"] < 3:
        lines.append(f"{result['seeds']} seeds: fewer than 3, so no change is resolved.")
    lines += [f"WARNING, arms not comparable: {m}" for m in result["agent_mismatches"]]
    note = versions_note(result["code_versions"])
    if note:
        lines.append(f"WARNING, {note}")
    lines.append(f"Tables and plots: {result['report_dir']}")
    reused = f" ({len(result['reused'])} runs reused)" if result["reused"] else ""
    lines.append(
        f"{result['seeds']} seeds, {result['parallel']} runs at a time, {result['wall_s']:.0f} s wall{reused}; "
        f"load before {load['loadavg_1m']} (1 min) on {load['cpus']} CPUs, after {result['load_after']['loadavg_1m']}"
    )
    return "\n".join(lines)
