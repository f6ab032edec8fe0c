"""Pad-and-fine-tune's checkpoint transfer: start an agent from another env's agent state.

Input layers are copied segment by segment (pad-and-align: obs, task one-hot, action), heads where
both agents have them, and the policy's last layer keeps the new agent's initialisation (SEAL
Appendix D); see `transfer_from`. `map_env` instead rewrites one env's modules into another
env's through maps known by construction (a positive control's oracle, e.g. the transfer
testbed's `seal.envs.testbed.ORACLE_MAP`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import torch

from seal.errors import SealError, UnknownNameError
from seal.learner.agent_state import AgentState
from seal.learner.config import EnvSpec
from seal.learner.networks import (
    LOG_STD_MIN,
    MultiHeadLinear,
    PerEnvCritic,
    Segments,
    StackedMLP,
    TaskNetwork,
)
from seal.learner.sac import Agent, module_key
from seal.pieces import map_pieces


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


# ---------------------------------------------------------------- mapping one env onto another

# The log std at which a zero-mean tanh-Gaussian entry has expected log-density 0 (differential
# entropy 0): solved numerically from tanh_gaussian's log-prob, E over 4e6 normal draws.
UNMAPPED_ZERO_LOG_DENSITY = -1.354


def map_env(
    agent: Agent,
    state: AgentState,
    source: str,
    target: str,
    *,
    obs_map: np.ndarray,
    task_order: Sequence[int],
    actions: Sequence[tuple[int, float]],
    modules: str | Sequence[str] = "all",
    unmapped_log_std: float = LOG_STD_MIN,
) -> None:
    """Start env `target`'s modules from the saved agent's env `source` through known linear maps.

    The source's observation is `obs_map @` the target's, target task j is source task
    `task_order[j]`, and source action entry k is sign * target entry index for `actions[k] =
    (index, sign)`. `modules` names the pieces mapped (`seal.pieces.map_pieces`: "all",
    "translator" or a list holding "translator"): the policy translator, the action heads, the
    critics (online and target), the per-task temperatures; the others keep their fresh init.
    Every mapped module computes on the target's inputs what the source's computed on the
    corresponding inputs: a first layer's weights W become Aᵀ W, where A maps
    the target's [obs, one-hot, action] columns to the source's; an output layer's become W Bᵀ,
    where B gives each target task's head its source task's head: the mapped entries' mean rows
    with their signs and their log-std rows, and for the entries the source has no counterpart
    of, weight 0, mean 0 and log std `unmapped_log_std` (default the lower clamp, LOG_STD_MIN:
    no noise; UNMAPPED_ZERO_LOG_DENSITY: expected log-density 0, so that they add nothing to the
    soft Bellman target of the mapped critic). The per-task temperatures are permuted; the
    env's target critics become copies of its mapped critics. Parameters are written in
    place (the optimiser slots keep them); other envs and the shared trunk are left as they are
    (`transfer_from` copies the trunk). Linear action heads only (agent.head_hidden = []).
    """
    saved_specs = {spec["name"]: spec for spec in state["specs"]}
    if source not in saved_specs:
        raise SealError(
            f"map_env: the saved agent has no env {source!r}; it has {list(saved_specs)}"
        )
    if target not in agent.specs:
        raise UnknownNameError("environment", target, list(agent.specs))
    try:
        pieces = map_pieces(modules)
    except SealError as exc:
        raise SealError(f"map_env: {exc}") from None
    saved_config = state["config"]
    if agent.config.architecture != "seal" or saved_config["architecture"] != "seal":
        raise SealError(
            f"map_env maps SEAL agents' translators; got a saved {saved_config['architecture']!r} agent and a {agent.config.architecture!r} one"
        )
    if agent.config.head_hidden or saved_config.get("head_hidden"):
        raise SealError("map_env maps linear action heads; set agent.head_hidden = [] in both runs")
    saved, spec = saved_specs[source], agent.specs[target]
    blocks = _input_blocks(
        obs_map, task_order, actions, (saved["obs_dim"], saved["num_tasks"], saved["act_dim"]), spec
    )
    key_s, key_t = module_key(source), module_key(target)
    actor_in = _input_map(state["segments"]["actor"][key_s], agent.actor_segments[key_t], blocks)
    with torch.no_grad():
        _map_stack(
            agent.actor.translators[key_t], state["actor"], f"translators.{key_s}.", actor_in
        )
        if "head" in pieces:
            head, fill = _policy_head_map(
                blocks["action"], int(saved["act_dim"]), spec.act_dim, unmapped_log_std
            )
            _map_head(
                agent.actor.heads[key_t], state["actor"], f"heads.{key_s}.", head, fill, task_order
            )
        if "critic" in pieces:
            _check_critic_layout(agent, state)
            _map_critic(agent, state, key_s, key_t, blocks, task_order)
        if "temperature" in pieces:
            agent.log_alpha[key_t].copy_(state["log_alpha"][key_s][list(task_order)])


def _map_critic(
    agent: Agent,
    state: AgentState,
    key_s: str,
    key_t: str,
    blocks: Mapping[str, torch.Tensor],
    task_order: Sequence[int],
) -> None:
    """Env `key_t`'s online critics from the saved env `key_s`'s through the input map and the
    task order, then its target critics as copies of them."""
    critic_in = _input_map(state["segments"]["critic"][key_s], agent.critic_segments[key_t], blocks)
    q_head, q_fill = torch.ones(1, 1, dtype=torch.float64), torch.zeros(1, dtype=torch.float64)
    critic, critic_target = agent.critic, agent.critic_target
    if isinstance(critic, PerEnvCritic):
        assert isinstance(critic_target, PerEnvCritic)
        inner, prefix = critic.nets[key_t], f"nets.{key_s}."
        _map_stack(inner.trunk, state["critic"], f"{prefix}trunk.", critic_in)
        _map_head(
            inner.heads[key_t],
            state["critic"],
            f"{prefix}heads.{key_s}.",
            q_head,
            q_fill,
            task_order,
        )
        mapped = [(critic_target.nets[key_t], inner)]
    else:
        assert isinstance(critic_target, TaskNetwork)
        _map_stack(critic.translators[key_t], state["critic"], f"translators.{key_s}.", critic_in)
        _map_head(
            critic.heads[key_t], state["critic"], f"heads.{key_s}.", q_head, q_fill, task_order
        )
        mapped = [
            (critic_target.translators[key_t], critic.translators[key_t]),
            (critic_target.heads[key_t], critic.heads[key_t]),
        ]
    # The target critics copy the mapped online ones, as transfer_from's do: with a shared
    # critic trunk (a copy of the online one there) only that keeps the target Q the source's.
    for target_module, online in mapped:
        target_module.load_state_dict(online.state_dict())


def _input_blocks(
    obs_map: np.ndarray,
    task_order: Sequence[int],
    actions: Sequence[tuple[int, float]],
    saved: tuple[int, int, int],
    spec: EnvSpec,
) -> dict[str, torch.Tensor]:
    """The (source width, target width) matrix of each input segment: obs, task one-hot, action."""
    obs_dim, num_tasks, act_dim = saved
    obs = torch.as_tensor(np.asarray(obs_map, dtype=np.float64))
    if tuple(obs.shape) != (obs_dim, spec.obs_dim):
        raise SealError(
            f"map_env: obs_map is {tuple(obs.shape)}, expected (saved obs_dim, {spec.name} obs_dim) = ({obs_dim}, {spec.obs_dim})"
        )
    order = list(task_order)
    if len(order) != spec.num_tasks or not all(0 <= i < num_tasks for i in order):
        raise SealError(
            f"map_env: task_order {order} must give each of {spec.name}'s {spec.num_tasks} tasks a saved task in [0, {num_tasks})"
        )
    indices = [index for index, _ in actions]
    if (
        len(indices) != act_dim
        or len(set(indices)) != act_dim
        or not all(0 <= i < spec.act_dim for i in indices)
    ):
        raise SealError(
            f"map_env: actions {list(actions)} must give each of the saved env's {act_dim} action entries its own {spec.name} entry in [0, {spec.act_dim})"
        )
    tasks = torch.zeros(num_tasks, spec.num_tasks, dtype=torch.float64)
    tasks[order, list(range(spec.num_tasks))] = 1.0
    action = torch.zeros(act_dim, spec.act_dim, dtype=torch.float64)
    for k, (index, sign) in enumerate(actions):
        action[k, index] = float(sign)
    return {"obs": obs, "task": tasks, "action": action}


def _input_map(
    source_segments: Segments, segments: Segments, blocks: Mapping[str, torch.Tensor]
) -> torch.Tensor:
    """A (source input width, target input width): the source's input is A @ the target's.

    An action segment wider than the env's actions (act_pad_to) gets zeros in the padding."""
    if [name for name, _ in source_segments] != [name for name, _ in segments]:
        raise SealError(
            f"map_env: input segments {source_segments} (saved) and {segments} differ; both runs need the same agent.task_encoder"
        )
    out = torch.zeros(
        sum(w for _, w in source_segments), sum(w for _, w in segments), dtype=torch.float64
    )
    row = col = 0
    for (name, rows), (_, cols) in zip(source_segments, segments, strict=True):
        block = blocks[name]
        if block.shape[0] > rows or block.shape[1] > cols:
            raise SealError(
                f"map_env: the {name} map is {tuple(block.shape)}, the layers' {name} columns {rows} (saved) and {cols}"
            )
        out[row : row + block.shape[0], col : col + block.shape[1]] = block
        row, col = row + rows, col + cols
    return out


