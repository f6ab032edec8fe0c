"""`seal bench`: speed of the learner and of collection, side by side in one run, as ratios.

Every figure is a ratio of two measurements taken in the same process, one after the other, so
machine load affects both sides (the load is recorded with the results):

- ``sac_vs_sb3``: gradient updates/s of our single-task SAC / stable-baselines3 SAC (widths
  (400, 400), batch 256, CPU, same torch threads), both including replay sampling. That the two
  compute the same update is a test (tests/learner/test_sb3_parity.py).
- ``mt10_update_flops_fraction``: matmul FLOPs an ideal MT10 MTMHSAC update needs
  (`ideal_update_gemms`), per second of our update, / the FLOP/s torch.mm reaches on exactly those
  GEMM shapes. Equivalently: time of the update's GEMMs alone / time of the whole update.
- ``small_update_flops_fraction``: the same for the quickstart's SEAL update (protocols/quickstart.toml:
  its two envs' real sizes, 128 samples per task, 128-wide networks), always on one torch thread;
  eager and with agent.compile side by side (the compiled figure is the headline when it compiles).
- ``ratio_lever``: at a 90/10 data ratio, the 90% environment's share of the shared policy trunk's
  step (`Agent.ratio_lever`) under the default ``shared_update = "weighted"``; the details list
  every mode with the ratio of the two environments' trunk gradient norms, the weighted mode's
  share of the raw (pre-Adam, unclipped) gradient, and the share that a noise-dominated gradient
  allows any sample-count weighting. Not a timing.
- ``collect_mt10_speedup`` / ``collect_fk_speedup``: env steps/s of `Collector` over the 10 tasks /
  a plain single-process loop over envs built by the same adapter (same wrappers), with the same
  actions; both must end on identical observations.

`seal bench --learn` adds the learning evidence (MTMHSAC on `point` with and without the one-hot,
SAC on Meta-World reach-v3); it is slow and not part of CI.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np
import pandas as pd
import torch

from seal.errors import SealError

if TYPE_CHECKING:
    import gymnasium as gym
    from stable_baselines3 import SAC

    from seal.envs.base import EnvAdapter
    from seal.learner import Agent, AgentConfig, Batch, EnvSpec

# ---------------------------------------------------------------- shared helpers


def _timeit(fn: Callable[[], object], repeats: int) -> float:
    """Best-of-`repeats` wall time of fn(): the least-disturbed run on a shared machine."""
    best = math.inf
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


@contextlib.contextmanager
def torch_threads(n: int | None) -> Iterator[None]:
    """Run with `n` torch intra-op threads (None: unchanged), restoring the previous count."""
    before = torch.get_num_threads()
    if n is not None:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(before)


class MachineLoad(TypedDict):
    """`machine_load`'s record."""

    loadavg_1m: float
    loadavg_5m: float
    loadavg_15m: float
    cpus: int | None
    torch_threads: int


def machine_load() -> MachineLoad:
    """Load averages and CPU count, recorded next to every figure."""
    one, five, fifteen = os.getloadavg()
    return {
        "loadavg_1m": round(one, 2),
        "loadavg_5m": round(five, 2),
        "loadavg_15m": round(fifteen, 2),
        "cpus": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
    }


def _rel(a: float, b: float) -> float:
    """|a - b| relative to the larger magnitude (0 when both are 0)."""
    scale = max(abs(a), abs(b))
    return 0.0 if scale == 0 else abs(a - b) / scale


# ---------------------------------------------------------------- SAC vs stable-baselines3

SB3_OBS_DIM, SB3_ACT_DIM = 39, 4  # Meta-World's shapes
SB3_WIDTHS = (400, 400)


def _sb3_env() -> gym.Env:
    import gymnasium as gym

    class BoxEnv(gym.Env):
        """Meta-World-shaped spaces; SB3 only needs them to build its networks and buffer."""

        observation_space = gym.spaces.Box(-np.inf, np.inf, (SB3_OBS_DIM,), np.float32)
        action_space = gym.spaces.Box(-1.0, 1.0, (SB3_ACT_DIM,), np.float32)

        def reset(
            self, *, seed: int | None = None, options: dict | None = None
        ) -> tuple[np.ndarray, dict]:
            return np.zeros(SB3_OBS_DIM, np.float32), {}

        def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
            return np.zeros(SB3_OBS_DIM, np.float32), 0.0, False, False, {}

    return BoxEnv()


def _require_sb3() -> ModuleType:
    try:
        import stable_baselines3
    except ImportError:
        raise SealError(
            "sac_vs_sb3 needs stable-baselines3, a benchmark-only extra: pip install -e '.[bench]'"
        ) from None
    return stable_baselines3


