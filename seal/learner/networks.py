"""Networks of the learner: batched MLPs, batched multi-head outputs and the SEAL forward pass.

Two architectures share one building block, `TaskNetwork`, which for environment i computes

    head_i( trunk( translator_i( x ) ), task_id )

- **mtmhsac** (Yu et al. 2019; SEAL §3.1): one environment, no translator, the trunk is the
  3 x 400 ReLU MLP over [obs, one-hot], and the head holds one output per task.
- **seal** (SEAL §3.3, Fig. 1c): the policy is g_phi_i(pi_eta(f_theta_i(s))) with a per-env state
  translator f_theta_i (input: obs_i and the one-hot over env i's tasks; by default 400 hidden,
  then the 400-wide latent, ReLU after both; the prototype has three layers), the shared latent
  trunk pi_eta (by default 3 x 400, ReLU; the prototype's is 6 x 400) and a per-env action head
  g_phi_i, by default one linear output per task of env i, each 2 * act_dim_i wide (tanh-Gaussian
  mean and log std); `head_hidden` gives it hidden layers (`MLPHead`, the prototype's 3 x 400 with
  a per-task last one; `agent.preset = "seal_prototype"` sets all three). The critics
  (`critic_sharing`): by default ("per_env", the authors' prototype) each env has its own twin
  critic, an MLP (LayerNorm before each hidden ReLU: `critic_layer_norm`) over (obs_i, one-hot, action_i) with one Q output per task of env i
  (`PerEnvCritic`); "shared" follows the policy's pattern instead (per-env critic translators, a
  shared critic trunk, per-env per-task Q heads). The twin Qs are two independent copies, and the
  target critics are deep copies that share no tensor with the online ones. Which Adam owns which
  parameters follows `shared_update` (see `seal.learner.update`); the per-task log temperatures
  have their own Adam.

Speed: an ensemble of G identical MLPs (the twin Q, G=2) is one `baddbmm` per layer over stacked
weights of shape (G, in, out); all heads of a layer are one matmul whose output is reshaped to
(B, heads, out) and the task's row gathered. No Python loop over tasks or heads, so the number of
torch ops of a forward pass does not depend on the number of tasks.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import torch
import torch.nn.functional as F
from torch import nn

# garage's TanhGaussianMLPPolicy (the Meta-World MTMHSAC) and stable-baselines3 clamp log std to
# [-20, 2]; cleanrl squashes it into [-5, 2] instead. We clamp, which also makes our losses
# comparable term by term with stable-baselines3 in `seal bench`.
LOG_STD_MIN = -20.0
LOG_STD_MAX = 2.0
_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)

# Input layer segments: (name, width) pairs in the order they are concatenated. Transfer maps
# columns segment by segment, so a one-hot that grows (MT1 -> MT10) keeps the old columns in place.
Segments = tuple[tuple[str, int], ...]
GeneratorOf = Callable[[str], torch.Generator]
"""A component's name ("translator.<env>", "trunk", "head.<env>", "critic.<env>") -> its init stream."""


def _uniform_(tensor: torch.Tensor, fan_in: int, generator: torch.Generator) -> None:
    """torch.nn.Linear's default init, U(-1/sqrt(fan_in), 1/sqrt(fan_in)), from our own generator."""
    _bounded_(tensor, 1.0 / math.sqrt(fan_in), generator)


def _bounded_(tensor: torch.Tensor, bound: float, generator: torch.Generator) -> None:
    """U(-bound, bound) in place from our own generator."""
    with torch.no_grad():
        tensor.uniform_(-bound, bound, generator=generator)


# Init schemes (AgentConfig.init). "metaworld_algorithms": hidden kernels He-uniform,
# U(+-sqrt(6 / fan_in)) (flax's he_uniform), hidden biases zero; output heads U(+-head_bound)
# for kernel and bias, head_bound 1e-3 for the policy and 3e-3 for Q (metaworld-algorithms'
# rl/networks.py). "torch": nn.Linear's default everywhere, head_bound unused.
HEAD_BOUND = {"actor": 1e-3, "critic": 3e-3}


