"""Memory a protocol needs, estimated from the resolved config before anything is allocated.

`seal run` calls `check_resources` before it creates the run directory, and `seal protocol
explain` prints `estimate_resources`. For each phase the estimate adds:

- the replay: `replay.capacity_per_env` transitions of every env, float32 (`replay_bytes`);
- the networks: actor, twin critic and its target, built on PyTorch's "meta" device (shapes
  only, nothing allocated) and counted; each trainable parameter also has a gradient and Adam's
  two moments, so 4 floats per actor and critic parameter plus 1 for the target critic;
- one update's activations: the batch (`training.batch_per_task` x the phase's tasks, and x
  `scheduler.absent`'s tasks, whose share this run's tasks draw in a matched alone run) times
  the hidden widths it passes through (the actor twice, the twin critic three times: Q(s, a),
  the target's Q(s', a'), Q(s, pi(s))), doubled for what backward keeps, plus the sampled
  batch itself and its int64 row indices;
- one task-encoder step's tensors (agent.task_encoder = "smt_gru"): `agent.encoder_episodes`
  whole episodes per env through the GRU, and `encoder_elbo_steps` x `encoder_decode_steps`
  decodes of each through the three decoders, doubled for backward (`encoder_batch_bytes`);
- one evaluation's per-episode results (`evaluation_bytes`): host memory, a few KB at any real
  `evaluation.episodes`, counted with the device's so that an absurd count is refused up front.

The largest phase counts. Replay, networks and activations live on the training device: on
CUDA they are compared with the device's free memory (`torch.cuda.mem_get_info`), on the CPU
with the host's available memory (`seal.learner.replay.available_memory_bytes`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import torch

from seal.device import ThreadChoice, choose_threads
from seal.envs.base import EnvAdapter
from seal.errors import ConfigError, SealError
from seal.learner.config import MTRL_ARCHITECTURES, AgentConfig, EnvSpec
from seal.learner.mtrl.network import activation_width
from seal.learner.networks import critic_layers
from seal.learner.replay import available_memory_bytes, replay_bytes
from seal.learner.sac import Agent
from seal.learner.task_encoder import EMBED
from seal.protocols.config import ProtocolConfig
from seal.run.phase_model import Phase, PhaseModel, build_alignment, plan_phases

FLOAT = 4
"""Bytes of a float32: the dtype of every network, optimiser state, activation and replay field."""


@dataclass(frozen=True)
class PhaseEstimate:
    """One phase's estimated memory, in bytes, by part."""

    phase: str
    replay: int
    networks: int
    activations: int
    parameters: int
    """Trainable parameters of actor and critic (the target critic not counted)."""
    batch: int = 0
    """Transitions per gradient step over the phase's (env, task) pairs."""
    encoder_parameters: int = 0
    """Trainable parameters of SMT's task encoder and decoders (agent.task_encoder = "smt_gru")."""
    replay_extra: int = 0
    """Bytes of the replay that hold each row's belief and episode step (smt_gru), in `replay`."""
    actor_parameters: int = 0
    """Of `parameters`, the policy's (the rest are the twin critics')."""
    encoder_batch: int = 0
    """Bytes of one task-encoder step's tensors (smt_gru; `encoder_batch_bytes`)."""
    evaluation: int = 0
    """Bytes of one evaluation's per-episode results (`evaluation_bytes`)."""

    @property
    def total(self) -> int:
        return self.replay + self.networks + self.activations + self.encoder_batch + self.evaluation


