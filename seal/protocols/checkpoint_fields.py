"""What a `seal run` checkpoint holds: the fields it adds to `seal.learner.checkpoint`'s own.

An epoch checkpoint (ckpt-*.pt, `EpochCheckpoint`) is the point a resume continues from; best.pt
(`BestCheckpoint`) is a policy. The `Checkpointer` (`seal.protocols.checkpointing`) writes them,
the loop (`seal.protocols.phase`) restores from an epoch checkpoint, and the run
(`seal.protocols.runner`) reads both; this module imports none of them.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, TypedDict

import torch

if TYPE_CHECKING:
    from seal.learner.replay import ReplayState
    from seal.learner.sac import AgentState


class RunnerFields(TypedDict):
    """An epoch checkpoint's "runner" field: what resume needs besides the agent, replay and scheduler."""

    phase_index: int
    state: dict[str, Any]
    """`dataclasses.asdict` of the phase's `PhaseState`."""
    rows: dict[str, int]
    """CSV file -> its rows when the checkpoint was taken (`RunDir.row_counts`)."""
    torch_rng: torch.Tensor
    py_rng: tuple[Any, ...]
    """random.getstate() (lists instead of tuples once read back)."""
    finished_phases: dict[str, dict[str, Any]]
    """Phase name -> `dataclasses.asdict` of its final `PhaseState`."""
    pending_evaluations: list[dict[str, Any]]
    """`PendingEvaluation.fields` of the asynchronous evaluations not yet written (resume re-runs them)."""


class CheckpointFields(TypedDict):
    """The fields `seal run` adds to every checkpoint, beside `seal.learner.checkpoint`'s own."""

    config_toml: str
    seed: int
    phase: str
    phase_envs: list[str]
    epoch: int
    best: bool
    mean_success: float
    """The phase's best mean success so far."""


class EpochFields(CheckpointFields):
    """An epoch checkpoint's (ckpt-*.pt) fields."""

    scheduler: dict[str, Any]
    """`Scheduler.state_dict()`."""
    runner: RunnerFields


class BestFields(CheckpointFields):
    """best.pt's fields (no scheduler, no runner, no replay: it is a policy, not a resume point)."""

    scheduler: None
    runner: None


class EpochCheckpoint(EpochFields):
    """An epoch checkpoint as `read_checkpoint` returns it: the point a resume continues from."""

    seal_checkpoint: int
    agent: AgentState
    """`Agent.state_dict()`."""
    replay: ReplayState | None
    """`MultiTaskReplay.state_dict()` (None with checkpoint.save_replay = false)."""


class BestCheckpoint(BestFields):
    """best.pt as `read_checkpoint` returns it."""

    seal_checkpoint: int
    agent: AgentState
    replay: None


RunCheckpoint = EpochCheckpoint | BestCheckpoint
"""A checkpoint `seal run` writes, either kind (`seal eval` takes both)."""
