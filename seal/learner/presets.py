"""Named sets of agent keys: `agent.preset = "<name>"` fills the keys a protocol leaves out.

A preset is data, applied when `[agent]` is resolved (`seal.protocols.loader`): every key the
protocol or `--set` gives explicitly wins over the preset's value, and `seal protocol explain`
says, key by key, what the preset set and where an explicit key overrode it.
"""

from __future__ import annotations

from collections.abc import Mapping

from seal.errors import ConfigError

PRESETS: dict[str, dict[str, object]] = {
    # The SEAL authors' network (reginald-mclean/cleanrl, cleanrl/mtmhsac_jax_seal.py at 3488472;
    # docs/hyperparameters.md cites each line as R:<line>).
    "seal_prototype": {
        "architecture": "seal",
        # TranslationLayer: 3 Dense layers, input -> 400 -> 400 -> 400 (R:140-159).
        "translator_hidden": (400, 400),
        "latent_dim": 400,
        # SEAL module: 5 hidden layers of 400 and a 400 output, 6 Dense layers (R:162-179).
        "trunk_hidden": (400, 400, 400, 400, 400, 400),
        # Actor per env: 3 hidden layers of 400, the last one per task (R:195, R:202-206), then
        # mean and log-std layers its tasks share (R:208-217).
        "head_hidden": (400, 400, 400),
        "head_per_task": True,
        # --policy-lr, --q-lr (R:82-84); the temperatures' optimiser takes q_lr (R:405-409).
        "actor_lr": 3e-5,
        "critic_lr": 3e-5,
        "alpha_lr": 3e-5,
        # 1.0 on each TrainState apart: each env's translator, head and critic, and the trunk (R:87,
        # R:375, R:387, R:402, R:757).
        "max_grad_norm": 1.0,
        "clip_per": "component",
        # Each env its own twin critic, 3 x 400 (R:300-315). Its per-task last hidden layer
        # (R:283) is not taken: ours keeps the per-task Q output (docs/hyperparameters.md).
        "critic_sharing": "per_env",
        "critic_hidden": (400, 400, 400),
        # Plain Dense layers (R:300-315): no LayerNorm, which is the default since issue 54.
        "critic_layer_norm": False,
        # Not set: shared_update stays "weighted" (the ratio lever's trunk step); the prototype
        # steps the trunk once per env (R:900-924), which is shared_update = "sequential".
        # init stays "metaworld_algorithms" (the prototype's 0.1 biases are not taken).
    },
}
"""Every preset: name -> the agent keys it sets."""


def preset_values(name: object, where: str) -> Mapping[str, object]:
    """The keys preset `name` sets ("" = none); one-line error naming the valid presets."""
    if name in ("", None):
        return {}
    if not isinstance(name, str) or name not in PRESETS:
        valid = ", ".join(repr(n) for n in PRESETS)
        raise ConfigError(f"{where}: agent.preset {name!r} is not a preset; valid: {valid}")
    return PRESETS[name]
