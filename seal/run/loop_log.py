"""What a phase's loop logs at the end of its epochs: train.csv's training curves (the mean of
every logged value over `logging.train_interval` epochs, named by `train_rows_for`), then the
callbacks' `on_train_log`; the scheduler's timeline (scheduler.csv); the callbacks'
`on_epoch_end` (the progress bar). The CSVs are the run directory's (`seal.run.rundir`); the
TensorBoard and wandb loggers are callbacks (`seal.run.loggers`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from seal.run.parts import LoopParts
    from seal.run.phase_model import PhaseModel
    from seal.run.rundir import TrainRow

# The agent's log keys ("losses/<env>/critic", "charts/<env>/alpha/<id>") -> train.csv keys.
_TRAIN_KEYS = {
    "losses/critic": "critic_loss",
    "losses/actor": "actor_loss",
    "losses/qf1": "qf1_loss",
    "losses/qf2": "qf2_loss",
    "losses/alpha": "alpha_loss",
    "charts/mean_q": "mean_q",
    "charts/entropy": "entropy",
}


class LoopLog:
    """The loop's end-of-epoch logging (see the module docstring)."""

    def __init__(self, loop: LoopParts) -> None:
        self.loop = loop

    def training_curves(self, last_epoch: bool) -> None:
        """train.csv: the mean of every logged value over the interval's updates, when due."""
        loop = self.loop
        state, epoch = loop.state, loop.state.epoch
        if state.log_updates and (epoch % loop.cfg.logging.train_interval == 0 or last_epoch):
            means = {k: v / state.log_updates for k, v in state.log_sums.items()}
            rows = self.train_rows(epoch, state.grad_steps, means)
            with loop.timed("log"), loop.stop.protected():
                loop.owner.rundir.log_train(rows)
                loop.notify("on_train_log", rows)
            state.log_sums, state.log_updates = {}, 0

    def timeline(self) -> None:
        """scheduler.csv: the scheduler's timeline records not written yet."""
        loop = self.loop
        state, timeline = loop.state, loop.scheduler.timeline()
        if len(timeline) > state.timeline_rows:
            with loop.timed("log", count=False):
                loop.owner.rundir.log_scheduler(
                    [{"phase": loop.phase.name, **r} for r in timeline[state.timeline_rows :]]
                )
            state.timeline_rows = len(timeline)

    def epoch_end(self) -> None:
        """The callbacks' `on_epoch_end` (the progress bar)."""
        with self.loop.timed("log", count=False):
            self.loop.notify("on_epoch_end")

    def train_rows(
        self, epoch: int, grad_steps: int, values: Mapping[str, float]
    ) -> list[TrainRow]:
        """train.csv rows of the mean logged values (`train_rows_for` names them)."""
        loop = self.loop
        return [
            {
                "seed": loop.owner.seed,
                "phase": loop.phase.name,
                "epoch": epoch,
                "grad_steps": grad_steps,
                "env": env,
                "key": name,
                "value": float(v),
            }
            for key, value in values.items()
            for env, name, v in train_rows_for(key, value, loop.model)
        ]


def train_rows_for(key: str, value: float, model: PhaseModel) -> list[tuple[str, str, float]]:
    """(env, train.csv key, value) rows for one of the agent's log values.

    "losses/<agent env>/critic" becomes (env, "critic_loss"); "charts/<agent env>/alpha/<id>"
    becomes one "alpha/<task>" row for every task of env whose head id is <id> (under
    pad-and-fine-tune several kitchen tasks share an aligned id, so they share a temperature).
    """
    parts = key.split("/")
    if len(parts) < 3 or parts[1] not in model.env_of_agent:
        return [("", key, value)]
    env = model.env_of_agent[parts[1]]
    if len(parts) == 4 and parts[2] == "alpha" and parts[3].isdigit():
        ids = model.aligned_ids(env)
        return [
            (env, f"alpha/{task}", value)
            for task, i in zip(model.env_tasks[env], ids, strict=True)
            if int(i) == int(parts[3])
        ]
    short = f"{parts[0]}/{'/'.join(parts[2:])}"
    return [(env, _TRAIN_KEYS.get(short, "/".join(parts[2:])), value)]
