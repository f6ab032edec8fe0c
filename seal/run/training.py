"""A phase's updates: the epoch's gradient steps on the replay (evaluating every K steps where
`evaluation.every_grad_steps` says), the agent's log values summed on the device and read back
in one sync (`read_logs`), and the update time and call counts they add to the phase's counters."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np
import torch

from seal.errors import SealError, TrainingDivergedError

if TYPE_CHECKING:
    from seal.run.parts import LoopParts
    from seal.schedulers.base import Plan


class Training:
    """The phase's gradient steps and the log values they leave (`state.log_sums`)."""

    def __init__(self, loop: LoopParts) -> None:
        self.loop = loop
        model = loop.model
        self.id_maps = {
            model.agent_env[e]: torch.as_tensor(model.aligned_ids(e), dtype=torch.long)
            for e in loop.phase.envs
        }
        """Pad-and-fine-tune: a task's local id -> the id the agent's heads use."""
        self.total_tasks = sum(len(t) for t in model.env_tasks.values())
        self.batch_now: dict[str, np.ndarray] = {}
        """The per-task batch of the latest update (metrics.csv's `batch`)."""
        self.pending_logs: dict[tuple[str, ...], torch.Tensor] = {}
        """Sums on the device of the agent's log values (by name tuple) since `read_logs`."""
        self.pending_since = loop.agent.num_updates

    def train(self, plan: Plan, lengths: Mapping[str, int]) -> None:
        """The epoch's gradient steps, once every env has finished its warm-up (evaluating every K steps)."""
        loop = self.loop
        state, model, cfg, agent, replay = loop.state, loop.model, loop.cfg, loop.agent, loop.replay
        self.batch_now = {e: np.zeros(len(model.env_tasks[e]), np.int64) for e in loop.phase.envs}
        warm = any(sum(state.env_steps[e]) < cfg.training.warmup_steps for e in loop.phase.envs)
        if warm or not lengths:
            return
        counts = plan.batch_counts(cfg.training.batch_per_task * self.total_tasks)
        sample_counts = {
            model.agent_env[e]: np.asarray(c, dtype=np.int64)
            for e, c in counts.items()
            if int(np.sum(c)) > 0
        }
        self.batch_now = {e: np.asarray(c, dtype=np.int64) for e, c in counts.items()}
        if not sample_counts:
            # Every task of this run rounds to 0 transitions (scheduler.absent envs hold all but a
            # sliver of the share): no update this epoch, as the matched joint run draws none of
            # this run's transitions either.
            return
        every = cfg.evaluation.every_grad_steps
        with loop.timed("update", count=False):
            agent.refresh_beliefs(replay)  # smt_gru with encoder_refresh_interval
        with loop.timed("update", count=False):  # a mid-epoch evaluation counts to itself
            steps = self._grad_steps(plan, lengths)
            last_epoch = state.epoch + 1 >= loop.phase.epochs
            for step in range(steps):
                batches = replay.sample(sample_counts)
                if model.alignment is not None:
                    batches = {
                        k: b._replace(task_ids=self.id_maps[k].to(b.task_ids.device)[b.task_ids])
                        for k, b in batches.items()
                    }
                names, values = agent.update_on_device(batches)
                sums = self.pending_logs.get(names)
                self.pending_logs[names] = values if sums is None else sums + values
                encoder_logs = agent.update_encoder(replay)
                if encoder_logs is not None:  # smt_gru, every agent.encoder_interval updates
                    names, values = encoder_logs
                    sums = self.pending_logs.get(names)
                    self.pending_logs[names] = values if sums is None else sums + values
                state.grad_steps += 1
                state.log_updates += 1
                state.calls["update"] = state.calls.get("update", 0) + 1
                if agent.last_ratio_lever is not None:
                    lever = agent.last_ratio_lever
                    state.log_sums["charts/ratio_lever"] = (
                        state.log_sums.get("charts/ratio_lever", 0.0) + lever
                    )
                if every and state.grad_steps % every == 0:
                    # mid-epoch: the update-count grid is K x batch; on the phase's last update
                    # it is the phase's last evaluation (the epoch's end does not repeat it)
                    loop.evaluate(final=last_epoch and step == steps - 1)
            self.read_logs()

    def read_logs(self) -> None:
        """Fetch the updates' log sums from the device (one sync) into `state.log_sums`.

        Runs at the end of every epoch's updates and before every evaluation, so a diverged run
        stops before it evaluates or writes a checkpoint; the sync's wait counts as update time.
        """
        loop = self.loop
        pending, self.pending_logs = self.pending_logs, {}
        first, self.pending_since = self.pending_since, loop.agent.num_updates
        if not pending:
            return
        with loop.timed("update", count=False):
            for names, sums in pending.items():
                try:
                    values = loop.agent.read_logs(names, sums, first_update=first)
                except TrainingDivergedError as exc:
                    rundir = loop.owner.rundir
                    raise SealError(
                        f"{rundir.path}: training diverged in phase {loop.phase.name!r} by gradient step {loop.state.grad_steps} ({exc.what}); last good checkpoint: {rundir.latest_checkpoint() or 'none yet'}"
                    ) from None
                for k, v in values.items():
                    loop.state.log_sums[k] = loop.state.log_sums.get(k, 0.0) + v

    def _grad_steps(self, plan: Plan, collected_lengths: Mapping[str, int]) -> int:
        from seal.schedulers import GRAD_STEPS_COLLECTED

        if plan.grad_steps is not None:
            if plan.grad_steps == GRAD_STEPS_COLLECTED:
                return int(sum(collected_lengths.values()))
            return int(plan.grad_steps)
        n = self.loop.cfg.training.grad_steps_per_epoch
        # -1: the longest episode collected this epoch (see TrainingConfig.grad_steps_per_epoch).
        return int(max(collected_lengths.values())) if n == -1 else int(n)
