"""What a run's phases are and what each phase's agent sees, before any loop runs.

`plan_phases` splits a protocol into its phases (`Phase`); `PhaseModel` says how one phase's agent
meets its envs (specs, names, the pad-and-fine-tune alignment's obs and id transforms);
`build_adapters`, `build_alignment` and `run_agent_config` build what a run, a worker process
and `seal protocol explain` each build for themselves; `seal.seeding.derive_seed` gives every stream of a run
its seed. The loop (`seal.run.loop`), its worker processes (`seal.run.workers`), the
memory estimate (`seal.run.resources`) and the run (`seal.run.runner`) all stand on
this module, which imports none of them.
"""

from __future__ import annotations

import dataclasses
import difflib
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from seal.envs import make_adapter
from seal.envs.base import EnvAdapter
from seal.errors import SealError, SealWarning
from seal.evaluation import AgentPolicy
from seal.protocols.config import ProtocolConfig
from seal.seeding import derive_seed

if TYPE_CHECKING:
    from seal.envs.alignment import Alignment
    from seal.learner.collection import Collector
    from seal.learner.config import AgentConfig, EnvSpec
    from seal.learner.sac import Agent

ALIGNED_ENV = "aligned"
"""The agent's name for the single padded pseudo-environment of pad-and-fine-tune."""
# Acting (collection, evaluation, scheduler scoring) runs on this many torch threads, whatever
# protocol.threads gives the updates: its policy calls are a row per env instance, which a second
# thread only slows, and the idle thread's spinning takes CPU from the collection workers
# (quickstart evaluation: 2.3 s with one thread, 4.6 s with two; scripts/evaluation_seconds.py).
ACTING_THREADS = 1


@dataclass(frozen=True)
class Phase:
    """One training phase of a run: which envs it trains on, for how long, and how the agent sees them."""

    name: str
    index: int
    envs: tuple[str, ...]
    epochs: int
    aligned: bool = False


class PhaseModel:
    """How the agent of one phase meets the envs: its specs, names, and the obs/id transforms."""

    def __init__(
        self,
        config: ProtocolConfig,
        phase: Phase,
        adapters: Mapping[str, EnvAdapter],
        alignment: Alignment | None,
    ) -> None:
        from seal.learner import EnvSpec

        self.phase = phase
        self.adapters = {e: adapters[e] for e in phase.envs}
        self.alignment = alignment if phase.aligned else None
        if self.alignment is None:
            self.agent_env = {e: e for e in phase.envs}
            self.specs = [
                EnvSpec(e, a.obs_dim, a.act_dim, len(a.tasks)) for e, a in self.adapters.items()
            ]
        else:
            (env,) = phase.envs
            a = self.adapters[env]
            self.agent_env = {env: ALIGNED_ENV}
            # The policy outputs the env's own action size (its last layer is per env and is
            # re-initialised at transfer); the critic's action input is padded to the widest env.
            self.specs = [
                EnvSpec(
                    ALIGNED_ENV,
                    self.alignment.obs_dim,
                    a.act_dim,
                    self.alignment.num_ids,
                    act_pad_to=self.alignment.act_dim,
                )
            ]
        # The replay keeps one buffer per task of the env even where tasks share an aligned id
        # (the three kitchen doors), so the per-task update counts stay separate; sampled task
        # ids are mapped to aligned ids before the update.
        # Under smt_gru each stored observation carries its belief and episode step
        # (`seal.learner.task_encoder`): the replay's rows are that much wider.
        self.replay_specs = [
            dataclasses.replace(
                s,
                num_tasks=len(self.env_tasks_of(s.name)),
                obs_dim=s.obs_dim + config.agent.obs_extra,
            )
            for s in self.specs
        ]
        self.env_of_agent = {v: k for k, v in self.agent_env.items()}
        self.env_tasks = {e: tuple(a.tasks) for e, a in self.adapters.items()}

    def specs_with_replay_tasks(self) -> list[EnvSpec]:
        """The replay's specs without the task encoder's columns: raw observations."""
        return [
            dataclasses.replace(r, obs_dim=s.obs_dim)
            for r, s in zip(self.replay_specs, self.specs, strict=True)
        ]

    def env_tasks_of(self, agent_env: str) -> tuple[str, ...]:
        """The tasks of the env the agent calls `agent_env`."""
        env = {v: k for k, v in self.agent_env.items()}[agent_env]
        return tuple(self.adapters[env].tasks)

    def aligned_names(self) -> dict[str, str]:
        """protocol env -> alignment env name (the adapter's name)."""
        return {e: a.name for e, a in self.adapters.items()}

    def policy(self, agent: Agent, deterministic: bool) -> AgentPolicy:
        """The agent as a collector policy over this phase's raw envs."""
        return AgentPolicy(
            agent,
            deterministic=deterministic,
            alignment=self.alignment,
            agent_env=self.agent_env,
            alignment_names=self.aligned_names(),
        )

    def aligned_ids(self, env: str) -> np.ndarray:
        """Local task index -> the id the agent's heads use."""
        if self.alignment is None:
            return np.arange(len(self.env_tasks[env]))
        return self.alignment.task_ids(self.adapters[env].name)


