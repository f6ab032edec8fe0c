"""One environment's task-conditioned actor or twin critic (`agent.architecture` in
`MTRL_ARCHITECTURES`), with the interface of `seal.learner.networks.TaskNetwork`.

The agent builds its inputs as for MTMHSAC ([obs, one-hot] for the policy, [obs, one-hot, action]
for the critics); this wrapper drops the one-hot columns and hands the architecture the rest with
the task ids, which each network embeds as its paper does. The twin critics are two members, each
a whole network of its own; the members draw in order from the "trunk" stream.

Components (`components`, for clip_per = "component" and PCGrad's shared set): "trunk" holds every
parameter some tasks share, "head.<env>" those whose every entry one task's samples alone reach
(each architecture's `task_parameters`: per-task output heads, task-embedding tables).
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import nn

from seal.learner.config import AgentConfig
from seal.learner.networks import GeneratorOf, Segments


def architecture_class(name: str) -> type[nn.Module]:
    """The network class of `agent.architecture = name` (imported on use)."""
    if name == "paco":
        from seal.learner.mtrl.paco import PaCo

        return PaCo
    if name == "soft_modular":
        from seal.learner.mtrl.soft_modular import SoftModular

        return SoftModular
    if name == "moore":
        from seal.learner.mtrl.moore import Moore

        return Moore
    if name == "care":
        from seal.learner.mtrl.care import Care

        return Care
    raise ValueError(f"no task-conditioned network {name!r}")


def activation_width(config: AgentConfig) -> int:
    """The summed widths of the activations one sample leaves for backward in one member of
    `config.architecture` (the memory estimate's per-sample term, as `sum(hidden)` for MTMHSAC)."""
    arch, hidden = config.architecture, sum(config.hidden)
    if arch == "paco":  # compiled: every set's outputs, then their mix (eager keeps less)
        return (config.paco_sets + 1) * hidden
    if arch == "moore":  # every expert's layers, the orthonormal basis and the mixed feature
        return config.moore_experts * (hidden + config.hidden[-1]) + config.hidden[-1]
    if arch == "care":  # context and attention MLPs, every encoder, the torso
        encoder = sum(config.care_encoder_hidden) + config.care_embedding
        return 2 * encoder + config.care_experts * encoder + 2 * config.care_embedding + hidden
    if arch == "soft_modular":  # embeddings, routing, every module of every layer and its mix
        width, n = config.soft_width, config.soft_modules
        routing = config.soft_layers * (2 * width + n * n)
        return 3 * config.soft_embedding + 2 * width + routing + config.soft_layers * 2 * n * width
    raise ValueError(f"no task-conditioned network {arch!r}")


class TaskConditionedNetwork(nn.Module):
    """forward(key, x, task_ids): (B, out) with ensemble 1, else (ensemble, B, out)."""

    def __init__(
        self,
        segments: Mapping[str, Segments],
        out_dims: Mapping[str, int],
        num_tasks: Mapping[str, int],
        config: AgentConfig,
        ensemble: int = 1,
        layer_norm: bool = False,
    ) -> None:
        super().__init__()
        if len(segments) != 1:
            raise ValueError(f"agent.architecture = {config.architecture!r} serves one environment")
        ((key, segs),) = segments.items()
        self.segments, self.ensemble, self.key = dict(segments), ensemble, key
        self.translators = nn.ModuleDict()  # none: the probes and transfer read this as MTMHSAC's
        self._keep: list[tuple[int, int]] = []
        start = 0
        for name, width in segs:
            if name != "task":
                self._keep.append((start, start + width))
            start += width
        in_dim = sum(b - a for a, b in self._keep)
        cls = architecture_class(config.architecture)
        self.members = nn.ModuleList(
            cls(in_dim, out_dims[key], num_tasks[key], config, layer_norm) for _ in range(ensemble)
        )

    def reset_parameters(
        self, generators: GeneratorOf, init: str = "torch", head_bound: float = 0.0
    ) -> None:
        """Re-draw every member from the "trunk" stream, in order; output layers with head_bound
        under init = "metaworld_algorithms" (`seal.learner.networks.HEAD_BOUND`)."""
        generator = generators("trunk")
        bound = head_bound if init == "metaworld_algorithms" else None
        for member in self.members:
            member.reset_parameters(generator, init, bound)

    def components(self) -> dict[str, list[nn.Parameter]]:
        """ "trunk": the shared parameters; "head.<env>": the per-task ones (module docstring)."""
        per_task = {id(p) for m in self.members for p in m.task_parameters()}
        params = list(self.parameters())
        return {
            "trunk": [p for p in params if id(p) not in per_task],
            f"head.{self.key}": [p for p in params if id(p) in per_task],
        }

    def env_parameters(self, key: str) -> list[nn.Parameter]:
        """Every parameter (there is one environment), the shared ones first, then the per-task
        ones: each component one run of the list, as clip_per = "component" needs."""
        components = self.components()
        return [*components["trunk"], *components[f"head.{self.key}"]]

    def forward(self, key: str, x: torch.Tensor, task_ids: torch.Tensor) -> torch.Tensor:
        """The network of each member on the inputs without their one-hot columns."""
        x = torch.cat([x[..., a:b] for a, b in self._keep], dim=-1)
        if self.ensemble == 1:
            return self.members[0](x, task_ids)
        return torch.stack([m(x, task_ids) for m in self.members])