class StackedMLP(nn.Module):
    """`ensemble` independent ReLU MLPs of the same shape, one batched matmul per layer.

    Weights are (ensemble, in, out), biases (ensemble, 1, out). With ensemble == 1 inputs and
    outputs are (B, width); otherwise inputs are (B, in) shared by all members or
    (ensemble, B, in), and outputs are (ensemble, B, width). ReLU follows every layer; with
    `layer_norm`, a LayerNorm with its own gain and bias per member comes between each layer's
    affine map and its ReLU (gains (ensemble, 1, width) drawn as ones, biases as zeros).
    """

    def __init__(
        self, in_dim: int, widths: Sequence[int], ensemble: int = 1, layer_norm: bool = False
    ) -> None:
        super().__init__()
        self.in_dim, self.widths, self.ensemble = in_dim, tuple(widths), ensemble
        dims = (in_dim, *self.widths)
        self.weights = nn.ParameterList(
            nn.Parameter(torch.empty(ensemble, i, o))
            for i, o in zip(dims[:-1], dims[1:], strict=True)
        )
        self.biases = nn.ParameterList(nn.Parameter(torch.empty(ensemble, 1, o)) for o in dims[1:])
        self.norm_gains = nn.ParameterList(
            nn.Parameter(torch.empty(ensemble, 1, o)) for o in (dims[1:] if layer_norm else ())
        )
        self.norm_biases = nn.ParameterList(
            nn.Parameter(torch.empty(ensemble, 1, o)) for o in (dims[1:] if layer_norm else ())
        )

    @property
    def out_dim(self) -> int:
        """Width of the last layer."""
        return self.widths[-1]

    def reset_parameters(self, generator: torch.Generator, init: str = "torch") -> None:
        """Re-draw every weight and bias: nn.Linear's default, or He-uniform kernels and zero biases."""
        for weight, bias in zip(self.weights, self.biases, strict=True):
            if init == "metaworld_algorithms":
                _bounded_(weight, math.sqrt(6.0 / weight.shape[1]), generator)
                with torch.no_grad():
                    bias.zero_()
            else:
                _uniform_(weight, weight.shape[1], generator)
                _uniform_(bias, weight.shape[1], generator)
        with torch.no_grad():  # no draws: the weights above are the same with or without norms
            for gain, shift in zip(self.norm_gains, self.norm_biases, strict=True):
                gain.fill_(1.0)
                shift.zero_()

    def layer(self, i: int, x: torch.Tensor) -> torch.Tensor:
        """Layer i's affine map, then its LayerNorm if it has one (no activation)."""
        weight, bias = self.weights[i], self.biases[i]
        if self.ensemble == 1:
            # squeeze, not [0]: its backward is a view, select's allocates and copies.
            x = torch.addmm(bias.squeeze(0), x, weight.squeeze(0))
        else:
            if x.dim() == 2:
                x = x.expand(self.ensemble, *x.shape)
            x = torch.baddbmm(bias, x, weight)
        if self.norm_gains:
            gain, shift = self.norm_gains[i], self.norm_biases[i]
            if self.ensemble == 1:
                gain, shift = gain.squeeze(0), shift.squeeze(0)
            x = torch.addcmul(shift, F.layer_norm(x, x.shape[-1:]), gain)
        return x

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Apply all layers; see the class docstring for shapes."""
        for i in range(len(self.weights)):
            # In place: addmm/baddbmm keep their inputs, not their output, for backward.
            x = F.relu(self.layer(i, x), inplace=True)
        return x


class ResidualMLP(StackedMLP):
    """BroNet (Nauman et al. 2024, "Bigger, Regularized, Optimistic"), for `ensemble` members: a
    stem Dense -> LN -> ReLU of width w, then `blocks` residual blocks
    x + LN(Dense(ReLU(LN(Dense(x))))); no activation after the last block (the Q head follows).

    Its layers are a `StackedMLP`'s with LayerNorm, (1 + 2 * blocks) of width w in order (stem,
    then each block's two), so checkpoints, transfer and the memory estimate read it as one.
    `residual_widths` maps a widths key to it: `blocks` = the key's length, w its one width.
    """

    def __init__(self, in_dim: int, widths: Sequence[int], ensemble: int = 1) -> None:
        if len(set(widths)) != 1:
            raise ValueError(f"a residual MLP has one width, got {tuple(widths)}")
        self.blocks = len(widths)
        super().__init__(in_dim, residual_widths(widths), ensemble, layer_norm=True)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """The stem, then the blocks; shapes as `StackedMLP`'s."""
        x = F.relu(self.layer(0, x), inplace=True)
        for b in range(self.blocks):
            h = F.relu(self.layer(1 + 2 * b, x), inplace=True)
            x = x + self.layer(2 + 2 * b, h)
        return x


