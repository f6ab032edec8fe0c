"""Where a resumed run starts: the newest intact epoch checkpoint, with the CSVs cut back to it.

A checkpoint that does not read as a seal checkpoint (torn, zero bytes), whose CSV rows are no
longer all there or whose scheduler state does not fit its phase's scheduler is skipped, named on
stderr with the reason and in provenance.json's "resumes"; none intact is a one-line refusal
that changes nothing.
"""

from __future__ import annotations

import copy
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from seal import provenance
from seal.errors import SealError
from seal.learner.checkpoint import read_checkpoint
from seal.protocols import scheduling
from seal.run.checkpoint_fields import EpochCheckpoint, check_epoch_checkpoint
from seal.run.state import PhaseState

if TYPE_CHECKING:
    from seal.run.checkpointing import Checkpointer
    from seal.run.rundir import RunDir
    from seal.run.setup import RunPlan


def resume_point(
    plan: RunPlan, rundir: RunDir, checkpointer: Checkpointer
) -> tuple[EpochCheckpoint | None, dict[str, PhaseState]]:
    """The latest epoch checkpoint, with the CSVs cut back to it and the resume recorded, and
    the final counters of the phases it had finished; (None, {}): start over."""
    checkpointer.clear_torn()
    latest = rundir.latest_checkpoint()
    if latest is None:
        ended = rundir.read_provenance().get("end_time")
        if ended:  # e.g. a run record, kept without its checkpoints: starting over would erase it
            raise SealError(
                f"--resume {rundir.path}: this run finished at {ended} and holds no checkpoint, "
                "so there is nothing to continue; its rows are unchanged"
            )
        if (rundir.path / "metrics.csv").exists():
            # Killed before the first checkpoint: start over cleanly.
            rundir.truncate_to({})
        return None, {}
    payload, latest, skipped = _newest_intact(plan, rundir)
    resumes = rundir.read_provenance().get("resumes", [])
    record = {"time": provenance.utc_now(), "from": latest.name}
    if skipped:
        record["skipped"] = skipped
    rundir.update_provenance(resumes=[*resumes, record])
    finished = payload["runner"].get("finished_phases", {})
    return payload, {name: PhaseState(**state) for name, state in finished.items()}


def _newest_intact(
    plan: RunPlan, rundir: RunDir
) -> tuple[EpochCheckpoint, Path, list[dict[str, str]]]:
    """The newest checkpoint that reads and whose CSV rows are all there, with the CSVs cut
    back to it, and the newer ones it skipped (each named on stderr with the reason).

    A skipped file stays: the resumed run writes a checkpoint of the same name when it gets
    there again, and until then it is older than every new one, so `prune` drops it first.
    SealError if no checkpoint is intact.
    """
    skipped: list[dict[str, str]] = []
    phases = [p.name for p in plan.phases]
    for path in reversed(rundir.epoch_checkpoints()):
        try:
            payload = check_epoch_checkpoint(read_checkpoint(path), path, phases, plan.seed)
            _check_scheduler_state(plan, payload, path)
            rundir.truncate_to(payload["runner"]["rows"])
        except SealError as exc:
            skipped.append({"file": path.name, "why": str(exc)})
            continue
        for skip in skipped:
            print(
                f"seal run --resume: skipping {rundir.checkpoints / skip['file']}: {skip['why']}",
                file=sys.stderr,
            )
        if skipped:
            print(f"seal run --resume: resuming from {path}", file=sys.stderr)
        return payload, path, skipped
    why = "; ".join(s["why"] for s in skipped)
    raise SealError(
        f"--resume {rundir.path}: no intact checkpoint to resume from ({why}); "
        f"delete {rundir.checkpoints} to start the run over"
    )


def _check_scheduler_state(plan: RunPlan, payload: EpochCheckpoint, path: Path) -> None:
    """SealError if the checkpoint's scheduler state does not load into a fresh scheduler of
    its phase: its keys are each scheduler's own, which the checkpoint's TypedDicts leave
    untyped, so it is loaded into a throwaway one here, before the resume changes anything."""
    config = plan.config
    phase = plan.phases[payload["runner"]["phase_index"]]
    model = plan.models[phase.name]
    scheduler = scheduling.build(
        config.scheduler,
        model.env_tasks,
        {e: config.envs[e].adapter for e in phase.envs},
        config.path,
        episode_lengths={e: plan.adapters[e].episode_length for e in phase.envs},
    )
    try:
        scheduler.load_state_dict(copy.deepcopy(payload["scheduler"]))
    except (KeyError, TypeError, ValueError, IndexError, AttributeError) as exc:
        raise SealError(
            f"checkpoint {path}: field scheduler does not fit this run's {scheduler.kind or type(scheduler).__name__!r} "
            f"scheduler ({type(exc).__name__}: {str(exc)[:100]})"
        ) from None
