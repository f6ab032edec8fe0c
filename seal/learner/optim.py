"""The machinery behind the losses' gradients: clipping, the fused Adam step, optimiser slots.

`fused_adam_step` steps `torch.optim.Adam(fused=True)` optimisers with the same kernel and
arithmetic as their `step()`, as one `torch._fused_adam_` call per setting whose argument lists
are built once (`tests/learner/test_optim.py` checks it against `torch.optim.Adam`, step for step).
`clip_grad_norm` is `nn.utils.clip_grad_norm_`'s arithmetic as plain tensor ops, so a compiled
stage fuses it with the backward. `Slots` says which Adam owns which environments' parameters
(`AgentConfig.shared_update`) and takes one role's gradients and steps.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import NamedTuple

import torch
from torch import nn

AdamState = dict[str, torch.Tensor]
"""One parameter's Adam state: `step`, `exp_avg`, `exp_avg_sq`."""


def unique_parameters(params: Iterable[nn.Parameter]) -> list[nn.Parameter]:
    """Parameters in first-seen order without repeats (the shared trunk appears once)."""
    seen: set[int] = set()
    out = []
    for p in params:
        if id(p) not in seen:
            seen.add(id(p))
            out.append(p)
    return out


def clip_grad_norm(
    grads: Sequence[torch.Tensor | None], max_norm: float
) -> list[torch.Tensor | None]:
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


def _step_counters(states: Sequence[AdamState]) -> torch.Tensor:
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


class AdamPlan(NamedTuple):
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


AdamCache = dict[tuple[int, ...], tuple[tuple[object, ...], list[AdamPlan]]]
"""`fused_adam_step`'s argument lists, by the optimisers they step (see its docstring)."""


def _adam_token(optimizers: Sequence[torch.optim.Optimizer]) -> tuple[object, ...]:
    """What an `AdamPlan` of these optimisers depends on: their state dicts and learning rates
    (load_state_dict replaces `state`; a first step fills it; set_lr_factor changes `lr`)."""
    return tuple(
        (id(o.state), len(o.state), *(g["lr"] for g in o.param_groups)) for o in optimizers
    )


def _adam_plans(
    optimizers: Sequence[torch.optim.Optimizer], num_grads: int
) -> list[AdamPlan] | None:
    """The fused calls stepping `optimizers` as Adam(fused=True).step() would, grouped by
    setting; None when a setting is not covered (amsgrad, weight decay, maximize, ...), a
    parameter has no state yet (a first step), or torch has no `_fused_adam_`."""
    if not hasattr(torch, "_fused_adam_"):  # a private op: a torch without it steps plainly
        return None
    by_setting: dict[
        tuple[float, float, float, float], list[tuple[int, torch.Tensor, AdamState]]
    ] = {}
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
            AdamPlan(
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


def fused_adam_step(
    optimizers: Sequence[torch.optim.Optimizer],
    grads: Sequence[torch.Tensor | None],
    cache: AdamCache,
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
        plans: list[AdamPlan] | None = cached[1]
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


class Slots:
    """One role's Adams (the policy's or the critics'): Adam k owns the parameters of the envs
    `members[k]` (a shared trunk once), as `AgentConfig.shared_update` and `critic_sharing` lay out."""

    def __init__(
        self,
        members: Sequence[Sequence[str]],
        params: Sequence[list[nn.Parameter]],
        *,
        lr: float,
        eps: float,
        max_grad_norm: float,
        groups: Sequence[Sequence[int]] | None = None,
        per_task: Sequence[Sequence[bool]] | None = None,
    ) -> None:
        self.members = [list(m) for m in members]
        self.params = list(params)
        # PCGrad (AgentConfig.gradient): per slot, which parameters only one task's samples reach
        # (`seal.learner.mtrl.pcgrad.task_parameters`); default none. By position, so a deep copy
        # of the agent keeps them.
        self.per_task = (
            [list(f) for f in per_task] if per_task else [[False] * len(p) for p in self.params]
        )
        for slot, flags in zip(self.params, self.per_task, strict=True):
            if len(flags) != len(slot):
                raise ValueError(f"{len(flags)} per-task flags for a slot of {len(slot)}")
        # Clipping groups: per slot, the sizes of the consecutive runs of parameters whose norm
        # max_grad_norm bounds apart (AgentConfig.clip_per); default one run, the whole slot.
        self.groups = [list(g) for g in groups] if groups else [[len(p)] for p in self.params]
        for slot, sizes in zip(self.params, self.groups, strict=True):
            if sum(sizes) != len(slot):
                raise ValueError(f"clipping groups {sizes} do not cover a slot of {len(slot)}")
        # measured: fused Adam is ~8x faster than foreach on CPU here
        self.optimizers = [torch.optim.Adam(p, lr=lr, fused=True, eps=eps) for p in self.params]
        self.max_grad_norm = max_grad_norm
        self._slot = {name: i for i, names in enumerate(self.members) for name in names}

    @property
    def shared(self) -> bool:
        """Whether one Adam steps several envs' parameters."""
        return any(len(m) > 1 for m in self.members)

    def of(self, names: Iterable[str]) -> list[int]:
        """The slots the envs `names` use, in slot order."""
        return sorted({self._slot[n] for n in names})

    def parameters_of(self, names: Iterable[str]) -> list[nn.Parameter]:
        """Every parameter of the slots `names` use, in slot order."""
        return [p for s in self.of(names) for p in self.params[s]]

    def per_task_of(self, names: Iterable[str]) -> list[bool]:
        """`parameters_of(names)`' per-task flags (PCGrad), in the same order."""
        return [f for s in self.of(names) for f in self.per_task[s]]

    def grads(self, loss: torch.Tensor, names: Sequence[str]) -> tuple[torch.Tensor | None, ...]:
        """Gradients of `loss` for every parameter of the slots `names` use, in slot order (unused
        ones None); with max_grad_norm > 0 each slot's gradients (each group's, with `groups`)
        are clipped to it."""
        grads = torch.autograd.grad(loss, self.parameters_of(names), allow_unused=True)
        return self.clip(grads, names)

    def clip(
        self, grads: Sequence[torch.Tensor | None], names: Sequence[str]
    ) -> tuple[torch.Tensor | None, ...]:
        """`grads` (those of `parameters_of(names)`), each slot's (each group's, with `groups`)
        clipped to max_grad_norm when it is > 0."""
        if self.max_grad_norm <= 0:
            return tuple(grads)
        slots = self.of(names)
        clipped: list[torch.Tensor | None] = []
        for s in slots:
            for n in self.groups[s]:
                part = grads[len(clipped) : len(clipped) + n]
                clipped += clip_grad_norm(part, self.max_grad_norm)
        return tuple(clipped)

    def step(
        self, names: Sequence[str], grads: Sequence[torch.Tensor | None], cache: AdamCache
    ) -> None:
        """One Adam step of every slot `names` use, on `grads` (None: that parameter rests)."""
        fused_adam_step([self.optimizers[s] for s in self.of(names)], grads, cache)

    def set_lr(self, lr: float) -> None:
        """Every slot's learning rate."""
        for optimizer in self.optimizers:
            for group in optimizer.param_groups:
                group["lr"] = lr

    def state_dicts(self) -> list[dict[str, object]]:
        """Each Adam's state dict, in slot order."""
        return [o.state_dict() for o in self.optimizers]

    def load_state_dicts(self, states: Sequence[Mapping[str, object]]) -> None:
        """Restore `state_dicts`' output (one per slot)."""
        for optimizer, saved in zip(self.optimizers, states, strict=True):
            optimizer.load_state_dict(saved)
