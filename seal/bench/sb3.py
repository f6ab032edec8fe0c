"""``sac_vs_sb3``: gradient updates/s of our single-task SAC / stable-baselines3 SAC.

Widths (400, 400) (`e2e_vs_sb3` adds (256, 256)), batch 256, CPU, same torch threads, both including replay sampling, from
identical weights (`_twin_sacs`); each side's matmul FLOPs per update are counted too. That the two
compute the same update is a test (tests/learner/test_sb3_parity.py), which uses `_twin_sacs` and
`_rel` from here.
"""

from __future__ import annotations

from types import ModuleType
from typing import TYPE_CHECKING, TypedDict

import numpy as np
import torch

from seal.bench.timing import _timeit
from seal.errors import SealError

if TYPE_CHECKING:
    import gymnasium as gym
    from stable_baselines3 import SAC

    from seal.learner import Agent


def _rel(a: float, b: float) -> float:
    """|a - b| relative to the larger magnitude (0 when both are 0)."""
    scale = max(abs(a), abs(b))
    return 0.0 if scale == 0 else abs(a - b) / scale


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


def _twin_sacs(
    seed: int, batch_size: int, buffer_size: int, widths: tuple[int, ...] = SB3_WIDTHS
) -> tuple[Agent, SAC]:
    """Our single-task SAC and an SB3 SAC with identical weights, `widths` wide, on CPU."""
    _require_sb3()
    from stable_baselines3 import SAC
    from stable_baselines3.common.logger import Logger

    from seal.learner import Agent, AgentConfig, EnvSpec

    # One task, no one-hot: the plain single-task SAC that SB3 implements (no gradient clipping,
    # torch's Adam eps).
    config = AgentConfig(
        hidden=widths,
        task_encoder="none",
        multi_head_policy=False,
        max_grad_norm=0.0,
        adam_eps=1e-8,
        critic_layer_norm=False,  # SB3's critics are plain MLPs
        device="cpu",
    )
    ours = Agent([EnvSpec("bench", SB3_OBS_DIM, SB3_ACT_DIM, 1)], config, seed)
    sb3 = SAC(
        "MlpPolicy",
        _sb3_env(),
        batch_size=batch_size,
        buffer_size=buffer_size,
        learning_starts=0,
        policy_kwargs={"net_arch": list(widths)},
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
    widths: list[int]


def bench_sac_vs_sb3(
    updates: int = 300, repeats: int = 3, seed: int = 0, widths: tuple[int, ...] = SB3_WIDTHS
) -> SacVsSb3:
    """Gradient updates/s of our SAC and SB3's, each sampling batch 256 from its own filled replay."""
    from seal.learner import MultiTaskReplay
    from seal.learner.config import EnvSpec

    batch_size, filled = 256, 20_000
    ours, sb3 = _twin_sacs(seed, batch_size, buffer_size=filled, widths=widths)
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
        "widths": list(widths),
    }
