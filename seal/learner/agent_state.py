"""What an `Agent` saves and restores: its state's layout (`AgentState`) and `StateIO`, the
part of `Agent` that writes and reads it.

Checkpoints hold the state (`seal.learner.checkpoint`); pad-and-fine-tune reads one as a source
(`seal.learner.transfer`).
"""

from __future__ import annotations

from dataclasses import asdict
from typing import NotRequired, TypedDict

import torch

from seal.errors import SealError
from seal.learner.networks import Segments  # at run time: checkpoints check AgentState's hints

# 2: per-env critics (critic_sharing), optimiser slots by shared_update, the cached ratio lever.
STATE_FORMAT = 2


class AgentState(TypedDict):
    """`Agent.state_dict()`: plain containers of tensors and values (checkpoints hold it)."""

    format: int
    specs: list[dict[str, object]]  # dataclasses.asdict of each EnvSpec
    config: dict[str, object]  # dataclasses.asdict of the AgentConfig it was saved with
    segments: dict[str, dict[str, Segments]]  # "actor"/"critic" -> env key -> input segments
    actor: dict[str, torch.Tensor]
    critic: dict[str, torch.Tensor]
    critic_target: dict[str, torch.Tensor]
    log_alpha: dict[str, torch.Tensor]
    actor_optimizers: list[dict[str, object]]  # torch.optim.Adam.state_dict() of each slot
    critic_optimizers: list[dict[str, object]]
    alpha_optimizer: dict[str, object]
    rng: dict[str, torch.Tensor]  # "update/<env>", "act/<env>", "pcgrad/<env>" generator states
    init_draws: NotRequired[int]  # how many times the weights were drawn (absent: older states)
    lr_factor: float
    num_updates: int
    ratio_lever: float | None
    encoder: NotRequired[dict[str, torch.Tensor]]  # smt_gru: the task encoders and decoders
    encoder_optimizer: NotRequired[dict[str, object]]
    encoder_rng: NotRequired[dict[str, torch.Tensor]]
    encoder_refreshed: NotRequired[int]  # num_updates at the last refresh of the replay's beliefs


class StateIO:
    """The part of `seal.learner.sac.Agent` that saves and restores its state (its networks,
    slots, generators and counters are the agent's attributes)."""

    def state_dict(self) -> AgentState:
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
            "actor_optimizers": self.actor_slots.state_dicts(),
            "critic_optimizers": self.critic_slots.state_dicts(),
            "alpha_optimizer": self.alpha_optimizer.state_dict(),
            "rng": {
                **{f"update/{n}": g.get_state() for n, g in self.update_generators.items()},
                **{f"act/{n}": g.get_state() for n, g in self._act_generators.items()},
                **{f"pcgrad/{n}": g.get_state() for n, g in self.pcgrad_generators.items()},
            },
            "init_draws": self._init_draws,
            "lr_factor": self._lr_factor,
            "num_updates": self.num_updates,
            "ratio_lever": self.last_ratio_lever,
            **(self.task_encoding.state_dict() if self.task_encoding is not None else {}),
        }

    def load_state_dict(self, state: AgentState) -> None:
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
        self.reset_optimizers(float(state["lr_factor"]))
        self.actor_slots.load_state_dicts(state["actor_optimizers"])
        self.critic_slots.load_state_dicts(state["critic_optimizers"])
        self.alpha_optimizer.load_state_dict(state["alpha_optimizer"])
        # A state saved before the per-env streams ("init", "update", "act") keeps this agent's
        # freshly seeded streams: that resume draws other noise than the run would have.
        for role, generators in (
            ("update", self.update_generators),
            ("act", self._act_generators),
            ("pcgrad", self.pcgrad_generators),
        ):
            for n, generator in generators.items():
                if f"{role}/{n}" in state["rng"]:
                    generator.set_state(state["rng"][f"{role}/{n}"])
        self._init_draws = int(state.get("init_draws", 1))
        self.num_updates = int(state["num_updates"])
        self.last_ratio_lever = state["ratio_lever"]
        if self.task_encoding is not None:
            self.task_encoding.load_state_dict(state)
