"""Overrides that shrink a testbed protocol to a few seconds a run, one list for the tests that use it."""

from __future__ import annotations

SMALL = [
    "training.warmup_steps=0",
    "training.grad_steps_per_epoch=2",
    "evaluation.interval=1",
    "evaluation.episodes=1",
    "agent.translator_hidden=[8]",
    "agent.latent_dim=8",
    "agent.trunk_hidden=[8]",
    "agent.critic_hidden=[8]",
]
"""8-wide networks, no warm-up, 2 gradient steps an epoch, one evaluation episode every epoch."""
TINY = ["protocol.epochs=2", *SMALL]
"""SMALL for two epochs."""
