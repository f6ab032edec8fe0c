"""The learner's configuration and the description of one environment that its networks need."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal, NamedTuple

import torch
from pydantic import with_config

from seal.errors import ConfigError
from seal.typed_config import SCHEMA

ARCHITECTURES = ("mtmhsac", "seal", "soft_modular", "paco", "moore", "care")
# One env, one network per actor and per twin critic, conditioned on the task id (issue 57;
# seal.learner.mtrl): the learners SMT Table 1 compares, beside MTMHSAC's heads.
MTRL_ARCHITECTURES = ("soft_modular", "paco", "moore", "care")
GRADIENTS = ("mean", "pcgrad")
SHARED_UPDATES = ("weighted", "sequential", "per_env")
CRITIC_SHARINGS = ("per_env", "shared")
INITS = ("torch", "metaworld_algorithms")
# Keys that no longer exist, with what replaced them (the protocol loader names the new key).
RENAMED_KEYS = {
    "optimizer": 'agent.shared_update ("weighted", "sequential" or "per_env"; the old "per_env" is "per_env")',
    "one_hot": 'agent.task_encoder ("one_hot", "none" or "smt_gru"; one_hot = true is "one_hot", false is "none")',
}
TASK_ENCODERS = ("one_hot", "none", "smt_gru")


@dataclass(frozen=True)
class EnvSpec:
    """What the networks need to know of one environment.

    `num_tasks` is the number of one-hot ids and output heads (the number of aligned ids for the
    padded pseudo-env of pad-and-fine-tune). `act_pad_to` fixes the width of the critic's action
    input: the policy outputs `act_dim` actions, which are zero-padded to `act_pad_to` before the
    critic sees them, so a critic trained on one environment keeps its input width when fine-tuned
    on another with a smaller action space (pad-and-fine-tune, SEAL Appendix D).
    """

    name: str
    obs_dim: int
    act_dim: int
    num_tasks: int
    act_pad_to: int | None = None

    def __post_init__(self) -> None:
        for key in ("obs_dim", "act_dim", "num_tasks"):
            value = getattr(self, key)
            if not isinstance(value, int) or value < 1:
                raise ConfigError(
                    f"EnvSpec {self.name!r}: {key} must be a positive int, got {value!r}"
                )
        if self.act_pad_to is not None and (
            not isinstance(self.act_pad_to, int) or self.act_pad_to < self.act_dim
        ):
            raise ConfigError(
                f"EnvSpec {self.name!r}: act_pad_to must be an int >= act_dim ({self.act_dim}) or None, got {self.act_pad_to!r}"
            )

    @property
    def critic_act_dim(self) -> int:
        """Width of the action input of the critic (act_pad_to, else act_dim)."""
        return self.act_dim if self.act_pad_to is None else self.act_pad_to


@with_config(SCHEMA)
@dataclass(frozen=True, kw_only=True)
class AgentConfig:
    """Multi-task SAC learner settings: MTMHSAC (Yu et al. 2019) or the SEAL policy (SEAL §3.3)."""

    architecture: Literal["mtmhsac", "seal", "soft_modular", "paco", "moore", "care"] = "mtmhsac"
    """Network family: "mtmhsac" (one MLP with per-task heads, one env), "seal" (per-env translators, shared latent trunk, per-env heads), or one env's task-conditioned network (`seal.learner.mtrl`): "soft_modular" (Yang et al. 2020), "paco" (Sun et al. 2022), "moore" (Hendawy et al. 2024) or "care" (Sodhani et al. 2021)."""
    hidden: tuple[int, ...] = (400, 400, 400)
    """MTMHSAC hidden layer widths of the actor and of each critic (Meta-World MTMHSAC: 3 x 400, ReLU)."""
    translator_hidden: tuple[int, ...] = (400,)
    """SEAL state translator hidden widths, then latent_dim: [400] makes two layers (400 hidden, then the 400-wide latent); the prototype's three are [400, 400]."""
    latent_dim: int = 400
    """SEAL shared latent width: output of every env's translator and input of the shared trunk."""
    trunk_hidden: tuple[int, ...] = (400, 400, 400)
    """SEAL shared latent policy (and critic) trunk widths; the paper gives no size, the prototype has 6 x 400."""
    head_hidden: tuple[int, ...] = ()
    """SEAL action heads: hidden widths of each env's head between the trunk and its outputs; empty = one linear output layer (the default). The prototype: 3 x 400."""
    head_per_task: bool = False
    """With head_hidden: the head's last hidden layer is per task (one block of its width per task, the sample's task's block taken) and the output layer is shared by the env's tasks, as the prototype's actor."""
    actor_lr: float = 3e-4
    """Adam learning rate of the policy (before lr_factor)."""
    critic_lr: float = 3e-4
    """Adam learning rate of the twin Q networks (before lr_factor)."""
    alpha_lr: float = 3e-4
    """Adam learning rate of the per-task log temperatures."""
    gamma: float = 0.99
    """Discount factor."""
    tau: float = 0.005
    """Polyak rate of the target critics: target <- (1 - tau) * target + tau * online, once per update."""
    init_alpha: float = 1.0
    """Initial temperature of every task."""
    min_alpha: float = 0.0
    """Floor of every task's temperature, held after each temperature step (0: none). A floor keeps
    a learned task exploring, one candidate against losing it again (issue 37's collapse test)."""
    # The default by issue 54's rules (docs/hyperparameters.md, "The learner's default"): on the
    # kitchen (reward v3, 15 runs each) it ended >= 0.9 in 6 against the plain critic's 2 and
    # crossed 90% in 9 against 8, and every Meta-World check passed its no-slower test (reach was
    # slower in 3 of 3 seeds, inside a wide 3-seed CI). LayerNorm bounds what the
    # critic extrapolates (Ball et al. 2023, RLPD; Nauman et al. 2024, BRO).
    critic_layer_norm: bool = True
    """LayerNorm (a gain and bias per unit, per twin) between each hidden layer's affine map and its ReLU in the critics; the Q output layer stays linear."""
    # Issue 54's second candidate, run only if LayerNorm leaves >= 3 of its 15 kitchen runs ending
    # below 0.9 after crossing. Widths and depth from BRO's public code (naumix/BiggerRegularizedOptimistic,
    # jaxrl/networks/critic_net.py: hidden_dims = 512, depth = 2, ~1.1 M parameters a critic), not the
    # paper's ~5 M figure; the kitchen's MTMHSAC critic would take hidden = [512, 512] for that size.
    critic_block: Literal["mlp", "bronet"] = "mlp"
    """The critic trunk: "mlp" = ReLU layers of the widths key (LayerNorm with critic_layer_norm); "bronet" = BRO's residual net (`seal.learner.networks.ResidualMLP`): a Dense -> LN -> ReLU stem of the key's one width, then one block x + LN(Dense(ReLU(LN(Dense(x))))) per entry of the key (the widths key: `critic_trunk_key`). SEAL's shared-critic translators stay MLPs."""
    target_entropy: float | None = None
    """Target entropy of every task; None means -|A| of each env's own action size."""
    task_encoder: Literal["one_hot", "none", "smt_gru"] = "one_hot"
    """What tells the networks the task: "one_hot" = the one-hot task id (width num_tasks) appended inside the agent; "none" = nothing; "smt_gru" = SMT's task-embedding network (App. D, `seal.learner.task_encoder`): a GRU over the episode's (s, a, r) history whose belief (mean and log-variance of encoder_latent dims) the policy and critics take instead of the id."""
    # SMT (Cho et al. 2024) App. D / Table 6 fixes these four; the VariBAD defaults fill the rest
    # (docs/hyperparameters.md, "SMT's task encoder", names each source).
    encoder_latent: int = 4
    """smt_gru: Dim(h), the belief's latent size (SMT Table 6: 4 for MT10, 8 for MT50); the policy takes 2 x this (mean, log-variance)."""
    encoder_gru: int = 256
    """smt_gru: the GRU's hidden units (SMT App. D: 256)."""
    encoder_hidden: tuple[int, ...] = (400, 400)
    """smt_gru: ReLU layers between the GRU's state and the belief's mean and log-variance (SMT §5: two hidden layers of 400)."""
    decoder_hidden: tuple[int, ...] = (400, 400)
    """smt_gru: hidden widths of each of the reward, state and task decoders (SMT App. D: 2 x 400 ReLU)."""
    encoder_lr: float = 1e-3
    """smt_gru: Adam learning rate of the encoder and decoders (VariBAD's lr_vae)."""
    encoder_kl_weight: float = 1.0
    """smt_gru: weight of the KL term, KL(q_t || q_t-1) with q_-1 = N(0, I) (VariBAD's kl_weight and its default KL to the previous posterior)."""
    decoder_weights: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """smt_gru: weights of the reward, state and task-id reconstruction losses (VariBAD's rew/state loss coefficients; SMT adds the task term at the same weight)."""
    encoder_interval: int = 1
    """smt_gru: one encoder step per this many SAC updates (MT10 at paper scale: 10)."""
    encoder_episodes: int = 16
    """smt_gru: whole stored episodes in each encoder step's batch (VariBAD's vae_batch_num_trajs)."""
    encoder_elbo_steps: int = 16
    """smt_gru: beliefs per episode decoded in one encoder step (VariBAD's vae_subsample_elbos)."""
    encoder_decode_steps: int = 32
    """smt_gru: transitions of the episode each sampled belief decodes (VariBAD's vae_subsample_decodes; drawn from the whole episode, past and future)."""
    encoder_refresh_interval: int = 0
    """smt_gru: every this many SAC updates (checked before each epoch's updates), recompute the beliefs stored in the replay with the encoder as it is now, so updates train on today's m rather than collection's; 0 = never (the stored m stays the one collection saw)."""
    # Defaults: each paper's MT10 setting where it gives one, else metaworld-algorithms'
    # config/nn.py (SoftModulesConfig, PaCoConfig, CAREConfig, MOOREConfig); PaCo, MOORE and CARE's
    # torso widths are agent.hidden.
    paco_sets: int = 5
    """paco: K, the parameter sets every layer composes by the task's learned weights (PaCo MT10: 5)."""
    soft_modules: int = 2
    """soft_modular: modules per layer (Soft Modularization MT10: 2; MT50: 4)."""
    soft_layers: int = 2
    """soft_modular: layers of modules (MT10: 2; MT50: 4)."""
    soft_width: int = 256
    """soft_modular: each module's width d, and the routing network's."""
    soft_embedding: int = 400
    """soft_modular: D, the width of the observation and task embeddings."""
    care_experts: int = 6
    """care: encoders in the mixture (CARE MT10: 6; MT50: 10)."""
    care_embedding: int = 50
    """care: width of the context (task) embedding and of each encoder's output."""
    care_encoder_hidden: tuple[int, ...] = (50, 50)
    """care: hidden widths of the context encoder, the attention network and each mixture encoder."""
    care_temperature: float = 1.0
    """care: softmax temperature of the attention over encoders."""
    moore_experts: int = 4
    """moore: orthogonal experts (MOORE MT10: 4; MT50: 6)."""
    gradient: Literal["mean", "pcgrad"] = "mean"
    """How the tasks' losses make one step: "mean" = the gradient of the batch's mean loss; "pcgrad" = PCGrad (Yu et al. 2020), in the critic's and the actor's steps: each task's gradient of its share of that mean loss on the shared parameters (all but the per-task ones, "head.<env>": per-task output layers and task embeddings, which take the "mean" gradient), with the components that conflict with another task's projected away, each task in its own seeded random order, then summed, so with no conflict it is "mean"; max_grad_norm then clips the result. One env, eager only (`seal.learner.mtrl.pcgrad`)."""
    multi_head_policy: bool = True
    """One policy output head per task (False: one head shared by all tasks; ablation)."""
    multi_head_critic: bool = True
    """One Q output per task (both references' MTMHSAC critics have per-task outputs); False: one Q head shared by all tasks (ablation)."""
    critic_sharing: Literal["per_env", "shared"] = "per_env"
    """SEAL critics: "per_env" = each env its own twin critic (critic_hidden, per-task outputs) on its own obs, one-hot and action, as the authors' prototype; "shared" = per-env critic translators into a shared critic trunk (ablation). MTMHSAC has one env, so one critic either way."""
    critic_hidden: tuple[int, ...] = (400, 400, 400)
    """Hidden widths of each env's critic under critic_sharing = "per_env" (the prototype: 3 x 400)."""
    # Default "weighted": the only mode whose data ratio moves the shared trunk in proportion
    # (`seal bench --only ratio_lever`); the transfer testbed's measurements are to confirm or overturn it.
    shared_update: Literal["weighted", "sequential", "per_env"] = "weighted"
    """How the envs of one update step the shared parameters (policy trunk; critic trunk when critic_sharing = "shared"): "weighted" = one step of one Adam on sum_i (n_i / N) L_i, so an env's share of the batch is its share of the trunk's signal; "sequential" = one step per env on its own mean loss through one shared Adam (the authors' prototype); "per_env" = one Adam per env over its translator, the trunk and its head, stepped in turn (SEAL §3.3 read literally; the ratio then changes only gradient noise, since Adam ignores a loss's scale)."""
    max_grad_norm: float = 1.0
    """Clip the global gradient norm of every actor and critic optimiser step to this (metaworld-algorithms' MT10 MTMHSAC and the prototype: 1.0); 0 turns clipping off. Temperatures are never clipped."""
    clip_per: Literal["optimizer", "component"] = "optimizer"
    """What max_grad_norm bounds: "optimizer" = the global norm of each optimiser slot; "component" = the norm of each env's translator, each env's head, the shared trunk and each env's critic apart (the prototype's per-TrainState clipping)."""
    preset: str = ""
    """A named set of agent keys filling those the protocol leaves out (seal.learner.presets: "seal_prototype" = the SEAL authors' network); explicit keys win, and `seal protocol explain` says which."""
    # Default "metaworld_algorithms": on `point` (protocols/learn/point.toml before it was a protocol, seeds 0-2) it reached 100% on
    # every task in 8,000 / 11,000 / 8,000 env steps against 12,000 / 11,000 / 10,000 with "torch".
    init: Literal["torch", "metaworld_algorithms"] = "metaworld_algorithms"
    """Weight init: "torch" = nn.Linear's default U(+-1/sqrt(fan_in)) everywhere; "metaworld_algorithms" = He-uniform kernels and zero biases in hidden layers, policy head U(+-1e-3), Q head U(+-3e-3)."""
    # 1e-5 kept: on `point` eps 1e-8 took 12,000 / 9,000 / 10,000 env steps (seeds 0-2) against
    # 12,000 / 11,000 / 10,000 at 1e-5 (torch init), no consistent difference to depart on.
    adam_eps: float = 1e-5
    """Adam epsilon of every optimiser (metaworld-algorithms: 1e-5; torch's default is 1e-8)."""
    ratio_lever_interval: int = 1000
    """Every this many updates with >= 2 envs, measure the ratio lever on the update's batches (three extra updates on copies of the agent) and log it as charts/ratio_lever until the next measurement; 0 = never."""
    lr_factor: float = 1.0
    """Multiplier of actor_lr and critic_lr, e.g. below 1 when fine-tuning a transferred agent."""
    reinit_critic_on_transfer: bool = False
    """Pad-and-fine-tune: also re-initialise the critics (not only the policy's last layer) when loading the other env's agent."""
    device: str = "auto"
    """Torch device: "auto" (CUDA when present, else CPU), "cpu", "cuda" or "cuda:<index>"."""
    # Off by default: compiling costs ~35 s at the quickstart's widths (more at MT10's); the
    # quickstart-shape update ran ~1.4x faster compiled (`seal bench --only small_update_flops_fraction`).
    compile: bool = False
    """torch.compile each update stage (the critic's, then the actor's losses with their gradients, forward and backward in one graph; on CUDA replayed as a CUDA graph); optimiser steps stay eager. Eager fallback, with one warning, if compilation fails; `Agent.compile_seconds` says what it cost."""

    def __post_init__(self) -> None:
        head = self.head_hidden
        if not isinstance(head, list | tuple) or any(
            not isinstance(w, int) or isinstance(w, bool) or w < 1 for w in head
        ):
            raise ConfigError(
                f"agent.head_hidden: expected a list of positive ints (empty = a linear head), got {head!r}"
            )
        object.__setattr__(self, "head_hidden", tuple(head))
        if self.head_per_task and not self.head_hidden:
            raise ConfigError(
                "agent.head_per_task = true needs a hidden layer to split by task; set agent.head_hidden (e.g. [400, 400, 400])"
            )
        if self.head_hidden and self.architecture != "seal":
            raise ConfigError(
                f"agent.head_hidden is for the SEAL policy's action heads; architecture is {self.architecture!r}"
            )
        for key in ("hidden", "translator_hidden", "trunk_hidden", "critic_hidden"):
            value = getattr(self, key)
            try:
                widths = tuple(int(w) for w in value)
            except (TypeError, ValueError):
                widths = ()
            if (
                not widths
                or any(w < 1 for w in widths)
                or any(w != v for w, v in zip(widths, value, strict=True))
            ):
                raise ConfigError(
                    f"agent.{key}: expected a non-empty list of positive ints, got {value!r}"
                )
            object.__setattr__(self, key, widths)
        for key in ("encoder_hidden", "decoder_hidden"):
            value = getattr(self, key)
            if (
                not isinstance(value, list | tuple)
                or not value
                or any(not isinstance(w, int) or isinstance(w, bool) or w < 1 for w in value)
            ):
                raise ConfigError(
                    f"agent.{key}: expected a non-empty list of positive ints, got {value!r}"
                )
            object.__setattr__(self, key, tuple(value))
        weights = self.decoder_weights
        if (
            not isinstance(weights, list | tuple)
            or len(weights) != 3
            or any(not isinstance(w, int | float) or not math.isfinite(w) or w < 0 for w in weights)
        ):
            raise ConfigError(
                f"agent.decoder_weights: expected 3 finite numbers >= 0 (reward, state, task id), got {weights!r}"
            )
        object.__setattr__(self, "decoder_weights", tuple(float(w) for w in weights))
        for key in (
            "encoder_latent",
            "encoder_gru",
            "encoder_interval",
            "encoder_episodes",
            "encoder_elbo_steps",
            "encoder_decode_steps",
        ):
            value = getattr(self, key)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ConfigError(f"agent.{key}: expected a positive int, got {value!r}")
        if (
            not isinstance(self.encoder_refresh_interval, int)
            or isinstance(self.encoder_refresh_interval, bool)
            or self.encoder_refresh_interval < 0
        ):
            raise ConfigError(
                f"agent.encoder_refresh_interval: expected an int >= 0 (0 = never), got {self.encoder_refresh_interval!r}"
            )
        for key in (
            "paco_sets",
            "soft_modules",
            "soft_layers",
            "soft_width",
            "soft_embedding",
            "care_experts",
            "care_embedding",
            "moore_experts",
        ):
            value = getattr(self, key)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ConfigError(f"agent.{key}: expected a positive int, got {value!r}")
        hidden = self.care_encoder_hidden
        if not isinstance(hidden, list | tuple) or any(
            not isinstance(w, int) or isinstance(w, bool) or w < 1 for w in hidden
        ):
            raise ConfigError(
                f"agent.care_encoder_hidden: expected a list of positive ints, got {hidden!r}"
            )
        object.__setattr__(self, "care_encoder_hidden", tuple(hidden))
        if self.architecture not in ARCHITECTURES:
            raise ConfigError(
                f"agent.architecture: unknown value {self.architecture!r}; valid: {', '.join(ARCHITECTURES)}"
            )
        for key, valid in (
            ("task_encoder", TASK_ENCODERS),
            ("gradient", GRADIENTS),
            ("critic_block", ("mlp", "bronet")),
            ("shared_update", SHARED_UPDATES),
            ("critic_sharing", CRITIC_SHARINGS),
            ("init", INITS),
            ("clip_per", ("optimizer", "component")),
        ):
            if getattr(self, key) not in valid:
                raise ConfigError(
                    f"agent.{key}: unknown value {getattr(self, key)!r}; valid: {', '.join(valid)}"
                )
        trunk = getattr(self, self.critic_trunk_key)
        if self.critic_block == "bronet" and len(set(trunk)) != 1:
            raise ConfigError(
                f'agent.{self.critic_trunk_key} = {list(trunk)}: agent.critic_block = "bronet" '
                "needs one width (a residual block keeps its width), e.g. [512, 512] for BRO's 2 blocks of 512"
            )
        if not isinstance(self.max_grad_norm, int | float) or not (
            math.isfinite(self.max_grad_norm) and self.max_grad_norm >= 0
        ):
            raise ConfigError(
                f"agent.max_grad_norm: expected a finite number >= 0 (0 = no clipping), got {self.max_grad_norm!r}"
            )
        if not isinstance(self.ratio_lever_interval, int) or self.ratio_lever_interval < 0:
            raise ConfigError(
                f"agent.ratio_lever_interval: expected an int >= 0 (0 = never), got {self.ratio_lever_interval!r}"
            )
        if not isinstance(self.latent_dim, int) or self.latent_dim < 1:
            raise ConfigError(f"agent.latent_dim: expected a positive int, got {self.latent_dim!r}")
        for key in (
            "actor_lr",
            "critic_lr",
            "alpha_lr",
            "init_alpha",
            "lr_factor",
            "adam_eps",
            "encoder_lr",
            "encoder_kl_weight",
            "care_temperature",
        ):
            value = getattr(self, key)
            if not isinstance(value, int | float) or not math.isfinite(value) or value <= 0:
                raise ConfigError(f"agent.{key}: expected a finite number > 0, got {value!r}")
        if (
            not isinstance(self.min_alpha, int | float)
            or not math.isfinite(self.min_alpha)
            or self.min_alpha < 0
        ):
            raise ConfigError(
                f"agent.min_alpha: expected a finite number >= 0 (0 = no floor), got {self.min_alpha!r}"
            )
        if not 0.0 <= self.gamma <= 1.0:
            raise ConfigError(f"agent.gamma: expected a number in [0, 1], got {self.gamma!r}")
        if not 0.0 < self.tau <= 1.0:
            raise ConfigError(f"agent.tau: expected a number in (0, 1], got {self.tau!r}")
        if self.target_entropy is not None and not math.isfinite(self.target_entropy):
            raise ConfigError(
                f"agent.target_entropy: expected a finite number or None, got {self.target_entropy!r}"
            )

        if self.gradient == "pcgrad" and self.compile:
            raise ConfigError(
                'agent.gradient = "pcgrad" runs eager (one backward pass per task, then the surgery): set agent.compile = false'
            )
        if self.architecture in MTRL_ARCHITECTURES:
            self._check_mtrl()

    def _check_mtrl(self) -> None:
        """What a task-conditioned network (`seal.learner.mtrl`) cannot combine with, in one line each."""
        arch = self.architecture
        if self.task_encoder != "one_hot":
            raise ConfigError(
                f'agent.architecture = "{arch}" conditions its network on the task id: agent.task_encoder must be "one_hot", got {self.task_encoder!r}'
            )
        if not (self.multi_head_policy and self.multi_head_critic):
            raise ConfigError(
                f'agent.architecture = "{arch}" has the output layer of its paper: leave agent.multi_head_policy and agent.multi_head_critic at true'
            )
        if self.critic_block != "mlp":
            raise ConfigError(
                f'agent.critic_block = "{self.critic_block}" is for MTMHSAC and SEAL critics, not agent.architecture = "{arch}"'
            )

    @staticmethod
    def upgrade(saved: Mapping[str, object]) -> dict[str, object]:
        """An [agent] table a run saved, its keys renamed since mapped to today's (a run's own
        record is data to read back; a protocol a user writes gets RENAMED_KEYS' message instead)."""
        values = dict(saved)
        if "one_hot" in values:  # saved before task_encoder (issue 56)
            values.setdefault("task_encoder", "one_hot" if values.pop("one_hot") else "none")
        return values

    @classmethod
    def from_saved(cls, saved: Mapping[str, object], **override: object) -> AgentConfig:
        """The config a checkpoint saved (`dataclasses.asdict`), keys renamed since mapped to today's."""
        return cls(**{**cls.upgrade(saved), **override})

    @property
    def one_hot(self) -> bool:
        """Whether the one-hot task id is appended (task_encoder = "one_hot")."""
        return self.task_encoder == "one_hot"

    @property
    def belief_dim(self) -> int:
        """Width of the encoder's belief the networks take (2 x encoder_latent under smt_gru, else 0)."""
        return 2 * self.encoder_latent if self.task_encoder == "smt_gru" else 0

    @property
    def obs_extra(self) -> int:
        """Columns appended to each stored and acted-on observation: the belief and the episode step
        under smt_gru (`seal.learner.task_encoder`), else 0."""
        return self.belief_dim + 1 if self.task_encoder == "smt_gru" else 0

    @property
    def critic_trunk_key(self) -> str:
        """The widths key of the critic trunk: hidden (MTMHSAC), critic_hidden (SEAL's per-env
        critics) or trunk_hidden (SEAL's shared critic)."""
        if self.architecture == "mtmhsac":
            return "hidden"
        return "critic_hidden" if self.critic_sharing == "per_env" else "trunk_hidden"

    @property
    def critic_multi_head(self) -> bool:
        """Whether critics have one Q head per task."""
        return self.multi_head_critic


class Batch(NamedTuple):
    """One environment's update batch, as tensors on the agent's device.

    `obs`/`next_obs` are raw observations (B, obs_dim) without the one-hot (the agent appends it
    when `one_hot` is on), `actions` (B, act_dim), `rewards` and `terminations` (B,) float32
    (termination 1.0 only when the episode truly ended: truncation bootstraps), `task_ids` (B,)
    int64 in [0, num_tasks).
    """

    obs: torch.Tensor
    actions: torch.Tensor
    rewards: torch.Tensor
    next_obs: torch.Tensor
    terminations: torch.Tensor
    task_ids: torch.Tensor
