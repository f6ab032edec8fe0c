"""What a rollback restores: the start of the epoch under way, which the loop keeps in memory.

While a run handles SIGTERM and SIGINT (`checkpoint.on_signal`, `seal.run.preemption`),
the phase loop (`seal.run.loop.PhaseLoop`) takes an `EpochMark` at every epoch's start.
When a signal rolls the epoch back, the loop restores its agent, scheduler, counters, RNG states
and CSV rows from the mark and saves the replay as a `RolledBackReplay`: the checkpoint it
writes is the one a checkpoint at the epoch's start would have been. The replay itself is not
copied: the mark keeps its counters and the few ring slots one episode per task can overwrite.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

if TYPE_CHECKING:
    from seal.learner.agent_state import AgentState
    from seal.learner.replay import MultiTaskReplay, ReplayState
    from seal.run.checkpoint_fields import PhaseStateFields
    from seal.run.workers import PendingEvaluation


@dataclass
class ReplayMark:
    """The replay at an epoch's start, as far as the epoch can change it: its counters, its
    sampling stream, and the filled ring slots that one more episode per task would overwrite."""

    size: dict[str, np.ndarray]
    position: dict[str, np.ndarray]
    consumed: dict[str, np.ndarray]
    generators: dict[str, torch.Tensor]
    """Each env's row stream (common random numbers: one per env)."""
    overwritten: dict[str, tuple[np.ndarray, np.ndarray, dict[str, torch.Tensor]]]
    """env -> (task rows, slots, field -> those slots' values on the CPU), where the ring can wrap."""

    @classmethod
    def take(cls, replay: MultiTaskReplay, steps: Mapping[str, int]) -> ReplayMark:
        """`steps`: replay env -> the most transitions a task adds in one epoch (one episode)."""
        overwritten = {}
        for env, size in replay.size.items():
            cap = replay.capacity_per_task[env]
            span = np.arange(min(int(steps[env]), cap))
            slots = (replay.position[env][:, None] + span[None, :]) % cap
            tasks = np.broadcast_to(np.arange(len(size))[:, None], slots.shape)
            filled = slots < size[:, None]
            if filled.any():  # the ring is full, or wraps within one episode
                rows, cols = tasks[filled], slots[filled]
                store = replay.storage[env]
                index = (torch.from_numpy(rows), torch.from_numpy(cols))
                index = tuple(i.to(replay.device) for i in index)
                values = {f: t[index].to("cpu", copy=True) for f, t in store.items()}
                overwritten[env] = (rows, cols, values)
        return cls(
            size={e: v.copy() for e, v in replay.size.items()},
            position={e: v.copy() for e, v in replay.position.items()},
            consumed={e: v.copy() for e, v in replay.consumed.items()},
            generators={e: g.get_state() for e, g in replay.generators.items()},
            overwritten=overwritten,
        )


class RolledBackReplay:
    """The replay as a `ReplayMark` saw it, for the checkpoint a rollback writes (only `state_dict`).

    Its `state_dict` is the one a checkpoint at the epoch's start would have held: the rows the
    epoch added are cut (zeroed where another task's rows keep the width), the slots it
    overwrote restored, the counters and the sampling stream the mark's.
    """

    def __init__(self, replay: MultiTaskReplay, mark: ReplayMark) -> None:
        self.replay, self.mark = replay, mark

    def state_dict(self) -> ReplayState:
        mark = self.mark
        state = self.replay.state_dict()  # copies, so the live replay is left as it is
        state["generators"] = dict(mark.generators)
        for env, saved in state["envs"].items():
            size, patch = mark.size[env], mark.overwritten.get(env)
            filled = int(size.max())
            for key in [k for k in saved if k not in ("size", "position", "consumed")]:
                rows = saved[key]
                if patch is not None:
                    rows[torch.from_numpy(patch[0]), torch.from_numpy(patch[1])] = patch[2][key]
                for task, n in enumerate(size.tolist()):
                    rows[task, n:] = 0.0
                saved[key] = rows[:, :filled]
            saved["size"] = torch.from_numpy(size.copy())
            saved["position"] = torch.from_numpy(mark.position[env].copy())
            saved["consumed"] = torch.from_numpy(mark.consumed[env].copy())
        return state


@dataclass
class EpochMark:
    """The loop at an epoch's start, kept in memory while the run handles signals
    (`checkpoint.on_signal`): what a rollback restores, then saves as that epoch's checkpoint."""

    state: PhaseStateFields
    """The phase's counters (`PhaseState.fields`), wall time at the mark."""
    agent: AgentState
    """The agent's `state_dict`, copied to the CPU."""
    scheduler: dict[str, Any]
    pending: list[PendingEvaluation]
    rows: dict[str, int]
    """CSV rows written by then (`RunDir.row_counts`)."""
    torch_rng: torch.Tensor
    py_rng: tuple[Any, ...]
    replay: ReplayMark
