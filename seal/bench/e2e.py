"""``e2e_vs_sb3``: wall time of the same learning work, stable-baselines3's `SAC.learn` / `seal run`'s loop.

One env per figure, each side stepping envs built by the same `adapter.make(task, seed)`:
Meta-World reach-v3 (`protocols/learn/reach.toml`) and the kitchen's slide-cabinet on reward v3
(`protocols/kitchen_learn/slide_cabinet.toml`). SEAL's side is `seal run`'s own runner on the
shipped protocol, shortened with --set overrides (`seal_overrides`): the loop a user runs.
SB3's side is a `SAC` with the protocol's widths, batch, learning rates, gamma and tau.

The same work: one gradient step per env step, batch `training.batch_per_task`, learning from
the same env step (`training.warmup_steps`; SB3's `learning_starts`), no evaluation inside the
window, the same torch threads (`protocol.threads` = this process's). Each side's window starts
at its first update and covers `steps` env steps (rounded up to whole episodes): SEAL's from the
end of its last warm-up epoch (its first update is in the next one, after that epoch's episode)
to the end of the window's last epoch, which is never the run's last (the run's final evaluation
and checkpoint fall outside it); SB3's is a second `learn` call after one of `learning_starts`
steps, which makes no update. The work done is read back from each side's counters (SEAL: the
phase's env steps, gradient steps and consumed transitions; SB3: `num_timesteps`, `_n_updates`
and the rows its replay buffer sampled), not from settings, and returned beside the figures.
"""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np
import torch

from seal.bench.sb3 import _require_sb3
from seal.protocols import load_protocol
from seal.run.loop import LoopCallback
from seal.run.phase_model import build_adapters
from seal.run.runner import run_seed
from seal.run.state import LOOP_PARTS

if TYPE_CHECKING:
    from seal.envs.base import EnvAdapter
    from seal.protocols.config import ProtocolConfig
    from seal.run.loop import PhaseLoop

PROTOCOLS = Path(__file__).resolve().parents[2] / "protocols"
E2E_PROTOCOLS = {
    "reach-v3": PROTOCOLS / "learn" / "reach.toml",
    "slide-cabinet": PROTOCOLS / "kitchen_learn" / "slide_cabinet.toml",
}
"""Figure name -> the one-task protocol whose loop is measured."""


class SideWork(TypedDict):
    """One side's window: the work read back from its counters, its wall and rates."""

    env_steps: int
    updates: int
    samples_per_update: float
    wall_s: float
    env_steps_per_s: float
    updates_per_s: float


class SealSide(SideWork):
    """SEAL's window, with the share of its wall in each part of the loop and other."""

    shares: dict[str, float]


class E2eFigure(TypedDict):
    """`bench_e2e`'s result for one env."""

    e2e_vs_sb3: float
    protocol: str
    task: str
    threads: int
    seal: SealSide
    sb3: SideWork


class _Window(LoopCallback):
    """Counters and part seconds at the ends of the epochs that open and close the window."""

    def __init__(self, first: int, last: int) -> None:
        self.first, self.last = first, last
        self.marks: dict[int, tuple[float, int, int, int, dict[str, float]]] = {}

    def _mark(self, loop: PhaseLoop) -> None:
        state = loop.state
        consumed = sum(int(np.sum(c)) for c in loop.replay.consumed.values())
        self.marks[state.epoch] = (
            time.perf_counter(),
            loop.env_steps(),
            state.grad_steps,
            consumed,
            dict(state.seconds),
        )

    def on_phase_start(self, loop: PhaseLoop) -> None:
        if loop.state.epoch == self.first:  # no warm-up epoch: the window opens at the start
            self._mark(loop)

    def on_epoch_end(self, loop: PhaseLoop) -> None:
        if loop.state.epoch in (self.first, self.last):
            self._mark(loop)


def seal_overrides(epochs: int, warmup: int, threads: int) -> list[str]:
    """--set overrides that make a protocol the bench's run: `epochs` epochs, warm-up `warmup`,
    one evaluation and one checkpoint (both after the last epoch), `threads` torch threads."""
    return [
        f"protocol.epochs={epochs}",
        "protocol.device='cpu'",
        f"protocol.threads={threads}",
        f"training.warmup_steps={warmup}",
        "training.collector='sync'",  # one instance: SB3's DummyVecEnv steps it in process too
        f"evaluation.interval={epochs}",
        "evaluation.episodes=1",
        "evaluation.stop_when_reached=false",
        "evaluation.mode='sync'",  # no worker process beside the timed loop
        f"checkpoint.interval={epochs}",
    ]


