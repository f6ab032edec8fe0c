"""`[transfer] map`: one env of a run also starts from the transfer checkpoint, through an env map.

A map (`seal.envs.EnvMap`, named by `transfer.map`) names two adapters. The run's env of its
target adapter is started from the checkpoint's env named as the run's env of its source adapter
(the pre-training saved it under the same [envs.<name>]), after `transfer_from` has copied the
checkpoint as usual; `seal.learner.transfer.map_env` does the rewriting. The transfer testbed's
oracle rungs use it (docs/transfer_testbed.md, round 5).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from seal.envs import EnvAdapter, EnvMap, env_map
from seal.errors import ConfigError, SealError
from seal.learner.agent_state import AgentState
from seal.learner.sac import Agent
from seal.learner.transfer import map_env
from seal.protocols.config import ProtocolConfig


@dataclass(frozen=True)
class MappedStart:
    """Which env of the run starts from which env of the checkpoint, through which map."""

    source: str
    """The env (its [envs.<name>], in the checkpoint and in the run) the map reads."""
    target: str
    """The run's env that is started."""
    known: EnvMap
    task_order: tuple[int, ...]
    """For each of the target's tasks, the index of its task among the source's."""
    modules: tuple[str, ...]
    """The pieces mapped: `transfer.map_modules` (`TransferConfig.pieces`)."""
    unmapped_log_std: float
    """`transfer.map_unmapped_log_std`."""

    def apply(self, agent: Agent, state: AgentState) -> None:
        """Rewrite `agent`'s target env from `state`'s source env (after `transfer_from`)."""
        map_env(
            agent,
            state,
            self.source,
            self.target,
            obs_map=self.known.obs,
            task_order=self.task_order,
            actions=self.known.actions,
            modules=self.modules,
            unmapped_log_std=self.unmapped_log_std,
        )


def mapped_start(
    config: ProtocolConfig, adapters: Mapping[str, EnvAdapter], state: AgentState
) -> MappedStart | None:
    """The run's `MappedStart` under [transfer] map (None without one); ConfigError naming
    `transfer.map` when the protocol's envs or the checkpoint's do not fit the map."""
    transfer = config.transfer
    if transfer is None or not transfer.map:
        return None
    known = env_map(transfer.map)
    where = f"{config.path}: transfer.map = {transfer.map!r} ({known.source} -> {known.target})"

    def env_of(adapter: str) -> str:
        names = [name for name, a in adapters.items() if a.name == adapter]
        if len(names) != 1:
            have = {name: a.name for name, a in adapters.items()}
            raise ConfigError(
                f"{where}: needs exactly one [envs.<name>] with adapter {adapter!r}, got {len(names)} (envs: {have})"
            )
        return names[0]

    source, target = env_of(known.source), env_of(known.target)
    saved = {spec["name"]: spec for spec in state["specs"]}
    if source not in saved:
        raise ConfigError(
            f"{where}: the checkpoint has no env {source!r} (it has {sorted(saved)}); the map reads the checkpoint's env named as this protocol's [envs.{source}]"
        )
    adapter = adapters[source]
    mine = (adapter.obs_dim, adapter.act_dim, len(adapter.tasks))
    theirs = (saved[source]["obs_dim"], saved[source]["act_dim"], saved[source]["num_tasks"])
    if mine != theirs:
        raise ConfigError(
            f"{where}: the checkpoint's env {source!r} has (obs_dim, act_dim, tasks) = {theirs}, this protocol's {mine}; the pre-training needs the same [envs.{source}]"
        )
    try:
        order = known.task_order(adapter.tasks, adapters[target].tasks)
    except SealError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    return MappedStart(
        source, target, known, tuple(order), transfer.pieces, transfer.map_unmapped_log_std
    )
