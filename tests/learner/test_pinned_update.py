"""Pins of the update: losses, the ratio lever and checkpoint tensors (`pinned_update.pt`).

Runs: MTMHSAC acting on `point` and learning from what it collected, then transferred into an
agent with more tasks (pad-and-fine-tune's copies); a small two-env SEAL agent under every
`shared_update` mode (per-env critics) and weighted with a shared critic, with the ratio lever
measured inside the run.

A stored float holds bit for bit only on the machine that wrote it: another CPU's kernels round
differently (one float32 ulp on an AVX2 machine against the AVX-512 one that wrote them). So the
pins carry the CPU model, the torch version and torch's CPU capability, and are compared bit for
bit only where all three match, else to `ATOL`. The guard against a refactor that reorders a sum
on any CPU is `test_reference_update.py` (two code paths in one process); these pins catch a
change of behaviour (noise drawn in another order moves values by far more than `ATOL`).
Regenerate only when behaviour is meant to change: `python -m tests.learner.test_pinned_update`.
"""

from __future__ import annotations

import dataclasses
import platform
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pytest
import torch

from seal.learner import Agent, AgentConfig, EnvSpec
from seal.learner.transfer import transfer_from
from tests.learner.test_reference_update import point_data, point_spec, seal_batches

PINS = Path(__file__).with_name("pinned_update.pt")
# Measured: the largest absolute deviation from the pins with the kernels capped at SSE4.2
# (ATEN_CPU_CAPABILITY=default MKL_ENABLE_INSTRUCTIONS=SSE4_2 DNNL_MAX_CPU_ISA=SSE41) on the
# AVX-512 machine that wrote them was 2.3e-6 (at AVX2: 1.5e-6); ATOL leaves a margin of ~9x.
ATOL = 2e-5
SMALL = {
    "critic_layer_norm": False,  # the learner the values were pinned with, whatever the default
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
    spec = point_spec()
    agent = Agent([spec], AgentConfig(**SMALL), seed=3)
    losses = [sorted(agent.update(batch).items()) for batch in point_data(agent, 12)]
    # pad-and-fine-tune's copies: two more tasks (one-hot columns and heads), a wider action input
    wider = EnvSpec("point", spec.obs_dim, spec.act_dim, spec.num_tasks + 2, act_pad_to=4)
    transferred = Agent([wider], AgentConfig(**SMALL), seed=4)
    transfer_from(transferred, agent.state_dict(), reinit_critic=False)
    return {
        "losses": losses,
        "state": _flatten(agent.state_dict()),
        "transferred": _flatten(transferred.state_dict()),
    }


def _seal_run(options: Mapping[str, str]) -> dict[str, object]:
    """A two-env SEAL agent, 8 updates with the ratio lever measured every 3 (updates 0, 3, 6)."""
    specs = [EnvSpec("mw", 6, 2, 3), EnvSpec("fk", 8, 3, 2)]
    config = AgentConfig(architecture="seal", ratio_lever_interval=3, **SMALL, **options)
    agent = Agent(specs, config, seed=5)
    losses = [sorted(agent.update(seal_batches(specs, i)).items()) for i in range(8)]
    lever = agent.ratio_lever(seal_batches(specs, 100))
    expected = agent.ratio_lever_expected([seal_batches(specs, 200 + i) for i in range(2)])
    return {
        "losses": losses,
        "lever": dict(lever),
        "lever_expected": dict(expected),
        "state": _flatten(agent.state_dict()),
    }


def _runs() -> dict[str, dict[str, object]]:
    torch.set_num_threads(1)
    return {"point": _point_run(), **{name: _seal_run(o) for name, o in SEAL_RUNS.items()}}


def machine() -> dict[str, str]:
    """What a bitwise float depends on besides the code: the CPU, torch and its kernels."""
    model = platform.processor()
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        names = [ln for ln in cpuinfo.read_text().splitlines() if ln.startswith("model name")]
        model = names[0].split(":", 1)[1].strip() if names else model
    return {
        "cpu": model,
        "torch": str(torch.__version__),
        "capability": torch.backends.cpu.get_cpu_capability(),
    }


NEW_AT_DEFAULT = {
    key: value
    for f in dataclasses.fields(AgentConfig)
    if f.default is not dataclasses.MISSING
    for key, value in (
        # A tuple field is stored flattened, one entry per element.
        [(f"config.{f.name}.{i}", v) for i, v in enumerate(f.default)]
        if isinstance(f.default, tuple)
        else [(f"config.{f.name}", f.default)]
    )
}
"""A checkpoint's config entries at the dataclass's defaults."""
NEW_AT_DEFAULT["config.critic_layer_norm"] = False  # added off after the pins, whatever its default


RENAMED = {"config.one_hot": ("config.task_encoder", {True: "one_hot", False: "none"})}
"""Config entries renamed after the pins were written: old key -> (new key, old value -> new)."""


def _assert_same(got: object, want: object, where: str, atol: float = 0.0) -> None:
    if isinstance(want, torch.Tensor):
        assert isinstance(got, torch.Tensor), where
        assert got.dtype == want.dtype and got.shape == want.shape, where
        same = torch.equal(got, want)
        if not same and want.is_floating_point():
            same = bool(torch.isclose(got, want, rtol=0.0, atol=atol, equal_nan=True).all())
        assert same, where
    elif isinstance(want, Mapping):
        assert isinstance(got, Mapping), where
        want = dict(want)
        for old, (new, values) in RENAMED.items():
            if old in want and new in got:
                assert got[new] == values[want.pop(old)], f"{where}.{new}"
                want[new] = got[new]
        # A config field added after the pins were written, at its default, changes no behaviour.
        added = {
            k for k in set(got) - set(want) if k in NEW_AT_DEFAULT and got[k] == NEW_AT_DEFAULT[k]
        }
        assert sorted(set(got) - added) == sorted(want), where
        for key in want:
            _assert_same(got[key], want[key], f"{where}.{key}", atol)
    elif isinstance(want, list | tuple):
        assert isinstance(got, list | tuple) and len(got) == len(want), where
        for i, (g, w) in enumerate(zip(got, want, strict=True)):
            _assert_same(g, w, f"{where}[{i}]", atol)
    elif isinstance(want, float) and want != want:
        assert isinstance(got, float) and got != got, where
    elif isinstance(want, float):
        assert isinstance(got, float) and abs(got - want) <= atol, f"{where}: {got!r} != {want!r}"
    else:
        assert got == want, f"{where}: {got!r} != {want!r}"


@pytest.fixture(scope="module")
def runs() -> dict[str, dict[str, object]]:
    return _runs()


@pytest.mark.parametrize("run", ["point", *SEAL_RUNS])
def test_update_is_what_it_was(runs: dict[str, dict[str, object]], run: str) -> None:
    """Bit for bit on the machine that wrote the pins, to ATOL on any other."""
    pins = torch.load(PINS, weights_only=True)
    atol = 0.0 if pins["machine"] == machine() else ATOL
    _assert_same(runs[run], pins["runs"][run], run, atol)


def test_the_tolerance_still_catches_a_changed_value(runs: dict[str, dict[str, object]]) -> None:
    """One policy weight moved by 10 * ATOL (a tenth of what one Adam step at lr 3e-4 can move
    it) fails the comparison that other CPUs get."""
    pins = torch.load(PINS, weights_only=True)["runs"]["point"]
    got = runs["point"]
    key = next(k for k in got["state"] if k.startswith("actor.") and "weight" in k)
    moved = {**got, "state": {**got["state"], key: got["state"][key].clone()}}
    moved["state"][key].view(-1)[0] += 10 * ATOL
    with pytest.raises(AssertionError, match=key):
        _assert_same(moved, pins, "point", ATOL)


if __name__ == "__main__":
    torch.save({"machine": machine(), "runs": _runs()}, PINS)
    print(f"wrote {PINS}")
