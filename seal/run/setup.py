"""A run's set-up, as a pipeline whose every step takes the previous step's result:

    config = saved_config(path)          # a resumed run's own config (else the caller's)
    plan = plan_run(config, seed)        # phases, adapters, alignment, each phase's model
    threads = check_resources(plan)      # memory refused in one line; update threads chosen
    run = build(plan, threads, path)     # `seal.run.runner`: transfer source, lock, run directory

`seal.run.runner.run_seed` reads so. Each phase's agent, replay and workers are built when its
loop starts (`seal.run.phase_parts`), from the plan's phase model. `load_policy` (seal eval)
plans a run's config the same way.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from seal import provenance
from seal.device import ThreadChoice, apply_matmul_precision
from seal.errors import ConfigError, SealError
from seal.learner.agent_state import AgentState
from seal.learner.checkpoint import read_checkpoint
from seal.learner.sac import Agent
from seal.learner.transfer import transfer_from
from seal.protocols.config import ProtocolConfig
from seal.protocols.loader import config_from_dict, upgrade_saved
from seal.protocols.toml_io import read_toml
from seal.run import resources
from seal.run.checkpoint_fields import RunCheckpoint, check_run_checkpoint, saved_config_table
from seal.run.mapped_start import mapped_start
from seal.run.phase_model import (
    Phase,
    PhaseModel,
    build_adapters,
    build_alignment,
    plan_phases,
    run_agent_config,
)
from seal.run.rundir import CONFIG_LIMIT, RunDir

if TYPE_CHECKING:
    from seal.envs.alignment import Alignment
    from seal.envs.base import EnvAdapter
    from seal.learner.config import AgentConfig


@dataclass(frozen=True)
class RunPlan:
    """What a run of `config` is, before anything is allocated (`plan_run`)."""

    config: ProtocolConfig
    seed: int
    device: str
    phases: list[Phase]
    adapters: dict[str, EnvAdapter]
    alignment: Alignment | None
    """Pad-and-fine-tune's alignment (finetune protocols), else None."""
    agent_cfg: AgentConfig
    models: dict[str, PhaseModel]
    """Phase name -> how its agent meets its envs (the memory estimate, the loop, resume checks)."""
    started: float
    """time.perf_counter() when the planning began: the run's start-up counts from it."""


def plan_run(config: ProtocolConfig, seed: int = 0, device: str | None = None) -> RunPlan:
    """The run's phases, adapters, alignment, agent config and phase models (`device`: instead
    of protocol.device's)."""
    started = time.perf_counter()
    phases = plan_phases(config)
    if device is None:
        try:
            device = provenance.resolve_device(config.protocol.device)
        except SealError as exc:
            raise ConfigError(
                f"{config.path}: protocol.device = {config.protocol.device!r}: {exc}"
            ) from None
    else:
        device = provenance.resolve_device(device)
    adapters = build_adapters(config)
    alignment = build_alignment(config, adapters) if config.kind == "finetune" else None
    agent_cfg = run_agent_config(config, device)
    models = {p.name: PhaseModel(config, p, adapters, alignment) for p in phases}
    return RunPlan(
        config, int(seed), device, phases, adapters, alignment, agent_cfg, models, started
    )


def check_resources(plan: RunPlan, cores: int | None = None) -> ThreadChoice:
    """Sizes the machine cannot hold fail here, in one line, before anything is allocated or
    written (`seal.run.resources`); the updates' threads are chosen (`cores`: a sweep trial's
    share) and set, with the matmul precision."""
    config = plan.config
    models = [(p, plan.models[p.name]) for p in plan.phases]
    threads = resources.check_resources(config, plan.adapters, plan.device, models, cores)
    if threads.threads:
        torch.set_num_threads(threads.threads)
    apply_matmul_precision(torch.device(plan.device), config.protocol.matmul_precision)
    return threads


def transfer_source(config: ProtocolConfig) -> AgentState | None:
    """The agent state named by [transfer] checkpoint (None without [transfer]).

    ConfigError naming `transfer.checkpoint` and the path if it is empty, missing or not a
    `seal run` checkpoint.
    """
    transfer = config.transfer
    if transfer is None:
        return None
    where = f"{config.path}: transfer.checkpoint"
    if not transfer.checkpoint:
        raise ConfigError(
            f"{where} is empty; give a checkpoint written by `seal run`, e.g. "
            "--set transfer.checkpoint=reports/<protocol>/<group>/seed-0/checkpoints/best.pt"
        )
    try:
        data = check_run_checkpoint(read_checkpoint(transfer.checkpoint), transfer.checkpoint)
    except SealError as exc:
        raise ConfigError(f"{where} = {transfer.checkpoint!r}: {exc}") from None
    return data["agent"]


