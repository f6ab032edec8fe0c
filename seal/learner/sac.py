"""Multi-task multi-head SAC (MTMHSAC) and the SEAL agent: what the agent is.

An `Agent` holds the networks (`seal.learner.networks`), the per-task temperatures, the optimiser
slots (`seal.learner.optim.Slots`), the RNG streams and the counters; it acts, runs one update
and saves and restores its state (`seal.learner.agent_state`). The update itself is
`seal.learner.update.sac_update` (critic, actor, temperature, target, in that order) over the
losses of `seal.learner.losses`; compile staging is `seal.learner.staging`, the ratio lever
`seal.learner.lever` and pad-and-fine-tune's copies `seal.learner.transfer`.
"""

from __future__ import annotations

import copy
import itertools
import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from seal.device import resolve_device
from seal.errors import SealError, TrainingDivergedError, UnknownNameError
from seal.learner import lever
from seal.learner.agent_state import StateIO
from seal.learner.build import build_networks
from seal.learner.config import AgentConfig, Batch, EnvSpec
from seal.learner.losses import Policy, TwinQ
from seal.learner.mtrl import pcgrad
from seal.learner.networks import (
    HEAD_BOUND,
    LOG_STD_MAX,
    LOG_STD_MIN,
    PerEnvCritic,
    TaskNetwork,
    tanh_gaussian,
)
from seal.learner.optim import AdamCache, Slots, unique_parameters
from seal.learner.staging import Stages
from seal.learner.task_encoder import TaskEncoder
from seal.learner.task_encoding import TaskEncoding
from seal.learner.update import (
    EnvInputs,
    actor_stage,
    batch_shares,
    critic_stage,
    draw_noise,
    sac_update,
)
from seal.seeding import stream

if TYPE_CHECKING:
    from seal.learner.replay import MultiTaskReplay

# Per-env scalars returned by update(), in the order `sac_update` stacks them.
_SCALARS = (
    "losses/{}/qf1",
    "losses/{}/qf2",
    "losses/{}/critic",
    "losses/{}/actor",
    "losses/{}/alpha",
    "charts/{}/mean_q",
    "charts/{}/entropy",
)


def module_key(name: str) -> str:
    """A ModuleDict-safe key for an env name: torch forbids only dots (and the empty name)."""
    return name.replace(".", "_") or "_"


def _check_specs(specs: Sequence[EnvSpec], config: AgentConfig) -> dict[str, str]:
    """Each env's module key; SealError for no env, repeated names or MTMHSAC over several."""
    if not specs:
        raise SealError("Agent needs at least one EnvSpec")
    names = [s.name for s in specs]
    if len(set(names)) != len(names):
        raise SealError(f"Agent: environment names repeat: {names}")
    if config.architecture != "seal" and len(specs) != 1:
        raise SealError(
            f'agent.architecture = "{config.architecture}" trains one environment, got {len(specs)} ({", ".join(names)}); use "seal" for several'
        )
    keys = {s.name: module_key(s.name) for s in specs}
    if len(set(keys.values())) != len(keys):
        raise SealError(f"Agent: environment names {names} collide after replacing '.' with '_'")
    return keys