def build_eval_collector(config: ProtocolConfig, model: PhaseModel, seed: int) -> Collector:
    """Evaluation's instances of a phase, several per task, seeded from (run seed, phase) only:
    every evaluation episode resets with a seed of its own (from its draw), so they need no
    re-seeding at checkpoints and a resumed run evaluates exactly as the original did."""
    from seal.learner.collection import evaluation_replicas

    count = sum(len(ts) for ts in model.env_tasks.values())
    return config.training.build_collector(
        model.adapters,
        derive_seed(seed, "eval", model.phase.index),
        replicas=evaluation_replicas(config.evaluation.episodes, count),
    )


def plan_phases(config: ProtocolConfig) -> list[Phase]:
    """The phases of a protocol, by kind."""
    if config.kind == "finetune":
        ft = config.finetune
        assert ft is not None
        return [
            Phase("pretrain", 0, (ft.source,), ft.pretrain_epochs, aligned=True),
            Phase("finetune", 1, (ft.target,), ft.finetune_epochs, aligned=True),
        ]
    return [Phase("train", 0, tuple(config.envs), config.protocol.epochs)]


def build_adapters(
    config: ProtocolConfig, envs: Sequence[str] | None = None
) -> dict[str, EnvAdapter]:
    """The adapters of the protocol's envs (all, or the named ones), with their resolved tasks."""
    names = list(config.envs) if envs is None else list(envs)
    return {
        n: make_adapter(
            config.envs[n].adapter,
            tasks=list(config.envs[n].tasks),
            episode_length=config.envs[n].episode_length,
            **config.envs[n].options,
        )
        for n in names
    }


def build_alignment(config: ProtocolConfig, adapters: Mapping[str, EnvAdapter]) -> Alignment:
    """The pad-and-fine-tune alignment over source then target adapters (Table 3 unless overridden)."""
    from seal.envs.alignment import Alignment, lone_entries

    ft = config.finetune
    assert ft is not None
    table = dict(ft.alignment) or None
    pair = [adapters[ft.source], adapters[ft.target]]
    try:
        alignment = Alignment.build(pair, table)
    except SealError as exc:
        raise SealError(f"{config.path}: finetune.alignment: {exc}") from None
    for key, group in lone_entries(pair, table or {}):
        names = {t for a in pair for t in a.tasks} | set(ft.alignment.values())
        close = difflib.get_close_matches(group, sorted(names - {group}), n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        warnings.warn(
            SealWarning(
                f"{config.path}: finetune.alignment: {key!r} = {group!r} shares its id with no "
                f"other task, which is what leaving the entry out does{hint}"
            ),
            stacklevel=2,
        )
    return alignment


def run_agent_config(config: ProtocolConfig, device: str) -> AgentConfig:
    """The AgentConfig a run trains with on `device`."""
    return dataclasses.replace(config.agent, device=device)
