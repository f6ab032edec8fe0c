"""The memory estimate: its parameter count against real agents, and refusals before any directory exists."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from seal.cli.main import main
from seal.learner.sac import Agent
from seal.protocols import load_protocol
from seal.run import resources as resources_module
from seal.run.phase_model import PhaseModel, build_adapters, plan_phases
from seal.run.resources import estimate_resources

POINT = Path(__file__).parents[2] / "protocols" / "learn" / "point.toml"
SMT_GRU = POINT.with_name("point_smt_gru.toml")
TWO_ENVS = """
[protocol]
name = "two"
kind = "joint"
epochs = 2
device = "cpu"
[envs.a]
adapter = "point"
tasks = ["east", "north"]
[envs.b]
adapter = "point"
tasks = ["west"]
[agent]
translator_hidden = [8]
latent_dim = 6
trunk_hidden = [8, 8]
critic_hidden = [5]
"""


@pytest.mark.parametrize(
    ("protocol", "overrides"),
    [
        ("point", []),
        ("two", []),
        ("two", ['agent.critic_sharing="shared"']),
        ("two", ['agent.task_encoder="none"', "agent.multi_head_policy=false"]),
    ],
)
def test_parameter_count_is_the_real_agents(
    protocol: str, overrides: list[str], tmp_path: Path
) -> None:
    if protocol == "point":
        path = POINT
    else:
        path = tmp_path / "two.toml"
        path.write_text(TWO_ENVS)
    config = load_protocol(path, overrides)
    adapters = build_adapters(config)
    (phase,) = plan_phases(config)
    model = PhaseModel(config, phase, adapters, None)
    agent = Agent(model.specs, dataclasses.replace(config.agent, device="cpu"), 0)
    real = sum(p.numel() for net in (agent.actor, agent.critic) for p in net.parameters())
    estimate = estimate_resources(config, adapters, "cpu")
    assert estimate.peak.parameters == real
    # Actor and critic: weights, gradients and two Adam moments; the target critic's weights.
    actor = sum(p.numel() for p in agent.actor.parameters())
    assert estimate.peak.networks == 4 * (4 * actor + 5 * (real - actor))


@pytest.mark.parametrize(
    ("override", "key"),
    [
        ("agent.hidden=[1000000, 1000000]", "agent.hidden = [1000000, 1000000]"),
        ("training.batch_per_task=1000000000", "training.batch_per_task = 1000000000"),
        ("replay.capacity_per_env=100000000000", "replay.capacity_per_env = 100000000000"),
        # These failed at the first evaluation or encoder step, after the run directory existed.
        ("evaluation.episodes=10000000000", "evaluation.episodes = 10000000000"),
        ("agent.encoder_episodes=1000000000", "agent.encoder_episodes = 1000000000"),
    ],
)
def test_too_large_for_the_machine_is_refused_in_one_line_before_the_run_directory(
    override: str, key: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "reports"
    path = SMT_GRU if "encoder" in override else POINT
    code = main(["run", str(path), "--out", str(out), "--quiet", "--set", override])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert key in err[0] and "available" in err[0] and f"lower {key.split(' ')[0]}" in err[0]
    assert not out.exists()


def test_the_check_uses_the_memory_available(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # The control: the shipped protocol, which runs, is refused on a machine with 1 MiB free.
    monkeypatch.setattr(resources_module, "available_memory_bytes", lambda: 2**20)
    out = tmp_path / "reports"
    assert main(["run", str(POINT), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "replay.capacity_per_env = 1000000" in err and "available: 0.00 GiB" in err
    assert not out.exists()


def test_explain_prints_the_estimate(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["protocol", "explain", str(POINT)]) == 0
    memory, threads = capsys.readouterr().out.strip().splitlines()[-2:]
    # 16,024 plain, + 512 of the critics' LayerNorm: a gain and a bias per unit, 2 x 64 units, twins.
    assert memory.startswith("# estimated memory: ") and "16,536 parameters" in memory
    assert threads.startswith("# update threads: 1 (auto: 16,536 parameters x batch 256, ")
    config = load_protocol(POINT)
    assert estimate_resources(config, build_adapters(config), "cpu").peak.parameters == 16_536


def test_on_cuda_the_devices_free_memory_counts(monkeypatch: pytest.MonkeyPatch) -> None:
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "mem_get_info", lambda device=None: (3 * 2**30, 80 * 2**30))
    monkeypatch.setattr(resources_module, "available_memory_bytes", lambda: 10**15)
    config = load_protocol(POINT)
    estimate = estimate_resources(config, build_adapters(config), "cuda")
    assert estimate.available == 3 * 2**30 and "on cuda" in estimate.describe()


@pytest.mark.parametrize("architecture", ["mtmhsac", "paco", "moore", "care", "soft_modular"])
def test_explain_prints_each_learners_actor_and_critic_parameters(
    architecture: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 57: the counts of the networks the run would build (against an Agent built here)."""
    override = [f"agent.architecture={architecture}"]
    assert main(["protocol", "explain", str(POINT), "--set", *override]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("# networks: "))
    config = load_protocol(POINT, override)
    specs = PhaseModel(config, plan_phases(config)[0], build_adapters(config), None).specs
    agent = Agent(specs, dataclasses.replace(config.agent, device="cpu"), seed=0)
    actor = sum(p.numel() for p in agent.actor.parameters())
    critic = sum(p.numel() for p in agent.critic.parameters())
    assert line == (
        f"# networks: {architecture}: actor {actor:,} parameters, critic {critic:,} (both twins)"
    )


