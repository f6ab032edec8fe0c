"""Kept or relearned: how far each piece of an env has moved from where its phase started.

    drift = ||W - W0|| / ||W0||

W is one piece's parameters concatenated into one vector (every tensor flattened, in module
order), W0 the same at the phase's start, after any transfer and mapped start; both norms are
Euclidean, in float64. The pieces (`seal.pieces.PIECES`) of env e:

- translator: e's policy input stack (SEAL; an agent without translators has no such piece);
- head: e's policy action head(s);
- critic: e's online twin critics, the parameters of them no other env uses (a per-env critic:
  all of it; a shared critic: e's translator and heads, not the shared trunk); the target
  critics follow them by Polyak averaging and are not counted;
- temperature: e's per-task temperatures, compared as alpha = exp(log alpha), not log alpha: a
  fresh log alpha is log(init_alpha) = 0, where the ratio would be undefined.

`[logging] drift` (`seal.run.loggers.DriftLogger`) writes it at every evaluation; W0 stays
on the agent's device and goes into every epoch checkpoint, so a resumed run measures from the
same start (the mapped start is not made again on resume). A piece whose W0 has norm 0 gets NaN.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import torch

from seal.learner.sac import Agent, module_key

DriftStart = dict[str, dict[str, torch.Tensor]]
"""Run env -> piece -> its parameters at the phase's start, flattened and concatenated."""


def piece_tensors(agent: Agent, name: str) -> dict[str, list[torch.Tensor]]:
    """The tensors of each piece of the agent's env `name` (the pieces it has), as the module
    docstring says; temperatures as alpha."""
    key = module_key(name)
    actor = agent.actor.components()
    out: dict[str, list[torch.Tensor]] = {}
    if f"translator.{key}" in actor:
        out["translator"] = list(actor[f"translator.{key}"])
    out["head"] = list(actor[f"head.{key}"])
    others = {
        id(p)
        for k in map(module_key, agent.specs)
        if k != key
        for p in agent.critic.env_parameters(k)
    }
    out["critic"] = [p for p in agent.critic.env_parameters(key) if id(p) not in others]
    out["temperature"] = [agent.log_alpha[key].exp()]
    return out


def _flat(tensors: list[torch.Tensor]) -> torch.Tensor:
    return torch.cat([t.detach().reshape(-1) for t in tensors])


def start_weights(agent: Agent, envs: Mapping[str, str]) -> DriftStart:
    """W0 of every piece of every env, on the agent's device; `envs`: run env -> agent env name."""
    with torch.no_grad():
        return {
            env: {piece: _flat(ts).clone() for piece, ts in piece_tensors(agent, name).items()}
            for env, name in envs.items()
        }


def relative_drift(
    agent: Agent, start: DriftStart, envs: Mapping[str, str]
) -> dict[tuple[str, str], float]:
    """(run env, piece) -> ||W - W0|| / ||W0|| of `agent` against `start` (NaN where ||W0|| = 0)."""
    out: dict[tuple[str, str], float] = {}
    with torch.no_grad():
        for env, name in envs.items():
            for piece, tensors in piece_tensors(agent, name).items():
                if piece not in start.get(env, {}):
                    continue
                w = _flat(tensors).double()
                w0 = start[env][piece].to(device=w.device, dtype=torch.float64)
                base = float(torch.linalg.vector_norm(w0))
                distance = float(torch.linalg.vector_norm(w - w0))
                out[(env, piece)] = distance / base if base > 0 else math.nan
    return out