@dataclass(frozen=True)
class ResourceEstimate:
    """A run's estimated memory: the largest phase's, against what the device has available."""

    peak: PhaseEstimate
    device: str
    available: int | None
    """Bytes available now on the device (None: unknown, no check)."""
    phases: tuple[PhaseEstimate, ...] = ()
    """Every phase's estimate, in order."""

    def describe_networks(self, architecture: str) -> str:
        """One line: the networks' architecture and parameter counts in the largest phase."""
        p = self.peak
        critic = p.parameters - p.actor_parameters
        encoder = f", task encoder {p.encoder_parameters:,}" if p.encoder_parameters else ""
        return (
            f"{architecture}: actor {p.actor_parameters:,} parameters, critic {critic:,} "
            f"(both twins){encoder}"
        )

    def update_shape(self) -> tuple[int, int]:
        """(parameters, batch) of the phase with the most update work (parameters x batch)."""
        largest = max(self.phases or (self.peak,), key=lambda p: p.parameters * p.batch)
        return largest.parameters, largest.batch

    def key(self, config: ProtocolConfig) -> str:
        """The protocol key behind the largest part, to name in a refusal."""
        parts = ("replay", "networks", "activations", "encoder_batch", "evaluation")
        part = max(parts, key=lambda p: getattr(self.peak, p))
        keys = {
            "replay": "replay.capacity_per_env",
            "activations": "training.batch_per_task",
            "encoder_batch": "agent.encoder_episodes",  # it scales every tensor of the step
            "evaluation": "evaluation.episodes",
        }
        return keys.get(part) or _width_key(config.agent)

    def describe(self) -> str:
        """One line: the total, its parts and what is available."""
        p = self.peak
        avail = "unknown" if self.available is None else _gib(self.available)
        beliefs = f" of which beliefs {_gib(p.replay_extra)}" if p.replay_extra else ""
        encoder = (
            f" and {p.encoder_parameters:,} of the task encoder" if p.encoder_parameters else ""
        )
        extra = "".join(
            f", {name} {_gib(n)}"
            for name, n in (
                ("one task-encoder step", p.encoder_batch),
                ("one evaluation's results", p.evaluation),
            )
            if n >= 2**20  # named from 1 MiB: below, it is noise beside the rest
        )
        return (
            f"{_gib(p.total)} on {self.device} (phase {p.phase}: replay {_gib(p.replay)}{beliefs}, "
            f"networks and optimiser state {_gib(p.networks)} for {p.parameters:,} parameters{encoder}, "
            f"one update's activations {_gib(p.activations)}{extra}); available: {avail}"
        )


def estimate_resources(
    config: ProtocolConfig,
    adapters: Mapping[str, EnvAdapter],
    device: str,
    models: Sequence[tuple[Phase, PhaseModel]] | None = None,
) -> ResourceEstimate:
    """The run's estimated memory on `device` (see the module docstring); allocates nothing.

    `models`: each phase with its model, as the run planned them (default: planned here)."""
    if models is None:
        alignment = build_alignment(config, adapters) if config.kind == "finetune" else None
        models = [(p, PhaseModel(config, p, adapters, alignment)) for p in plan_phases(config)]
    phases = [_phase_estimate(config, phase, model) for phase, model in models]
    peak = max(phases, key=lambda p: p.total)
    return ResourceEstimate(peak, device, _available(device), tuple(phases))


def choose_update_threads(
    config: ProtocolConfig, estimate: ResourceEstimate, cores: int | None = None
) -> ThreadChoice:
    """protocol.threads resolved for this run (`seal.device.choose_threads`) on the update shape
    of its largest phase; `cores`: a sweep trial's share (default: this process's usable cores)."""
    parameters, batch = estimate.update_shape()
    return choose_threads(config.protocol.threads, parameters, batch, cores)


def check_resources(
    config: ProtocolConfig,
    adapters: Mapping[str, EnvAdapter],
    device: str,
    models: Sequence[tuple[Phase, PhaseModel]] | None = None,
    cores: int | None = None,
) -> ThreadChoice:
    """The update threads for the run (`choose_update_threads`); ConfigError naming the largest
    part's key if the estimate exceeds what is available."""
    estimate = estimate_resources(config, adapters, device, models)
    if estimate.available is not None and estimate.peak.total > estimate.available:
        key = estimate.key(config)
        raise ConfigError(
            f"{config.path}: {key} = {_value_of(config, key)}: the run needs an estimated "
            f"{estimate.describe()}; lower {key}"
        )
    return choose_update_threads(config, estimate, cores)


