"""Our SAC update equals stable-baselines3's: from identical weights, batches and policy noise.

This is what makes `seal bench`'s `sac_vs_sb3` a speed ratio of the same computation. Run with
`-s` to see the largest relative difference.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
import torch

from seal.bench.sb3 import SB3_ACT_DIM, SB3_OBS_DIM, _rel, _twin_sacs

pytest.importorskip("stable_baselines3")


@contextlib.contextmanager
def _fixed_normal_noise(queue: list[torch.Tensor]) -> Iterator[None]:
    """Make torch Normal.rsample (used by SB3's squashed Gaussian) take its noise from `queue`."""
    original = torch.distributions.Normal.rsample

    def rsample(self: torch.distributions.Normal, sample_shape: Any = ()) -> torch.Tensor:
        return self.loc + self.scale * queue.pop(0)

    torch.distributions.Normal.rsample = rsample  # type: ignore[method-assign]
    try:
        yield
    finally:
        torch.distributions.Normal.rsample = original  # type: ignore[method-assign]


def sac_loss_check(seed: int = 0, updates: int = 3, batch_size: int = 256) -> dict[str, Any]:
    """From identical weights and the same batches and noise, compare our and SB3's losses per update.

    Known differences, handled rather than hidden: SB3 draws the policy noise for s before that
    for s', ours the other way round (the same noise is fed to both). Both critic losses are
    0.5 * (mse1 + mse2). Returns per-update losses and the largest relative difference.
    """
    from stable_baselines3.common.type_aliases import ReplayBufferSamples

    from seal.learner import Batch

    torch.manual_seed(seed)
    ours, sb3 = _twin_sacs(seed, batch_size, buffer_size=batch_size)
    rng = np.random.default_rng(seed)
    rows: list[dict[str, float]] = []
    worst = 0.0
    for _ in range(updates):
        obs, next_obs = (
            torch.from_numpy(rng.normal(size=(batch_size, SB3_OBS_DIM)).astype(np.float32))
            for _ in range(2)
        )
        actions = torch.from_numpy(rng.uniform(-1, 1, (batch_size, SB3_ACT_DIM)).astype(np.float32))
        rewards = torch.from_numpy(rng.uniform(0, 10, batch_size).astype(np.float32))
        terms = torch.from_numpy((rng.random(batch_size) < 0.1).astype(np.float32))
        # Our update draws the s' noise (critic target), then the s noise (actor), from its own
        # generator; predict both from a copy of it and hand them to SB3 in SB3's order (s, s').
        gen = torch.Generator().set_state(ours.update_generators["bench"].get_state())
        noise_next = torch.randn(batch_size, SB3_ACT_DIM, generator=gen)
        noise_obs = torch.randn(batch_size, SB3_ACT_DIM, generator=gen)
        metrics = ours.update(
            {
                "bench": Batch(
                    obs,
                    actions,
                    rewards,
                    next_obs,
                    terms,
                    torch.zeros(batch_size, dtype=torch.int64),
                )
            }
        )
        fields = {f: None for f in ReplayBufferSamples._fields}
        fields.update(
            observations=obs,
            actions=actions,
            next_observations=next_obs,
            dones=terms[:, None],
            rewards=rewards[:, None],
        )
        sample = ReplayBufferSamples(**fields)
        sb3.replay_buffer.sample = lambda *_a, _s=sample, **_k: _s  # type: ignore[method-assign]
        with _fixed_normal_noise([noise_obs, noise_next]):
            sb3.train(gradient_steps=1, batch_size=batch_size)
        logged = sb3.logger.name_to_value
        row = {
            "critic_ours": metrics["losses/bench/critic"],
            "critic_sb3": float(logged["train/critic_loss"]),
            "actor_ours": metrics["losses/bench/actor"],
            "actor_sb3": float(logged["train/actor_loss"]),
            "alpha_loss_ours": metrics["losses/bench/alpha"],
            "alpha_loss_sb3": float(logged["train/ent_coef_loss"]),
            "alpha_ours": metrics["charts/bench/alpha/0"],
            "alpha_sb3": float(logged["train/ent_coef"]),
        }
        rows.append(row)
        for a, b in (
            ("critic_ours", "critic_sb3"),
            ("actor_ours", "actor_sb3"),
            ("alpha_ours", "alpha_sb3"),
        ):
            worst = max(worst, _rel(row[a], row[b]))
        # The temperature loss is 0 at the first update (log alpha = 0): compare it absolutely.
        worst = max(
            worst,
            abs(row["alpha_loss_ours"] - row["alpha_loss_sb3"])
            / max(1.0, abs(row["alpha_loss_sb3"])),
        )
    differences = [
        "policy noise: SB3 samples for s, then s'; we for s', then s; both get the same noise here",
        "temperature step: SB3 steps log alpha before the critic, we after the actor; both use the pre-step alpha in every loss",
        "Polyak: SB3 target*(1-tau) + tau*online, we lerp; equal up to float rounding",
    ]
    return {
        "updates": rows,
        "max_rel_diff": worst,
        "match_1e-4": worst <= 1e-4,
        "differences": differences,
    }


def test_our_sac_losses_match_stable_baselines3() -> None:
    # Identical weights, batches and policy noise: critic, actor and temperature agree over 3
    # updates (batch 256), i.e. the optimiser steps agree too.
    check = sac_loss_check()
    print(
        f"max relative loss difference over {len(check['updates'])} updates: {check['max_rel_diff']:.1e}"
    )
    assert check["max_rel_diff"] <= 1e-4, check
    assert check["updates"][1]["alpha_ours"] < 1.0  # the temperature did move