def test_the_task_encoders_step_is_estimated_from_what_backward_keeps() -> None:
    """The estimate of one smt_gru encoder step covers the tensors its backward keeps (counted by
    autograd's saved-tensor hooks, a second code path), at most 2.5 x over (measured: 1.6-1.8 x)."""
    import torch

    from seal.learner.task_encoder import Episodes, TaskEncoder, elbo

    for overrides in ([], ["agent.encoder_episodes=40", "agent.encoder_decode_steps=4"]):
        config = load_protocol(SMT_GRU, overrides)
        adapters = build_adapters(config)
        (phase,) = plan_phases(config)
        model = PhaseModel(config, phase, adapters, None)
        (spec,) = model.specs
        b, t = config.agent.encoder_episodes, adapters[spec.name].episode_length
        encoder = TaskEncoder(spec.obs_dim, spec.act_dim, spec.num_tasks, config.agent)
        episodes = Episodes(
            torch.randn(b, t, spec.obs_dim),
            torch.randn(b, t, spec.act_dim),
            torch.randn(b, t),
            torch.randn(b, t, spec.obs_dim),
            torch.full((b,), t),
            torch.randint(0, spec.num_tasks, (b,)),
        )
        kept: dict[int, int] = {}

        def pack(x: torch.Tensor, kept: dict[int, int] = kept) -> torch.Tensor:
            kept[x.untyped_storage().data_ptr()] = x.untyped_storage().nbytes()
            return x

        with torch.autograd.graph.saved_tensors_hooks(pack, lambda x: x):
            elbo(encoder, episodes, config.agent, torch.Generator().manual_seed(0))
        estimate = resources_module.encoder_batch_bytes(config.agent, model)
        assert sum(kept.values()) <= estimate <= 2.5 * sum(kept.values()), overrides
        total = estimate_resources(config, adapters, "cpu").peak
        assert total.encoder_batch == estimate and total.total >= total.replay + estimate
    config = load_protocol(POINT)  # one_hot: no encoder step
    model = PhaseModel(config, plan_phases(config)[0], build_adapters(config), None)
    assert resources_module.encoder_batch_bytes(config.agent, model) == 0


def test_evaluation_results_are_counted() -> None:
    # Four float64 arrays of episodes x tasks: 4 x 8 x 50 x 4 bytes for point's 4 tasks.
    config = load_protocol(POINT, ["evaluation.episodes=50"])
    assert estimate_resources(config, build_adapters(config), "cpu").peak.evaluation == 6_400


def test_absent_tasks_count_in_the_batchs_memory_not_in_the_threads() -> None:
    """scheduler.absent's tasks enlarge this run's own tasks' draws (up to share 1): their
    activations count at batch_per_task each; the update threads keep the plain batch."""
    sets = ['scheduler.kind="constant"', "scheduler.ratios={pt=0.5,g=0.5}"]
    config = load_protocol(POINT)  # no absent env: point's 4 tasks
    plain = estimate_resources(config, build_adapters(config), "cpu").peak
    config = load_protocol(POINT, [*sets, "scheduler.absent={g=1000}"])
    estimate = estimate_resources(config, build_adapters(config), "cpu")
    assert estimate.peak.activations == plain.activations * (4 + 1000) // 4  # point's 4 tasks
    assert estimate.update_shape() == (plain.parameters, plain.batch)
