"""A tiny `point` protocol for the sweep tests: one task ("east"), 15-step episodes, 32-unit
networks, 20 epochs, a few seconds a trial. With init_alpha = 0.01 and gamma = 0.9 this config learns,
while lr_factor = 1e-9 (a learning rate of ~0; 0 itself is not a valid Adam rate) stays at success 0
and return ~ -16 (the point barely moves). Measured after common random numbers (`seal run` of
`write_protocol`'s file, seeds 0-9, one thread): at 20 epochs 8 of 10 seeds have success > 0 at the
last evaluation (seeds 0 and 8 do not), at 40 epochs 10 of 10 at both epoch 30 and epoch 40; a test
that needs a seed to learn runs 40 epochs.
"""

from __future__ import annotations

import textwrap
from pathlib import Path

TINY = """
[protocol]
name = "{name}"
kind = "baseline"
seeds = 2
epochs = {epochs}
device = "cpu"

[envs.point]
adapter = "point"
tasks = ["east"]
episode_length = 15

[agent]
hidden = [32, 32]
actor_lr = 3e-3
critic_lr = 3e-3
init_alpha = {init_alpha}
gamma = 0.9
# The learner settings the module docstring's learning was measured with (before
# issue 10's reference defaults); these tests are about sweep plumbing, not about the learner.
init = "torch"
max_grad_norm = 0.0
adam_eps = 1e-8

[replay]
capacity_per_env = 2000

[training]
warmup_steps = 60
batch_per_task = 64
grad_steps_per_epoch = 15
collector = "sync"

[evaluation]
interval = 10
episodes = 2

[checkpoint]
interval = 20
save_replay = false

[logging]
tensorboard = false
"""


def write_protocol(
    tmp_path: Path, name: str = "tiny", init_alpha: float = 0.01, extra: str = "", epochs: int = 20
) -> Path:
    """A tiny point protocol (a few seconds per seed) written to tmp_path/<name>.toml."""
    path = tmp_path / f"{name}.toml"
    text = TINY.format(name=name, init_alpha=init_alpha, epochs=epochs)
    path.write_text(text + textwrap.dedent(extra))
    return path
