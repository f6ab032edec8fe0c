"""What a `seal run` checkpoint holds: the fields it adds to `seal.learner.checkpoint`'s own.

An epoch checkpoint (ckpt-*.pt, `EpochCheckpoint`) is the point a resume continues from; best.pt
(`BestCheckpoint`) is a policy. The `Checkpointer` (`seal.protocols.checkpointing`) writes them,
the loop (`seal.protocols.phase`) restores from an epoch checkpoint, and the run
(`seal.protocols.runner`) reads both; this module imports none of them.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NotRequired, TypedDict

import torch

if TYPE_CHECKING:
    from seal.learner.replay import ReplayState
    from seal.learner.sac import AgentState
    from seal.protocols.workers import PendingFields


class PhaseStateFields(TypedDict):
    """`PhaseState.fields()`: a phase's counters as a checkpoint holds them (see `PhaseState` for
    each key; tests/protocols/test_checkpointing.py holds the keys to its fields). A checkpoint
    written before a key was kept lacks it, and `PhaseState(**fields)` gives it its default."""

    epoch: int
    grad_steps: int
    env_steps: dict[str, list[int]]
    best_mean_success: float
    wall_s: float
    anchor_epoch: int
    last_success: dict[str, dict[str, float]]
    reached: dict[str, dict[str, float]]
    timeline_rows: int
    log_sums: NotRequired[dict[str, float]]
    log_updates: NotRequired[int]
    seconds: NotRequired[dict[str, float]]
    calls: NotRequired[dict[str, int]]
    demos: NotRequired[dict[str, dict[str, float]]]
    collected_lengths: NotRequired[dict[str, int]]
    evaluated_at: NotRequired[int]


class RunnerFields(TypedDict):
    """An epoch checkpoint's "runner" field: what resume needs besides the agent, replay and scheduler."""

    phase_index: int
    state: PhaseStateFields
    """The phase's `PhaseState`."""
    rows: dict[str, int]
    """CSV file -> its rows when the checkpoint was taken (`RunDir.row_counts`)."""
    torch_rng: torch.Tensor
    py_rng: tuple[Any, ...]
    """random.getstate(), typed as the standard library types it (lists instead of tuples once read back)."""
    finished_phases: dict[str, PhaseStateFields]
    """Phase name -> its final `PhaseState`."""
    pending_evaluations: list[PendingFields]
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
    """`Scheduler.state_dict()`: each scheduler's own keys."""
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
