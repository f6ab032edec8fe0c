"""A phase's typed parts, built when its loop starts: the agent (fresh, transferred or
fine-tuned: `PhaseOwner.initial_agent`), logging.drift's start weights, the replay, the scheduler
and the counters, all restored from the checkpoint's payload when the phase resumes."""

from __future__ import annotations

import random
from typing import TYPE_CHECKING, Any, NamedTuple

import torch

from seal.errors import SealError
from seal.run.state import PhaseState
from seal.seeding import derive_seed

if TYPE_CHECKING:
    from seal.learner.drift import DriftStart
    from seal.learner.replay import MultiTaskReplay
    from seal.learner.sac import Agent
    from seal.run.checkpoint_fields import EpochCheckpoint
    from seal.run.parts import PhaseOwner
    from seal.run.phase_model import Phase, PhaseModel
    from seal.schedulers.base import Scheduler


class PhaseParts(NamedTuple):
    """What a phase's loop trains (`build_phase_parts`)."""

    agent: Agent
    drift_start: DriftStart | None
    """logging.drift: W0, each env's pieces at the phase's start, after any mapped start
    (`seal.learner.drift`); a resumed phase takes its checkpoint's, as the start is not redone."""
    replay: MultiTaskReplay
    scheduler: Scheduler
    state: PhaseState


def build_phase_parts(
    run: PhaseOwner, phase: Phase, model: PhaseModel, payload: EpochCheckpoint | None
) -> PhaseParts:
    """The phase's agent, drift start, replay, scheduler and counters, in that order (each draws
    its seed from (run seed, part, phase)); restored from `payload` when it is a resume."""
    from seal.schedulers.ratio import UniformConfig

    cfg = run.config
    agent = run.initial_agent(phase, model, resuming=payload is not None)
    drift_start = _drift_start(run, agent, model, payload) if cfg.logging.drift else None
    replay = cfg.replay.build(
        model.replay_specs, device=run.device, seed=derive_seed(run.seed, "replay", phase.index)
    )
    scheduler = (cfg.scheduler or UniformConfig()).build(
        model.env_tasks,
        seed=derive_seed(run.seed, "scheduler", phase.index),
        adapters={e: cfg.envs[e].adapter for e in phase.envs},
        episode_lengths={e: run.adapters[e].episode_length for e in phase.envs},
        source=cfg.path,
    )
    state = PhaseState(env_steps={e: [0] * len(t) for e, t in model.env_tasks.items()})
    if payload is not None:
        state = _restore(run, payload, agent, replay, scheduler)
    return PhaseParts(agent, drift_start, replay, scheduler, state)


def _drift_start(
    run: PhaseOwner, agent: Agent, model: PhaseModel, payload: EpochCheckpoint | None
) -> DriftStart:
    """W0 of the fresh phase's agent (before any restore), or the checkpoint's, on the agent's device."""
    from seal.learner.drift import start_weights

    if payload is None:
        return start_weights(agent, model.agent_env)
    saved = payload["runner"].get("drift_start")
    if saved is None:
        raise SealError(
            f"{run.rundir.path}: logging.drift is on, but the checkpoint holds no drift start (W0) to measure from; it was written without logging.drift"
        )
    device = agent.device
    return {env: {p: t.to(device) for p, t in pieces.items()} for env, pieces in saved.items()}


def _restore(
    run: PhaseOwner,
    payload: EpochCheckpoint,
    agent: Agent,
    replay: MultiTaskReplay,
    scheduler: Scheduler,
) -> PhaseState:
    """Agent, replay, scheduler and RNG streams from a checkpoint's payload; its counters."""
    agent.load_state_dict(payload["agent"])
    saved = payload.get("replay")
    if saved is None:
        raise SealError(
            f"{run.rundir.path}: the checkpoint holds no replay (checkpoint.save_replay = false), so the run cannot resume exactly"
        )
    replay.load_state_dict(saved)
    scheduler.load_state_dict(payload["scheduler"])
    state = PhaseState(**payload["runner"]["state"])
    torch.set_rng_state(payload["runner"]["torch_rng"])
    random.setstate(_tuple_state(payload["runner"]["py_rng"]))
    return state


def _tuple_state(state: Any) -> Any:
    """random.getstate() after a round trip through torch.save (lists back to tuples)."""
    if isinstance(state, list):
        return tuple(_tuple_state(s) for s in state)
    return state
