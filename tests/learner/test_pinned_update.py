"""Bitwise pins of the update: losses, the ratio lever and checkpoint tensors from the code before
the learner was split into losses, update and machinery (`pinned_update.pt`).

Runs: MTMHSAC acting on `point` and learning from what it collected, then transferred into an
agent with more tasks (pad-and-fine-tune's copies); a small two-env SEAL agent under every
`shared_update` mode (per-env critics) and weighted with a shared critic, with the ratio lever
measured inside the run. Every value must be equal bit for bit: a refactor that reorders a sum or
draws noise in another order fails here. Regenerate only when behaviour is meant to change:
`python tests/learner/test_pinned_update.py`.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pytest
import torch

from seal.envs import make_adapter
from seal.learner import Agent, AgentConfig, Batch, EnvSpec, MultiTaskReplay
from seal.learner.transfer import transfer_from

PINS = Path(__file__).with_name("pinned_update.pt")
SMALL = {
    "hidden": (16, 16),
    "translator_hidden": (16,),
    "latent_dim": 16,
    "trunk_hidden": (16, 16),
    "critic_hidden": (16, 16),
    "device": "cpu",
}
SEAL_RUNS = {
    "seal-weighted": {"shared_update": "weighted"},
    "seal-sequential": {"shared_update": "sequential"},
    "seal-per_env": {"shared_update": "per_env"},
    "seal-weighted-shared-critic": {"shared_update": "weighted", "critic_sharing": "shared"},
}


def _flatten(state: object, prefix: str = "") -> dict[str, object]:
    """Every leaf of a nested state dict under a dotted path; tensors cloned, numpy as tensors."""
    out: dict[str, object] = {}
    if isinstance(state, Mapping):
        for key, value in state.items():
            out.update(_flatten(value, f"{prefix}{key}."))
    elif isinstance(state, list | tuple):
        for i, value in enumerate(state):
            out.update(_flatten(value, f"{prefix}{i}."))
    elif isinstance(state, torch.Tensor):
        out[prefix[:-1]] = state.detach().clone()
    elif isinstance(state, np.ndarray):
        out[prefix[:-1]] = torch.from_numpy(state.copy())
    else:
        out[prefix[:-1]] = state
    return out


def _point_run() -> dict[str, object]:
    """MTMHSAC acts on `point` for 3 episodes of 20 steps per task, then 12 updates of 8 per task."""
    adapter = make_adapter("point", episode_length=20)
    spec = EnvSpec("point", adapter.obs_dim, adapter.act_dim, len(adapter.tasks))
    agent = Agent([spec], AgentConfig(**SMALL), seed=3)
    replay = MultiTaskReplay([spec], capacity=200, seed=3)
    envs = [adapter.make(task, seed=i) for i, task in enumerate(adapter.tasks)]
    ids = np.arange(len(envs))
    for episode in range(3):
        obs = np.stack([env.reset(seed=10 * episode + i)[0] for i, env in enumerate(envs)])
        for _ in range(20):
            actions = agent.act("point", obs.astype(np.float32), ids)
            steps = [env.step(a) for env, a in zip(envs, actions, strict=True)]
            next_obs = np.stack([s[0] for s in steps])
            rewards = np.array([s[1] for s in steps])
            terminated = np.array([s[2] for s in steps])
            replay.add("point", ids, obs, actions, rewards, next_obs, terminated)
            obs = next_obs
    counts = {"point": np.full(len(envs), 8)}
    losses = [sorted(agent.update(replay.sample(counts)).items()) for _ in range(12)]
    # pad-and-fine-tune's copies: two more tasks (one-hot columns and heads), a wider action input
    wider = EnvSpec("point", adapter.obs_dim, adapter.act_dim, spec.num_tasks + 2, act_pad_to=4)
    transferred = Agent([wider], AgentConfig(**SMALL), seed=4)
    transfer_from(transferred, agent.state_dict(), reinit_critic=False)
    return {
        "losses": losses,
        "state": _flatten(agent.state_dict()),
        "transferred": _flatten(transferred.state_dict()),
    }


def _seal_batches(specs: list[EnvSpec], seed: int) -> dict[str, Batch]:
    g = torch.Generator().manual_seed(seed)
    out = {}
    for spec, per_task in zip(specs, (6, 2), strict=True):  # a 75/25-ish data ratio
        n = per_task * spec.num_tasks
        out[spec.name] = Batch(
            torch.randn(n, spec.obs_dim, generator=g),
            torch.rand(n, spec.act_dim, generator=g) * 2 - 1,
            torch.randn(n, generator=g),
            torch.randn(n, spec.obs_dim, generator=g),
            (torch.rand(n, generator=g) < 0.1).float(),
            torch.arange(spec.num_tasks).repeat_interleave(per_task),
        )
    return out


def _seal_run(options: Mapping[str, str]) -> dict[str, object]:
    """A two-env SEAL agent, 8 updates with the ratio lever measured every 3 (updates 0, 3, 6)."""
    specs = [EnvSpec("mw", 6, 2, 3), EnvSpec("fk", 8, 3, 2)]
    config = AgentConfig(architecture="seal", ratio_lever_interval=3, **SMALL, **options)
    agent = Agent(specs, config, seed=5)
    losses = [sorted(agent.update(_seal_batches(specs, i)).items()) for i in range(8)]
    lever = agent.ratio_lever(_seal_batches(specs, 100))
    expected = agent.ratio_lever_expected([_seal_batches(specs, 200 + i) for i in range(2)])
    return {
        "losses": losses,
        "lever": dict(lever),
        "lever_expected": dict(expected),
        "state": _flatten(agent.state_dict()),
    }


def _runs() -> dict[str, dict[str, object]]:
    torch.set_num_threads(1)
    return {"point": _point_run(), **{name: _seal_run(o) for name, o in SEAL_RUNS.items()}}


def _assert_same(got: object, want: object, where: str) -> None:
    if isinstance(want, torch.Tensor):
        assert isinstance(got, torch.Tensor), where
        assert got.dtype == want.dtype and got.shape == want.shape, where
        same = torch.equal(got, want)
        if not same and want.is_floating_point():
            same = bool(torch.isclose(got, want, rtol=0.0, atol=0.0, equal_nan=True).all())
        assert same, where
    elif isinstance(want, Mapping):
        assert isinstance(got, Mapping) and sorted(got) == sorted(want), where
        for key in want:
            _assert_same(got[key], want[key], f"{where}.{key}")
    elif isinstance(want, list | tuple):
        assert isinstance(got, list | tuple) and len(got) == len(want), where
        for i, (g, w) in enumerate(zip(got, want, strict=True)):
            _assert_same(g, w, f"{where}[{i}]")
    elif isinstance(want, float) and want != want:
        assert isinstance(got, float) and got != got, where
    else:
        assert got == want, f"{where}: {got!r} != {want!r}"


@pytest.fixture(scope="module")
def runs() -> dict[str, dict[str, object]]:
    return _runs()


# Agent keys added after the pins were taken, at their defaults (which keep the update as it was):
# the saved config carries them; nothing else may differ.
ADDED_KEYS = {"head_hidden": (), "head_per_task": False, "clip_per": "optimizer", "preset": ""}


@pytest.mark.parametrize("run", ["point", *SEAL_RUNS])
def test_update_is_bitwise_what_it_was(runs: dict[str, dict[str, object]], run: str) -> None:
    pins = torch.load(PINS, weights_only=True)
    _assert_same(_without_added_keys(runs[run]), pins[run], run)


def _without_added_keys(run: Mapping[str, object]) -> dict[str, object]:
    """The run's results with every saved state's ADDED_KEYS taken out, each checked at its default."""
    out = dict(run)
    for name, state in run.items():
        if isinstance(state, Mapping) and "config.compile" in state:
            state = dict(state)
            for key, default in ADDED_KEYS.items():
                value = state.pop(f"config.{key}", default)
                assert value == default or (value == [] and default == ()), (name, key)
            out[name] = state
    return out


if __name__ == "__main__":
    torch.save(_runs(), PINS)
    print(f"wrote {PINS}")