def _rates(env_steps: int, updates: int, samples: int, wall_s: float) -> SideWork:
    return {
        "env_steps": env_steps,
        "updates": updates,
        "samples_per_update": samples / updates if updates else 0.0,
        "wall_s": wall_s,
        "env_steps_per_s": env_steps / wall_s,
        "updates_per_s": updates / wall_s,
    }


def bench_e2e(
    name: str,
    steps: int = 20_000,
    warmup: int | None = None,
    overrides: list[str] | None = None,
    seed: int = 0,
) -> E2eFigure:
    """SB3 / SEAL wall time per env step over `steps` env steps with updates on `name`
    (`E2E_PROTOCOLS`); `warmup`: env steps before the first update (default: the protocol's);
    `overrides`: further --set overrides of the protocol (a test's shorter episodes)."""
    _require_sb3()  # before SEAL's run
    path = E2E_PROTOCOLS[name]
    threads = torch.get_num_threads()
    base = load_protocol(path, list(overrides or []))
    ((env, env_cfg),) = base.envs.items()
    (task,) = env_cfg.tasks
    adapter = build_adapters(base)[env]
    length = adapter.episode_length
    warmup = base.training.warmup_steps if warmup is None else warmup
    first = math.ceil(warmup / length) - 1  # the last warm-up epoch (its end opens the window)
    last = first + math.ceil(steps / length)
    config = load_protocol(path, [*(overrides or []), *seal_overrides(last + 1, warmup, threads)])
    window = _Window(first, last)
    with tempfile.TemporaryDirectory(prefix="seal-bench-e2e-") as tmp:
        run_seed(config, seed, Path(tmp) / name, callbacks=[window])
    (t0, env0, upd0, con0, sec0), (t1, env1, upd1, con1, sec1) = (
        window.marks[first],
        window.marks[last],
    )
    wall = t1 - t0
    parts = {p: sec1.get(p, 0.0) - sec0.get(p, 0.0) for p in LOOP_PARTS}
    seal: SealSide = {
        **_rates(env1 - env0, upd1 - upd0, con1 - con0, wall),  # type: ignore[typeddict-item]
        "shares": {
            **{p: s / wall for p, s in parts.items()},
            "other": (wall - sum(parts.values())) / wall,
        },
    }
    sb3 = _sb3_window(config, adapter, task, seed, warmup, seal["env_steps"], threads)
    ratio = (sb3["wall_s"] / sb3["env_steps"]) / (seal["wall_s"] / seal["env_steps"])
    return {
        "e2e_vs_sb3": ratio,
        "protocol": str(path),
        "task": task,
        "threads": threads,
        "seal": seal,
        "sb3": sb3,
    }


def sb3_sac(config: ProtocolConfig, env: Any, seed: int, buffer_size: int) -> Any:
    """stable-baselines3's `SAC` on `env` with a one-task protocol's widths, batch, learning rate,
    gamma, tau and warm-up (`learning_starts`), one gradient step per env step, on the CPU."""
    from stable_baselines3 import SAC

    agent, training = config.agent, config.training
    return SAC(
        "MlpPolicy",
        env,
        learning_rate=agent.actor_lr,
        buffer_size=buffer_size,
        learning_starts=training.warmup_steps,
        batch_size=training.batch_per_task,
        tau=agent.tau,
        gamma=agent.gamma,
        train_freq=1,
        gradient_steps=1,
        policy_kwargs={"net_arch": list(agent.hidden)},
        device="cpu",
        seed=seed,
    )


def _sb3_window(
    config: ProtocolConfig,
    adapter: EnvAdapter,
    task: str,
    seed: int,
    warmup: int,
    steps: int,
    threads: int,
) -> SideWork:
    """SB3's `SAC.learn` over `steps` env steps from its first update, after `warmup` without."""
    torch.set_num_threads(threads)
    model = sb3_sac(config, adapter.make(task, seed), seed, warmup + steps + 1)
    buffer, sampled = model.replay_buffer, [0]
    sample = buffer.sample

    def counted(batch_size: int, env: Any = None) -> Any:
        sampled[0] += batch_size
        return sample(batch_size, env=env)

    buffer.sample = counted  # type: ignore[method-assign]
    model.learn(total_timesteps=warmup)  # learning_starts steps: no update yet
    env0, upd0, rows0 = model.num_timesteps, model._n_updates, sampled[0]
    start = time.perf_counter()
    model.learn(total_timesteps=steps, reset_num_timesteps=False)
    wall = time.perf_counter() - start
    return _rates(model.num_timesteps - env0, model._n_updates - upd0, sampled[0] - rows0, wall)
