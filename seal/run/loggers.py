"""Loop callbacks that mirror a run's scalars to TensorBoard and to Weights & Biases.

The CSV files of the run directory (`seal.run.rundir`) are the record; these loggers only
mirror what the phase loop writes to them, at the same steps (the phase's gradient steps):

    eval/<env>/<task>/success, eval/<env>/<task>/return    every evaluation (metrics.csv)
    charts/<env>/mean_success                              every evaluation
    losses/<env>/<key>, charts/<env>/<key>                 every train.csv row (keys ending in "loss"
                                                           go under losses/)

`AlignmentLogger` is no mirror: in a joint SEAL run of the transfer testbed's two envs it
measures, at every evaluation, how alike the two translators map one world (linear CKA,
`seal.learner.probes`), appends the rows `alignment/cka_translator` and `alignment/cka_trunk` to
train.csv and hands them to the other callbacks' `on_train_log`, so the mirrors log them too.

`[logging] tensorboard` turns on `TensorBoardLogger` (events under tb/<phase>/), `[logging] wandb`
("offline" or "online") turns on `WandbLogger` (files under wandb/; needs the `wandb` extra).
"""

from __future__ import annotations

import contextlib
import os
import secrets
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from seal.errors import SealError
from seal.run.loop import LoopCallback
from seal.run.rundir import atomic_write_text

if TYPE_CHECKING:
    from torch.utils.tensorboard import SummaryWriter

    from seal.protocols.config import ProtocolConfig
    from seal.run.loop import PhaseLoop
    from seal.run.rundir import TrainRow

WANDB_EXTRA_HINT = 'pip install -e ".[wandb]"'
"""How to install the optional wandb extra (named in the error when it is missing)."""


def eval_scalars(loop: PhaseLoop) -> dict[str, float]:
    """The scalars of the loop's latest evaluation: per-task success and return, per-env mean
    success, and the critic probe's rows (charts/<env>/eval_q_ratio/<task>, ...)."""
    scalars: dict[str, float] = {}
    for r in loop.last_rows:
        scalars[f"eval/{r['env']}/{r['task']}/success"] = float(r["success"])
        scalars[f"eval/{r['env']}/{r['task']}/return"] = float(r["return"])
    for env, per_task in loop.state.last_success.items():
        scalars[f"charts/{env}/mean_success"] = float(np.mean(list(per_task.values())))
    return {**scalars, **train_scalars(loop.last_critic_rows)}


def train_scalars(rows: Sequence[TrainRow]) -> dict[str, float]:
    """train.csv rows as scalars: losses/<env>/<key> for keys ending in "loss", else charts/<env>/<key>."""
    scalars: dict[str, float] = {}
    for r in rows:
        group = "losses" if str(r["key"]).endswith("loss") else "charts"
        scalars[f"{group}/{r['env']}/{r['key']}"] = float(r["value"])
    return scalars


class ScalarLogger(LoopCallback):
    """A loop callback that writes the evaluation and training scalars at the phase's gradient steps."""

    def write(self, scalars: Mapping[str, float], step: int, loop: PhaseLoop) -> None:
        """Write `scalars` at gradient step `step`."""
        raise NotImplementedError

    def flush(self) -> None:
        """Push what is buffered to disk."""

    def close(self) -> None:
        """End the logger (the `Run` calls this once, after its last phase)."""

    def on_evaluation(self, loop: PhaseLoop) -> None:
        assert loop.evaluated is not None
        self.write(eval_scalars(loop), loop.evaluated.grad_steps, loop)

    def on_train_log(self, loop: PhaseLoop, rows: Sequence[TrainRow]) -> None:
        if rows:
            self.write(train_scalars(rows), int(rows[0]["grad_steps"]), loop)

    def on_checkpoint(self, loop: PhaseLoop) -> None:
        self.flush()


ALIGNMENT_STATES = 1024
"""Testbed states the alignment logger feeds each env under each of the 4 task pairs."""
ALIGNMENT_SEED = 0
"""Seed of those states' own generator: the same states at every evaluation, no draw from the run's."""


