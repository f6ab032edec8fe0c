"""The learner's configuration and the description of one environment that its networks need."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Literal, NamedTuple

import torch

from seal.errors import ConfigError

ARCHITECTURES = ("mtmhsac", "seal")
OPTIMIZERS = ("per_env", "shared")


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


@dataclass(frozen=True, kw_only=True)
class AgentConfig:
    """Multi-task SAC learner settings: MTMHSAC (Yu et al. 2019) or the SEAL policy (SEAL §3.3)."""

    architecture: Literal["mtmhsac", "seal"] = "mtmhsac"
    """Network family: "mtmhsac" (one MLP with per-task heads, one env) or "seal" (per-env translators, shared latent trunk, per-env heads)."""
    hidden: tuple[int, ...] = (400, 400, 400)
    """MTMHSAC hidden layer widths of the actor and of each critic (Meta-World MTMHSAC: 3 x 400, ReLU)."""
    translator_hidden: tuple[int, ...] = (400,)
    """SEAL state translator hidden widths; with latent_dim it makes the prototype's "2 x 400" translator (two layers: 400 hidden, then the 400-wide latent)."""
    latent_dim: int = 400
    """SEAL shared latent width: output of every env's translator and input of the shared trunk."""
    trunk_hidden: tuple[int, ...] = (400, 400, 400)
    """SEAL shared latent policy (and critic) trunk widths (SEAL §3.3: 3 x 400)."""
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
    target_entropy: float | None = None
    """Target entropy of every task; None means -|A| of each env's own action size."""
    one_hot: bool = True
    """Append the one-hot task id (width num_tasks) to the observation inside the agent."""
    multi_head_policy: bool = True
    """One policy output head per task (False: one head shared by all tasks; ablation)."""
    multi_head_critic: bool | None = None
    """One Q head per task; None means the architecture's default: False for mtmhsac, True for seal."""
    optimizer: Literal["per_env", "shared"] = "per_env"
    """"per_env": one actor and one critic Adam per env over its translator, its head and the shared trunk (SEAL §3.3); "shared": one of each over everything."""
    lr_factor: float = 1.0
    """Multiplier of actor_lr and critic_lr, e.g. below 1 when fine-tuning a transferred agent."""
    reinit_critic_on_transfer: bool = False
    """Pad-and-fine-tune: also re-initialise the critics (not only the policy's last layer) when loading the other env's agent."""
    device: str = "auto"
    """Torch device: "auto" (CUDA when present, else CPU), "cpu", "cuda" or "cuda:<index>"."""
    compile: bool = False
    """torch.compile the loss computations (eager fallback if compilation fails); off: no gain measured at MT10 defaults on CPU, ~90 s to compile."""

    def __post_init__(self) -> None:
        for key in ("hidden", "translator_hidden", "trunk_hidden"):
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
        if self.architecture not in ARCHITECTURES:
            raise ConfigError(
                f"agent.architecture: unknown value {self.architecture!r}; valid: {', '.join(ARCHITECTURES)}"
            )
        if self.optimizer not in OPTIMIZERS:
            raise ConfigError(
                f"agent.optimizer: unknown value {self.optimizer!r}; valid: {', '.join(OPTIMIZERS)}"
            )
        if not isinstance(self.latent_dim, int) or self.latent_dim < 1:
            raise ConfigError(f"agent.latent_dim: expected a positive int, got {self.latent_dim!r}")
        for key in ("actor_lr", "critic_lr", "alpha_lr", "init_alpha", "lr_factor"):
            value = getattr(self, key)
            if not isinstance(value, int | float) or not math.isfinite(value) or value <= 0:
                raise ConfigError(f"agent.{key}: expected a finite number > 0, got {value!r}")
        if not 0.0 <= self.gamma <= 1.0:
            raise ConfigError(f"agent.gamma: expected a number in [0, 1], got {self.gamma!r}")
        if not 0.0 < self.tau <= 1.0:
            raise ConfigError(f"agent.tau: expected a number in (0, 1], got {self.tau!r}")
        if self.target_entropy is not None and not math.isfinite(self.target_entropy):
            raise ConfigError(
                f"agent.target_entropy: expected a finite number or None, got {self.target_entropy!r}"
            )

    @property
    def critic_multi_head(self) -> bool:
        """Whether critics have one Q head per task, after resolving the architecture default."""
        if self.multi_head_critic is None:
            return self.architecture == "seal"
        return self.multi_head_critic

    @classmethod
    def field_help(cls) -> dict[str, str]:
        """Each field's one-line docstring, for --help and `explain` text."""
        import ast
        import inspect
        import textwrap

        tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
        body = tree.body[0].body  # type: ignore[attr-defined]
        docs: dict[str, str] = {}
        for node, after in zip(body, body[1:], strict=False):
            if (
                isinstance(node, ast.AnnAssign)
                and isinstance(after, ast.Expr)
                and isinstance(after.value, ast.Constant)
            ):
                docs[node.target.id] = str(after.value.value)  # type: ignore[union-attr]
        return {f.name: docs.get(f.name, "") for f in fields(cls)}


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