def _policy_head_map(
    action: torch.Tensor, source_act: int, act_dim: int, unmapped_log_std: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """One policy head's B (2 * act_dim, 2 * source_act) and bias fill, from the action map (source_act, act_dim)."""
    head = torch.zeros(2 * act_dim, 2 * source_act, dtype=torch.float64)
    head[:act_dim, :source_act] = action.T  # means, with their signs
    head[act_dim:, source_act:] = action.T.abs()  # log stds: the spread of x and -x is the same
    fill = torch.zeros(2 * act_dim, dtype=torch.float64)
    mapped = action.abs().sum(0) > 0
    fill[act_dim:][~mapped] = unmapped_log_std  # entries no source entry drives
    return head, fill


def _map_stack(
    stack: StackedMLP, saved: Mapping[str, torch.Tensor], prefix: str, input_map: torch.Tensor
) -> None:
    """`stack`'s layers from the saved ones under `prefix`, the first one's inputs through `input_map`."""
    for i, (weight, bias) in enumerate(zip(stack.weights, stack.biases, strict=True)):
        old = _saved(saved, f"{prefix}weights.{i}").double()
        if i == 0:
            old = input_map.T @ old  # (in, in_saved) @ (G, in_saved, out)
        _write(weight, old, f"{prefix}weights.{i}")
        _write(bias, _saved(saved, f"{prefix}biases.{i}"), f"{prefix}biases.{i}")
    for i, (gain, shift) in enumerate(zip(stack.norm_gains, stack.norm_biases, strict=True)):
        _write(gain, _saved(saved, f"{prefix}norm_gains.{i}"), f"{prefix}norm_gains.{i}")
        _write(shift, _saved(saved, f"{prefix}norm_biases.{i}"), f"{prefix}norm_biases.{i}")


def _map_head(
    layer: MultiHeadLinear,
    saved: Mapping[str, torch.Tensor],
    prefix: str,
    head: torch.Tensor,
    fill: torch.Tensor,
    task_order: Sequence[int],
) -> None:
    """`layer`'s heads from the saved ones under `prefix`: head j from task_order[j]'s through `head` (one head: its only one)."""
    weight, bias = (
        _saved(saved, f"{prefix}weight").double(),
        _saved(saved, f"{prefix}bias").double(),
    )
    out, source_out = head.shape
    source_heads = weight.shape[-1] // source_out
    order = [0] if layer.num_heads == source_heads == 1 else list(task_order)
    if len(order) != layer.num_heads or max(order) >= source_heads:
        raise SealError(
            f"map_env: {prefix}: {source_heads} saved heads and {layer.num_heads} here; both runs need the same agent.multi_head_policy and multi_head_critic"
        )
    full = torch.zeros(layer.num_heads * out, source_heads * source_out, dtype=torch.float64)
    for j, i in enumerate(order):
        full[j * out : (j + 1) * out, i * source_out : (i + 1) * source_out] = head
    _write(layer.weight, weight @ full.T, f"{prefix}weight")
    _write(layer.bias, bias @ full.T + fill.repeat(layer.num_heads), f"{prefix}bias")


def _saved(saved: Mapping[str, torch.Tensor], name: str) -> torch.Tensor:
    if name not in saved:
        raise SealError(
            f"map_env: the saved agent has no parameter {name!r} (is it the same architecture?)"
        )
    return saved[name]


def _write(param: torch.Tensor, value: torch.Tensor, name: str) -> None:
    """Copy `value` into `param` in place, or SealError naming `name` when the shapes differ."""
    if value.shape != param.shape:
        raise SealError(
            f"map_env: {name}: the mapped shape {tuple(value.shape)} differs from {tuple(param.shape)} here; hidden widths must match"
        )
    param.copy_(value.to(param.dtype))