def _twin_sacs(seed: int, batch_size: int, buffer_size: int) -> tuple[Agent, SAC]:
    """Our single-task SAC and an SB3 SAC with identical weights, (400, 400), on CPU."""
    _require_sb3()
    from stable_baselines3 import SAC
    from stable_baselines3.common.logger import Logger

    from seal.learner import Agent, AgentConfig, EnvSpec

    # One task, no one-hot: the plain single-task SAC that SB3 implements (no gradient clipping,
    # torch's Adam eps).
    config = AgentConfig(
        hidden=SB3_WIDTHS,
        one_hot=False,
        multi_head_policy=False,
        max_grad_norm=0.0,
        adam_eps=1e-8,
        device="cpu",
    )
    ours = Agent([EnvSpec("bench", SB3_OBS_DIM, SB3_ACT_DIM, 1)], config, seed)
    sb3 = SAC(
        "MlpPolicy",
        _sb3_env(),
        batch_size=batch_size,
        buffer_size=buffer_size,
        learning_starts=0,
        policy_kwargs={"net_arch": list(SB3_WIDTHS)},
        device="cpu",
        seed=seed,
    )
    sb3.set_logger(Logger(folder=None, output_formats=[]))
    _copy_weights(ours, sb3)
    return ours, sb3


def _copy_weights(ours: Agent, sb3: SAC) -> None:
    """Load our networks' weights into SB3's (our layers store (in, out); torch Linear (out, in))."""
    key = ours._keys["bench"]
    actor, critic = ours.actor, ours.critic
    with torch.no_grad():
        linears = [m for m in sb3.actor.latent_pi if isinstance(m, torch.nn.Linear)]
        for lin, w, b in zip(linears, actor.trunk.weights, actor.trunk.biases, strict=True):
            lin.weight.copy_(w[0].T)
            lin.bias.copy_(b[0, 0])
        head_w, head_b = actor.heads[key].weight[0], actor.heads[key].bias[0, 0]
        sb3.actor.mu.weight.copy_(head_w[:, :SB3_ACT_DIM].T)
        sb3.actor.mu.bias.copy_(head_b[:SB3_ACT_DIM])
        sb3.actor.log_std.weight.copy_(head_w[:, SB3_ACT_DIM:].T)
        sb3.actor.log_std.bias.copy_(head_b[SB3_ACT_DIM:])
        for q, qf in enumerate(sb3.critic.q_networks):
            layers = [m for m in qf if isinstance(m, torch.nn.Linear)]
            weights = [*critic.trunk.weights, critic.heads[key].weight]
            biases = [*critic.trunk.biases, critic.heads[key].bias]
            for lin, w, b in zip(layers, weights, biases, strict=True):
                lin.weight.copy_(w[q].T)
                lin.bias.copy_(b[q, 0])
        sb3.critic_target.load_state_dict(sb3.critic.state_dict())


class SacVsSb3(TypedDict):
    """`bench_sac_vs_sb3`'s figures."""

    ours_updates_per_s: float
    sb3_updates_per_s: float
    sac_vs_sb3: float
    ours_flops_per_update: int
    sb3_flops_per_update: int
    flops_ratio_sb3_over_ours: float
    ours_gflops: float
    sb3_gflops: float
    updates_timed: int
    repeats: int


def bench_sac_vs_sb3(updates: int = 300, repeats: int = 3, seed: int = 0) -> SacVsSb3:
    """Gradient updates/s of our SAC and SB3's, each sampling batch 256 from its own filled replay."""
    from seal.learner import MultiTaskReplay
    from seal.learner.config import EnvSpec

    batch_size, filled = 256, 20_000
    ours, sb3 = _twin_sacs(seed, batch_size, buffer_size=filled)
    rng = np.random.default_rng(seed)
    data = {
        "obs": rng.normal(size=(filled, SB3_OBS_DIM)).astype(np.float32),
        "actions": rng.uniform(-1, 1, (filled, SB3_ACT_DIM)).astype(np.float32),
        "rewards": rng.uniform(0, 10, filled).astype(np.float32),
        "next_obs": rng.normal(size=(filled, SB3_OBS_DIM)).astype(np.float32),
        "terminations": np.zeros(filled, np.float32),
    }
    replay = MultiTaskReplay(
        [EnvSpec("bench", SB3_OBS_DIM, SB3_ACT_DIM, 1)], capacity=filled, seed=seed + 1
    )
    replay.add(
        "bench",
        np.zeros(filled, np.int64),
        data["obs"],
        data["actions"],
        data["rewards"],
        data["next_obs"],
        data["terminations"],
    )
    buf = sb3.replay_buffer
    buf.observations[:filled, 0] = data["obs"]
    buf.next_observations[:filled, 0] = data["next_obs"]
    buf.actions[:filled, 0] = data["actions"]
    buf.rewards[:filled, 0] = data["rewards"]
    buf.dones[:filled, 0] = data["terminations"]
    buf.full = True
    counts = {"bench": np.array([batch_size])}

    def ours_run(n: int) -> None:
        for _ in range(n):
            ours.update(replay.sample(counts))

    def sb3_run(n: int) -> None:
        sb3.train(gradient_steps=n, batch_size=batch_size)

    from torch.utils.flop_counter import FlopCounterMode

    ours_run(10)
    sb3_run(10)  # warm-up: allocator, Adam state
    # Matmul FLOPs per update of each: their ratio is the speedup two GEMM-bound codes would show.
    # SB3's actor loss backward also computes the critics' weight gradients (then zeroed).
    flops = {}
    for side, fn in (("ours", ours_run), ("sb3", sb3_run)):
        with FlopCounterMode(display=False) as counter:
            fn(1)
        flops[side] = int(counter.get_total_flops())
    t_ours = _timeit(lambda: ours_run(updates), repeats)
    t_sb3 = _timeit(lambda: sb3_run(updates), repeats)
    return {
        "ours_updates_per_s": updates / t_ours,
        "sb3_updates_per_s": updates / t_sb3,
        "sac_vs_sb3": t_sb3 / t_ours,
        "ours_flops_per_update": flops["ours"],
        "sb3_flops_per_update": flops["sb3"],
        "flops_ratio_sb3_over_ours": flops["sb3"] / flops["ours"],
        "ours_gflops": flops["ours"] * updates / t_ours / 1e9,
        "sb3_gflops": flops["sb3"] * updates / t_sb3 / 1e9,
        "updates_timed": updates,
        "repeats": repeats,
    }