# ---------------------------------------------------------------- parts


def _phase_estimate(config: ProtocolConfig, phase: Phase, model: PhaseModel) -> PhaseEstimate:
    try:
        actor, critic, encoder = _parameter_counts(config.agent, model.specs)
    except RuntimeError as exc:  # a layer wider than torch can index, even on the meta device
        key = _width_key(config.agent)
        first = (str(exc).strip().splitlines() or [""])[0][:200]
        raise ConfigError(
            f"{config.path}: {key} = {_value_of(config, key)}: the networks are too large to "
            f"lay out ({first}); lower {key}"
        ) from None
    tasks = sum(s.num_tasks for s in model.replay_specs)
    batch = config.training.batch_per_task * tasks
    # scheduler.absent's tasks are batch this run's tasks draw in their stead (a matched alone
    # run): their memory is counted as if this run's share were 1, an upper bound (the update
    # threads keep the plain batch, which a matched run draws about).
    absent = sum((getattr(config.scheduler, "absent", None) or {}).values())
    drawn = batch + config.training.batch_per_task * absent
    widest = max(2 * s.obs_dim + s.act_dim + 2 for s in model.replay_specs)
    actor_width, critic_width = _widths(config.agent, len(model.specs))
    per_sample = 2 * (2 * actor_width + 3 * 2 * critic_width) + widest
    return PhaseEstimate(
        phase=phase.name,
        replay=replay_bytes(model.replay_specs, config.replay.capacity_per_env),
        # The encoder and decoders (smt_gru): weights, gradients and Adam's two moments.
        networks=FLOAT * (4 * actor + 5 * critic + 4 * encoder),
        activations=drawn * (FLOAT * per_sample + 8),
        parameters=actor + critic,
        batch=batch,
        encoder_parameters=encoder,
        actor_parameters=actor,
        replay_extra=replay_bytes(model.replay_specs, config.replay.capacity_per_env)
        - replay_bytes(model.specs_with_replay_tasks(), config.replay.capacity_per_env),
        encoder_batch=encoder_batch_bytes(config.agent, model),
        evaluation=evaluation_bytes(config.evaluation.episodes, tasks),
    )


def evaluation_bytes(episodes: int, tasks: int) -> int:
    """Bytes of one evaluation's per-episode results over `tasks` tasks: `evaluate_in_waves`
    keeps four float64 arrays (success, return, Q at the start, earned) of episodes x tasks."""
    return 4 * 8 * int(episodes) * int(tasks)


def check_evaluation_memory(episodes: int, tasks: int, name: str) -> None:
    """SealError naming `name` (the key or flag that set `episodes`) when one evaluation's
    results (`evaluation_bytes`) exceed the host's available memory."""
    need, available = evaluation_bytes(episodes, tasks), available_memory_bytes()
    if available is not None and need > available:
        raise SealError(
            f"{name} {episodes}: one evaluation's results over {tasks} tasks need an estimated "
            f"{_gib(need)}; available: {_gib(available)}; lower {name}"
        )


