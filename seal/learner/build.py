"""What an `Agent` is built of: its networks' input segments, the policy, the twin critics and
the per-task log temperatures, for every `agent.architecture` (weights drawn later, by
`Agent._initialise`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import NamedTuple

import torch
from torch import nn

from seal.learner.config import MTRL_ARCHITECTURES, AgentConfig, EnvSpec
from seal.learner.mtrl.network import TaskConditionedNetwork
from seal.learner.networks import PerEnvCritic, Segments, TaskNetwork

Network = TaskNetwork | PerEnvCritic | TaskConditionedNetwork


class Networks(NamedTuple):
    """An agent's networks, keyed by its envs' module keys."""

    actor_segments: dict[str, Segments]
    critic_segments: dict[str, Segments]
    actor: Network
    critic: Network
    log_alpha: nn.ParameterDict


def build_networks(
    specs: Sequence[EnvSpec], config: AgentConfig, keys: Mapping[str, str]
) -> Networks:
    """The policy, the twin critics (per env or shared) and the per-task log temperatures."""
    task_segment = {
        s.name: (
            (("task", s.num_tasks),)
            if config.one_hot
            else (("belief", config.belief_dim),)
            if config.belief_dim
            else ()
        )
        for s in specs
    }
    actor_segments: dict[str, Segments] = {
        keys[s.name]: (("obs", s.obs_dim), *task_segment[s.name]) for s in specs
    }
    critic_segments: dict[str, Segments] = {
        keys[s.name]: (("obs", s.obs_dim), *task_segment[s.name], ("action", s.critic_act_dim))
        for s in specs
    }
    log_alpha = nn.ParameterDict(
        {keys[s.name]: nn.Parameter(torch.empty(s.num_tasks)) for s in specs}
    )
    if config.architecture in MTRL_ARCHITECTURES:
        # A task-conditioned architecture (`seal.learner.mtrl`): one env, its paper's output layer.
        tasks = {keys[s.name]: s.num_tasks for s in specs}
        actor: Network = TaskConditionedNetwork(
            actor_segments, {keys[s.name]: 2 * s.act_dim for s in specs}, tasks, config
        )
        critic: Network = TaskConditionedNetwork(
            critic_segments,
            {keys[s.name]: 1 for s in specs},
            tasks,
            config,
            ensemble=2,
            layer_norm=config.critic_layer_norm,
        )
        return Networks(actor_segments, critic_segments, actor, critic, log_alpha)
    translator = (
        None if config.architecture == "mtmhsac" else (config.translator_hidden, config.latent_dim)
    )
    trunk = config.hidden if config.architecture == "mtmhsac" else config.trunk_hidden
    actor = TaskNetwork(
        actor_segments,
        {keys[s.name]: 2 * s.act_dim for s in specs},
        {keys[s.name]: s.num_tasks if config.multi_head_policy else 1 for s in specs},
        trunk,
        translator,
        ensemble=1,
        head_hidden=config.head_hidden,
        head_per_task=config.head_per_task,
    )
    critic_heads = {keys[s.name]: s.num_tasks if config.critic_multi_head else 1 for s in specs}
    if config.architecture == "seal" and config.critic_sharing == "per_env":
        critic = PerEnvCritic(
            critic_segments,
            critic_heads,
            config.critic_hidden,
            ensemble=2,
            layer_norm=config.critic_layer_norm,
            block=config.critic_block,
        )
    else:
        critic = TaskNetwork(
            critic_segments,
            {keys[s.name]: 1 for s in specs},
            critic_heads,
            trunk,
            translator,
            ensemble=2,  # twin Q: qf1 and qf2 as one stacked network
            layer_norm=config.critic_layer_norm,
            block=config.critic_block,
        )
    return Networks(actor_segments, critic_segments, actor, critic, log_alpha)