def alignment_envs(config: ProtocolConfig) -> tuple[str, str] | None:
    """(point-world env, point_view env) of a joint SEAL run whose envs are exactly those two; else None."""
    from seal.learner.probes import POINT_VIEW, POINT_WORLD

    if config.kind != "joint" or config.agent.architecture != "seal" or len(config.envs) != 2:
        return None
    world = [e for e, c in config.envs.items() if c.adapter in POINT_WORLD]
    view = [e for e, c in config.envs.items() if c.adapter == POINT_VIEW]
    return (world[0], view[0]) if len(world) == len(view) == 1 else None


class AlignmentLogger(ScalarLogger):
    """At every evaluation: linear CKA of the two testbed envs' translator (and trunk) outputs, as train rows.

    One world seen by both envs (`seal.envs.testbed.paired_states`), each env's one-hot set to
    corresponding tasks (`seal.learner.probes.shared_world_cka`). The rows go under the point_view env
    (`target`); forward passes without gradient on states of the logger's own generator, so the
    run learns exactly as it would without it.
    """

    def __init__(self, world_env: str, view_env: str) -> None:
        self.world_env, self.view_env = world_env, view_env

    def on_evaluation(self, loop: PhaseLoop) -> None:
        from seal.learner.probes import shared_world_cka

        model, evaluated = loop.model, loop.evaluated
        envs = (self.world_env, self.view_env)
        if loop.phase.aligned or not set(envs) <= set(loop.phase.envs) or evaluated is None:
            return
        agent = evaluated.agent  # the policy evaluated (an asynchronous evaluation's snapshot)
        cka = shared_world_cka(
            *(agent, model.agent_env[self.world_env], model.adapters[self.world_env]),
            *(agent, model.agent_env[self.view_env], model.adapters[self.view_env]),
            n=ALIGNMENT_STATES,
            seed=ALIGNMENT_SEED,
        )
        rows: list[TrainRow] = [
            {
                "seed": loop.owner.seed,
                "phase": loop.phase.name,
                "epoch": evaluated.epoch,
                "grad_steps": evaluated.grad_steps,
                "env": self.view_env,
                "key": f"alignment/cka_{part}",
                "value": value,
            }
            for part, value in cka.items()
        ]
        loop.owner.rundir.log_train(rows)
        for callback in loop.callbacks:
            if callback is not self:
                callback.on_train_log(loop, rows)

    def on_train_log(self, loop: PhaseLoop, rows: Sequence[TrainRow]) -> None:
        """Nothing: this logger makes rows, it mirrors none."""

    def write(self, scalars: Mapping[str, float], step: int, loop: PhaseLoop) -> None:
        """Nothing (see `on_train_log`)."""


class DriftLogger(ScalarLogger):
    """[logging] drift: at every evaluation, each env's pieces' relative distance from the phase's
    start (`seal.learner.drift`: ||W - W0|| / ||W0||, the piece's parameters concatenated), as
    train rows `drift/<piece>` under the env, of the policy evaluated (an asynchronous
    evaluation's snapshot). No gradient and no random draw: the run learns exactly as without it."""

    def on_evaluation(self, loop: PhaseLoop) -> None:
        from seal.learner.drift import relative_drift

        evaluated, start = loop.evaluated, loop.drift_start
        if evaluated is None or start is None:
            return
        drift = relative_drift(evaluated.agent, start, loop.model.agent_env)
        rows: list[TrainRow] = [
            {
                "seed": loop.owner.seed,
                "phase": loop.phase.name,
                "epoch": evaluated.epoch,
                "grad_steps": evaluated.grad_steps,
                "env": env,
                "key": f"drift/{piece}",
                "value": value,
            }
            for (env, piece), value in drift.items()
            if np.isfinite(value)
        ]
        loop.owner.rundir.log_train(rows)
        for callback in loop.callbacks:
            if callback is not self:
                callback.on_train_log(loop, rows)

    def on_train_log(self, loop: PhaseLoop, rows: Sequence[TrainRow]) -> None:
        """Nothing: this logger makes rows, it mirrors none."""

    def write(self, scalars: Mapping[str, float], step: int, loop: PhaseLoop) -> None:
        """Nothing (see `on_train_log`)."""


