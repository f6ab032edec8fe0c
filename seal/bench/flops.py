"""``mt10_update_flops_fraction`` and ``small_update_flops_fraction``: how close an update runs to torch.mm.

The matmul FLOPs an ideal update needs (`ideal_update_gemms`: every GEMM of one SAC update, only
each sample's task head), per second of our update, / the FLOP/s torch.mm reaches on exactly those
GEMM shapes; equivalently the time of the update's GEMMs alone / the time of the whole update.
MT10: the MTMHSAC update (3 x 400, 128 per task x 10). Small: the quickstart's SEAL update
(protocols/quickstart.toml: its two envs' real sizes, its batch and widths), always on one torch
thread. Both are timed eager and with agent.compile (the compiled figure is the headline when it
compiles). `flop_formula_check` / `agent_flop_formula_check` check the
formula, set to what our update really computes, against FlopCounterMode's count.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

import torch

from seal.bench.timing import _timeit
from seal.device import torch_threads
from seal.errors import SealError
from seal.learner.networks import critic_layers

if TYPE_CHECKING:
    from seal.learner import Agent, AgentConfig, Batch, EnvSpec


@dataclass(frozen=True)
class UpdateShape:
    """The shapes of one MTMHSAC update: widths, batch and what an implementation computes.

    `actor_heads` / `critic_heads` are the heads whose outputs are computed (1 for an ideal
    implementation, which computes only each sample's task head); `critic_input_grad` is the
    number of critic input columns whose gradient the actor step computes (ideal: the action).
    """

    obs_dim: int = 39
    act_dim: int = 4
    num_tasks: int = 10
    hidden: tuple[int, ...] = (400, 400, 400)
    batch: int = 1280
    one_hot: bool = True
    actor_heads: int = 1
    critic_heads: int = 1
    critic_input_grad: int | None = None  # None: act_dim
    critic_hidden: tuple[int, ...] | None = None  # None: hidden (SEAL per-env critics differ)

    @property
    def actor_dims(self) -> list[int]:
        """Layer widths of the actor, input to output."""
        return [
            self.obs_dim + (self.num_tasks if self.one_hot else 0),
            *self.hidden,
            2 * self.act_dim * self.actor_heads,
        ]

    @property
    def critic_dims(self) -> list[int]:
        """Layer widths of one critic, input to output."""
        hidden = self.hidden if self.critic_hidden is None else self.critic_hidden
        return [self.actor_dims[0] + self.act_dim, *hidden, self.critic_heads]


Gemm = tuple[int, int, int]  # (m, k, n): an (m, k) @ (k, n) product, 2 m k n FLOPs


def _forward(b: int, dims: Sequence[int]) -> list[Gemm]:
    return [(b, i, o) for i, o in zip(dims[:-1], dims[1:], strict=True)]


def _grad_weights(b: int, dims: Sequence[int]) -> list[Gemm]:
    return [(i, b, o) for i, o in zip(dims[:-1], dims[1:], strict=True)]  # dW = X^T dY


def _grad_inputs(b: int, dims: Sequence[int], first_layer_cols: int) -> list[Gemm]:
    out = [(b, o, i) for i, o in zip(dims[1:-1], dims[2:], strict=True)]  # dX = dY W^T
    if first_layer_cols:
        out.insert(0, (b, dims[1], first_layer_cols))
    return out


def ideal_update_gemms(shape: UpdateShape) -> list[Gemm]:
    """Every matrix product one SAC update needs (cleanrl order), twin critics counted twice.

    Critic step: policy on s' (no grad), 2 target Qs on (s', a'), 2 online Qs on (s, a) forward and
    backward (weight grads; input grads of all but the first layer). Actor step: policy on s, 2 Qs
    on (s, pi(s)) forward and backward to the action only (no critic weight grads), policy backward
    (weight grads; input grads of all but the first layer). Elementwise work (ReLU, Adam, Polyak,
    log-probs) is not counted.
    """
    b, a, c = shape.batch, shape.actor_dims, shape.critic_dims
    cols = shape.act_dim if shape.critic_input_grad is None else shape.critic_input_grad
    critic_step = (
        _forward(b, a)
        + 2 * _forward(b, c)
        + 2 * (_forward(b, c) + _grad_weights(b, c) + _grad_inputs(b, c, 0))
    )
    actor_step = (
        _forward(b, a)
        + 2 * (_forward(b, c) + _grad_inputs(b, c, cols))
        + _grad_weights(b, a)
        + _grad_inputs(b, a, 0)
    )
    return critic_step + actor_step


def gemm_flops(gemms: Sequence[Gemm]) -> int:
    """2 FLOPs per multiply-add."""
    return sum(2 * m * k * n for m, k, n in gemms)


def _mt10_setup(
    num_tasks: int = 10, hidden: tuple[int, ...] = (400, 400, 400)
) -> tuple[list[EnvSpec], AgentConfig]:
    """The MTMHSAC agent's spec and config that the MT10 figures time, on CPU."""
    from seal.learner import AgentConfig, EnvSpec

    return [EnvSpec("metaworld", 39, 4, num_tasks)], AgentConfig(hidden=hidden, device="cpu")


def _mt10_agent(seed: int, num_tasks: int = 10, hidden: tuple[int, ...] = (400, 400, 400)) -> Agent:
    from seal.learner import Agent

    return Agent(*_mt10_setup(num_tasks, hidden), seed)


def _random_batch(
    num_tasks: int, per_task: int, seed: int, obs_dim: int = 39, act_dim: int = 4
) -> Batch:
    from seal.learner import Batch

    g = torch.Generator().manual_seed(seed)
    n = num_tasks * per_task
    return Batch(
        torch.randn(n, obs_dim, generator=g),
        torch.rand(n, act_dim, generator=g) * 2 - 1,
        torch.rand(n, generator=g),
        torch.randn(n, obs_dim, generator=g),
        torch.zeros(n),
        torch.arange(num_tasks).repeat_interleave(per_task),
    )


class FlopCheck(TypedDict):
    """FlopCounterMode's count of one update next to the formula's (`flop_formula_check`)."""

    flop_counter: int
    formula_as_implemented: int
    formula_ideal: int
    equal: bool


def flop_formula_check(
    num_tasks: int = 3, per_task: int = 8, hidden: tuple[int, ...] = (32, 32, 32)
) -> FlopCheck:
    """FlopCounterMode's count of one real update vs the formula set to what our update computes.

    Our update computes every policy and Q head (then gathers) and the critic's input gradient over
    all its input columns; the formula with actor_heads=num_tasks and critic_input_grad = the
    critic's input width must then equal the counter exactly. The ideal count is also returned.
    """
    from torch.utils.flop_counter import FlopCounterMode

    agent = _mt10_agent(0, num_tasks, hidden)
    batch = {"metaworld": _random_batch(num_tasks, per_task, 0)}
    with FlopCounterMode(display=False) as counter:
        agent.update(batch)
    counted = int(counter.get_total_flops())
    as_implemented = UpdateShape(
        num_tasks=num_tasks,
        hidden=hidden,
        batch=num_tasks * per_task,
        actor_heads=num_tasks,
        critic_heads=num_tasks,
        critic_input_grad=39 + num_tasks + 4,
    )
    ideal = UpdateShape(num_tasks=num_tasks, hidden=hidden, batch=num_tasks * per_task)
    formula = gemm_flops(ideal_update_gemms(as_implemented))
    return {
        "flop_counter": counted,
        "formula_as_implemented": formula,
        "formula_ideal": gemm_flops(ideal_update_gemms(ideal)),
        "equal": counted == formula,
    }


def _time_gemms(gemms: Sequence[Gemm], repeats: int) -> float:
    """Seconds torch.mm needs for all `gemms` (fp32, contiguous operands), best of `repeats`."""
    distinct: dict[Gemm, int] = {}
    for g in gemms:
        distinct[g] = distinct.get(g, 0) + 1
    total, inner = 0.0, 20
    for (m, k, n), count in distinct.items():
        x, w, out = torch.randn(m, k), torch.randn(k, n), torch.empty(m, n)

        def run(x: torch.Tensor = x, w: torch.Tensor = w, out: torch.Tensor = out) -> None:
            for _ in range(inner):
                torch.mm(x, w, out=out)

        run()
        total += count * _timeit(run, repeats) / inner
    return total


def bench_mt10_flops(
    updates: int = 50, repeats: int = 3, seed: int = 0, compile: bool = True
) -> dict[str, Any]:
    """FLOP/s of the MT10 MTMHSAC update (defaults: 3 x 400, 128 per task x 10) / torch.mm FLOP/s at its shapes.

    Measured like `bench_small_update_flops` (`_time_eager_and_compiled`): eager and, with
    `compile`, with agent.compile on; the headline is the compiled figure when it compiled.
    """
    from torch.utils.flop_counter import FlopCounterMode

    shape = UpdateShape()
    gemms = ideal_update_gemms(shape)
    flops = gemm_flops(gemms)
    agent = _mt10_agent(seed)
    batch = {"metaworld": _random_batch(10, 128, seed)}
    agent.update(batch)  # the first update's Adam states: the counted one is a steady-state step
    with FlopCounterMode(display=False) as counter:
        agent.update(batch)
    specs, config = _mt10_setup(shape.num_tasks, shape.hidden)
    timed = _time_eager_and_compiled(specs, config, 128, updates, repeats, seed, compile)
    t_mm = _time_gemms(gemms, repeats)
    for path in timed["paths"].values():
        path["update_gflops"] = flops / path["update_s"] / 1e9
        path["mt10_update_flops_fraction"] = t_mm / path["update_s"]
    headline = timed["paths"][timed["headline_path"]]
    return {
        "ideal_flops_per_update": flops,
        # What our update really multiplies (all 10 policy and Q heads, the critic's full input
        # gradient): the excess over ideal is work an ideal implementation would not do.
        "flop_counter_per_update": int(counter.get_total_flops()),
        "matmul_gflops_same_shapes": flops / t_mm / 1e9,
        **timed,
        "update_s": headline["update_s"],
        "update_gflops": headline["update_gflops"],
        "mt10_update_flops_fraction": headline["mt10_update_flops_fraction"],
        "updates_timed": updates,
    }


# ---------------------------------------------------------------- small (quickstart) update FLOPs

QUICKSTART = Path(__file__).resolve().parents[2] / "protocols" / "quickstart.toml"


def agent_update_shapes(
    specs: Sequence[EnvSpec], config: AgentConfig, per_task: int
) -> list[UpdateShape]:
    """One UpdateShape per env of an agent's update (ideal: only each sample's task head).

    SEAL env i's policy is one chain of layers, translator_i -> shared trunk -> head_i, so as
    GEMMs it is an MLP with hidden widths (*translator_hidden, latent_dim, *trunk_hidden); its
    critic is its own MLP over critic_hidden (critic_sharing = "per_env") or the same chain
    (shared). The shared trunk is counted once per env's rows: an ideal implementation that ran
    both envs' rows through it in one product does the same multiply-adds. act_pad_to is ignored.
    """
    from seal.learner.config import MTRL_ARCHITECTURES

    if config.architecture in MTRL_ARCHITECTURES:
        raise SealError(
            f"agent.architecture = {config.architecture!r}: the GEMM formula covers MTMHSAC and "
            "SEAL; count its update with seal.bench.flops.counted_update_flops"
        )
    trunk = critic_layers(getattr(config, config.critic_trunk_key), config.critic_block)
    if config.architecture == "seal":
        actor_hidden = (*config.translator_hidden, config.latent_dim, *config.trunk_hidden)
        translator = (*config.translator_hidden, config.latent_dim)
        critic_hidden = trunk if config.critic_sharing == "per_env" else (*translator, *trunk)
    else:
        actor_hidden, critic_hidden = config.hidden, trunk
    return [
        UpdateShape(
            obs_dim=s.obs_dim,
            act_dim=s.act_dim,
            num_tasks=s.num_tasks,
            hidden=tuple(actor_hidden),
            critic_hidden=tuple(critic_hidden),
            batch=per_task * s.num_tasks,
            one_hot=config.one_hot,
        )
        for s in specs
    ]


def agent_update_gemms(shapes: Sequence[UpdateShape]) -> list[Gemm]:
    """`ideal_update_gemms` of every env's shape, env after env."""
    return [g for shape in shapes for g in ideal_update_gemms(shape)]


def as_implemented(shape: UpdateShape) -> UpdateShape:
    """`shape` set to what our update computes: every policy and Q head, the critic's full input gradient."""
    return dataclasses.replace(
        shape,
        actor_heads=shape.num_tasks,
        critic_heads=shape.num_tasks,
        critic_input_grad=shape.actor_dims[0] + shape.act_dim,
    )


def quickstart_setup(
    protocol: str | Path = QUICKSTART, device: str = "cpu"
) -> tuple[list[EnvSpec], AgentConfig, int]:
    """A protocol's EnvSpecs (its envs' real obs/action sizes and task counts), its resolved
    AgentConfig on `device` and its batch_per_task (default: the quickstart's, on CPU); SealError
    when an env's adapter is not installed."""
    from seal.learner import EnvSpec
    from seal.protocols import load_protocol
    from seal.run.phase_model import build_adapters

    config = load_protocol(str(protocol))
    try:
        adapters = build_adapters(config)
    except ImportError as exc:  # an env's simulator is missing
        raise SealError(f"{protocol}: cannot build its envs ({exc})") from None
    specs = [EnvSpec(n, a.obs_dim, a.act_dim, len(a.tasks)) for n, a in adapters.items()]
    agent_cfg = dataclasses.replace(config.agent, device=device)
    return specs, agent_cfg, int(config.training.batch_per_task)


def _agent_batches(
    specs: Sequence[EnvSpec], per_task: int, seed: int, device: torch.device | str = "cpu"
) -> dict[str, Batch]:
    from seal.learner import Batch

    return {
        s.name: Batch(
            *(
                t.to(device)
                for t in _random_batch(s.num_tasks, per_task, seed + i, s.obs_dim, s.act_dim)
            )
        )
        for i, s in enumerate(specs)
    }


def counted_update_flops(
    specs: Sequence[EnvSpec], config: AgentConfig, per_task: int, seed: int = 0
) -> int:
    """FlopCounterMode's count of one real update (the second) of any agent, every architecture
    included: the FLOP count of the task-conditioned learners (`seal.learner.mtrl`), which the
    GEMM formula of `agent_update_shapes` does not describe."""
    from torch.utils.flop_counter import FlopCounterMode

    from seal.learner import Agent

    agent = Agent(specs, dataclasses.replace(config, compile=False), seed)
    batches = _agent_batches(specs, per_task, seed, agent.device)
    agent.update(batches)
    with FlopCounterMode(display=False) as counter:
        agent.update(batches)
    return int(counter.get_total_flops())


def agent_flop_formula_check(
    specs: Sequence[EnvSpec], config: AgentConfig, per_task: int, seed: int = 0
) -> FlopCheck:
    """FlopCounterMode's count of one real update of any agent vs the `as_implemented` formula (and the ideal count).

    The update counted is the second one (the first measures the ratio lever on copies). Give
    every env >= 2 tasks: a single-task ensemble Q head is a multiply-and-sum, not a matmul, so
    FlopCounterMode does not see it (`run_bench` checks the quickstart's shapes with 2 tasks each).
    """
    from torch.utils.flop_counter import FlopCounterMode

    from seal.learner import Agent

    agent = Agent(specs, config, seed)
    batches = _agent_batches(specs, per_task, seed)
    agent.update(batches)
    with FlopCounterMode(display=False) as counter:
        agent.update(batches)
    counted = int(counter.get_total_flops())
    shapes = agent_update_shapes(specs, config, per_task)
    formula = gemm_flops(agent_update_gemms([as_implemented(s) for s in shapes]))
    return {
        "flop_counter": counted,
        "formula_as_implemented": formula,
        "formula_ideal": gemm_flops(agent_update_gemms(shapes)),
        "equal": counted == formula,
    }


def _time_eager_and_compiled(
    specs: Sequence[EnvSpec],
    config: AgentConfig,
    per_task: int,
    updates: int,
    repeats: int,
    seed: int,
    compile: bool,
) -> dict[str, Any]:
    """Seconds per update of `config`'s agent eager and, with `compile`, compiled (same batches,
    seed and device; repeats interleaved, the best counts), timed as a training loop runs them
    (`update_on_device`, one sync per timed run). Five untimed updates first (the first also
    measures the ratio lever); `loss_max_rel_diff` compares the two agents' losses at updates 1
    and 5. The headline path is the compiled one when it compiled, else eager."""
    from seal.learner import Agent

    agents = {"eager": Agent(specs, config, seed)}
    if compile:
        agents["compiled"] = Agent(specs, dataclasses.replace(config, compile=True), seed)
    device = agents["eager"].device
    batches = _agent_batches(specs, per_task, seed, device)
    losses: dict[str, list[dict[str, float]]] = {k: [] for k in agents}
    for _ in range(5):
        for name, agent in agents.items():
            metrics = agent.update(batches)
            losses[name].append({k: v for k, v in metrics.items() if k.startswith("losses")})
    best = dict.fromkeys(agents, math.inf)
    for _ in range(repeats):
        for name, agent in agents.items():

            def run(agent: Agent = agent) -> None:
                for _ in range(updates):
                    _, values = agent.update_on_device(batches)
                values.cpu()  # waits for the device's queued work

            best[name] = min(best[name], _timeit(run, 1) / updates)
    paths: dict[str, Any] = {name: {"update_s": best[name]} for name in agents}
    if "compiled" in agents:
        compiled = agents["compiled"]
        paths["compiled"]["compiled"] = compiled.compiled
        paths["compiled"]["compile_seconds"] = compiled.compile_seconds
        paths["compiled"]["loss_max_rel_diff"] = {
            f"update_{i + 1}": max(
                abs(losses["compiled"][i][k] - v) / max(abs(v), 1e-12)
                for k, v in losses["eager"][i].items()
            )
            for i in (0, 4)
        }
    headline = "compiled" if compile and agents["compiled"].compiled else "eager"
    return {"device": str(device), "paths": paths, "headline_path": headline}


def bench_small_update_flops(
    updates: int = 30, repeats: int = 3, seed: int = 0, compile: bool = True
) -> dict[str, Any]:
    """FLOP/s of the quickstart-shape SEAL update / torch.mm FLOP/s at its ideal GEMM shapes, one thread.

    The agent is the quickstart protocol's (`quickstart_setup`): two envs, batch_per_task samples
    per task, its widths. Ideal FLOPs as `mt10_update_flops_fraction` counts them, per env
    (`agent_update_shapes`). Measured for the eager update and, with `compile`, for the same agent
    with agent.compile on (`_time_eager_and_compiled`); the headline `small_update_flops_fraction`
    is the compiled one when it compiled, else eager's.
    """
    specs, config, per_task = quickstart_setup()
    shapes = agent_update_shapes(specs, config, per_task)
    gemms = agent_update_gemms(shapes)
    flops = gemm_flops(gemms)
    with torch_threads(1):
        timed = _time_eager_and_compiled(specs, config, per_task, updates, repeats, seed, compile)
        t_mm = _time_gemms(gemms, repeats)
    for path in timed["paths"].values():
        path["update_gflops"] = flops / path["update_s"] / 1e9
        path["small_update_flops_fraction"] = t_mm / path["update_s"]
    headline = timed["paths"][timed["headline_path"]]
    return {
        "envs": {s.name: dataclasses.asdict(s) for s in specs},
        "batch_per_task": per_task,
        "ideal_flops_per_update": flops,
        "matmul_gflops_same_shapes": flops / t_mm / 1e9,
        **timed,
        "update_s": headline["update_s"],
        "update_gflops": headline["update_gflops"],
        "small_update_flops_fraction": headline["small_update_flops_fraction"],
        "updates_timed": updates,
        "threads": 1,
    }


PAPER_PROTOCOL = QUICKSTART.parent / "high_fk.toml"


def bench_update_rate(
    protocol: str | Path = PAPER_PROTOCOL,
    updates: int = 50,
    repeats: int = 3,
    seed: int = 0,
    device: str = "auto",
    compile: bool = True,
) -> dict[str, Any]:
    """Updates/s of a protocol's agent at its real update shape on `device`, eager and compiled.

    Default: the paper-scale SEAL update (protocols/high_fk.toml: MT10 and the 10 kitchens, 128
    per task, batch 2,560, 400-wide). On CUDA the compiled path replays each update stage as a CUDA
    graph (`seal.learner.staging.compile_mode`). Every env gets batch_per_task samples per task (the
    50/50 point of a ratio schedule: the total batch, hence the work, is the same at any ratio).
    ``paper_update_rate`` is the headline path's updates/s (compiled when it compiled), at full
    float32; on CUDA the same paths again with TF32 matmuls (`protocol.matmul_precision = "high"`)
    give ``paper_update_rate_tf32``.
    """
    specs, config, per_task = quickstart_setup(protocol, device=device)

    def rates() -> dict[str, Any]:
        timed = _time_eager_and_compiled(specs, config, per_task, updates, repeats, seed, compile)
        for path in timed["paths"].values():
            path["updates_per_s"] = 1.0 / path["update_s"]
        return timed

    timed = rates()
    if timed["device"].startswith("cuda"):
        timed["device_name"] = torch.cuda.get_device_name(torch.device(timed["device"]))
        before = torch.get_float32_matmul_precision()
        torch.set_float32_matmul_precision("high")
        try:
            tf32 = rates()
        finally:
            torch.set_float32_matmul_precision(before)
        timed["tf32"] = tf32
        timed["paper_update_rate_tf32"] = tf32["paths"][tf32["headline_path"]]["updates_per_s"]
    return {
        "protocol": str(protocol),
        "envs": {s.name: dataclasses.asdict(s) for s in specs},
        "batch": per_task * sum(s.num_tasks for s in specs),
        **timed,
        "paper_update_rate": timed["paths"][timed["headline_path"]]["updates_per_s"],
        "updates_timed": updates,
        "threads": torch.get_num_threads(),
    }
