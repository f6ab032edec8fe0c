"""Multi-task multi-head SAC (MTMHSAC) and the SEAL agent: acting, one gradient update, state.

The update follows cleanrl's sac_continuous_action.py with the paper's names, per environment i
(B samples of env i, each with its task id t):

    next_state_actions, next_state_log_pi ~ pi(. | s')
    min_qf_next_target = min(qf1_target, qf2_target)(s', a') - alpha_t * next_state_log_pi
    next_q_value       = r + gamma * (1 - termination) * min_qf_next_target
    qf_loss            = mse(qf1(s, a), next_q_value) + mse(qf2(s, a), next_q_value)
    actor_loss         = mean(alpha_t * log_pi - min(qf1, qf2)(s, pi(s)))       (critic just updated)
    alpha_loss         = mean(-log_alpha_t * (log_pi + target_entropy))          (log_pi detached)
    target             <- (1 - tau) * target + tau * online                      (once per update)

Temperatures are per task (one log_alpha per task of each env, MTMHSAC). The alpha loss uses
log_alpha rather than alpha, as garage's MTSAC (the Meta-World MTMHSAC) and stable-baselines3 do:
same sign of gradient as cleanrl's alpha form, and Adam makes the scale immaterial.

How the environments of one update step the shared parameters (`AgentConfig.shared_update`):

- "weighted": one Adam over the whole policy (and over the whole critic when critics are shared);
  one step on sum_i (n_i / N) L_i, L_i env i's mean loss over its n_i samples, N = sum_i n_i. At a
  90/10 ratio the 90% env carries ~90% of the trunk's gradient.
- "sequential": the same single Adam, stepped once per env on that env's mean loss, env after env
  (critic then actor for env 1, then env 2, ...): the authors' prototype.
- "per_env": one Adam per env over its translator, the shared trunk and its head (SEAL §3.3:
  "optimizer i is operating on f_theta_i, g_phi_i and pi_eta"), stepped env after env. Adam is
  invariant to a loss's scale, so the data ratio then changes only gradient noise.

Per-env critics (`critic_sharing = "per_env"`) share nothing, so each has its own Adam stepped on its
own mean loss in every mode. Every actor and critic step clips the global gradient norm of that
optimiser's parameters to `max_grad_norm` (0: off); the temperatures' Adam is never clipped.
`ratio_lever` measures how much of the trunk's step each environment causes.

Each stage of an update (`_critic_stage`, then `_actor_stage`) computes its losses and their
gradients as one function of pre-drawn policy noise; with `AgentConfig.compile` that function is
torch.compiled, forward and backward (and the gradient clipping, `_clipped`) in one graph (eager
fallback on any compiler failure), and the optimiser steps (`_adam_step`) stay eager either way.
On CUDA each compiled stage is replayed as a CUDA graph (`compile_mode`); between the two graphs
run the noise draws, the fused Adam kernels and the Polyak lerp.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict
from typing import Any, NamedTuple, TypedDict

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from seal.device import resolve_device
from seal.errors import SealError, TrainingDivergedError, UnknownNameError
from seal.learner.config import AgentConfig, Batch, EnvSpec
from seal.learner.networks import (
    HEAD_BOUND,
    LOG_STD_MAX,
    LOG_STD_MIN,
    PerEnvCritic,
    Segments,
    TaskNetwork,
    tanh_gaussian,
)

# 2: per-env critics (critic_sharing), optimiser slots by shared_update, the cached ratio lever.
STATE_FORMAT = 2
# Per-env scalars returned by update(), in the order they are stacked before the single .tolist().
_SCALARS = (
    "losses/{}/qf1",
    "losses/{}/qf2",
    "losses/{}/critic",
    "losses/{}/actor",
    "losses/{}/alpha",
    "charts/{}/mean_q",
    "charts/{}/entropy",
)


StageInputs = Mapping[str, tuple[Batch, torch.Tensor, torch.Tensor, torch.Tensor]]
"""Per env, what both update stages read (`Agent._inputs`): batch, alpha, actor input, next actor input."""


class RatioLever(TypedDict):
    """`Agent.ratio_lever`'s measurement (see its docstring)."""

    lever: float
    env: str
    share: float
    step_norm: float
    effect: dict[str, float]
    grad_norm: dict[str, float]


class RatioLeverExpected(TypedDict):
    """`Agent.ratio_lever_expected`'s measurement (see its docstring)."""

    lever: float
    env: str
    share: float
    draws: int
    step_norm: float
    effect: dict[str, float]
    single_draw_lever_mean: float


def _lever_effects(steps: Mapping[str | None, torch.Tensor]) -> dict[str, float]:
    """||Δ - Δ₋X|| for every X of `Agent._trunk_steps`' steps (Δ under the key None)."""
    return {n: float((steps[None] - step).norm()) for n, step in steps.items() if n is not None}


def _lever(effect: Mapping[str, float], env_a: str) -> float:
    """||Δ - Δ₋A|| / sum_X ||Δ - Δ₋X|| (NaN when no env moves the trunk)."""
    total = sum(effect.values())
    return effect[env_a] / total if total > 0 else float("nan")


def _module_key(name: str) -> str:
    """A ModuleDict-safe key for an env name: torch forbids only dots (and the empty name)."""
    return name.replace(".", "_") or "_"


def _unique(params: Iterable[nn.Parameter]) -> list[nn.Parameter]:
    """Parameters in first-seen order without repeats (the shared trunk appears once)."""
    seen: set[int] = set()
    out = []
    for p in params:
        if id(p) not in seen:
            seen.add(id(p))
            out.append(p)
    return out


def _clipped(grads: Sequence[torch.Tensor | None], max_norm: float) -> list[torch.Tensor | None]:
    """nn.utils.clip_grad_norm_'s arithmetic on one slot's gradients (2-norm over those present,
    coefficient max_norm / (norm + 1e-6) capped at 1), as plain tensor ops: inside a compiled
    stage they fuse with the backward. No host sync: the coefficient stays a tensor.
    """
    present = [g for g in grads if g is not None]
    if not present:
        return list(grads)
    # foreach ops: one dispatch for all tensors instead of one each (eager: ~60 fewer ops/update)
    total = torch.linalg.vector_norm(torch.stack(torch._foreach_norm(present)))
    coefficient = torch.clamp(max_norm / (total + 1e-6), max=1.0)
    scaled = iter(torch._foreach_mul(present, coefficient))
    return [None if g is None else next(scaled) for g in grads]