def residual_widths(widths: Sequence[int]) -> tuple[int, ...]:
    """The layer widths of a `ResidualMLP` given a widths key: the stem and two layers per block
    (one block per entry; BRO's default critic, 512 wide with 2 blocks, is [512, 512])."""
    return tuple(widths[:1]) * (1 + 2 * len(widths))


def critic_layers(widths: Sequence[int], block: str) -> tuple[int, ...]:
    """The hidden layer widths one sample passes through in a critic trunk of `widths` under
    `AgentConfig.critic_block` ("mlp": `widths` itself)."""
    return residual_widths(widths) if block == "bronet" else tuple(widths)


def hidden_stack(
    in_dim: int, widths: Sequence[int], ensemble: int, layer_norm: bool, block: str = "mlp"
) -> StackedMLP:
    """A trunk of `widths`: a ReLU MLP (LayerNorm with `layer_norm`) or, for "bronet", a `ResidualMLP`."""
    if block == "bronet":
        return ResidualMLP(in_dim, widths, ensemble)
    return StackedMLP(in_dim, widths, ensemble, layer_norm)


class MultiHeadLinear(nn.Module):
    """A linear output layer with `num_heads` heads of width `out_dim`, for `ensemble` members.

    All heads are computed in one matmul and the row of each sample's task is gathered, so the
    cost in torch ops is independent of the number of heads. With num_heads == 1 the task ids are
    ignored (single-head ablations).
    """

    def __init__(self, in_dim: int, out_dim: int, num_heads: int, ensemble: int = 1) -> None:
        super().__init__()
        self.in_dim, self.out_dim, self.num_heads, self.ensemble = (
            in_dim,
            out_dim,
            num_heads,
            ensemble,
        )
        self.weight = nn.Parameter(torch.empty(ensemble, in_dim, num_heads * out_dim))
        self.bias = nn.Parameter(torch.empty(ensemble, 1, num_heads * out_dim))

    def reset_parameters(self, generator: torch.Generator, bound: float | None = None) -> None:
        """Re-draw with nn.Linear's default init (each head as its own Linear(in_dim, out_dim)), or U(+-bound)."""
        if bound is None:
            _uniform_(self.weight, self.in_dim, generator)
            _uniform_(self.bias, self.in_dim, generator)
        else:
            _bounded_(self.weight, bound, generator)
            _bounded_(self.bias, bound, generator)

    def forward(self, x: torch.Tensor, task_ids: torch.Tensor) -> torch.Tensor:
        """(B, in) or (ensemble, B, in) -> (B, out_dim) or (ensemble, B, out_dim) of each sample's task head."""
        if self.ensemble == 1:
            y = torch.addmm(self.bias.squeeze(0), x, self.weight.squeeze(0))
        elif self.weight.shape[-1] == 1:
            # One output column (a single-task Q head): a batched matmul with n = 1 and its
            # backward (an outer product) are ~2x slower on CPU than this multiply-and-sum.
            y = (x * self.weight.transpose(-1, -2)).sum(-1, keepdim=True) + self.bias
        else:
            if x.dim() == 2:
                x = x.expand(self.ensemble, *x.shape)
            y = torch.baddbmm(self.bias, x, self.weight)
        if self.num_heads == 1:
            return y
        y = y.unflatten(-1, (self.num_heads, self.out_dim))  # (..., B, heads, out)
        index = task_ids.view(-1, 1, 1).expand(*y.shape[:-2], 1, self.out_dim)
        return torch.gather(y, -2, index).squeeze(-2)