def encoder_batch_bytes(agent: AgentConfig, model: PhaseModel) -> int:
    """Bytes of one task-encoder step over the phase's envs (`seal.learner.task_encoder.elbo`);
    0 unless agent.task_encoder = "smt_gru".

    Per env: its `encoder_episodes` episodes of the adapter's episode length (obs, next obs,
    action, reward; int64 row indices), the embeddings, GRU (its three gates kept for backward),
    encoder layers and beliefs at every step; then `encoder_elbo_steps` x `encoder_decode_steps`
    decodes per episode, each with its three decoders' inputs, hidden layers and outputs. The
    tensors are doubled for what backward keeps. Measured (one step of MT10's sizes, 500-step
    episodes, peak RSS on CPU): 0.32 GiB at 16 episodes (estimate 0.28), 1.61 at 128 (2.27).
    """
    if agent.task_encoder != "smt_gru":
        return 0
    total = 0
    for spec in model.specs:
        steps = model.adapters[spec.name].episode_length + 1
        obs, act, latent = spec.obs_dim, spec.act_dim, agent.encoder_latent
        per_step = (
            2 * obs
            + act
            + 1
            + sum(EMBED.values())
            + 4 * agent.encoder_gru
            + sum(agent.encoder_hidden)
            + 2 * latent
        )
        decoder_inputs = 3 * (2 * obs + act + 1 + latent)
        per_decode = decoder_inputs + 3 * sum(agent.decoder_hidden) + 1 + obs + spec.num_tasks
        decodes = agent.encoder_elbo_steps * agent.encoder_decode_steps
        floats = agent.encoder_episodes * (steps * per_step + decodes * per_decode)
        total += 2 * FLOAT * floats + 8 * 2 * agent.encoder_episodes * steps
    return total


class _ShapesOnly(Agent):
    """An Agent whose networks are built but never initialised, placed or given optimisers."""

    def _initialise(self) -> None:
        pass

    def _build_encoders(self, specs: Sequence[EnvSpec], draw: bool = True) -> None:
        super()._build_encoders(specs, draw=False)


def _parameter_counts(agent: AgentConfig, specs: list[EnvSpec]) -> tuple[int, int, int]:
    """(actor, critic, task encoder with its decoders) trainable parameters, from networks built
    on the meta device."""
    shapes_only = dataclasses.replace(agent, device="cpu", compile=False)
    with torch.device("meta"):
        built = _ShapesOnly(specs, shapes_only, seed=0)
    encoders = built.encoders.parameters() if built.encoders is not None else ()
    return (
        sum(p.numel() for p in built.actor.parameters()),
        sum(p.numel() for p in built.critic.parameters()),
        sum(p.numel() for p in encoders),
    )


def _widths(agent: AgentConfig, num_envs: int) -> tuple[int, int]:
    """Summed hidden widths one sample passes through in the actor and in one critic (a BroNet
    trunk's stem and two layers per block: `critic_layers`)."""
    if agent.architecture in MTRL_ARCHITECTURES:
        width = activation_width(agent)
        return width, width
    trunk = sum(critic_layers(getattr(agent, agent.critic_trunk_key), agent.critic_block))
    if agent.architecture == "mtmhsac":
        return sum(agent.hidden), trunk
    # Every env's translator sees only its own samples, so one translator's widths count.
    actor = sum(agent.translator_hidden) + agent.latent_dim + sum(agent.trunk_hidden)
    critic = trunk if agent.critic_sharing == "per_env" else actor - sum(agent.trunk_hidden) + trunk
    return actor, critic


def _width_key(agent: AgentConfig) -> str:
    """The widths key that dominates the networks' size."""
    if agent.architecture == "soft_modular":
        return "agent.soft_width"
    if agent.architecture == "mtmhsac" or agent.architecture in MTRL_ARCHITECTURES:
        return "agent.hidden"
    keys = {
        "agent.translator_hidden": max(agent.translator_hidden, default=0),
        "agent.latent_dim": agent.latent_dim,
        "agent.trunk_hidden": max(agent.trunk_hidden, default=0),
        "agent.critic_hidden": max(agent.critic_hidden, default=0),
    }
    return max(keys, key=lambda k: keys[k])


def _value_of(config: ProtocolConfig, key: str) -> object:
    table, name = key.split(".")
    value = getattr(getattr(config, table), name)
    return list(value) if isinstance(value, tuple) else value


def _available(device: str) -> int | None:
    if device.startswith("cuda") and torch.cuda.is_available():
        free, _total = torch.cuda.mem_get_info(torch.device(device))
        return int(free)
    return available_memory_bytes()


def _gib(n: int) -> str:
    return f"{n / 2**30:,.2f} GiB"