def compile_mode(device: torch.device) -> str | None:
    """torch.compile's mode for the update stages: on CUDA "reduce-overhead", which replays each
    compiled stage as a CUDA graph (one launch for its forward and backward kernels); elsewhere
    the default, since CPU has no graphs. Not yet run on a GPU (README, Speed)."""
    return "reduce-overhead" if device.type == "cuda" else None


def _step_counters(states: Sequence[dict[str, torch.Tensor]]) -> torch.Tensor:
    """One tensor whose elements are these Adam states' `step` counters (rebinding each state's
    `step` to a view of it the first time), so a step increments them all with one add_.

    On CPU `_foreach_add_` over ~40 scalar counters costs ~0.2 ms an update (one add per
    tensor); the views keep each state's own `step`, saved and loaded as before.
    """
    steps = [s["step"] for s in states]
    flat = steps[0]._base
    if (
        flat is None
        or flat.dim() != 1
        or flat.numel() != len(steps)
        or any(t._base is not flat or t.storage_offset() != i for i, t in enumerate(steps))
    ):
        flat = torch.stack([t.detach() for t in steps])
        for i, state in enumerate(states):
            state["step"] = flat[i]
    return flat


class _AdamPlan(NamedTuple):
    """One `torch._fused_adam_` call's fixed arguments: parameters and states of one setting."""

    lr: float
    betas: tuple[float, float]
    eps: float
    positions: list[int]  # where these parameters' gradients sit in the step's gradient list
    params: list[torch.Tensor]
    exp_avgs: list[torch.Tensor]
    exp_avg_sqs: list[torch.Tensor]
    counters: torch.Tensor  # every `step` as a view of this one tensor (`_step_counters`)
    steps: list[torch.Tensor]


def _adam_token(optimizers: Sequence[torch.optim.Optimizer]) -> tuple[object, ...]:
    """What an `_AdamPlan` of these optimisers depends on: their state dicts and learning rates
    (load_state_dict replaces `state`; a first step fills it; set_lr_factor changes `lr`)."""
    return tuple(
        (id(o.state), len(o.state), *(g["lr"] for g in o.param_groups)) for o in optimizers
    )


def _adam_plans(
    optimizers: Sequence[torch.optim.Optimizer], num_grads: int
) -> list[_AdamPlan] | None:
    """The fused calls stepping `optimizers` as Adam(fused=True).step() would, grouped by
    setting; None when a setting is not covered (amsgrad, weight decay, maximize, ...), a
    parameter has no state yet (a first step), or torch has no `_fused_adam_`."""
    if not hasattr(torch, "_fused_adam_"):  # a private op: a torch without it steps plainly
        return None
    by_setting: dict[tuple[float, float, float, float], list[tuple[int, torch.Tensor, dict]]] = {}
    position = 0
    for optimizer in optimizers:
        for group in optimizer.param_groups:
            if (
                not group.get("fused")
                or group["amsgrad"]
                or group["weight_decay"]
                or group["maximize"]
                or group.get("decoupled_weight_decay")
                or group["capturable"]
                or group["differentiable"]
                or not isinstance(group["lr"], float)
            ):
                return None
            beta1, beta2 = group["betas"]
            key = (group["lr"], float(beta1), float(beta2), float(group["eps"]))
            for p in group["params"]:
                state = optimizer.state.get(p)
                if not state:
                    return None
                by_setting.setdefault(key, []).append((position, p, state))
                position += 1
    if position != num_grads:
        raise ValueError(f"{num_grads} gradients for {position} optimised parameters")
    plans = []
    for (lr, beta1, beta2, eps), members in by_setting.items():
        states = [state for _, _, state in members]
        counters = _step_counters(states)
        plans.append(
            _AdamPlan(
                lr=lr,
                betas=(beta1, beta2),
                eps=eps,
                positions=[i for i, _, _ in members],
                params=[p for _, p, _ in members],
                exp_avgs=[state["exp_avg"] for state in states],
                exp_avg_sqs=[state["exp_avg_sq"] for state in states],
                counters=counters,
                steps=list(counters.unbind()),
            )
        )
    return plans


def _adam_step(
    optimizers: Sequence[torch.optim.Optimizer],
    grads: Sequence[torch.Tensor | None],
    cache: dict[tuple[int, ...], tuple[tuple[object, ...], list[_AdamPlan]]],
) -> None:
    """`step()` of each of these fused Adams on `grads` (one per parameter, in the optimisers'
    order), done as one `torch._fused_adam_` call per setting.

    The same kernel and arithmetic as Adam(fused=True).step(), without its per-call grouping
    and checks (~0.2 ms a call on CPU; an update steps 3-4 optimisers): the calls' lists are
    built once and kept in `cache` while the optimisers' states and learning rates stay the
    same (`_adam_token`). A parameter whose gradient is None is left alone, as Adam does. Falls
    back to setting `.grad` and plain step() where `_adam_plans` does not cover the optimisers.
    """
    key = tuple(id(o) for o in optimizers)
    token = _adam_token(optimizers)
    cached = cache.get(key)
    if cached is not None and cached[0] == token:
        plans: list[_AdamPlan] | None = cached[1]
    else:
        plans = _adam_plans(optimizers, len(grads))
        if plans is None:
            params = [p for o in optimizers for g in o.param_groups for p in g["params"]]
            for p, g in zip(params, grads, strict=True):
                p.grad = g
            for optimizer in optimizers:
                optimizer.step()
            return
        cache[key] = (token, plans)
    for plan in plans:
        plan_grads = [grads[i] for i in plan.positions]
        params, exp_avgs, exp_avg_sqs, steps = (
            plan.params,
            plan.exp_avgs,
            plan.exp_avg_sqs,
            plan.steps,
        )
        if any(g is None for g in plan_grads):
            kept = [i for i, g in enumerate(plan_grads) if g is not None]
            if not kept:
                continue
            params, exp_avgs, exp_avg_sqs, steps = (
                [x[i] for i in kept] for x in (params, exp_avgs, exp_avg_sqs, steps)
            )
            for i, step in enumerate(plan.steps):
                if plan_grads[i] is not None:
                    step.add_(1)
            plan_grads = [plan_grads[i] for i in kept]
        else:
            plan.counters.add_(1)
        torch._fused_adam_(
            params,
            plan_grads,
            exp_avgs,
            exp_avg_sqs,
            [],
            steps,
            amsgrad=False,
            lr=plan.lr,
            beta1=plan.betas[0],
            beta2=plan.betas[1],
            weight_decay=0.0,
            eps=plan.eps,
            maximize=False,
            grad_scale=None,
            found_inf=None,
        )