# ---------------------------------------------------------------- MT10 update FLOPs


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


def _mt10_agent(seed: int, num_tasks: int = 10, hidden: tuple[int, ...] = (400, 400, 400)) -> Agent:
    from seal.learner import Agent, AgentConfig, EnvSpec

    return Agent(
        [EnvSpec("metaworld", 39, 4, num_tasks)], AgentConfig(hidden=hidden, device="cpu"), seed
    )


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


class Mt10Flops(TypedDict):
    """`bench_mt10_flops`' figures."""

    ideal_flops_per_update: int
    flop_counter_per_update: int
    update_s: float
    update_gflops: float
    matmul_gflops_same_shapes: float
    mt10_update_flops_fraction: float
    updates_timed: int


def bench_mt10_flops(updates: int = 50, repeats: int = 3, seed: int = 0) -> Mt10Flops:
    """FLOP/s of the MT10 MTMHSAC update (defaults: 3 x 400, 128 per task x 10) / torch.mm FLOP/s at its shapes."""
    shape = UpdateShape()
    gemms = ideal_update_gemms(shape)
    flops = gemm_flops(gemms)
    agent = _mt10_agent(seed)
    batch = {"metaworld": _random_batch(10, 128, seed)}
    for _ in range(5):
        agent.update(batch)

    def run() -> None:
        for _ in range(updates):
            agent.update(batch)

    from torch.utils.flop_counter import FlopCounterMode

    with FlopCounterMode(display=False) as counter:
        agent.update(batch)
    t_update = _timeit(run, repeats) / updates
    t_mm = _time_gemms(gemms, repeats)
    return {
        "ideal_flops_per_update": flops,
        # What our update really multiplies (all 10 policy and Q heads, the critic's full input
        # gradient): the excess over ideal is work an ideal implementation would not do.
        "flop_counter_per_update": int(counter.get_total_flops()),
        "update_s": t_update,
        "update_gflops": flops / t_update / 1e9,
        "matmul_gflops_same_shapes": flops / t_mm / 1e9,
        "mt10_update_flops_fraction": t_mm / t_update,
        "updates_timed": updates,
    }


# ---------------------------------------------------------------- small (quickstart) update FLOPs

QUICKSTART = Path(__file__).resolve().parents[1] / "protocols" / "quickstart.toml"


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
    if config.architecture == "seal":
        actor_hidden = (*config.translator_hidden, config.latent_dim, *config.trunk_hidden)
        critic_hidden = config.critic_hidden if config.critic_sharing == "per_env" else actor_hidden
    else:
        actor_hidden = critic_hidden = config.hidden
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


def quickstart_setup(protocol: str | Path = QUICKSTART) -> tuple[list[EnvSpec], AgentConfig, int]:
    """The quickstart's EnvSpecs (its envs' real obs/action sizes and task counts), its resolved
    AgentConfig on CPU and its batch_per_task; SealError when an env's adapter is not installed."""
    from seal.learner import EnvSpec
    from seal.protocols import load_protocol
    from seal.protocols.runner import build_adapters

    config = load_protocol(str(protocol))
    try:
        adapters = build_adapters(config)
    except ImportError as exc:  # an env's simulator is missing
        raise SealError(f"{protocol}: cannot build its envs ({exc})") from None
    specs = [EnvSpec(n, a.obs_dim, a.act_dim, len(a.tasks)) for n, a in adapters.items()]
    agent_cfg = dataclasses.replace(config.agent, device="cpu")
    return specs, agent_cfg, int(config.training.batch_per_task)


def _agent_batches(specs: Sequence[EnvSpec], per_task: int, seed: int) -> dict[str, Batch]:
    return {
        s.name: _random_batch(s.num_tasks, per_task, seed + i, s.obs_dim, s.act_dim)
        for i, s in enumerate(specs)
    }


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