class TensorBoardLogger(ScalarLogger):
    """TensorBoard events, one TensorBoard run per phase under <run_dir>/tb/<phase>.

    Each phase's gradient steps start again at 0, so its own run keeps phases from drawing over
    one another. `purge` maps a phase to the step from which its events, written before a resumed
    checkpoint, are hidden (TensorBoard's purge_step); phases not in it are untouched.
    """

    def __init__(self, run_dir: Path, purge: Mapping[str, int] | None = None) -> None:
        from torch.utils.tensorboard import SummaryWriter

        self._summary_writer = SummaryWriter
        self.root = Path(run_dir) / "tb"
        self.purge = dict(purge or {})
        self.writers: dict[str, SummaryWriter] = {}

    def _writer(self, phase: str) -> SummaryWriter:
        """The phase's writer, opened at its first event (with the purge when it is the phase's)."""
        if phase not in self.writers:
            self.writers[phase] = self._summary_writer(
                str(self.root / phase), purge_step=self.purge.get(phase)
            )
        return self.writers[phase]

    def write(self, scalars: Mapping[str, float], step: int, loop: PhaseLoop) -> None:
        writer = self._writer(loop.phase.name)
        for tag, value in scalars.items():
            writer.add_scalar(tag, value, step)

    def flush(self) -> None:
        for writer in self.writers.values():
            writer.flush()

    def close(self) -> None:
        for writer in self.writers.values():
            writer.close()
        self.writers = {}


class WandbLogger(ScalarLogger):
    """A Weights & Biases run under <run_dir>/wandb, "offline" (never touches the network) or "online".

    The run id is kept in <run_dir>/wandb/run_id, so a resumed run continues the same wandb run.
    Each log carries `grad_steps` and `phase`; the scalars are plotted against `grad_steps`.
    """

    def __init__(self, run_dir: Path, mode: str, config: ProtocolConfig) -> None:
        wandb = import_wandb(mode)
        from seal.protocols.loader import config_to_dict

        run_dir = Path(run_dir)
        folder = run_dir / "wandb"
        folder.mkdir(parents=True, exist_ok=True)
        if mode == "offline":
            os.environ["WANDB_MODE"] = "offline"
        self.run = wandb.init(
            project=config.name or "seal",
            group=run_dir.parent.name,
            name=f"{run_dir.parent.name}/{run_dir.name}",
            id=wandb_run_id(folder),
            resume="allow",
            dir=str(folder),
            mode=mode,
            config=config_to_dict(config),
        )
        self.run.define_metric("grad_steps")
        self.run.define_metric("*", step_metric="grad_steps")

    def write(self, scalars: Mapping[str, float], step: int, loop: PhaseLoop) -> None:
        if self.run is not None:
            self.run.log({**scalars, "grad_steps": step, "phase": loop.phase.name})

    def close(self) -> None:
        if self.run is not None:
            self.run.finish()
            self.run = None


def import_wandb(mode: str) -> ModuleType:
    """The wandb module; a one-line SealError naming the extra to install when it is missing."""
    try:
        import wandb
    except ImportError:
        raise SealError(
            f"logging.wandb = {mode!r} needs the wandb package; install the extra: {WANDB_EXTRA_HINT}"
        ) from None
    return wandb


def wandb_run_id(folder: Path) -> str:
    """The wandb run id kept in `folder`/run_id, made (and saved) on the run's first start."""
    path = folder / "run_id"
    if path.is_file():
        saved = path.read_text().strip()
        if saved:
            return saved
    run_id = secrets.token_hex(8)
    atomic_write_text(path, run_id + "\n")
    return run_id


def open_loggers(
    config: ProtocolConfig, run_dir: Path, purge: Mapping[str, int] | None = None
) -> list[ScalarLogger]:
    """The loggers `[logging]` turns on for one run (TensorBoard is skipped if not installed),
    then, in a joint run of the testbed's two envs, the `AlignmentLogger`, then with
    logging.drift the `DriftLogger`; `purge`: per phase,
    the step from which a resumed run hides events (`TensorBoardLogger`)."""
    loggers: list[ScalarLogger] = []
    if config.logging.tensorboard:
        with contextlib.suppress(ImportError):  # tensorboard missing: the CSVs remain the record
            loggers.append(TensorBoardLogger(run_dir, purge))
    if config.logging.wandb != "off":
        loggers.append(WandbLogger(run_dir, config.logging.wandb, config))
    testbed = alignment_envs(config)
    if testbed is not None:
        loggers.append(AlignmentLogger(*testbed))
    if config.logging.drift:
        loggers.append(DriftLogger())
    return loggers
