"""The small `point` protocol the fault tests run (a few seconds a run), one text for them all."""

from __future__ import annotations


def point_protocol(
    name: str,
    epochs: int,
    *,
    interval: int = 2,
    keep_last: int = 2,
    train_interval: int | None = 3,
) -> str:
    """Two point tasks, 8-wide nets, an evaluation every epoch, a checkpoint every `interval`."""
    logging = "" if train_interval is None else f"train_interval = {train_interval}\n"
    return f"""
[protocol]
name = "{name}"
kind = "baseline"
epochs = {epochs}
seeds = 1
device = "cpu"
threads = 1
[envs.pt]
adapter = "point"
tasks = ["east", "north"]
episode_length = 10
[agent]
hidden = [8, 8]
[training]
warmup_steps = 10
batch_per_task = 8
collector = "sync"
[evaluation]
interval = 1
episodes = 1
[checkpoint]
interval = {interval}
keep_last = {keep_last}
[logging]
{logging}tensorboard = false
"""