def bench_small_update_flops(
    updates: int = 30, repeats: int = 3, seed: int = 0, compile: bool = True
) -> dict[str, Any]:
    """FLOP/s of the quickstart-shape SEAL update / torch.mm FLOP/s at its ideal GEMM shapes, one thread.

    The agent is the quickstart protocol's (`quickstart_setup`): two envs, batch_per_task samples
    per task, its widths. Ideal FLOPs as `mt10_update_flops_fraction` counts them, per env
    (`agent_update_shapes`). Measured for the eager update and, with `compile`, for the same agent
    with agent.compile on (its repeats interleaved with eager's, same batches and seed); the
    headline `small_update_flops_fraction` is the compiled one when it compiled, else eager's.
    `loss_max_rel_diff` compares the two agents' losses at updates 1 and 5.
    """
    from seal.learner import Agent

    specs, config, per_task = quickstart_setup()
    shapes = agent_update_shapes(specs, config, per_task)
    gemms = agent_update_gemms(shapes)
    flops = gemm_flops(gemms)
    with torch_threads(1):
        agents = {"eager": Agent(specs, config, seed)}
        if compile:
            agents["compiled"] = Agent(specs, dataclasses.replace(config, compile=True), seed)
        batches = _agent_batches(specs, per_task, seed)
        losses: dict[str, list[dict[str, float]]] = {k: [] for k in agents}
        for _ in range(5):  # the first also measures the ratio lever (every 1000 updates)
            for name, agent in agents.items():
                metrics = agent.update(batches)
                losses[name].append({k: v for k, v in metrics.items() if k.startswith("losses")})
        best = dict.fromkeys(agents, math.inf)
        for _ in range(repeats):
            for name, agent in agents.items():

                def run(agent: Agent = agent) -> None:
                    for _ in range(updates):
                        agent.update(batches)

                best[name] = min(best[name], _timeit(run, 1) / updates)
        t_mm = _time_gemms(gemms, repeats)
    paths: dict[str, Any] = {}
    for name in agents:
        paths[name] = {
            "update_s": best[name],
            "update_gflops": flops / best[name] / 1e9,
            "small_update_flops_fraction": t_mm / best[name],
        }
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
    return {
        "envs": {s.name: dataclasses.asdict(s) for s in specs},
        "batch_per_task": per_task,
        "ideal_flops_per_update": flops,
        "matmul_gflops_same_shapes": flops / t_mm / 1e9,
        "paths": paths,
        "headline_path": headline,
        "update_s": best[headline],
        "update_gflops": paths[headline]["update_gflops"],
        "small_update_flops_fraction": paths[headline]["small_update_flops_fraction"],
        "updates_timed": updates,
        "threads": 1,
    }


# ---------------------------------------------------------------- collection


class _PlainLoop:
    """The reference: one process, one env after another, envs built by the same adapter (same wrappers)."""

    def __init__(self, adapter: EnvAdapter, env_name: str, seed: int) -> None:
        from seal.learner.collection import instance_seed

        self.seeds = [instance_seed(seed, env_name, task) for task in adapter.tasks]
        self.envs = [
            adapter.make(task, s) for task, s in zip(adapter.tasks, self.seeds, strict=True)
        ]
        self.first = True

    def run(self, actions: np.ndarray) -> list[np.ndarray]:
        """Episodes of `actions` (episodes, steps, tasks, act_dim); the last observation of each task."""
        last: list[np.ndarray] = [np.empty(0)] * len(self.envs)
        for ep in range(actions.shape[0]):
            for i, env in enumerate(self.envs):
                last[i], _ = env.reset(seed=self.seeds[i] if self.first else None)
            self.first = False
            for t in range(actions.shape[1]):
                for i, env in enumerate(self.envs):
                    last[i], _, terminated, truncated, _ = env.step(actions[ep, t, i])
        return last

    def close(self) -> None:
        for env in self.envs:
            env.close()


class _CollectorLoop:
    """Our Collector replaying a fixed action sequence through its batched policy call."""

    def __init__(
        self, adapter: EnvAdapter, env_name: str, seed: int, backend: str, num_workers: int | None
    ) -> None:
        from seal.learner.collection import Collector

        start = time.perf_counter()
        self.collector = Collector(
            {env_name: adapter}, seed=seed, backend=backend, num_workers=num_workers
        )
        self.startup_s = time.perf_counter() - start
        self.num_tasks = len(adapter.tasks)

    def run(self, actions: np.ndarray) -> list[np.ndarray]:
        """Like `_PlainLoop.run`."""
        last: list[np.ndarray] = [np.empty(0)] * self.num_tasks
        step = [0, 0]  # episode, t

        def policy(env: str, obs: np.ndarray, task_ids: np.ndarray) -> np.ndarray:
            a = actions[step[0], step[1], task_ids]
            step[1] += 1
            return a

        def sink(
            env: str,
            task_ids: np.ndarray,
            obs: np.ndarray,
            act: np.ndarray,
            rew: np.ndarray,
            next_obs: np.ndarray,
            term: np.ndarray,
        ) -> None:
            for k, i in enumerate(task_ids):
                last[int(i)] = next_obs[k]

        for ep in range(actions.shape[0]):
            step[:] = [ep, 0]
            self.collector.collect_episodes(policy, sink=sink)
        return last

    def close(self) -> None:
        self.collector.close()


