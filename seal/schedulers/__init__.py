"""Schedulers: which (env, task) pairs collect each epoch and how the update batch is composed.

The interface is in `seal.schedulers.base` (Plan, Progress, Scheduler, ScoreRequest); the kinds
are the data-ratio schedules (`ratio.py`), SMT (`smt.py`) and the curricula (`curriculum.py`);
`registry.py` turns a protocol's [scheduler] table into a config and a config into a scheduler.
"""

from __future__ import annotations

from seal.schedulers.base import (
    GRAD_STEPS_COLLECTED,
    Plan,
    Progress,
    Scheduler,
    SchedulerConfig,
    ScoreRequest,
    TaskKey,
)
from seal.schedulers.curriculum import (
    CurriculumPhase,
    CurriculumV1Config,
    CurriculumV2Config,
    ProgressivePhase,
)
from seal.schedulers.ratio import ConstantRatioConfig, SteppedRatioConfig, UniformConfig
from seal.schedulers.registry import SCHEDULER_CONFIGS, build_scheduler, config_from_table
from seal.schedulers.smt import SMTConfig

__all__ = [
    "GRAD_STEPS_COLLECTED",
    "SCHEDULER_CONFIGS",
    "ConstantRatioConfig",
    "CurriculumPhase",
    "CurriculumV1Config",
    "CurriculumV2Config",
    "ProgressivePhase",
    "SMTConfig",
    "SteppedRatioConfig",
    "UniformConfig",
    "build_scheduler",
    "config_from_table",
    "Plan",
    "Progress",
    "Scheduler",
    "SchedulerConfig",
    "ScoreRequest",
    "TaskKey",
]