class Agent:
    """MTMHSAC (one EnvSpec) or SEAL (several) soft actor-critic over multi-task batches.

    `act` maps raw observations of one environment to actions in [-1, 1]; `update` takes one
    gradient step for every environment in its batches and returns grouped scalar logs.
    """

    def __init__(self, specs: Sequence[EnvSpec], config: AgentConfig, seed: int) -> None:
        specs = list(specs)
        if not specs:
            raise SealError("Agent needs at least one EnvSpec")
        names = [s.name for s in specs]
        if len(set(names)) != len(names):
            raise SealError(f"Agent: environment names repeat: {names}")
        if config.architecture == "mtmhsac" and len(specs) != 1:
            raise SealError(
                f'agent.architecture = "mtmhsac" trains one environment, got {len(specs)} ({", ".join(names)}); use "seal" for several'
            )
        keys = {s.name: _module_key(s.name) for s in specs}
        if len(set(keys.values())) != len(keys):
            raise SealError(
                f"Agent: environment names {names} collide after replacing '.' with '_'"
            )
        self.config = config
        self.seed = int(seed)
        self.device = resolve_device(config.device)
        self.specs: dict[str, EnvSpec] = {s.name: s for s in specs}
        self._keys = keys
        init_seed, update_seed, act_seed = (
            np.random.SeedSequence(self.seed).generate_state(3, np.uint32).tolist()
        )
        # Init draws on CPU so the same seed gives the same weights on every device.
        self._init_generator = torch.Generator().manual_seed(init_seed)
        # Separate streams: how often the collector acts does not change the update's noise.
        self._update_generator = torch.Generator(self.device).manual_seed(update_seed)
        self._act_generator = torch.Generator(self.device).manual_seed(act_seed)

        task_segment = {s.name: ((("task", s.num_tasks),) if config.one_hot else ()) for s in specs}
        self.actor_segments: dict[str, Segments] = {
            keys[s.name]: (("obs", s.obs_dim), *task_segment[s.name]) for s in specs
        }
        self.critic_segments: dict[str, Segments] = {
            keys[s.name]: (("obs", s.obs_dim), *task_segment[s.name], ("action", s.critic_act_dim))
            for s in specs
        }
        translator = (
            None
            if config.architecture == "mtmhsac"
            else (config.translator_hidden, config.latent_dim)
        )
        trunk = config.hidden if config.architecture == "mtmhsac" else config.trunk_hidden
        self.actor = TaskNetwork(
            self.actor_segments,
            {keys[s.name]: 2 * s.act_dim for s in specs},
            {keys[s.name]: s.num_tasks if config.multi_head_policy else 1 for s in specs},
            trunk,
            translator,
            ensemble=1,
        )
        critic_heads = {keys[s.name]: s.num_tasks if config.critic_multi_head else 1 for s in specs}
        self.critic: TaskNetwork | PerEnvCritic
        if config.architecture == "seal" and config.critic_sharing == "per_env":
            self.critic = PerEnvCritic(
                self.critic_segments, critic_heads, config.critic_hidden, ensemble=2
            )
        else:
            self.critic = TaskNetwork(
                self.critic_segments,
                {keys[s.name]: 1 for s in specs},
                critic_heads,
                trunk,
                translator,
                ensemble=2,  # twin Q: qf1 and qf2 as one stacked network
            )
        self.log_alpha = nn.ParameterDict(
            {keys[s.name]: nn.Parameter(torch.empty(s.num_tasks)) for s in specs}
        )
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
        self._actor_slot = {n: i for i, ns in enumerate(self._actor_members) for n in ns}
        self._critic_slot = {n: i for i, ns in enumerate(self._critic_members) for n in ns}
        # Independent critics each see their own mean loss; a shared critic follows shared_update.
        self._weighted = {
            "actor": config.shared_update == "weighted",
            "critic": config.shared_update == "weighted" and not independent_critics,
        }
        self.last_ratio_lever: float | None = None
        """The ratio lever last measured by update() (every config.ratio_lever_interval updates)."""
        self._lr_factor = config.lr_factor
        self.num_updates = 0
        self.last_checkpoint: str | None = None
        """Path of the last checkpoint written by seal.learner.checkpoint.save_checkpoint."""
        self._initialise()
        self._compiled: dict[str, Callable[..., object]] = {}
        self.compile_seconds = 0.0
        """Wall seconds of the compiled stage calls that compiled (config.compile); 0 when eager."""
        if config.compile:
            self._try_compile()

    # ------------------------------------------------------------------ construction and reset
    def _initialise(self) -> None:
        """Draw all weights, copy the target critics, set temperatures, build fresh optimisers."""
        for net, role in ((self.actor, "actor"), (self.critic, "critic")):
            net.cpu()
            net.reset_parameters(self._init_generator, self.config.init, HEAD_BOUND[role])
            net.to(self.device)
        # A deep copy: the targets own their tensors (never views of the online critics).
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        with torch.no_grad():
            for log_alpha in self.log_alpha.values():
                log_alpha.fill_(math.log(self.config.init_alpha))
        self.log_alpha.to(self.device)
        self._build_optimizers()

    def _build_optimizers(self) -> None:
        """Fresh Adam states: one actor and one critic Adam per optimiser slot, one for temperatures."""
        # measured: fused Adam is ~8x faster than foreach on CPU here
        adam = {"fused": True, "eps": self.config.adam_eps}
        self._adam_cache: dict[tuple[int, ...], tuple[tuple[object, ...], list[_AdamPlan]]] = {}
        # New parameters or states may fail the compiled stages' guards: the next call of each
        # stage key may recompile, so it traces again (`_stage`).
        self._compiled_keys: set[tuple[object, ...]] = set()
        self.actor_optimizers: list[torch.optim.Adam] = []
        self.critic_optimizers: list[torch.optim.Adam] = []
        self._actor_params: list[list[nn.Parameter]] = []
        self._critic_params: list[list[nn.Parameter]] = []
        for net, slots, params, optimizers, lr in (
            (
                self.actor,
                self._actor_members,
                self._actor_params,
                self.actor_optimizers,
                "actor_lr",
            ),
            (
                self.critic,
                self._critic_members,
                self._critic_params,
                self.critic_optimizers,
                "critic_lr",
            ),
        ):
            for members in slots:
                owned = _unique(p for n in members for p in net.env_parameters(self._keys[n]))
                params.append(owned)
                optimizers.append(
                    torch.optim.Adam(owned, lr=getattr(self.config, lr) * self._lr_factor, **adam)
                )
        self._alpha_params = list(self.log_alpha.values())
        alpha_keys = list(self.log_alpha.keys())
        self._alpha_slot = {n: alpha_keys.index(self._keys[n]) for n in self.specs}
        self.alpha_optimizer = torch.optim.Adam(self._alpha_params, lr=self.config.alpha_lr, **adam)
        self._online_critic = list(self.critic.parameters())
        self._target_critic = list(self.critic_target.parameters())

    def reset_parameters(self) -> None:
        """SMT reset: re-draw the policy, Q networks and targets, reset temperatures and optimiser states.

        The learning-rate factor in force is kept; update and act counters and RNG streams go on.
        """
        self._initialise()

    def set_lr_factor(self, factor: float) -> None:
        """Scale the actor and critic learning rates to factor * actor_lr / critic_lr (temperatures keep alpha_lr)."""
        if not math.isfinite(factor) or factor <= 0:
            raise SealError(f"lr_factor must be a finite number > 0, got {factor!r}")
        self._lr_factor = float(factor)
        for optimizer in self.actor_optimizers:
            for group in optimizer.param_groups:
                group["lr"] = self.config.actor_lr * self._lr_factor
        for optimizer in self.critic_optimizers:
            for group in optimizer.param_groups:
                group["lr"] = self.config.critic_lr * self._lr_factor

    def _try_compile(self) -> None:
        """torch.compile each update stage's losses and their gradients, forward and backward in
        one graph (compilation itself happens at the first call of each stage)."""
        mode = compile_mode(self.device)
        self._compiled["critic"] = torch.compile(
            self._critic_stage, fullgraph=True, dynamic=False, mode=mode
        )
        self._compiled["actor"] = torch.compile(
            self._actor_stage, fullgraph=True, dynamic=False, mode=mode
        )

    @property
    def compiled(self) -> bool:
        """Whether updates run compiled (config.compile on and compilation has not failed)."""
        return bool(self._compiled)

    def _stage(self, kind: str, *args: Any) -> Any:
        """The compiled stage `kind` ("critic"/"actor") when compile is on and works, else eager.

        torch.compile fails lazily (no C++ compiler, unsupported op or torch version): the first
        failure warns once and switches this agent to eager for good; a real error then re-raises
        from eager. A stage has no side effects (its noise is drawn before), so a failed compiled
        call is simply run again eagerly. A call that compiles adds its seconds to
        `compile_seconds`.
        """
        eager = self._critic_stage if kind == "critic" else self._actor_stage
        compiled = self._compiled.get(kind)
        if compiled is not None:
            stage, kept, inputs, _, weights = args
            sizes = tuple((n, batch.obs.shape[0]) for n, (batch, *_) in inputs.items())
            key = (kind, tuple(stage), tuple(kept), sizes, tuple(sorted(weights.items())))
            start = time.perf_counter()
            try:
                if key in self._compiled_keys:
                    out = compiled(*args)  # compiled for this key: no tracing, no config patch
                else:
                    # Tracing autograd.grad needs this flag; patching costs ~50 us, so only here.
                    with torch._dynamo.config.patch(trace_autograd_ops=True):
                        out = compiled(*args)
            except Exception as exc:  # any compiler failure means: run eager
                import warnings

                warnings.warn(
                    f"torch.compile failed ({type(exc).__name__}: {exc}); running eager",
                    stacklevel=3,
                )
                self._compiled.clear()
            else:
                if key not in self._compiled_keys:
                    self._compiled_keys.add(key)
                    self.compile_seconds += time.perf_counter() - start
                return out
        return eager(*args)

    # ------------------------------------------------------------------ forward passes
    def _actor_input(self, name: str, obs: torch.Tensor, task_ids: torch.Tensor) -> torch.Tensor:
        """Raw obs with the one-hot task id appended when config.one_hot."""
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

    # ------------------------------------------------------------------ acting
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
                self._act_generator,
                deterministic,
            )
            return actions.cpu().numpy()

    def log_prob(
        self, env_name: str, obs: np.ndarray, actions: np.ndarray, task_ids: np.ndarray
    ) -> np.ndarray:
        """Log-density (N,) of the stochastic policy at given actions in [-1, 1] (SMT's entropy term).

        Same density as the update's: the pre-tanh value is atanh(action) (actions clipped to
        +-(1 - 1e-6) so that atanh stays finite), then `tanh_gaussian`'s formula.
        """
        spec = self._spec(env_name)
        actions = np.asarray(actions, dtype=np.float32)
        if actions.ndim != 2 or actions.shape[1] != spec.act_dim:
            raise SealError(
                f"log_prob({env_name!r}): expected actions (N, {spec.act_dim}), got {actions.shape}"
            )
        obs, task_ids = self._check_inputs(env_name, spec, obs, task_ids)
        with torch.inference_mode():
            obs_t = torch.from_numpy(obs).to(self.device)
            ids_t = torch.from_numpy(task_ids).to(self.device)
            mean_log_std = self.actor(
                self._keys[env_name], self._actor_input(env_name, obs_t, ids_t), ids_t
            )
            mean, log_std = mean_log_std.chunk(2, dim=-1)
            pre_tanh = torch.from_numpy(actions).to(self.device).clamp(-1 + 1e-6, 1 - 1e-6).atanh()
            noise = (pre_tanh - mean) / log_std.clamp(LOG_STD_MIN, LOG_STD_MAX).exp()
            _, log_prob = tanh_gaussian(mean_log_std, noise)
            return log_prob.cpu().numpy()

    @staticmethod
    def _check_inputs(
        env_name: str, spec: EnvSpec, obs: np.ndarray, task_ids: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """obs as float32 (N, obs_dim) and task ids as int64 (N,) in range, else SealError."""
        obs = np.asarray(obs, dtype=np.float32)
        task_ids = np.asarray(task_ids, dtype=np.int64)
        if obs.ndim != 2 or obs.shape[1] != spec.obs_dim or task_ids.shape != (obs.shape[0],):
            raise SealError(
                f"{env_name!r}: expected obs (N, {spec.obs_dim}) and task_ids (N,), got {obs.shape} and {task_ids.shape}"
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
    def _draw_noise(self, names: Iterable[str], inputs: StageInputs) -> dict[str, torch.Tensor]:
        """The update's standard normal policy noise (B, act_dim) of each env, in `names` order."""
        return {
            name: torch.randn(
                inputs[name][0].obs.shape[0],
                self.specs[name].act_dim,
                generator=self._update_generator,
                device=self.device,
                dtype=inputs[name][2].dtype,
            )
            for name in names
        }

    def _critic_loss(
        self,
        name: str,
        obs_in: torch.Tensor,
        next_obs_in: torch.Tensor,
        batch: Batch,
        alpha: torch.Tensor,
        noise: torch.Tensor,
    ) -> tuple[torch.Tensor, ...]:
        """qf1_loss, qf2_loss and the (2, B) Q values of the batch's actions."""
        key = self._keys[name]
        with torch.no_grad():
            next_state_actions, next_state_log_pi = tanh_gaussian(
                self.actor(key, next_obs_in, batch.task_ids), noise
            )
            qf_next_target = self.critic_target(
                key, self._critic_input(name, next_obs_in, next_state_actions), batch.task_ids
            ).squeeze(-1)
            min_qf_next_target = qf_next_target.amin(0) - alpha[batch.task_ids] * next_state_log_pi
            next_q_value = (
                batch.rewards + (1.0 - batch.terminations) * self.config.gamma * min_qf_next_target
            )
        qf_a_values = self.critic(
            key, self._critic_input(name, obs_in, batch.actions), batch.task_ids
        ).squeeze(-1)
        qf1_a_values, qf2_a_values = qf_a_values
        qf1_loss = F.mse_loss(qf1_a_values, next_q_value)
        qf2_loss = F.mse_loss(qf2_a_values, next_q_value)
        return qf1_loss, qf2_loss, qf_a_values

    def _actor_loss(
        self,
        name: str,
        obs_in: torch.Tensor,
        task_ids: torch.Tensor,
        alpha: torch.Tensor,
        noise: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """actor_loss and the (detached later) log-probabilities of the sampled actions."""
        pi, log_pi = tanh_gaussian(self.actor(self._keys[name], obs_in, task_ids), noise)
        qf_pi = self.critic(
            self._keys[name], self._critic_input(name, obs_in, pi), task_ids
        ).squeeze(-1)
        min_qf_pi = qf_pi.amin(0)
        actor_loss = (alpha[task_ids] * log_pi - min_qf_pi).mean()
        return actor_loss, log_pi

    def _slots(self, role: str, names: list[str]) -> list[int]:
        slot_of = self._actor_slot if role == "actor" else self._critic_slot
        return sorted({slot_of[n] for n in names})

    def _grads(
        self,
        role: str,
        names: list[str],
        losses: Mapping[str, torch.Tensor],
        weights: Mapping[str, float],
    ) -> tuple[torch.Tensor | None, ...]:
        """Gradients for every `role` ("actor"/"critic") slot the envs `names` use, in slot order.

        The loss is sum_i w_i L_i under weighting, else sum_i L_i (one env, or independent
        critics whose slots share no parameter). Backward goes into exactly the slots' parameters
        (unused ones get None); with max_grad_norm > 0 each slot's gradients are clipped to it.
        """
        if self._weighted[role]:
            terms = [losses[n] if weights[n] == 1.0 else losses[n] * weights[n] for n in names]
        else:
            terms = [losses[n] for n in names]
        loss = terms[0] if len(terms) == 1 else torch.stack(terms).sum()
        all_params = self._actor_params if role == "actor" else self._critic_params
        slots = self._slots(role, names)
        params = [p for s in slots for p in all_params[s]]
        grads = torch.autograd.grad(loss, params, allow_unused=True)
        max_norm = self.config.max_grad_norm
        if max_norm <= 0:
            return grads
        clipped: list[torch.Tensor | None] = []
        for s in slots:
            clipped += _clipped(grads[len(clipped) : len(clipped) + len(all_params[s])], max_norm)
        return tuple(clipped)

    def _step(self, role: str, names: list[str], grads: Sequence[torch.Tensor | None]) -> None:
        """One optimiser step of every `role` slot the envs `names` use, on `_grads`' gradients.

        Unused parameters have no grad, so Adam leaves them alone (`_grads` clipped them).
        """
        slots = self._slots(role, names)
        optimizers = self.actor_optimizers if role == "actor" else self.critic_optimizers
        _adam_step([optimizers[s] for s in slots], grads, self._adam_cache)

    def _inputs(
        self, batches: Mapping[str, Batch]
    ) -> dict[str, tuple[Batch, torch.Tensor, torch.Tensor, torch.Tensor]]:
        """Per env with samples, in spec order: (batch on device, alpha, actor input, next actor input)."""
        inputs = {}
        for name in self.specs:
            # An env with an empty batch (a ratio of 0) takes no step this update.
            if name not in batches or batches[name].obs.shape[0] == 0:
                continue
            batch = batches[name]
            if batch.obs.device != self.device:
                batch = Batch(*(t.to(self.device, non_blocking=True) for t in batch))
            alpha = self.log_alpha[self._keys[name]].detach().exp()
            inputs[name] = (
                batch,
                alpha,
                self._actor_input(name, batch.obs, batch.task_ids),
                self._actor_input(name, batch.next_obs, batch.task_ids),
            )
        return inputs

    def update(self, batches: Mapping[str, Batch]) -> dict[str, float]:
        """One gradient update (critic, actor, per-task alpha, Polyak target) over every env in `batches`.

        Returns `losses/<env>/{critic,qf1,qf2,actor,alpha}`, `charts/<env>/{mean_q,entropy}`,
        `charts/<env>/alpha/<task index>` (the temperature used by this update) and, with two or
        more envs and config.ratio_lever_interval > 0, `charts/ratio_lever` (the last measured
        value). Raises TrainingDivergedError naming the update and the last good checkpoint if a
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
        order, scalars = self._update(batches)
        self.num_updates += 1
        values = torch.cat(scalars) if scalars else torch.zeros(0, device=self.device)
        return self._log_names(tuple(order)), values

    def _update(
        self, batches: Mapping[str, Batch], drop: str | None = None
    ) -> tuple[list[str], list[torch.Tensor]]:
        """The update itself; with `drop`, that env's losses are computed (same noise draws) but
        left out of every step, its weight n_X / N still counted in N (the ratio lever's Δ₋X)."""
        if self._compiled and self.device.type == "cuda":
            # CUDA graphs: a stage's outputs live until the next update replays it (cudagraph
            # trees); every one is consumed within this update (steps, stacked scalars).
            torch.compiler.cudagraph_mark_step_begin()
        inputs = self._inputs(batches)
        total = sum(batch.obs.shape[0] for batch, *_ in inputs.values())
        weights = {name: batch.obs.shape[0] / total for name, (batch, *_) in inputs.items()}
        names = list(inputs)
        stages = [names] if self.config.shared_update == "weighted" else [[n] for n in names]
        scalars: list[torch.Tensor] = []
        alpha_grads: list[torch.Tensor | None] = [None] * len(self._alpha_params)
        # Eager or compiled (config.compile), each stage computes its losses and their gradients
        # (`_critic_stage`, `_actor_stage`); the optimiser steps happen here, eagerly.
        for stage in stages:
            kept = [n for n in stage if n != drop]
            # ---- critic: each stage's critic slots, on (weighted) mean losses
            noise = self._draw_noise(stage, inputs)
            critic_terms, grads = self._stage("critic", stage, kept, inputs, noise, weights)
            if kept:
                self._step("critic", kept, grads)

            # ---- actor and temperature: with the critic just updated, as in cleanrl
            noise = self._draw_noise(stage, inputs)
            actor_terms, grads, kept_alpha_grads = self._stage(
                "actor", stage, kept, inputs, noise, weights
            )
            if kept:
                self._step("actor", kept, grads)
            for name, grad in zip(kept, kept_alpha_grads, strict=True):
                alpha_grads[self._alpha_slot[name]] = grad
            for name in stage:
                actor_loss, log_pi, env_alpha_loss = actor_terms[name]
                qf1, qf2, qf_a_values = critic_terms[name]
                scalars.append(
                    torch.stack(
                        (
                            qf1,
                            qf2,
                            0.5 * (qf1 + qf2),
                            actor_loss,
                            env_alpha_loss,
                            qf_a_values.mean(),
                            -log_pi.mean(),
                        )
                    )
                )
                scalars.append(inputs[name][1])
        if any(g is not None for g in alpha_grads):
            # ---- temperature: one step for every env's log_alpha, after all stages
            _adam_step([self.alpha_optimizer], alpha_grads, self._adam_cache)

        # ---- target critics: Polyak averaging in place
        with torch.no_grad():
            torch._foreach_lerp_(self._target_critic, self._online_critic, self.config.tau)
        return names, scalars

    def _critic_stage(
        self,
        stage: list[str],
        kept: list[str],
        inputs: StageInputs,
        noise: Mapping[str, torch.Tensor],
        weights: Mapping[str, float],
    ) -> tuple[dict[str, tuple[torch.Tensor, ...]], tuple[torch.Tensor | None, ...]]:
        """Critic losses of the envs of `stage` (detached) and the critic gradients of `kept`'s."""
        terms = {
            name: self._critic_loss(name, obs_in, next_obs_in, batch, alpha, noise[name])
            for name, (batch, alpha, obs_in, next_obs_in) in inputs.items()
            if name in stage
        }
        grads: tuple[torch.Tensor | None, ...] = ()
        if kept:
            # Mean over the twin critics, as metaworld-algorithms, the prototype and SB3: with
            # max_grad_norm the loss's scale sets how often clipping bites, so it must match.
            losses = {n: 0.5 * (terms[n][0] + terms[n][1]) for n in kept}
            grads = self._grads("critic", kept, losses, weights)
        return {n: tuple(t.detach() for t in ts) for n, ts in terms.items()}, grads

    def _actor_stage(
        self,
        stage: list[str],
        kept: list[str],
        inputs: StageInputs,
        noise: Mapping[str, torch.Tensor],
        weights: Mapping[str, float],
    ) -> tuple[
        dict[str, tuple[torch.Tensor, ...]],
        tuple[torch.Tensor | None, ...],
        tuple[torch.Tensor | None, ...],
    ]:
        """Actor losses, log-probabilities and temperature losses of `stage`'s envs (detached), the
        actor gradients of `kept`'s and the gradients of `kept`'s log_alpha (in `kept` order)."""
        terms = {}
        for name, (batch, alpha, obs_in, _) in inputs.items():
            if name in stage:
                actor_loss, log_pi = self._actor_loss(
                    name, obs_in, batch.task_ids, alpha, noise[name]
                )
                # one log_alpha per task, trained towards the env's target entropy
                alpha_loss = (
                    -self.log_alpha[self._keys[name]][batch.task_ids]
                    * (log_pi.detach() + self.target_entropy[name])
                ).mean()
                terms[name] = (actor_loss, log_pi, alpha_loss)
        grads: tuple[torch.Tensor | None, ...] = ()
        alpha_grads: tuple[torch.Tensor | None, ...] = ()
        if kept:
            grads = self._grads("actor", kept, {n: terms[n][0] for n in kept}, weights)
            alpha_loss = torch.stack([terms[n][2] for n in kept]).sum()
            alpha_params = [self.log_alpha[self._keys[n]] for n in kept]
            alpha_grads = torch.autograd.grad(alpha_loss, alpha_params)
        return {n: tuple(t.detach() for t in ts) for n, ts in terms.items()}, grads, alpha_grads

    # ------------------------------------------------------------------ the ratio lever
    def _clone(self) -> Agent:
        """A deep copy (networks, optimiser states, RNG streams) that shares nothing with self."""
        compiled, self._compiled = self._compiled, {}
        try:
            return copy.deepcopy(self)
        finally:
            self._compiled = compiled

    def _lever_envs(self, batches: Mapping[str, Batch]) -> tuple[dict[str, int], str]:
        """(samples of each env with samples, in spec order; A = the env with the most samples)."""
        sizes = {
            n: batches[n].obs.shape[0]
            for n in self.specs
            if n in batches and batches[n].obs.shape[0]
        }
        if len(sizes) < 2:
            raise SealError(f"ratio_lever needs batches of >= 2 envs, got {sorted(sizes)}")
        first = max(sizes.values())
        return sizes, next(n for n in sizes if sizes[n] == first)

    def _trunk_steps(
        self,
        batches: Mapping[str, Batch],
        drops: Sequence[str],
        noise_seed: int | None = None,
    ) -> dict[str | None, torch.Tensor]:
        """Δ (key None) and Δ₋X for X in `drops`: the shared policy trunk's parameter change of one
        `_update` on a fresh copy of this agent each (clipping and Adam included), flattened.

        The copies share this agent's update noise stream, so Δ and every Δ₋X draw the same noise;
        `noise_seed` reseeds that stream in every copy first. This agent is unchanged.
        """
        before = [p.detach().clone() for p in self.actor.trunk.parameters()]
        steps: dict[str | None, torch.Tensor] = {}
        for drop in (None, *drops):
            clone = self._clone()
            if noise_seed is not None:
                clone._update_generator.manual_seed(noise_seed)
            clone._update(batches, drop)
            steps[drop] = torch.cat(
                [
                    (p.detach() - b).flatten()
                    for p, b in zip(clone.actor.trunk.parameters(), before, strict=True)
                ]
            )
        return steps

    def ratio_lever(self, batches: Mapping[str, Batch]) -> RatioLever:
        """How much of the shared policy trunk's step each env causes, measured on copies of the agent.

        Δ = the trunk's parameter change of one full update (clipping and Adam included); Δ₋X =
        the same with env X's terms dropped (`_update`'s drop). For A the env with the most
        samples, lever = ||Δ - Δ₋A|| / sum_X ||Δ - Δ₋X|| (two envs: the issue's
        ||Δ - Δ₋A|| / (||Δ - Δ₋A|| + ||Δ - Δ₋B||)); ~n_A / N means the ratio is the lever it
        should be, ~0.5 at 90/10 means it is not. Also returns the trunk gradient norm of each
        env's own mean actor loss at the current parameters (`grad_norm`). This agent is unchanged.
        """
        sizes, env_a = self._lever_envs(batches)
        steps = self._trunk_steps(batches, list(sizes))
        effect = _lever_effects(steps)
        clone = self._clone()
        grad_norm = {}
        inputs = clone._inputs(batches)
        for name, (batch, alpha, obs_in, _) in inputs.items():
            noise = clone._draw_noise([name], inputs)[name]
            loss, _ = clone._actor_loss(name, obs_in, batch.task_ids, alpha, noise)
            trunk = list(clone.actor.trunk.parameters())
            grads = torch.autograd.grad(loss, trunk, allow_unused=True)
            flat = [g.flatten() for g in grads if g is not None]
            grad_norm[name] = float(torch.linalg.vector_norm(torch.cat(flat))) if flat else 0.0
        return {
            "lever": _lever(effect, env_a),
            "env": env_a,
            "share": sizes[env_a] / sum(sizes.values()),
            "step_norm": float(steps[None].norm()),
            "effect": effect,
            "grad_norm": grad_norm,
        }

    def ratio_lever_expected(
        self, batch_draws: Sequence[Mapping[str, Batch]]
    ) -> RatioLeverExpected:
        """`ratio_lever` of the expected steps: batch noise averaged out before the norms are taken.

        For each of the K = len(batch_draws) draws (independent batches with the same env sizes),
        Δ and Δ₋X are taken as `ratio_lever` takes them (`_trunk_steps`), every draw from this
        agent's current state (fresh copies: parameters and optimiser states do not move between
        draws). With E the mean over the K draws, for A the env with the most samples,
            lever = ||E[Δ] - E[Δ₋A]|| / sum_X ||E[Δ] - E[Δ₋X]||
        (two envs: ||E[Δ] - E[Δ₋A]|| / (||E[Δ] - E[Δ₋A]|| + ||E[Δ] - E[Δ₋B]||)).
        Chosen: the mean over independent minibatches, not each env's gradient over its whole
        replay, so that every step averaged is the optimiser's own step on a training-sized batch.
        Draw k reseeds the copies' policy noise (k-th seed of SeedSequence((seed, num_updates))),
        so that noise averages out too; within a draw Δ and Δ₋X share it. Also returns the mean
        over draws of the single-draw (`ratio_lever`-style) levers, for comparison.
        """
        if not batch_draws:
            raise SealError("ratio_lever_expected needs at least one batch draw, got 0")
        sizes, env_a = self._lever_envs(batch_draws[0])
        for k, draw in enumerate(batch_draws):
            draw_sizes = self._lever_envs(draw)[0]
            if draw_sizes != sizes:
                raise SealError(
                    f"ratio_lever_expected: batch draw {k} has env sizes {draw_sizes}, "
                    f"draw 0 has {sizes}; every draw needs the same sizes"
                )
        seeds = np.random.SeedSequence((self.seed, self.num_updates)).generate_state(
            len(batch_draws), np.uint32
        )
        sums: dict[str | None, torch.Tensor] = {}
        single: list[float] = []
        for draw, seed in zip(batch_draws, seeds.tolist(), strict=True):
            steps = self._trunk_steps(draw, list(sizes), noise_seed=seed)
            for key, step in steps.items():
                sums[key] = sums[key] + step if key in sums else step
            single.append(_lever(_lever_effects(steps), env_a))
        means = {key: total / len(batch_draws) for key, total in sums.items()}
        effect = _lever_effects(means)
        return {
            "lever": _lever(effect, env_a),
            "env": env_a,
            "share": sizes[env_a] / sum(sizes.values()),
            "draws": len(batch_draws),
            "step_norm": float(means[None].norm()),
            "effect": effect,
            "single_draw_lever_mean": float(np.mean(single)),
        }

    def _log_names(self, order: tuple[str, ...]) -> tuple[str, ...]:
        """The names of `update_on_device`'s values for envs updated in `order`."""
        return tuple(
            name
            for env in order
            for name in (
                *(template.format(env) for template in _SCALARS),
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
            where = self.last_checkpoint or "none saved yet"
            updates = (
                f"update {self.num_updates}"
                if first_update + 1 >= self.num_updates
                else f"one of updates {first_update + 1}-{self.num_updates}"
            )
            raise TrainingDivergedError(
                f"training diverged at {updates}: {', '.join(f'{k} = {metrics[k]}' for k in bad)}; last good checkpoint: {where}"
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
        ]
        return bool(torch.stack([torch.isfinite(p).all() for p in params]).all())

    def state_dict(self) -> dict[str, Any]:
        """Networks, target critics, temperatures, optimiser states, RNG states and counters."""
        return {
            "format": STATE_FORMAT,
            "specs": [asdict(s) for s in self.specs.values()],
            "config": asdict(self.config),
            "segments": {"actor": self.actor_segments, "critic": self.critic_segments},
            "actor": self.actor.state_dict(),
            "critic": self.critic.state_dict(),
            "critic_target": self.critic_target.state_dict(),
            "log_alpha": {k: v.detach().clone() for k, v in self.log_alpha.items()},
            "actor_optimizers": [o.state_dict() for o in self.actor_optimizers],
            "critic_optimizers": [o.state_dict() for o in self.critic_optimizers],
            "alpha_optimizer": self.alpha_optimizer.state_dict(),
            "rng": {
                "init": self._init_generator.get_state(),
                "update": self._update_generator.get_state(),
                "act": self._act_generator.get_state(),
            },
            "lr_factor": self._lr_factor,
            "num_updates": self.num_updates,
            "ratio_lever": self.last_ratio_lever,
        }

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore everything `state_dict` saved; the specs and network shapes must match."""
        if state.get("format") != STATE_FORMAT:
            raise SealError(
                f"agent state has format {state.get('format')!r}; this seal resumes format {STATE_FORMAT} (an older state can seed a new run through [transfer])"
            )
        mine = [asdict(s) for s in self.specs.values()]
        if list(state["specs"]) != mine:
            raise SealError(
                f"agent state is for environments {state['specs']}, but this agent has {mine}"
            )
        try:
            self.actor.load_state_dict(state["actor"])
            self.critic.load_state_dict(state["critic"])
            self.critic_target.load_state_dict(state["critic_target"])
        except RuntimeError as exc:
            raise SealError(
                f"agent state does not fit this agent's networks (saved config {state['config']}): {exc}"
            ) from exc
        with torch.no_grad():
            for k, v in state["log_alpha"].items():
                self.log_alpha[k].copy_(v)
        self._lr_factor = float(state["lr_factor"])
        self._build_optimizers()
        for optimizer, saved in zip(self.actor_optimizers, state["actor_optimizers"], strict=True):
            optimizer.load_state_dict(saved)
        for optimizer, saved in zip(
            self.critic_optimizers, state["critic_optimizers"], strict=True
        ):
            optimizer.load_state_dict(saved)
        self.alpha_optimizer.load_state_dict(state["alpha_optimizer"])
        self._init_generator.set_state(state["rng"]["init"])
        self._update_generator.set_state(state["rng"]["update"])
        self._act_generator.set_state(state["rng"]["act"])
        self.num_updates = int(state["num_updates"])
        self.last_ratio_lever = state["ratio_lever"]

    def transfer_from(self, state: Mapping[str, Any], *, reinit_critic: bool | None = None) -> None:
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
            reinit_critic = self.config.reinit_critic_on_transfer
        if state["config"]["architecture"] != self.config.architecture:
            raise SealError(
                f"cannot transfer a {state['config']['architecture']!r} agent into a {self.config.architecture!r} agent"
            )
        if not reinit_critic:
            self._check_critic_layout(state)  # before anything is copied
        source_keys = list(state["segments"]["actor"])
        if len(source_keys) == 1 and len(self._keys) == 1:
            key_map = {next(iter(self._keys.values())): source_keys[0]}
        else:
            key_map = {k: k for k in self._keys.values() if k in source_keys}
        _transfer_network(
            self.actor,
            state["actor"],
            state["segments"]["actor"],
            self.actor_segments,
            key_map,
            copy_heads=False,
        )
        if not reinit_critic:
            self._transfer_critic(state, key_map)
        self.critic_target.load_state_dict(self.critic.state_dict())
        with torch.no_grad():
            for key, source_key in key_map.items():
                old = state["log_alpha"][source_key]
                n = min(old.shape[0], self.log_alpha[key].shape[0])
                self.log_alpha[key][:n].copy_(old[:n])
        self._lr_factor = self.config.lr_factor
        self._build_optimizers()

    def _check_critic_layout(self, state: Mapping[str, Any]) -> None:
        """SealError (one line) when the saved critics are laid out otherwise than this agent's."""
        theirs = _critic_layout(state["config"])
        mine = "per_env" if isinstance(self.critic, PerEnvCritic) else "shared"
        if theirs != mine:
            raise SealError(
                f'cannot transfer the critic: the saved agent has {theirs} critics (critic_sharing = "{theirs}"; states from before critic_sharing have shared ones) and this agent {mine}; set [transfer] reinit_critic = true or agent.critic_sharing = "{theirs}"'
            )

    def _transfer_critic(self, state: Mapping[str, Any], key_map: Mapping[str, str]) -> None:
        """Copy the saved critics into this agent's, env by env; refuse across critic layouts."""
        self._check_critic_layout(state)
        if not isinstance(self.critic, PerEnvCritic):
            _transfer_network(
                self.critic,
                state["critic"],
                state["segments"]["critic"],
                self.critic_segments,
                key_map,
                copy_heads=True,
            )
            return
        for key, source_key in key_map.items():
            prefix = f"nets.{source_key}."
            _transfer_network(
                self.critic.nets[key],
                {k[len(prefix) :]: v for k, v in state["critic"].items() if k.startswith(prefix)},
                {source_key: state["segments"]["critic"][source_key]},
                {key: self.critic_segments[key]},
                {key: source_key},
                copy_heads=True,
            )


def _critic_layout(config: Mapping[str, Any]) -> str:
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
    """Copy `source` parameters into `net` as `Agent.transfer_from` describes."""
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