def bench_collection(
    adapter_name: str,
    episodes: int = 2,
    episode_length: int | None = None,
    backends: Sequence[str] = ("sync", "subproc-batched", "inline-batched", "gym-async"),
    num_workers: int | None = None,
    seed: int = 0,
    repeats: int = 1,
) -> dict[str, Any]:
    """Env steps/s of each collection backend and of the plain loop over all tasks of an adapter.

    Each repeat runs `episodes` episodes on the plain loop and then on every backend, all built
    once (start-up is reported, not timed); the best repeat of each counts, so a burst of load
    from other processes hits one side's single run rather than the ratio. Speedup = backend
    steps/s / plain steps/s; `speedup` is that of the backend `auto` picks. Raises
    AssertionError if a backend ends any repeat on other observations than the plain loop.
    """
    from seal.envs import make_adapter
    from seal.learner.collection import auto_backend

    adapter = make_adapter(
        adapter_name, episode_length=episode_length
    )  # all tasks: MT10, the 10 kitchens
    n, length = len(adapter.tasks), adapter.episode_length
    space = adapter.action_space
    actions = (
        np.random.default_rng(seed)
        .uniform(space.low, space.high, (episodes, length, n, *space.shape))
        .astype(space.dtype)
    )
    steps = episodes * length * n
    loops: dict[str, Any] = {"plain": _PlainLoop(adapter, adapter_name, seed)}
    try:
        for backend in backends:
            loops[backend] = _CollectorLoop(adapter, adapter_name, seed, backend, num_workers)
        best = {name: math.inf for name in loops}
        for _ in range(repeats):
            finals = {}
            for name, loop in loops.items():
                start = time.perf_counter()
                finals[name] = loop.run(actions)
                best[name] = min(best[name], time.perf_counter() - start)
            for name in backends:
                for task, a, b in zip(adapter.tasks, finals["plain"], finals[name], strict=True):
                    if not np.array_equal(a, b):
                        raise AssertionError(
                            f"collection backend {name!r} ended task {task!r} on other observations than the plain loop"
                        )
    finally:
        for loop in loops.values():
            loop.close()
    result: dict[str, Any] = {
        "tasks": n,
        "episodes": episodes,
        "episode_length": length,
        "env_steps": steps,
        "repeats": repeats,
        "plain_steps_per_s": steps / best["plain"],
        "backends": {},
    }
    for name in backends:
        result["backends"][name] = {
            "steps_per_s": steps / best[name],
            "speedup": best["plain"] / best[name],
            "startup_s": loops[name].startup_s,
            "same_final_obs": True,
        }
    result["auto_backend"] = auto_backend({adapter_name: adapter}, seed, num_workers)
    chosen = result["backends"].get(result["auto_backend"])
    result["speedup"] = chosen["speedup"] if chosen else None
    return result


# ---------------------------------------------------------------- the ratio lever

SHARED_UPDATES = ("weighted", "sequential", "per_env")