def apply_transfer(
    config: ProtocolConfig, adapters: Mapping[str, EnvAdapter], agent: Agent, state: AgentState
) -> None:
    """Start `agent` from the [transfer] checkpoint's agent `state`: pad-and-fine-tune's copy,
    then transfer.map's, then the lowered learning rates; ConfigError naming transfer.checkpoint
    when the state does not fit the agent."""
    transfer = config.transfer
    assert transfer is not None
    mapped = mapped_start(config, adapters, state)  # its own errors name transfer.map
    try:
        transfer_from(agent, state, reinit_critic=transfer.reinit_critic)
        if mapped is not None:
            mapped.apply(agent, state)
    except SealError as exc:
        raise ConfigError(
            f"{config.path}: transfer.checkpoint = {transfer.checkpoint!r}: {exc}"
        ) from None
    agent.set_lr_factor(transfer.lr_factor)


def check_transfer(plan: RunPlan, state: AgentState) -> None:
    """Apply the transfer to a throwaway CPU agent of the phase it starts (\"train\"), so that a
    checkpoint that does not fit this protocol's agent (other widths, another architecture)
    fails before anything is written; the run applies it again to its own agent."""
    model = plan.models.get("train")
    assert model is not None, "[transfer] starts a baseline's or joint run's train phase"
    cpu = dataclasses.replace(plan.agent_cfg, device="cpu", compile=False)
    with torch.random.fork_rng(devices=[]):  # the global RNG as if this never ran
        apply_transfer(plan.config, plan.adapters, Agent(model.specs, cpu, 0), state)


def check_transfer_source(config: ProtocolConfig) -> None:
    """What a run checks of [transfer] before it writes anything (`transfer_source`, then
    `check_transfer`), for `seal protocol check` and `seal sweep`; nothing without [transfer]."""
    state = transfer_source(config)
    if state is not None:  # on CPU: the machine that checks need not have the run's GPU
        check_transfer(plan_run(config, device="cpu"), state)


def saved_config(path: Path) -> ProtocolConfig:
    """The config a run directory saved, read as data (`seal.files`): a regular file inside it,
    at most CONFIG_LIMIT bytes, valid TOML and a valid protocol; ConfigError naming the file."""
    RunDir.check(path)
    config_path = path / "config.toml"
    raw = read_toml(config_path, what="run config", within=path, limit=CONFIG_LIMIT)
    return config_from_dict(upgrade_saved(raw), str(config_path))


def load_policy(
    checkpoint: str | Path, device: str = "auto"
) -> tuple[ProtocolConfig, PhaseModel, Agent, RunCheckpoint]:
    """(config, phase model, agent with the saved weights, raw checkpoint) of a run checkpoint.

    SealError naming the file and the field when a field is missing, of the wrong type, or does
    not fit the rest (a phase its saved config has not, an agent state its networks refuse).
    """
    data = check_run_checkpoint(read_checkpoint(checkpoint), checkpoint)
    table = saved_config_table(data, checkpoint)
    config = config_from_dict(upgrade_saved(table), f"checkpoint {checkpoint}: field config_toml")
    phases = {p.name: p for p in plan_phases(config)}
    if data["phase"] not in phases:
        raise SealError(
            f"checkpoint {checkpoint}: field phase = {data['phase']!r}; expected a phase of its "
            f"saved config (kind {config.kind!r}): {', '.join(phases)}"
        )
    plan = plan_run(config, device=device)
    model = plan.models[data["phase"]]
    agent = Agent(model.specs, plan.agent_cfg, 0)
    try:
        agent.load_state_dict(data["agent"])
    except (SealError, RuntimeError, ValueError, KeyError, TypeError, IndexError) as exc:
        # The fields have their types; their values (shapes, optimiser slots) must also fit.
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:300]
        raise SealError(
            f"checkpoint {checkpoint}: field agent does not fit the agent its saved config "
            f"builds: {first}"
        ) from None
    return config, model, agent, data
