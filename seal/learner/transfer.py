"""Pad-and-fine-tune's checkpoint transfer: start an agent from another env's agent state.

Input layers are copied segment by segment (pad-and-align: obs, task one-hot, action), heads where
both agents have them, and the policy's last layer keeps the new agent's initialisation (SEAL
Appendix D); see `transfer_from`.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch

from seal.errors import SealError
from seal.learner.networks import PerEnvCritic, Segments, TaskNetwork
from seal.learner.sac import Agent, AgentState


def transfer_from(agent: Agent, state: AgentState, *, reinit_critic: bool | None = None) -> None:
    """Pad-and-fine-tune: start from another env's agent state (SEAL Appendix D).

    Every parameter is kept except the policy's last layer (its heads), which keeps this
    agent's fresh initialisation because its width is the new env's action size. Input layers
    are copied segment by segment (obs, task one-hot, action): columns that are new here (a
    grown one-hot, MT1 -> MT10, or a wider obs/action) start at zero, so the transferred
    network computes what it did on the inputs it knew. Critic heads and temperatures are
    copied for the task ids both agents have; new ids keep their fresh init. The target
    critics become copies of the transferred critics; optimiser states start fresh, with
    lr_factor applied. `reinit_critic` (default: config.reinit_critic_on_transfer) keeps the
    fresh critics instead. Environments are matched by name, or one to one when both agents
    have a single environment (the aligned pseudo-env of each phase).
    """
    if reinit_critic is None:
        reinit_critic = agent.config.reinit_critic_on_transfer
    if state["config"]["architecture"] != agent.config.architecture:
        raise SealError(
            f"cannot transfer a {state['config']['architecture']!r} agent into a {agent.config.architecture!r} agent"
        )
    if not reinit_critic:
        _check_critic_layout(agent, state)  # before anything is copied
    source_keys = list(state["segments"]["actor"])
    if len(source_keys) == 1 and len(agent._keys) == 1:
        key_map = {next(iter(agent._keys.values())): source_keys[0]}
    else:
        key_map = {k: k for k in agent._keys.values() if k in source_keys}
    _transfer_network(
        agent.actor,
        state["actor"],
        state["segments"]["actor"],
        agent.actor_segments,
        key_map,
        copy_heads=False,
    )
    if not reinit_critic:
        _transfer_critic(agent, state, key_map)
    agent.critic_target.load_state_dict(agent.critic.state_dict())
    with torch.no_grad():
        for key, source_key in key_map.items():
            old = state["log_alpha"][source_key]
            n = min(old.shape[0], agent.log_alpha[key].shape[0])
            agent.log_alpha[key][:n].copy_(old[:n])
    agent.reset_optimizers(agent.config.lr_factor)


def _check_critic_layout(agent: Agent, state: AgentState) -> None:
    """SealError (one line) when the saved critics are laid out otherwise than this agent's."""
    theirs = _critic_layout(state["config"])
    mine = "per_env" if isinstance(agent.critic, PerEnvCritic) else "shared"
    if theirs != mine:
        raise SealError(
            f'cannot transfer the critic: the saved agent has {theirs} critics (critic_sharing = "{theirs}"; states from before critic_sharing have shared ones) and this agent {mine}; set [transfer] reinit_critic = true or agent.critic_sharing = "{theirs}"'
        )


def _transfer_critic(agent: Agent, state: AgentState, key_map: Mapping[str, str]) -> None:
    """Copy the saved critics into this agent's, env by env; refuse across critic layouts."""
    _check_critic_layout(agent, state)
    if not isinstance(agent.critic, PerEnvCritic):
        _transfer_network(
            agent.critic,
            state["critic"],
            state["segments"]["critic"],
            agent.critic_segments,
            key_map,
            copy_heads=True,
        )
        return
    for key, source_key in key_map.items():
        prefix = f"nets.{source_key}."
        _transfer_network(
            agent.critic.nets[key],
            {k[len(prefix) :]: v for k, v in state["critic"].items() if k.startswith(prefix)},
            {source_key: state["segments"]["critic"][source_key]},
            {key: agent.critic_segments[key]},
            {key: source_key},
            copy_heads=True,
        )


def _critic_layout(config: Mapping[str, object]) -> str:
    """ "per_env" or "shared" critics of a saved agent config; states saved before critic_sharing
    existed (format 1) had shared SEAL critics."""
    if config["architecture"] == "seal" and config.get("critic_sharing", "shared") == "per_env":
        return "per_env"
    return "shared"


def _transfer_network(
    net: TaskNetwork,
    source: Mapping[str, torch.Tensor],
    source_segments: Mapping[str, Segments],
    segments: Mapping[str, Segments],
    key_map: Mapping[str, str],
    *,
    copy_heads: bool,
) -> None:
    """Copy `source` parameters into `net` as `transfer_from` describes."""
    target = net.state_dict()
    reverse = {f".{k}.": f".{v}." for k, v in key_map.items()}
    loaded: dict[str, torch.Tensor] = {}
    for name, param in target.items():
        source_name = name
        for new, old in reverse.items():
            source_name = source_name.replace(new, old)
        env_key = next((k for k in key_map if f".{k}." in name), None)
        if name.startswith(("translators.", "heads.")) and env_key is None:
            continue  # an env the source never had keeps its fresh init
        if source_name not in source:
            raise SealError(
                f"cannot transfer: the saved agent has no parameter {source_name!r} (is it the same architecture?)"
            )
        old = source[source_name].to(param.device)
        if name.startswith("heads."):
            if copy_heads:
                loaded[name] = _copy_heads(param, old, name)
            continue
        is_input = name.endswith("weights.0") and (
            name.startswith("translators.") or not net.translators
        )
        if is_input:
            key = env_key if env_key is not None else next(iter(key_map))
            loaded[name] = _copy_columns(param, old, segments[key], source_segments[key_map[key]])
        elif old.shape == param.shape:
            loaded[name] = old.clone()
        else:
            raise SealError(
                f"cannot transfer {name}: saved shape {tuple(old.shape)} vs {tuple(param.shape)} here; hidden widths must match"
            )
    net.load_state_dict({**target, **loaded})


def _copy_columns(
    param: torch.Tensor, old: torch.Tensor, segments: Segments, source_segments: Segments
) -> torch.Tensor:
    """Input-layer weight (G, in, out): copy each named segment's overlapping rows, zero the rest."""
    if old.shape[0] != param.shape[0] or old.shape[2] != param.shape[2]:
        raise SealError(
            f"cannot transfer input layer: saved shape {tuple(old.shape)} vs {tuple(param.shape)} here; hidden widths must match"
        )
    out = torch.zeros_like(param)
    source_offsets, offset = {}, 0
    for seg, width in source_segments:
        source_offsets[seg] = (offset, width)
        offset += width
    offset = 0
    for seg, width in segments:
        if seg in source_offsets:
            start, old_width = source_offsets[seg]
            n = min(width, old_width)
            out[:, offset : offset + n] = old[:, start : start + n]
        offset += width
    return out


def _copy_heads(param: torch.Tensor, old: torch.Tensor, name: str) -> torch.Tensor:
    """Multi-head weight (G, in, H*out) or bias (G, 1, H*out): copy heads both have, keep the rest."""
    if old.shape[:2] != param.shape[:2]:
        raise SealError(
            f"cannot transfer {name}: saved shape {tuple(old.shape)} vs {tuple(param.shape)} here"
        )
    out = param.clone()
    n = min(old.shape[-1], param.shape[-1])
    out[..., :n] = old[..., :n]
    return out