class Agent(StateIO):
    """MTMHSAC (one EnvSpec) or SEAL (several) soft actor-critic over multi-task batches.

    `act` maps raw observations of one environment to actions in [-1, 1]; `update` takes one
    gradient step for every environment in its batches and returns grouped scalar logs.
    """

    def __init__(self, specs: Sequence[EnvSpec], config: AgentConfig, seed: int) -> None:
        specs = list(specs)
        keys = _check_specs(specs, config)
        pcgrad.check_config(config, specs)
        self.config = config
        self.seed = int(seed)
        self.device = resolve_device(config.device)
        self.specs: dict[str, EnvSpec] = {s.name: s for s in specs}
        self._keys = keys
        # Common random numbers: every stream is keyed by (seed, env name, purpose), never by the
        # set of envs, so an env's weights and noise are the same alone and in any joint run.
        # Separate update and act streams: how often the collector acts does not change the
        # update's noise.
        self.update_generators = {
            n: stream(self.seed, "update", n, device=self.device) for n in self.specs
        }
        self._act_generators = {
            n: stream(self.seed, "act", n, device=self.device) for n in self.specs
        }
        # gradient = "pcgrad": each env's tasks' orders (seal.learner.mtrl.pcgrad), its own stream
        # so the update's policy noise is the one "mean" draws.
        self.pcgrad_generators = (
            {n: stream(self.seed, "pcgrad", n, device=self.device) for n in self.specs}
            if config.gradient == "pcgrad"
            else {}
        )
        self._init_draws = 0
        self._build_networks(specs)
        self._build_encoders(specs)
        self.target_entropy = {
            s.name: float(-s.act_dim if config.target_entropy is None else config.target_entropy)
            for s in specs
        }
        # Optimiser slots: which envs' parameters each actor / critic Adam owns.
        per_env = [[name] for name in self.specs]
        self._actor_members = per_env if config.shared_update == "per_env" else [list(self.specs)]
        independent_critics = isinstance(self.critic, PerEnvCritic) or len(specs) == 1
        self._critic_members = (
            per_env
            if independent_critics or config.shared_update == "per_env"
            else [list(self.specs)]
        )
        self.last_ratio_lever: float | None = None
        """The ratio lever last measured by update() (every config.ratio_lever_interval updates)."""
        self._lr_factor = config.lr_factor
        self.num_updates = 0
        self.last_checkpoint: str | None = None
        """Path of the last checkpoint written by seal.learner.checkpoint.save_checkpoint."""
        self.stages = Stages((critic_stage, actor_stage))
        self._initialise()
        if config.compile:
            self.stages.compile(self.device)

    # ------------------------------------------------------------------ construction and reset
    def _build_networks(self, specs: Sequence[EnvSpec]) -> None:
        """The policy, the twin critics (per env or shared) and the per-task log temperatures."""
        built = build_networks(specs, self.config, self._keys)
        self.actor_segments, self.critic_segments = built.actor_segments, built.critic_segments
        self.actor, self.critic, self.log_alpha = built.actor, built.critic, built.log_alpha

    def _build_encoders(self, specs: Sequence[EnvSpec], draw: bool = True) -> None:
        """SMT's task encoders (agent.task_encoder = "smt_gru"): drawn once, kept by an SMT reset."""
        self.task_encoding: TaskEncoding | None = None
        if self.config.task_encoder == "smt_gru":
            self.task_encoding = TaskEncoding(
                specs, self._keys, self.config, self.seed, self.device, draw
            )

    @property
    def encoders(self) -> nn.ModuleDict | None:
        """Every env's task encoder and decoders (agent.task_encoder = "smt_gru"), else None."""
        return None if self.task_encoding is None else self.task_encoding.modules

    def encoder(self, name: str) -> TaskEncoder:
        """Env `name`'s task encoder (agent.task_encoder = "smt_gru")."""
        if self.task_encoding is None:
            raise SealError(
                f'agent.task_encoder is {self.config.task_encoder!r}, not "smt_gru": no task encoder'
            )
        return self.task_encoding.encoder(self._spec(name).name)

    def update_encoder(
        self, replay: MultiTaskReplay
    ) -> tuple[tuple[str, ...], torch.Tensor] | None:
        """`TaskEncoding.update` at this agent's update count; None without a task encoder."""
        if self.task_encoding is None:
            return None
        return self.task_encoding.update(replay, self.num_updates)

    def refresh_beliefs(self, replay: MultiTaskReplay) -> int:
        """`TaskEncoding.refresh` at this agent's update count; 0 without a task encoder."""
        if self.task_encoding is None:
            return 0
        return self.task_encoding.refresh(replay, self.num_updates)

    def _initialise(self) -> None:
        """Draw all weights, copy the target critics, set temperatures, build fresh optimisers.

        Each component draws from its own stream, keyed by (seed, draw, role, component): the
        shared trunk by the seed alone, an env's translator, head and critic by its name. Init
        draws on CPU so the same seed gives the same weights on every device.
        """
        draw = self._init_draws
        self._init_draws += 1
        for net, role in ((self.actor, "actor"), (self.critic, "critic")):
            net.cpu()
            net.reset_parameters(
                lambda component, role=role: stream(self.seed, "init", draw, role, component),
                self.config.init,
                HEAD_BOUND[role],
            )
            net.to(self.device)
        # A deep copy: the targets own their tensors (never views of the online critics).
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        with torch.no_grad():
            for log_alpha in self.log_alpha.values():
                log_alpha.fill_(math.log(self.config.init_alpha))
        self.log_alpha.to(self.device)
        self.reset_optimizers(self._lr_factor)

    def reset_optimizers(self, lr_factor: float) -> None:
        """Fresh Adam states at `lr_factor`: one actor and one critic Adam per optimiser slot, one
        for the temperatures (which keep alpha_lr)."""
        self._lr_factor = float(lr_factor)
        config = self.config
        self.adam_cache: AdamCache = {}
        # New parameters or states may fail the compiled stages' guards: trace again.
        self.stages.forget_keys()

        def slots(net: TaskNetwork | PerEnvCritic, members: list[list[str]], lr: float) -> Slots:
            params = [
                unique_parameters(p for n in names for p in net.env_parameters(self._keys[n]))
                for names in members
            ]
            groups = None
            if config.clip_per == "component":
                component = {id(p): c for c, ps in net.components().items() for p in ps}
                groups = []
                for slot in params:
                    runs = [
                        (c, len(list(run)))
                        for c, run in itertools.groupby(slot, lambda p: component[id(p)])
                    ]
                    names = [c for c, _ in runs]
                    if len(set(names)) != len(names):  # a split component would be clipped twice
                        raise ValueError(f"clip_per: a component is split in a slot: {names}")
                    groups.append([n for _, n in runs])
            per_task = None
            if config.gradient == "pcgrad":
                task_params = {id(p) for p in pcgrad.task_parameters(net)}
                per_task = [[id(p) in task_params for p in slot] for slot in params]
            return Slots(
                members,
                params,
                lr=lr * self._lr_factor,
                eps=config.adam_eps,
                max_grad_norm=config.max_grad_norm,
                groups=groups,
                per_task=per_task,
            )

        self.actor_slots = slots(self.actor, self._actor_members, config.actor_lr)
        self.critic_slots = slots(self.critic, self._critic_members, config.critic_lr)
        self.alpha_optimizer = torch.optim.Adam(
            list(self.log_alpha.values()), lr=config.alpha_lr, fused=True, eps=config.adam_eps
        )
        alpha_keys = list(self.log_alpha.keys())
        self._alpha_position = {n: alpha_keys.index(self._keys[n]) for n in self.specs}
        self._polyak = (list(self.critic_target.parameters()), list(self.critic.parameters()))

    @property
    def actor_optimizers(self) -> list[torch.optim.Adam]:
        """The policy's Adams, one per slot."""
        return self.actor_slots.optimizers

    @property
    def critic_optimizers(self) -> list[torch.optim.Adam]:
        """The critics' Adams, one per slot."""
        return self.critic_slots.optimizers

    def reset_parameters(self) -> None:
        """SMT reset: re-draw the policy, Q networks and targets, reset temperatures and optimiser states.

        The learning-rate factor in force is kept; update and act counters and RNG streams go on.
        SMT's task encoder, its decoders and their Adam are kept (SMT Algorithm 1, line 24).
        """
        self._initialise()

    def set_lr_factor(self, factor: float) -> None:
        """Scale the actor and critic learning rates to factor * actor_lr / critic_lr (temperatures keep alpha_lr)."""
        if not math.isfinite(factor) or factor <= 0:
            raise SealError(f"lr_factor must be a finite number > 0, got {factor!r}")
        self._lr_factor = float(factor)
        self.actor_slots.set_lr(self.config.actor_lr * self._lr_factor)
        self.critic_slots.set_lr(self.config.critic_lr * self._lr_factor)

    @property
    def compiled(self) -> bool:
        """Whether updates run compiled (config.compile on and compilation has not failed)."""
        return self.stages.compiled

    @property
    def compile_seconds(self) -> float:
        """Wall seconds of the compiled stage calls that compiled (config.compile); 0 when eager."""
        return self.stages.compile_seconds

    def clone(self) -> Agent:
        """A deep copy (networks, optimiser states, RNG streams) that shares nothing with self;
        its updates run eager."""
        return copy.deepcopy(self)

    # ------------------------------------------------------------------ networks of one env
    def policy(self, name: str, task_ids: torch.Tensor) -> Policy:
        """Env `name`'s actor at the heads of `task_ids`: actor input -> mean and log std."""
        return lambda x: self.actor(self._keys[name], x, task_ids)

    def qf(self, name: str, task_ids: torch.Tensor) -> TwinQ:
        """Env `name`'s twin critics: (actor input, actions) -> (2, B)."""
        return lambda x, a: self.critic(
            self._keys[name], self._critic_input(name, x, a), task_ids
        ).squeeze(-1)

    def qf_target(self, name: str, task_ids: torch.Tensor) -> TwinQ:
        """Env `name`'s target critics: (actor input, actions) -> (2, B)."""
        return lambda x, a: self.critic_target(
            self._keys[name], self._critic_input(name, x, a), task_ids
        ).squeeze(-1)

    def log_alpha_of(self, name: str) -> nn.Parameter:
        """Env `name`'s per-task log temperatures."""
        return self.log_alpha[self._keys[name]]

    def alpha_position(self, name: str) -> int:
        """Where env `name`'s log temperatures sit in the temperatures' Adam."""
        return self._alpha_position[name]

    def polyak_pairs(self) -> tuple[list[nn.Parameter], list[nn.Parameter]]:
        """(target critic parameters, online critic parameters), in the same order."""
        return self._polyak

    # ------------------------------------------------------------------ acting
    def _actor_input(self, name: str, obs: torch.Tensor, task_ids: torch.Tensor) -> torch.Tensor:
        """Raw obs with the one-hot task id appended when config.one_hot; under smt_gru the
        observation [obs | belief | step] without its step."""
        if self.config.obs_extra:
            return obs[..., :-1]
        if not self.config.one_hot:
            return obs
        return torch.cat(
            (obs, F.one_hot(task_ids, self.specs[name].num_tasks).to(obs.dtype)), dim=-1
        )

    def _critic_input(
        self, name: str, actor_input: torch.Tensor, actions: torch.Tensor
    ) -> torch.Tensor:
        """[actor input, action zero-padded to act_pad_to]."""
        pad = self.specs[name].critic_act_dim - actions.shape[-1]
        if pad:
            actions = F.pad(actions, (0, pad))
        return torch.cat((actor_input, actions), dim=-1)

    def _policy(
        self,
        name: str,
        x: torch.Tensor,
        task_ids: torch.Tensor,
        generator: torch.Generator,
        deterministic: bool,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Tanh-Gaussian action and its log-probability for each row."""
        mean_log_std = self.actor(self._keys[name], x, task_ids)
        noise = None
        if not deterministic:
            noise = torch.randn(
                mean_log_std.shape[0],
                self.specs[name].act_dim,
                generator=generator,
                device=x.device,
                dtype=x.dtype,
            )
        return tanh_gaussian(mean_log_std, noise)

    def act(
        self, env_name: str, obs: np.ndarray, task_ids: np.ndarray, deterministic: bool = False
    ) -> np.ndarray:
        """Actions (N, act_dim) float32 in [-1, 1] for raw observations (N, obs_dim) of `env_name`."""
        spec = self._spec(env_name)
        obs, task_ids = self._check_inputs(env_name, spec, obs, task_ids)
        with torch.inference_mode():
            obs_t = torch.from_numpy(obs).to(self.device)
            ids_t = torch.from_numpy(task_ids).to(self.device)
            actions, _ = self._policy(
                env_name,
                self._actor_input(env_name, obs_t, ids_t),
                ids_t,
                self._act_generators[env_name],
                deterministic,
            )
            return actions.cpu().numpy()

    def reseed_acting(self, seed: int) -> None:
        """Seed every env's exploration noise from (seed, "act", env name)."""
        self._act_generators = {n: stream(seed, "act", n, device=self.device) for n in self.specs}

    def log_prob(
        self, env_name: str, obs: np.ndarray, actions: np.ndarray, task_ids: np.ndarray
    ) -> np.ndarray:
        """Log-density (N,) of the stochastic policy at given actions in [-1, 1] (SMT's entropy term).

        Same density as the update's: the pre-tanh value is atanh(action) (actions clipped to
        +-(1 - 1e-6) so that atanh stays finite), then `tanh_gaussian`'s formula.
        """
        with torch.inference_mode():
            x, actions_t, ids_t = self._state_actions("log_prob", env_name, obs, actions, task_ids)
            mean_log_std = self.actor(self._keys[env_name], x, ids_t)
            mean, log_std = mean_log_std.chunk(2, dim=-1)
            pre_tanh = actions_t.clamp(-1 + 1e-6, 1 - 1e-6).atanh()
            noise = (pre_tanh - mean) / log_std.clamp(LOG_STD_MIN, LOG_STD_MAX).exp()
            _, log_prob = tanh_gaussian(mean_log_std, noise)
            return log_prob.cpu().numpy()

    def q_values(
        self, env_name: str, obs: np.ndarray, actions: np.ndarray, task_ids: np.ndarray
    ) -> np.ndarray:
        """The twin critics' Q (2, N) of raw observations (N, obs_dim) and actions (N, act_dim)."""
        with torch.inference_mode():
            x, actions_t, ids_t = self._state_actions("q_values", env_name, obs, actions, task_ids)
            return self.qf(env_name, ids_t)(x, actions_t).cpu().numpy()

    def _state_actions(
        self, what: str, env_name: str, obs: np.ndarray, actions: np.ndarray, task_ids: np.ndarray
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(actor input, actions, task ids) as tensors on the device, or SealError naming `what`."""
        spec = self._spec(env_name)
        actions = np.asarray(actions, dtype=np.float32)
        if actions.ndim != 2 or actions.shape[1] != spec.act_dim:
            raise SealError(
                f"{what}({env_name!r}): expected actions (N, {spec.act_dim}), got {actions.shape}"
            )
        obs, task_ids = self._check_inputs(env_name, spec, obs, task_ids)
        obs_t = torch.from_numpy(obs).to(self.device)
        ids_t = torch.from_numpy(task_ids).to(self.device)
        actions_t = torch.from_numpy(actions).to(self.device)
        return self._actor_input(env_name, obs_t, ids_t), actions_t, ids_t

    def _check_inputs(
        self, env_name: str, spec: EnvSpec, obs: np.ndarray, task_ids: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """obs as float32 (N, obs_dim + obs_extra) and task ids as int64 (N,) in range, else SealError."""
        obs = np.asarray(obs, dtype=np.float32)
        task_ids = np.asarray(task_ids, dtype=np.int64)
        width = spec.obs_dim + self.config.obs_extra
        if obs.ndim != 2 or obs.shape[1] != width or task_ids.shape != (obs.shape[0],):
            under = (
                " ([obs | belief | step] under smt_gru: act through seal.evaluation.AgentPolicy, whose BeliefMemory adds them)"
                if self.config.obs_extra
                else ""
            )
            raise SealError(
                f"{env_name!r}: expected obs (N, {width}){under} and task_ids (N,), got {obs.shape} and {task_ids.shape}"
            )
        if task_ids.size and (task_ids.min() < 0 or task_ids.max() >= spec.num_tasks):
            raise SealError(
                f"{env_name!r}: task ids must be in [0, {spec.num_tasks}), got {sorted(set(task_ids.tolist()))}"
            )
        return obs, task_ids

    def _spec(self, env_name: str) -> EnvSpec:
        if env_name not in self.specs:
            raise UnknownNameError("environment", env_name, list(self.specs))
        return self.specs[env_name]

    # ------------------------------------------------------------------ the update
    def inputs(self, batches: Mapping[str, Batch]) -> dict[str, EnvInputs]:
        """Per env with samples, in spec order: its batch on the device, its temperatures and the
        actor's inputs of its observations and next observations."""
        inputs = {}
        for name in self.specs:
            # An env with an empty batch (a ratio of 0) takes no step this update.
            if name not in batches or batches[name].obs.shape[0] == 0:
                continue
            batch = batches[name]
            if batch.obs.device != self.device:
                batch = Batch(*(t.to(self.device, non_blocking=True) for t in batch))
            inputs[name] = EnvInputs(
                batch,
                self.log_alpha_of(name).detach().exp(),
                self._actor_input(name, batch.obs, batch.task_ids),
                self._actor_input(name, batch.next_obs, batch.task_ids),
            )
        return inputs

    def update(self, batches: Mapping[str, Batch]) -> dict[str, float]:
        """One gradient update (critic, actor, per-task alpha, Polyak target) over every env in `batches`.

        Returns `losses/<env>/{critic,qf1,qf2,actor,alpha}`, `charts/<env>/{mean_q,entropy}`,
        `charts/<env>/alpha/<task index>` (the temperature used by this update), with
        config.gradient = "pcgrad" `charts/<env>/pcgrad_conflicts/{critic,actor}` (the projections
        PCGrad made, `seal.learner.mtrl.pcgrad`) and, with two or more envs and
        config.ratio_lever_interval > 0, `charts/ratio_lever` (the last measured value). Raises TrainingDivergedError naming the update and the last good checkpoint if a
        loss is NaN/inf. One device sync; a training loop uses `update_on_device` and reads its
        sums once per interval instead.
        """
        metrics = self.read_logs(*self.update_on_device(batches), first_update=self.num_updates)
        if self.last_ratio_lever is not None:
            metrics["charts/ratio_lever"] = self.last_ratio_lever
        return metrics

    def update_on_device(
        self, batches: Mapping[str, Batch]
    ) -> tuple[tuple[str, ...], torch.Tensor]:
        """`update` without the sync: (the log names, their values as one tensor on the device).

        Sums of these tensors over updates with the same names are read by `read_logs`.
        """
        for name in batches:
            self._spec(name)
        interval = self.config.ratio_lever_interval
        multi_env = sum(1 for b in batches.values() if b.obs.shape[0] > 0) >= 2
        if interval and self.num_updates % interval == 0 and multi_env:
            # Off the hot path: three updates on copies of the agent, every `interval` updates.
            self.last_ratio_lever = self.ratio_lever(batches)["lever"]
        inputs = self.inputs(batches)
        scalars = sac_update(self, inputs, draw_noise(self, inputs), batch_shares(inputs))
        self.num_updates += 1
        values = torch.cat(scalars) if scalars else torch.zeros(0, device=self.device)
        return self._log_names(tuple(inputs)), values

    def ratio_lever(self, batches: Mapping[str, Batch]) -> lever.RatioLever:
        """`seal.learner.lever.ratio_lever` of this agent (which it leaves unchanged)."""
        return lever.ratio_lever(self, batches)

    def ratio_lever_expected(
        self, batch_draws: Sequence[Mapping[str, Batch]]
    ) -> lever.RatioLeverExpected:
        """`seal.learner.lever.ratio_lever_expected` of this agent (which it leaves unchanged)."""
        return lever.ratio_lever_expected(self, batch_draws)

    def _log_names(self, order: tuple[str, ...]) -> tuple[str, ...]:
        """The names of `update_on_device`'s values for envs updated in `order`."""
        return tuple(
            name
            for env in order
            for name in (
                *(template.format(env) for template in _SCALARS),
                *(
                    (
                        f"charts/{env}/pcgrad_conflicts/critic",
                        f"charts/{env}/pcgrad_conflicts/actor",
                    )
                    if self.config.gradient == "pcgrad"
                    else ()
                ),
                *(f"charts/{env}/alpha/{task}" for task in range(self.specs[env].num_tasks)),
            )
        )

    def read_logs(
        self, names: tuple[str, ...], values: torch.Tensor, first_update: int
    ) -> dict[str, float]:
        """One device sync: `names` -> values (sums, when summed over updates since `first_update`).

        Raises TrainingDivergedError on a non-finite value (a NaN/inf in any summed update makes
        its sum non-finite), naming the updates and the last good checkpoint.
        """
        metrics = dict(zip(names, values.tolist(), strict=True))
        bad = [k for k, v in metrics.items() if not math.isfinite(v)]
        if bad:
            updates = (
                f"update {self.num_updates}"
                if first_update + 1 >= self.num_updates
                else f"one of updates {first_update + 1}-{self.num_updates}"
            )
            raise TrainingDivergedError(
                f"training diverged at {updates}: {', '.join(f'{k} = {metrics[k]}' for k in bad)}",
                self.last_checkpoint,
            )
        return metrics

    # ------------------------------------------------------------------ state
    def parameters_finite(self) -> bool:
        """True when every network parameter and temperature is finite."""
        params = [
            *self.actor.parameters(),
            *self.critic.parameters(),
            *self.critic_target.parameters(),
            *self.log_alpha.values(),
            *(self.encoders.parameters() if self.encoders is not None else ()),
        ]
        return bool(torch.stack([torch.isfinite(p).all() for p in params]).all())