def bench_ratio_lever(
    seed: int = 0,
    warmup_updates: int = 100,
    ratio: float = 0.9,
    batch_per_task: int = 128,
    episodes: int = 3,
    modes: Sequence[str] = SHARED_UPDATES,
    agent: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """`Agent.ratio_lever` of a default-width SEAL agent under each shared_update mode.

    Replay: seeded uniform-random episodes of `point` (A, the `ratio` share) and `point_view`
    (B: other observation and action spaces), `episodes` per task. Each mode's agent (same seed)
    first takes `warmup_updates` updates at the ratio so that Adam's moments are not fresh, then
    the lever is measured on the next update's batches. Goal: >= 0.8 under "weighted".
    `agent` overrides AgentConfig fields (default widths otherwise).
    """
    from seal.envs import make_adapter
    from seal.learner import Agent, AgentConfig, EnvSpec, MultiTaskReplay
    from seal.learner.collection import Collector
    from seal.schedulers.base import counts_from_ratio

    adapters = {"a": make_adapter("point"), "b": make_adapter("point_view")}
    specs = [EnvSpec(name, ad.obs_dim, ad.act_dim, len(ad.tasks)) for name, ad in adapters.items()]
    replay = MultiTaskReplay(specs, capacity=sum(len(a.tasks) for a in adapters.values()) * 1000)
    with Collector(adapters, seed=seed, backend="sync") as collector:
        for _ in range(episodes):
            collector.collect_episodes(None, random_actions=True, sink=replay.add)
    counts = counts_from_ratio(
        {"a": ratio, "b": 1.0 - ratio}, {s.name: s.num_tasks for s in specs}, batch_per_task
    )
    out: dict[str, Any] = {
        "ratio": ratio,
        "warmup_updates": warmup_updates,
        "batch": {k: int(v.sum()) for k, v in counts.items()},
        "modes": {},
    }
    for mode in modes:
        config = AgentConfig(
            architecture="seal",
            shared_update=mode,
            ratio_lever_interval=0,
            device="cpu",
            **(agent or {}),
        )
        learner = Agent(specs, config, seed)
        replay.generator.manual_seed(seed)  # every mode sees the same batches
        for _ in range(warmup_updates):
            learner.update(replay.sample(counts))
        lever = learner.ratio_lever(replay.sample(counts))
        g = lever["grad_norm"]
        out["modes"][mode] = {**lever, "grad_norm_ratio_a_over_b": g["a"] / g["b"]}
    n = out["batch"]
    # Where the optimiser's lever comes from, for "weighted": the same share of the raw gradient
    # sum_X (n_X / N) g_X (no Adam, no clip), and that share were every per-sample gradient
    # independent noise, when ||(n_X / N) g_X|| grows as sqrt(n_X) (the ceiling of any weighting by
    # sample counts while gradients are noise-dominated): sqrt(n_A) / (sqrt(n_A) + sqrt(n_B)).
    weighted = out["modes"].get("weighted")
    if weighted is not None:
        part = {x: n[x] * weighted["grad_norm"][x] for x in ("a", "b")}
        out["gradient_lever"] = part["a"] / (part["a"] + part["b"])
    out["noise_ceiling"] = math.sqrt(n["a"]) / (math.sqrt(n["a"]) + math.sqrt(n["b"]))
    out["ratio_lever"] = out["modes"].get("weighted", {}).get("lever")
    return out


# ---------------------------------------------------------------- learning evidence


LEARN = Path(__file__).resolve().parents[1] / "protocols" / "learn"
"""The learning-evidence protocols (point with and without the one-hot, reach-v3)."""


class LearnResult(TypedDict):
    """`learn_protocol`'s record of one run."""

    env_steps: int
    gradient_updates: int
    epochs: int
    wall_s: float
    success: dict[str, float]
    reached: dict[str, bool]


def learn_protocol(
    name: str, seed: int = 0, overrides: Sequence[str] = (), out: Path | None = None
) -> LearnResult:
    """Run `protocols/learn/<name>.toml` (one seed, this process, the runner's phase loop).

    Into `out` (default: a temporary directory, removed after). Returns the env steps and
    gradient steps the run took (it may stop early: `evaluation.stop_when_reached`), its epochs,
    wall time, the last evaluation's success per task and which tasks ever reached the threshold.
    """
    import tempfile

    from seal.protocols import load_protocol, run_seed

    config = load_protocol(LEARN / f"{name}.toml", list(overrides))
    (env,) = config.envs
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        result = run_seed(config, seed, (out or Path(tmp)) / name)
        metrics = pd.read_csv(result.run_dir / "metrics.csv")
    (timing,) = result.timing.values()
    last = metrics[metrics["epoch"] == metrics["epoch"].max()]
    return {
        "env_steps": int(last["env_steps"].sum()),
        "gradient_updates": int(timing["grad_steps"]),
        "epochs": int(timing["epochs"]),
        "wall_s": time.perf_counter() - start,
        "success": result.final_success[env],
        "reached": {t: v > 0 for t, v in result.update_counts[env].items()},
    }


def random_success(adapter: EnvAdapter, episodes: int = 20, seed: int = 0) -> dict[str, float]:
    """Success rate per task of uniform random actions."""
    from seal.learner.collection import Collector

    with Collector({adapter.name: adapter}, seed=seed, backend="sync") as col:
        runs = [col.collect_episodes(None, random_actions=True) for _ in range(episodes)]
    return {
        task: float(np.mean([r.successes[adapter.name][i] for r in runs]))
        for i, task in enumerate(adapter.tasks)
    }


def point_evidence(seed: int = 0) -> dict[str, Any]:
    """Random baseline, `protocols/learn/point.toml`, and its no-one-hot control for as many epochs."""
    from seal.envs.point import PointAdapter

    random = random_success(PointAdapter(), seed=seed)
    with_one_hot = learn_protocol("point", seed)
    epochs = f"protocol.epochs={with_one_hot['epochs']}"
    without = learn_protocol("point_no_one_hot", seed, [epochs])
    return {
        "random": random,
        "one_hot": with_one_hot,
        "no_one_hot": without,
        "checks": {
            "one_hot_all_tasks_100pct": all(with_one_hot["reached"].values()),
            "random_le_20pct": all(v <= 0.2 for v in random.values()),
            "no_one_hot_fails_a_task": any(v < 1.0 for v in without["success"].values()),
        },
    }


# ---------------------------------------------------------------- the command


@dataclass(frozen=True)
class BenchSettings:
    """Repeat counts of `seal bench`; `quick()` is for smoke runs (numbers are noisier)."""

    sac_updates: int = 200
    """Updates per timed run of each side of sac_vs_sb3."""
    flops_updates: int = 30
    """Updates per timed run of the MT10 update."""
    repeats: int = 3
    """Timed runs of everything; the best counts."""
    collect_episodes: int = 1
    """Episodes of all 10 tasks per timed collection run (MT10: 5,000 env steps; kitchens: 2,800)."""
    mt10_episode_length: int | None = None  # None: the adapter's 500
    fk_episode_length: int | None = None  # None: the adapter's 280

    @classmethod
    def quick(cls) -> BenchSettings:
        """Few repeats and short episodes."""
        return cls(
            sac_updates=40,
            flops_updates=10,
            repeats=1,
            collect_episodes=1,
            mt10_episode_length=100,
            fk_episode_length=60,
        )


def run_bench(
    settings: BenchSettings,
    only: Sequence[str] | None = None,
    learn: bool = False,
    log: Callable[[str], None] = lambda _: None,
) -> dict[str, Any]:
    """Run the benchmarks (all, or the keys in `only`) and return one JSON-able dict."""
    keys = (
        "sac_vs_sb3",
        "mt10_update_flops_fraction",
        "small_update_flops_fraction",
        "collect_mt10_speedup",
        "collect_fk_speedup",
        "ratio_lever",
    )
    chosen = list(only or keys)
    unknown = [k for k in chosen if k not in keys]
    if unknown:
        from seal.errors import UnknownNameError

        raise UnknownNameError("benchmark", unknown[0], keys)
    out: dict[str, Any] = {
        "load_before": machine_load(),
        "settings": settings.__dict__,
        "details": {},
    }
    if "sac_vs_sb3" in chosen:
        log("sac_vs_sb3: timing")
        d: Mapping[str, Any] = bench_sac_vs_sb3(settings.sac_updates, settings.repeats)
        out["details"]["sac_vs_sb3"] = d
        out["sac_vs_sb3"] = d["sac_vs_sb3"]
    if "mt10_update_flops_fraction" in chosen:
        log("mt10_update_flops_fraction")
        out["details"]["flop_formula_check"] = flop_formula_check()
        d = bench_mt10_flops(settings.flops_updates, settings.repeats)
        out["details"]["mt10_update_flops"] = d
        out["mt10_update_flops_fraction"] = d["mt10_update_flops_fraction"]
    if "small_update_flops_fraction" in chosen:
        log("small_update_flops_fraction")
        try:
            specs, config, per_task = quickstart_setup()
        except SealError as exc:
            out["details"]["small_update_flops"] = {"skipped": str(exc)}
            out["small_update_flops_fraction"] = None
        else:
            two_tasks = [dataclasses.replace(sp, num_tasks=max(2, sp.num_tasks)) for sp in specs]
            out["details"]["small_flop_formula_check"] = agent_flop_formula_check(
                two_tasks, config, per_task
            )
            d = bench_small_update_flops(settings.flops_updates, settings.repeats)
            out["details"]["small_update_flops"] = d
            out["small_update_flops_fraction"] = d["small_update_flops_fraction"]
    for key, adapter, length in (
        ("collect_mt10_speedup", "metaworld", settings.mt10_episode_length),
        ("collect_fk_speedup", "franka_kitchen_dense", settings.fk_episode_length),
    ):
        if key in chosen:
            log(key)
            try:
                d = bench_collection(
                    adapter, settings.collect_episodes, length, repeats=settings.repeats
                )
            except SealError as exc:
                out["details"][key] = {"skipped": str(exc)}
                out[key] = None
                continue
            out["details"][key] = d
            out[key] = d["speedup"]
    if "ratio_lever" in chosen:
        log("ratio_lever")
        d = bench_ratio_lever()
        out["details"]["ratio_lever"] = d
        out["ratio_lever"] = d["ratio_lever"]
    if learn:
        out["learn"] = run_learn(log)
    out["load_after"] = machine_load()
    return out


def run_learn(log: Callable[[str], None] = lambda _: None) -> dict[str, Any]:
    """The learning evidence: point with and without one-hot and a random baseline, then reach-v3."""
    log("learn: point (random, MTMHSAC, MTMHSAC without one-hot): protocols/learn/point*.toml")
    point = point_evidence()
    log("learn: reach-v3 SAC: protocols/learn/reach.toml")
    reach = learn_protocol("reach")
    return {
        "point_random": point["random"],
        "point_mtmhsac": point["one_hot"],
        "point_no_one_hot": point["no_one_hot"],
        "reach_v3_sac": reach,
        "checks": {**point["checks"], "reach_v3_ge_90pct": reach["reached"]["reach-v3"]},
    }


GOALS = {
    "sac_vs_sb3": 1.3,
    "mt10_update_flops_fraction": 0.75,
    "small_update_flops_fraction": 0.6,
    "collect_mt10_speedup": 1.7,
    "collect_fk_speedup": 1.7,
    "ratio_lever": 0.8,
}


def _small_detail(small: Mapping[str, Any], check: Mapping[str, Any]) -> str:
    parts = []
    for name, p in small["paths"].items():
        text = f"{name} {p['small_update_flops_fraction']:.2f} ({p['update_s'] * 1e3:.1f} ms, {p['update_gflops']:.1f} GFLOP/s"
        if name == "compiled":
            diff = max(p["loss_max_rel_diff"].values())
            text += f"; compiled {p['compile_seconds']:.0f} s; losses vs eager {diff:.0e} rel"
            if not p["compiled"]:
                text += "; FELL BACK TO EAGER"
        parts.append(text + ")")
    return (
        f"{small['headline_path']} shown; {', '.join(parts)}; mm {small['matmul_gflops_same_shapes']:.1f} GFLOP/s, "
        f"{small['ideal_flops_per_update'] / 1e6:.0f} MFLOP, 1 thread; formula==FlopCounter: {check['equal']}"
    )


def format_table(result: Mapping[str, Any]) -> str:
    """The human-readable summary of `run_bench` output."""
    lines = [f"{'key':<28} {'value':>8} {'goal':>7}  detail", "-" * 90]
    d = result["details"]
    detail = {
        "sac_vs_sb3": lambda: (
            f"ours {d['sac_vs_sb3']['ours_updates_per_s']:.1f}/s ({d['sac_vs_sb3'].get('ours_gflops', 0):.1f} GFLOP/s), "
            f"sb3 {d['sac_vs_sb3']['sb3_updates_per_s']:.1f}/s ({d['sac_vs_sb3'].get('sb3_gflops', 0):.1f} GFLOP/s); "
            f"sb3/ours FLOPs {d['sac_vs_sb3'].get('flops_ratio_sb3_over_ours', float('nan')):.2f}"
        ),
        "mt10_update_flops_fraction": lambda: (
            f"update {d['mt10_update_flops']['update_gflops']:.1f} GFLOP/s, mm {d['mt10_update_flops']['matmul_gflops_same_shapes']:.1f} GFLOP/s "
            f"({d['mt10_update_flops']['update_s'] * 1e3:.1f} ms/update); formula==FlopCounter: {d['flop_formula_check']['equal']}"
        ),
    }
    small = d.get("small_update_flops", {})
    if "skipped" in small:
        detail["small_update_flops_fraction"] = lambda: f"skipped: {small['skipped']}"
    elif small:
        detail["small_update_flops_fraction"] = lambda: _small_detail(
            small, d["small_flop_formula_check"]
        )
    if "ratio_lever" in d:
        detail["ratio_lever"] = lambda: (
            "; ".join(
                f"{mode} {m['lever']:.2f} (|g_A|/|g_B| {m['grad_norm_ratio_a_over_b']:.2f})"
                for mode, m in d["ratio_lever"]["modes"].items()
            )
            + f"; {d['ratio_lever']['ratio']:.0%} of the batch from A, after {d['ratio_lever']['warmup_updates']} updates"
            + (
                f"; weighted raw-gradient share {d['ratio_lever']['gradient_lever']:.2f}"
                if "gradient_lever" in d["ratio_lever"]
                else ""
            )
            + f", pure-noise ceiling {d['ratio_lever']['noise_ceiling']:.2f}"
        )
    for key in ("collect_mt10_speedup", "collect_fk_speedup"):
        if key in d and "backends" in d[key]:
            c = d[key]
            parts = ", ".join(
                f"{b} {v['steps_per_s']:.0f} (x{v['speedup']:.2f})"
                for b, v in c["backends"].items()
            )
            detail[key] = lambda c=c, parts=parts: (
                f"plain {c['plain_steps_per_s']:.0f} steps/s; {parts}; auto={c['auto_backend']}; same final obs"
            )
        elif key in d:
            detail[key] = lambda k=key: f"skipped: {d[k]['skipped']}"
    for key, goal in GOALS.items():
        if key not in result:
            continue
        value = result[key]
        shown = "n/a" if value is None else f"{value:.2f}"
        lines.append(f"{key:<28} {shown:>8} {'>=' + str(goal):>7}  {detail[key]()}")
    load = result["load_before"]
    lines.append(
        f"load before: {load['loadavg_1m']} (1 min) on {load['cpus']} CPUs, torch threads {load['torch_threads']}; after: {result['load_after']['loadavg_1m']}"
    )
    if "learn" in result:
        learn = result["learn"]
        for key in ("point_mtmhsac", "point_no_one_hot", "reach_v3_sac"):
            r = learn[key]
            lines.append(
                f"{key}: success {r['success']}; {r['env_steps']} env steps, {r['gradient_updates']} updates, {r['wall_s']:.0f} s"
            )
        lines.append(f"point_random: {learn['point_random']}")
        lines.append(f"checks: {learn['checks']}")
    return "\n".join(lines)
