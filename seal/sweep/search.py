"""`seal sweep FILE --search`: random search with Ray Tune, its resume, and the best config.

`search` makes (or re-reads) the search directory, lets Tune draw every sample and run it as
`search_trainable` (reporting each evaluation from the phase loop through `TuneReporter`, so that
ASHA can stop weak samples early), records Tune's results per trial (`_record_results`), then
ranks the trials and writes search.{csv,md} and best.toml (`_write_best`).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from seal.errors import SealError
from seal.protocols.config import ProtocolConfig
from seal.protocols.loader import config_to_dict, load_protocol
from seal.protocols.toml_io import dumps_toml
from seal.run.loop import LoopCallback, PhaseLoop
from seal.run.rundir import atomic_write_text, new_group_id, seed_dir
from seal.sweep.config_tables import Resources, SearchSpec
from seal.sweep.manifest import (
    SweepResult,
    _command,
    _load_configs,
    _now,
    _save_configs,
    _saved_config_path,
    _write_manifest,
    read_manifest,
)
from seal.sweep.ray_session import RaySession, check_address, check_feasible, parse_resources
from seal.sweep.samples import (
    count_trials,
    describe_sample,
    evaluation_horizon,
    parse_search,
    plain_sample,
    sample_overrides,
    search_algorithm,
    search_space,
    trial_index,
    trial_name,
    with_overrides,
)
from seal.sweep.tables import _write_trials_table, rank_trials
from seal.sweep.trials import (
    TrialRecord,
    _outcome,
    _set_threads,
    _write_error,
    is_finished,
    is_started,
    read_evaluations,
)

if TYPE_CHECKING:  # Ray is imported only where it is used (see the package docstring)
    from ray.tune import Callback, ResultGrid
    from ray.tune.experiment import Trial
    from ray.tune.schedulers import ASHAScheduler


@dataclass(frozen=True)
class SearchPlan:
    """What every search trial needs (shipped once to Ray's object store)."""

    base: ProtocolConfig
    """The resolved config a sample's values are set on."""
    search_dir: Path
    seed: int
    """The run seed of every sample."""
    threads: int
    command: tuple[str, ...]
    recorded: Mapping[int, Mapping[str, Any]]
    """Samples sweep.json already holds, by index: what their run directories were started with."""
    kept: frozenset[int]
    """Samples not run again (finished, or stopped by ASHA before): their evaluations are only reported."""

    def run_dir(self, index: int) -> Path:
        """The run directory of sample `index`."""
        return seed_dir(self.search_dir / trial_name(index), self.seed)


def search_trainable(tune_config: Mapping[str, Any], plan: SearchPlan) -> None:
    """The Ray Tune function trainable of one sample: run it, reporting mean success per evaluation.

    `tune_config` holds the values Tune drew. The run reports from its phase loop (`TuneReporter`,
    a `LoopCallback`), so each evaluation reaches Tune as it is made (`training_iteration` counts
    evaluations, which ASHA's grace period uses) and ASHA stops the trial at its report. A
    continued run first reports the evaluations it kept; a kept one only reports them.
    """
    from ray import tune

    from seal.run.runner import run_seed

    index = trial_index(tune.get_context().get_trial_id())
    sample, run_dir = plain_sample(tune_config), plan.run_dir(index)
    reporter = TuneReporter(run_dir)
    if index in plan.kept:
        reporter.report_kept()
        return
    (run_dir / "error.txt").unlink(missing_ok=True)
    try:
        recorded = plan.recorded.get(index)
        if recorded is not None and dict(recorded) != sample:
            raise SealError(
                f"{trial_name(index)}: Tune drew {describe_sample(sample)}, but this search recorded "
                f"{describe_sample(recorded)} (was it started with another Ray version?); start a new search"
            )
        where = f"{plan.base.path} [{trial_name(index)}]"
        config = with_overrides(plan.base, sample_overrides(sample), where)
        _set_threads(plan.threads)
        run_seed(
            config,
            plan.seed,
            run_dir.parent,
            quiet=True,
            resume=is_started(run_dir),
            command=list(plan.command),
            callbacks=[reporter],
            cores=plan.threads,
        )
    except Exception as exc:
        _write_error(run_dir, exc)
        raise


class TuneReporter(LoopCallback):
    """Reports each evaluation's means to Ray Tune from the phase loop (`tune.report`)."""

    def __init__(self, run_dir: Path) -> None:
        self.run_dir = run_dir
        self.kept_reported = False

    def report_kept(self) -> None:
        """The evaluations metrics.csv already holds (a finished or continued run), once."""
        if not self.kept_reported:
            self.kept_reported = True
            for e in read_evaluations(self.run_dir):
                self._report(e.mean_success, e.mean_return, e.epoch, e.grad_steps, e.phase)

    def on_phase_start(self, loop: PhaseLoop) -> None:
        # Run.run has cut metrics.csv back to the checkpoint it continues from.
        self.report_kept()

    def on_evaluation(self, loop: PhaseLoop) -> None:
        rows = loop.last_rows
        self._report(
            sum(float(r["success"]) for r in rows) / len(rows),
            sum(float(r["return"]) for r in rows) / len(rows),
            int(rows[0]["epoch"]),
            int(rows[0]["grad_steps"]),
            loop.phase.name,
        )

    @staticmethod
    def _report(success: float, ret: float, epoch: int, grad_steps: int, phase: str) -> None:
        from ray import tune

        tune.report(
            {
                "mean_success": success,
                "mean_return": ret,
                "epoch": epoch,
                "grad_steps": grad_steps,
                "phase": phase,
            }
        )


@dataclass
class TuneLog:
    """What the driver learns from Tune's callbacks while a search runs."""

    samples: dict[int, dict[str, Any]] = field(default_factory=dict)
    """Each started trial's drawn values, by index (a ResultGrid has no config for a trial that never reported)."""
    completed: set[int] = field(default_factory=set)
    """Trials Tune completed (ran out or stopped by the scheduler); an interrupted search leaves its
    running trials out, so they stay pending, not "stopped"."""

    def callback(self) -> Callback:
        """A Tune callback that fills this log."""
        from ray import tune

        log = self

        class _Log(tune.Callback):
            def on_trial_start(
                self, iteration: int, trials: list[Trial], trial: Trial, **info: object
            ) -> None:
                log.samples[trial_index(trial.trial_id)] = plain_sample(trial.config)

            def on_trial_complete(
                self, iteration: int, trials: list[Trial], trial: Trial, **info: object
            ) -> None:
                log.completed.add(trial_index(trial.trial_id))

        return _Log()


def _resume_search(search_dir: Path) -> tuple[dict[str, Any], list[TrialRecord], ProtocolConfig]:
    """(manifest, its trials as recorded, base config) of an earlier search directory.

    Tune's own resume (`Tuner.restore`) unpickles its experiment state, so a resume reads sweep.json.
    """
    manifest = read_manifest(search_dir)
    if manifest.get("kind") != "search":
        raise SealError(
            f"--resume {search_dir}: this is a {manifest.get('kind')!r} directory; resume it without --search"
        )
    records = manifest["trials"]
    base = load_protocol(_saved_config_path(search_dir, manifest["protocol"]))
    manifest.setdefault("seed", records[0].seed if records else base.protocol.first_seed)
    return manifest, records, base


def _new_search(
    path: str | Path,
    seed: int | None,
    num_samples: int | None,
    overrides: Sequence[str],
    scale: float | None,
    out: str | Path,
    command: Sequence[str],
    local: bool,
) -> tuple[Path, dict[str, Any], ProtocolConfig]:
    """(search directory, manifest, base config) of a new search, its directory created;
    `local`: its trials run on this machine (a local Ray), so their memory is checked here."""
    (base,) = _load_configs([path], overrides, scale, search=True, local=local)
    spec = parse_search(base, num_samples)
    search_dir = (
        Path(out).resolve() / base.name / f"search-{new_group_id(dumps_toml(config_to_dict(base)))}"
    )
    search_dir.mkdir(parents=True, exist_ok=True)
    _save_configs(search_dir, [base])
    manifest = {
        "created": _now(),
        "command": " ".join(command),
        "protocol": base.name,
        "file": str(path),
        "seed": base.protocol.first_seed if seed is None else seed,
        "search": dataclasses.asdict(spec),
    }
    return search_dir, manifest, base


def _search_records(
    search_dir: Path,
    base: ProtocolConfig,
    spec: SearchSpec,
    seed: int,
    earlier: Sequence[TrialRecord],
) -> list[TrialRecord]:
    """One record per trial, by sample index; samples and ASHA stops recorded earlier are kept."""
    before = {t.trial: t for t in earlier}
    records = []
    for index in range(count_trials(spec)):
        name = trial_name(index)
        old = before.get(name)
        record = TrialRecord(
            trial=name,
            protocol=base.name,
            seed=seed,
            run_dir=str(seed_dir(search_dir / name, seed)),
            sample=dict(old.sample) if old else {},
        )
        if is_finished(record.run_dir):
            record.start, record.status = "kept", "finished"
        elif old is not None and old.status == "stopped":
            # A trial ASHA stopped was judged by the scheduler already: kept, not run again.
            record.start, record.status = "kept", "stopped"
        elif is_started(record.run_dir):
            record.start = "continued"
        records.append(record)
    return records


def search(
    path: str | Path | None = None,
    *,
    seed: int | None = None,
    num_samples: int | None = None,
    overrides: Sequence[str] = (),
    scale: float | None = None,
    out: str | Path = "reports",
    address: str | None = None,
    num_cpus: int | None = None,
    resume: str | Path | None = None,
    command: Sequence[str] | None = None,
    progress: Callable[[str], None] | None = None,
) -> SweepResult:
    """Random search over the protocol's [search] table with Ray Tune; returns the ranked trials.

    Each sample is one run (one seed: `seed`, default the protocol's first) of the protocol with
    the sampled values set, under `<out>/<protocol>/search-<id>/sample-<k>/seed-<n>/`. Writes
    search.{csv,md} (ranked) and best.toml (the best sample's resolved config, for `seal run`).
    """
    command = _command(command)
    check_address(address)
    say = progress or (lambda _msg: None)
    earlier: list[TrialRecord] = []
    if resume is not None:
        search_dir = Path(resume)
        manifest, earlier, base = _resume_search(search_dir)
    elif path is None:
        raise SealError("seal sweep --search: give one protocol FILE (or --resume SEARCH_DIR)")
    else:
        search_dir, manifest, base = _new_search(
            path,
            seed,
            num_samples,
            overrides,
            scale,
            out,
            command,
            local=address in (None, "local"),
        )
    spec = parse_search(base, manifest["search"]["num_samples"])
    records = _search_records(search_dir, base, spec, manifest["seed"], earlier)
    extra = {k: v for k, v in manifest.items() if k not in ("kind", "trials")}
    _write_manifest(search_dir, "search", records, extra)
    say(f"search directory: {search_dir} ({len(records)} samples)")
    res = parse_resources(base)
    plan = SearchPlan(
        base=base,
        search_dir=search_dir.resolve(),
        seed=manifest["seed"],
        threads=res.threads,
        command=tuple(command),
        recorded={i: r.sample for i, r in enumerate(records) if r.sample},
        kept=frozenset(i for i, r in enumerate(records) if r.start == "kept"),
    )
    if len(plan.kept) < len(records):
        with RaySession(address, num_cpus) as ray:
            check_feasible(ray, base, res)
            results, log = _run_tune(plan, spec, res)
        _record_results(records, results, log, say)
    else:
        for record in records:
            record.refresh()  # a search with every trial kept runs nothing: no Ray
    return _finish_search(search_dir, records, base, extra)


def _finish_search(
    search_dir: Path, records: list[TrialRecord], base: ProtocolConfig, extra: Mapping[str, Any]
) -> SweepResult:
    """Rank the trials; write search.{csv,md}, best.toml and sweep.json."""
    ranked = rank_trials(records)
    trials_table = _write_trials_table(search_dir / "search", ranked, ranked=True)
    best = _write_best(search_dir, ranked, base)
    notes: list[str] = []
    if best is None:
        notes.append("no trial finished, so there is no best config")
    unfinished = [t.trial for t in ranked if t.status == "pending"]
    if unfinished:
        notes.append(
            f"{len(unfinished)} trial(s) did not finish; continue them with: seal sweep --search --resume {search_dir}"
        )
    _write_manifest(search_dir, "search", ranked, extra)
    return SweepResult(
        sweep_dir=search_dir,
        trials=ranked,
        table=trials_table,
        trials_table=trials_table,
        best_config=best,
        notes=notes,
    )


def _scheduler(base: ProtocolConfig, spec: SearchSpec) -> ASHAScheduler | None:
    """ASHA over evaluations when [search].scheduler = "asha", else None (every trial runs to its end)."""
    if spec.scheduler != "asha":
        return None
    from ray.tune.schedulers import ASHAScheduler

    return ASHAScheduler(
        time_attr="training_iteration",
        # One beyond the last evaluation: ASHA stops a trial that reaches max_t at that report,
        # which would cut a run off before it writes its end (it would read as "stopped").
        max_t=max(evaluation_horizon(base, spec) + 1, spec.grace_period),
        grace_period=spec.grace_period,
        reduction_factor=spec.reduction_factor,
    )


def _run_tune(plan: SearchPlan, spec: SearchSpec, res: Resources) -> tuple[ResultGrid, TuneLog]:
    """Let Ray Tune draw every sample (seeded) and run it; its ResultGrid and what its callbacks saw."""
    from ray import tune

    # The legacy reporter honours verbose=0; the new one still draws a banner on stdout, which
    # would sit among `seal sweep`'s own output (the --json line must stay the last one).
    os.environ.setdefault("RAY_AIR_NEW_OUTPUT", "0")
    trainable = tune.with_resources(
        tune.with_parameters(search_trainable, plan=plan), {"cpu": res.cpus, "gpu": res.gpus}
    )
    scheduler = _scheduler(plan.base, spec)
    log = TuneLog()
    tuner = tune.Tuner(
        trainable,
        param_space=search_space(spec),
        tune_config=tune.TuneConfig(
            metric="mean_success",
            mode="max",
            num_samples=spec.num_samples,
            search_alg=search_algorithm(spec),
            scheduler=scheduler,
            trial_dirname_creator=lambda trial: trial_name(trial_index(trial.trial_id)),
            # Reusing actors saves a Python + torch start per trial; only safe when no trial is
            # stopped early, since a stopped trial's run (Tune's function thread) would live on in the reused actor.
            reuse_actors=scheduler is None,
        ),
        run_config=tune.RunConfig(
            name="tune",
            storage_path=str(plan.search_dir),
            verbose=0,
            failure_config=tune.FailureConfig(max_failures=0, fail_fast=False),
            callbacks=[log.callback()],
        ),
    )
    return tuner.fit(), log


def _record_results(
    records: Sequence[TrialRecord],
    results: ResultGrid,
    log: TuneLog,
    say: Callable[[str], None],
) -> None:
    """Each record's sample, scores, status and time from Tune's ResultGrid (its last report)."""
    by_index = {int(Path(r.path).name.removeprefix("sample-")): r for r in results}
    for index, record in enumerate(records):
        # A recorded sample is what its run directory was started with (a resume checks they match).
        record.sample = record.sample or log.samples.get(index, {})
        result = by_index.get(index)
        if result is None:  # never drawn: the search was interrupted first
            record.refresh()
            continue
        metrics = result.metrics or {}
        if "mean_success" in metrics:
            record.mean_success, record.mean_return = (
                metrics["mean_success"],
                metrics["mean_return"],
            )
            record.evaluations = int(metrics["training_iteration"])
        else:
            record.refresh()  # no report reached Tune (it failed first)
        if is_finished(record.run_dir):
            record.status = "finished"
        elif result.error is not None:
            record.status = "failed"
            record.error = _error_line(Path(record.run_dir) / "error.txt") or _last_line(
                result.error
            )
        elif index in log.completed:
            record.status = "stopped"  # Tune completed it before the run finished: ASHA stopped it
        else:
            record.status = "pending"  # interrupted (Ctrl-C): --resume continues it
        if record.start != "kept":
            record.wall_s = round(float(metrics.get("time_total_s") or 0.0), 3)
        say(f"{record.trial} [{describe_sample(record.sample)}]: {_outcome(record)}")


def _last_line(error: BaseException) -> str:
    """The last line of an exception's text (Tune wraps a trial's error in its own traceback)."""
    text = str(error).strip()
    return text.splitlines()[-1] if text else type(error).__name__


def _error_line(error_file: Path) -> str:
    """The last line of a saved traceback ("SealError: ..."), or ""."""
    try:
        lines = [ln for ln in error_file.read_text().splitlines() if ln.strip()]
    except OSError:
        return ""
    return lines[-1] if lines else ""


def _write_best(
    search_dir: Path, ranked: Sequence[TrialRecord], base: ProtocolConfig
) -> Path | None:
    """best.toml: the best finished sample's resolved config without [search], ready for `seal run`."""
    best = next((t for t in ranked if t.status == "finished"), None)
    if best is None:
        return None
    config = with_overrides(base, sample_overrides(best.sample), f"{base.path} [{best.trial}]")
    data = config_to_dict(config)
    data.pop("search", None)
    score = (
        f"mean success {best.mean_success:.3f}, mean return {best.mean_return:.3f}"
        if best.mean_success is not None
        else "no evaluation"
    )
    header = (
        f"# Best config of the random search in {search_dir}\n"
        f"# {best.trial} ({score} at its last evaluation): {describe_sample(best.sample)}\n"
        f"# Run it with: seal run {search_dir / 'best.toml'}\n\n"
    )
    path = search_dir / "best.toml"
    atomic_write_text(path, header + dumps_toml(data))
    return path
