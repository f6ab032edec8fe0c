"""Checkpoints as a loop callback: the `Checkpointer` writes a run's best and epoch checkpoints.

The `PhaseLoop` decides when a checkpoint is due and the `Checkpointer` writes it:

- after an evaluation whose mean success beats the phase's best, the loop calls `write_best`
  (before any callback's `on_evaluation`, inside the evaluation's timing): best.pt
  (best-<phase>.pt in a run with several phases), the agent only;
- every `checkpoint.interval` epochs and after the phase's last epoch, the loop records the
  checkpoint's epoch (`PhaseState.anchor_epoch`), calls every callback's `on_checkpoint` (the
  loggers flush, so a resume purges exactly what comes after the checkpoint), then
  `write_checkpoint`: ckpt-<epoch>.pt (ckpt-<phase>-<epoch>.pt) with the agent, the replay and
  the fields below, keeping the last `checkpoint.keep_last`; then the loop re-seeds its env
  instances (see `seal.run.runner`). All of it counts as the loop's "checkpoint" time;
- on SIGTERM or SIGINT, the loop calls for the checkpoint of the last finished epoch
  (`seal.run.preemption`); after a rollback it holds the epoch start's agent, counters and
  RNG states, and the replay as it was then (`PhaseLoop.checkpoint_replay`).

The file format is `seal.learner.checkpoint`'s: an atomic, data-only `torch.save`; the fields
are the TypedDicts of `seal.run.checkpoint_fields`.
"""

from __future__ import annotations

import random
from typing import TYPE_CHECKING

import torch

from seal.learner.checkpoint import save_checkpoint
from seal.protocols.loader import config_to_dict
from seal.protocols.toml_io import dumps_toml
from seal.run.checkpoint_fields import BestFields, CheckpointFields, EpochFields
from seal.run.loop import LoopCallback, PhaseLoop
from seal.run.parts import PhaseOwner

if TYPE_CHECKING:
    from seal.run.rundir import RunDir


class Checkpointer(LoopCallback):
    """Writes the run's checkpoints when the loop says one is due (see the module docstring)."""

    def __init__(self, run: PhaseOwner) -> None:
        self.run = run
        self.config_toml = dumps_toml(config_to_dict(run.config))
        """The run's config, saved in every checkpoint (it loads back with `seal eval`)."""

    @property
    def rundir(self) -> RunDir:
        return self.run.rundir

    def write_best(self, loop: PhaseLoop) -> None:
        assert loop.evaluated is not None
        fields: BestFields = {**self._fields(loop, best=True), "scheduler": None, "runner": None}
        # The agent evaluated: the live one, or an asynchronous evaluation's snapshot.
        save_checkpoint(
            self.rundir.best_path(self._label(loop)), loop.evaluated.agent, fields=fields
        )

    def write_checkpoint(self, loop: PhaseLoop) -> None:
        state, checkpoint = loop.state, self.run.config.checkpoint
        fields: EpochFields = {
            **self._fields(loop, best=False),
            "scheduler": loop.scheduler.state_dict(),
            "runner": {
                "phase_index": loop.phase.index,
                "state": state.fields(),
                "rows": self.rundir.row_counts(),
                "torch_rng": torch.get_rng_state(),
                "py_rng": random.getstate(),
                "finished_phases": {k: v.fields() for k, v in self.run.results.items()},
                "pending_evaluations": [p.fields() for p in loop.pending],
            },
        }
        if loop.drift_start is not None:
            fields["runner"]["drift_start"] = loop.drift_start
        replay = loop.checkpoint_replay if checkpoint.save_replay else None
        save_checkpoint(
            self.rundir.checkpoint_path(state.epoch, self._label(loop)), loop.agent, replay, fields
        )
        self.rundir.prune(checkpoint.keep_last)

    def clear_torn(self) -> None:
        """Delete the temporary files of saves cut short by a kill (their rename never happened)."""
        folder = self.rundir.checkpoints
        # atomic_save's .<name>.<random>.tmp, and atomic_write_text's .<name>.tmp-<pid>
        for torn in [*folder.glob(".*.tmp"), *folder.glob(".*.tmp-*")]:
            torn.unlink(missing_ok=True)

    def _fields(self, loop: PhaseLoop, best: bool) -> CheckpointFields:
        return {
            "config_toml": self.config_toml,
            "seed": self.run.seed,
            "phase": loop.phase.name,
            "phase_envs": list(loop.phase.envs),
            "epoch": loop.evaluated.epoch if best and loop.evaluated else loop.state.epoch,
            "best": best,
            "mean_success": loop.state.best_mean_success,
        }

    def _label(self, loop: PhaseLoop) -> str | None:
        """The phase's name in file names, in a run with several phases."""
        return loop.phase.name if len(self.run.phases) > 1 else None