class MLPHead(nn.Module):
    """An env's action head with hidden layers (`AgentConfig.head_hidden`), for one member.

    ReLU hidden layers, then the outputs. With `per_task` (the SEAL prototype's actor) the last
    hidden layer has one block of its width per task, the sample's task's block taken, and the
    output layer is shared by the env's tasks; otherwise the output layer has the per-task heads.
    """

    def __init__(
        self, in_dim: int, hidden: Sequence[int], out_dim: int, num_heads: int, per_task: bool
    ) -> None:
        super().__init__()
        shared = tuple(hidden[:-1]) if per_task else tuple(hidden)
        self.body = StackedMLP(in_dim, shared) if shared else None
        width = shared[-1] if shared else in_dim
        self.task_layer = MultiHeadLinear(width, hidden[-1], num_heads) if per_task else None
        self.out = MultiHeadLinear(hidden[-1], out_dim, 1 if per_task else num_heads)

    def reset_parameters(self, generator: torch.Generator, init: str, bound: float | None) -> None:
        """Hidden layers as the trunk's (`StackedMLP`), the output layer as a linear head's."""
        if self.body is not None:
            self.body.reset_parameters(generator, init)
        if self.task_layer is not None:
            layer = self.task_layer
            if init == "metaworld_algorithms":
                _bounded_(layer.weight, math.sqrt(6.0 / layer.in_dim), generator)
                with torch.no_grad():
                    layer.bias.zero_()
            else:
                layer.reset_parameters(generator)
        self.out.reset_parameters(generator, bound)

    def forward(self, x: torch.Tensor, task_ids: torch.Tensor) -> torch.Tensor:
        """(B, in) -> (B, out_dim) of each sample's task."""
        if self.body is not None:
            x = self.body(x)
        if self.task_layer is not None:
            x = F.relu(self.task_layer(x, task_ids))
        return self.out(x, task_ids)


class TaskNetwork(nn.Module):
    """Per environment i: head_i(trunk(translator_i(x)), task_id); see the module docstring.

    `segments[env]` names the input columns of env i (e.g. obs, task, action), `out_dims[env]`
    the width of each head and `num_heads[env]` the number of heads. With `translator=None`
    (MTMHSAC) there is exactly one environment and its input goes straight into the trunk.
    """

    def __init__(
        self,
        segments: dict[str, Segments],
        out_dims: dict[str, int],
        num_heads: dict[str, int],
        trunk_hidden: Sequence[int],
        translator: tuple[tuple[int, ...], int] | None,
        ensemble: int = 1,
        head_hidden: Sequence[int] = (),
        head_per_task: bool = False,
        layer_norm: bool = False,
        block: str = "mlp",
    ) -> None:
        super().__init__()
        if head_hidden and ensemble != 1:
            raise ValueError("heads with hidden layers serve one member (the policy)")
        self.segments = dict(segments)
        self.ensemble = ensemble
        self.translators = nn.ModuleDict()
        if translator is None:
            if len(segments) != 1:
                raise ValueError("a TaskNetwork without translators serves exactly one environment")
            (only,) = segments.values()
            trunk_in = sum(width for _, width in only)
        else:
            translator_hidden, latent_dim = translator
            for key, segs in segments.items():
                self.translators[key] = StackedMLP(
                    sum(width for _, width in segs),
                    (*translator_hidden, latent_dim),
                    ensemble,
                    layer_norm,
                )
            trunk_in = latent_dim
        self.trunk = hidden_stack(trunk_in, trunk_hidden, ensemble, layer_norm, block)
        self.heads = nn.ModuleDict(
            {
                key: MLPHead(
                    self.trunk.out_dim, head_hidden, out_dims[key], num_heads[key], head_per_task
                )
                if head_hidden
                else MultiHeadLinear(self.trunk.out_dim, out_dims[key], num_heads[key], ensemble)
                for key in segments
            }
        )

    def reset_parameters(
        self, generators: GeneratorOf, init: str = "torch", head_bound: float = 0.0
    ) -> None:
        """Re-draw every parameter, each component from `generators(<component name>)` (the
        names of `components`), so one env's draws do not depend on the others; see HEAD_BOUND."""
        for key, translator in self.translators.items():
            translator.reset_parameters(generators(f"translator.{key}"), init)
        self.trunk.reset_parameters(generators("trunk"), init)
        bound = head_bound if init == "metaworld_algorithms" else None
        for key, head in self.heads.items():
            if isinstance(head, MLPHead):
                head.reset_parameters(generators(f"head.{key}"), init, bound)
            else:
                head.reset_parameters(generators(f"head.{key}"), bound)

    def components(self) -> dict[str, list[nn.Parameter]]:
        """The parameters by component: "translator.<env>", "trunk", "head.<env>"."""
        out = {f"translator.{k}": list(m.parameters()) for k, m in self.translators.items()}
        out["trunk"] = list(self.trunk.parameters())
        out.update({f"head.{k}": list(m.parameters()) for k, m in self.heads.items()})
        return out

    def env_parameters(self, key: str) -> list[nn.Parameter]:
        """Parameters used by env `key`: its translator, the shared trunk and its heads."""
        modules = [self.translators[key]] if key in self.translators else []
        return [p for m in (*modules, self.trunk, self.heads[key]) for p in m.parameters()]

    def forward(self, key: str, x: torch.Tensor, task_ids: torch.Tensor) -> torch.Tensor:
        """Output of env `key`'s head for each sample's task: (B, out) or (ensemble, B, out)."""
        if key in self.translators:
            x = self.translators[key](x)
        return self.heads[key](self.trunk(x), task_ids)


def tanh_gaussian(
    mean_log_std: torch.Tensor, noise: torch.Tensor | None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Action and log-probability of a tanh-squashed Gaussian policy output.

    `mean_log_std` is (B, 2 * act_dim): the mean, then the log std (clamped to [LOG_STD_MIN,
    LOG_STD_MAX]). With `noise` (B, act_dim) of standard normals the action is
    tanh(mean + std * noise) (reparameterised); with None it is tanh(mean) and log_prob is that
    of the mode. log_prob = sum_j [log N(u_j; mean_j, std_j) - log(1 - tanh(u_j)^2 + 1e-6)],
    the same correction (and epsilon) as cleanrl and stable-baselines3.
    """
    mean, log_std = mean_log_std.chunk(2, dim=-1)
    log_std = log_std.clamp(LOG_STD_MIN, LOG_STD_MAX)
    if noise is None:
        noise = torch.zeros_like(mean)
    x_t = mean + log_std.exp() * noise
    y_t = torch.tanh(x_t)
    # log N(x_t; mean, std) = -noise^2 / 2 - log std - log(2 pi) / 2, since (x_t - mean) / std = noise
    log_prob = -0.5 * noise.square() - log_std - _HALF_LOG_2PI - torch.log1p(1e-6 - y_t.square())
    return y_t, log_prob.sum(-1)


class PerEnvCritic(nn.Module):
    """Independent per-environment critics (the SEAL authors' prototype): env i's twin Q is its own
    MLP over (obs_i, one-hot, action_i) with one linear Q output per task of env i; nothing is
    shared between environments. Same interface as `TaskNetwork`: forward(key, x, task_ids).
    """

    def __init__(
        self,
        segments: dict[str, Segments],
        num_heads: dict[str, int],
        hidden: Sequence[int],
        ensemble: int = 2,
        layer_norm: bool = False,
        block: str = "mlp",
    ) -> None:
        super().__init__()
        self.segments = dict(segments)
        self.nets = nn.ModuleDict(
            {
                key: TaskNetwork(
                    {key: segs},
                    {key: 1},
                    {key: num_heads[key]},
                    hidden,
                    None,
                    ensemble,
                    layer_norm=layer_norm,
                    block=block,
                )
                for key, segs in segments.items()
            }
        )

    def reset_parameters(
        self, generators: GeneratorOf, init: str = "torch", head_bound: float = 0.0
    ) -> None:
        """Re-draw every env's critic, each from its own `generators("critic.<env>")`."""
        for key, net in self.nets.items():
            generator = generators(f"critic.{key}")
            net.reset_parameters(lambda _component, g=generator: g, init, head_bound)

    def components(self) -> dict[str, list[nn.Parameter]]:
        """The parameters by component: "critic.<env>" (each env's whole critic)."""
        return {f"critic.{k}": list(net.parameters()) for k, net in self.nets.items()}

    def env_parameters(self, key: str) -> list[nn.Parameter]:
        """Parameters of env `key`'s critic (all of them: nothing is shared)."""
        return list(self.nets[key].parameters())

    def forward(self, key: str, x: torch.Tensor, task_ids: torch.Tensor) -> torch.Tensor:
        """(ensemble, B, 1) Q values of env `key`'s critic for each sample's task."""
        return self.nets[key](key, x, task_ids)
