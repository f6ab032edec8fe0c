"""Probes of a trained SEAL policy: does it align related tasks in the shared latent space?

SEAL's claim is that the per-env translators f_theta_i map corresponding states of different
environments to nearby points of the shared latent space, so that the trunk pi_eta serves both.
The measure is linear CKA (Kornblith et al. 2019), a similarity of two representations of the
same inputs that is invariant to orthogonal transforms and isotropic scaling of either, so two
translators that agree up to a rotation of the latent space score 1:

    CKA(X, Y) = ||Y^T X||_F^2 / (||X^T X||_F ||Y^T Y||_F),   X, Y centred column-wise, rows paired.

The inputs must be the same states seen by each environment, which the transfer testbed
provides: `point`, `point_diagonal` and `point_view` observe one world
(`seal.envs.testbed.paired_states`). Each state is fed under every pair of corresponding tasks
(`TESTBED_TABLE`: point_view t0 <-> north, t1 <-> east, t2 <-> south, t3 <-> west), so one row
is one (state, task pair) and the rows of both envs mean the same situation.

Read the values against a control, never against 0: `VIEW_MATRIX` has orthonormal columns, so
the two envs' observations of the same states have identical Gram matrices (input CKA 1), and
even untrained translators of both score well above 0. The control is a pair of runs that never
met (`seal bench --learn transfer` sets each alone run against the pre-training of its seed).

For two envs that share no world (Meta-World and the kitchens), no CKA is computed here. The
candidate, the CKA between the latents' per-task means over rows that are the aligned task
pairs of an alignment table (`seal.envs.alignment`), is not defined in a useful way: (1) it has
as many rows as aligned pairs (6 in the paper's Table 3), and linear CKA on k << width rows is
biased towards 1 (independent Gaussian features of width 64 score ~0.92 on 6 rows, ~0.03 on
2,000), so a trained and an untrained translator would look alike; (2) each env's task means
average over its own state distribution, which differs between the envs, so a difference in the
means mixes what the envs visit with how the translators map it.

`cka_from_checkpoints` rebuilds agents from `seal run` checkpoints (the agent state records its
own specs and config) for a bench to measure the runs post hoc; `seal.run.loggers`' alignment
logger calls `translator_cka` at every evaluation of a joint testbed run.
"""

from __future__ import annotations

import os
import tomllib
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from seal.envs.base import EnvAdapter
from seal.envs.registry import make_adapter
from seal.envs.testbed import TESTBED_TABLE, paired_states
from seal.errors import SealError
from seal.learner.agent_state import AgentState
from seal.learner.checkpoint import read_checkpoint
from seal.learner.config import AgentConfig, EnvSpec
from seal.learner.sac import Agent

POINT_VIEW = "point_view"
"""The testbed env that sees the world through `VIEW_MATRIX`."""
POINT_WORLD = ("point", "point_diagonal")
"""The testbed envs that see the world's [x, y, vx, vy] as it is."""


def linear_cka(x: torch.Tensor | np.ndarray, y: torch.Tensor | np.ndarray) -> float:
    """Linear CKA of two representations (n, d_x) and (n, d_y) of the same n inputs, rows paired.

    Columns are centred first; computed in float64 on the CPU. 1 for representations equal up to
    an orthogonal transform and an isotropic scale, near 0 for unrelated ones (given n >> d).
    A representation that is constant over the rows has no CKA: SealError.
    """
    a, b = _matrix(x, "x"), _matrix(y, "y")
    if a.shape[0] != b.shape[0]:
        raise SealError(f"linear_cka: x and y must have the same rows, got {a.shape} and {b.shape}")
    if a.shape[0] < 2:
        raise SealError(f"linear_cka: needs at least 2 rows, got {a.shape[0]}")
    a = a - a.mean(axis=0)
    b = b - b.mean(axis=0)
    norm_a, norm_b = np.linalg.norm(a.T @ a), np.linalg.norm(b.T @ b)
    if norm_a == 0.0 or norm_b == 0.0:
        raise SealError(
            "linear_cka: a representation is constant over the rows (e.g. all ReLUs dead)"
        )
    return float(np.linalg.norm(b.T @ a) ** 2 / (norm_a * norm_b))


def _matrix(x: torch.Tensor | np.ndarray, name: str) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu().numpy()
    a = np.asarray(x, dtype=np.float64)
    if a.ndim != 2:
        raise SealError(f"linear_cka: {name} must be 2-D (rows, features), got shape {a.shape}")
    return a


# ---------------------------------------------------------------- activations of one agent


def latent_activations(
    agent: Agent, env: str, obs: np.ndarray, task_ids: np.ndarray
) -> tuple[torch.Tensor, torch.Tensor]:
    """(translator output, trunk output) of `agent`'s policy for env `env` at raw `obs` (N, obs_dim).

    The SEAL forward pass of `TaskNetwork` up to the heads: translator_i([obs, one-hot]) is the
    latent, the trunk's last ReLU layer the input of the heads. No gradient, no random draw.
    """
    if env not in agent.specs:
        raise SealError(
            f"latent_activations: the agent has no env {env!r}; it has {list(agent.specs)}"
        )
    # The networks' modules are keyed in spec order (the agent's keys replace '.' with '_').
    key = list(agent.actor_segments)[list(agent.specs).index(env)]
    if key not in agent.actor.translators:
        raise SealError(
            f"latent_activations: the agent's architecture {agent.config.architecture!r} has no translators; "
            'only "seal" does'
        )
    if agent.config.belief_dim:
        raise SealError(
            'latent_activations: under agent.task_encoder = "smt_gru" the translator also reads the '
            "belief of an episode's history, which single observations do not have; probe a "
            '"one_hot" or "none" agent'
        )
    spec = agent.specs[env]
    obs_t = torch.as_tensor(np.asarray(obs), dtype=torch.float32, device=agent.device)
    ids_t = torch.as_tensor(np.asarray(task_ids), dtype=torch.long, device=agent.device)
    if obs_t.dim() != 2 or obs_t.shape[1] != spec.obs_dim or ids_t.shape != (obs_t.shape[0],):
        raise SealError(
            f"latent_activations({env!r}): expected obs (N, {spec.obs_dim}) and task_ids (N,), "
            f"got {tuple(obs_t.shape)} and {tuple(ids_t.shape)}"
        )
    # The actor's input, segment by segment as the agent lays it out (obs, then the one-hot).
    parts = {"obs": obs_t, "task": F.one_hot(ids_t, spec.num_tasks).to(obs_t.dtype)}
    with torch.no_grad():
        x = torch.cat([parts[name] for name, _ in agent.actor_segments[key]], dim=-1)
        latent = agent.actor.translators[key](x)
        trunk = agent.actor.trunk(latent)
    return latent, trunk


def translator_cka(
    agent_a: Agent,
    env_a: str,
    obs_a: np.ndarray,
    tasks_a: Sequence[int],
    agent_b: Agent,
    env_b: str,
    obs_b: np.ndarray,
    tasks_b: Sequence[int],
) -> dict[str, float]:
    """Linear CKA between two translators' latents, and between the trunk's outputs, on paired inputs.

    Row i of `obs_a` and of `obs_b` are one state seen by env_a and by env_b; `tasks_a[k]` and
    `tasks_b[k]` are corresponding task ids (local one-hot indices). Every state is fed under every
    task pair, so both representations have len(tasks) x n rows. The agents may be one agent (two
    envs of a joint run) or two (runs that never met: the baseline). Returns {"translator", "trunk"}.
    """
    if len(tasks_a) != len(tasks_b) or not len(tasks_a):
        raise SealError(
            f"translator_cka: tasks_a and tasks_b must pair tasks one to one, got {list(tasks_a)} and {list(tasks_b)}"
        )
    n = len(obs_a)
    if len(obs_b) != n:
        raise SealError(
            f"translator_cka: obs_a has {n} rows but obs_b {len(obs_b)}; rows must pair"
        )
    ids_a = np.repeat(np.asarray(tasks_a, dtype=np.int64), n)
    ids_b = np.repeat(np.asarray(tasks_b, dtype=np.int64), n)
    latent_a, trunk_a = latent_activations(agent_a, env_a, np.tile(obs_a, (len(tasks_a), 1)), ids_a)
    latent_b, trunk_b = latent_activations(agent_b, env_b, np.tile(obs_b, (len(tasks_b), 1)), ids_b)
    return {"translator": linear_cka(latent_a, latent_b), "trunk": linear_cka(trunk_a, trunk_b)}


# ---------------------------------------------------------------- the testbed's shared world


def corresponding_tasks(
    adapter_a: EnvAdapter, adapter_b: EnvAdapter
) -> tuple[list[int], list[int]]:
    """(ids of adapter_a, ids of adapter_b): the local indices of corresponding tasks, pairwise.

    Tasks correspond when they have one goal: `point`'s tasks are goals, `TESTBED_TABLE` names
    each `point_view` task's, and any other task is a goal of its own. Envs with no
    corresponding task (`point_diagonal` and `point_view`, the no-correspondence control) are
    paired by position in their task lists, an arbitrary pairing: the control's CKA then says how
    alike the same states map, under tasks that do not correspond.
    """
    goals_b = [_goal(adapter_b, t) for t in adapter_b.tasks]
    pairs = [
        (i, goals_b.index(goal))
        for i, goal in enumerate(_goal(adapter_a, t) for t in adapter_a.tasks)
        if goal in goals_b
    ]
    if not pairs:
        pairs = [(i, i) for i in range(min(len(adapter_a.tasks), len(adapter_b.tasks)))]
    return [i for i, _ in pairs], [j for _, j in pairs]


def _goal(adapter: EnvAdapter, task: str) -> str:
    if adapter.name == "point":
        return task
    key = f"{adapter.name}:{task}"
    return TESTBED_TABLE.get(key, key)


def shared_world_obs(adapter: EnvAdapter, states: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The observations adapter sees of `paired_states`' states (point's or point_view's)."""
    if adapter.name in POINT_WORLD:
        return states[0]
    if adapter.name == POINT_VIEW:
        return states[1]
    raise SealError(
        f"adapter {adapter.name!r} does not see the testbed's world; the CKA probe needs two of "
        f"{', '.join((*POINT_WORLD, POINT_VIEW))} (see seal.learner.probes on other env pairs)"
    )


def shared_world_cka(
    agent_a: Agent,
    env_a: str,
    adapter_a: EnvAdapter,
    agent_b: Agent,
    env_b: str,
    adapter_b: EnvAdapter,
    n: int = 2048,
    seed: int = 0,
) -> dict[str, float]:
    """`translator_cka` on `n` paired testbed states (`paired_states(n, seed)`) under corresponding tasks."""
    states = paired_states(n, seed)
    obs_a, obs_b = shared_world_obs(adapter_a, states), shared_world_obs(adapter_b, states)
    tasks_a, tasks_b = corresponding_tasks(adapter_a, adapter_b)
    return translator_cka(agent_a, env_a, obs_a, tasks_a, agent_b, env_b, obs_b, tasks_b)


# ---------------------------------------------------------------- from checkpoints


def agent_from_state(state: AgentState, device: str = "cpu") -> Agent:
    """An agent with the weights of `Agent.state_dict()` `state`, rebuilt from the specs and config it records.

    Built on `device` and eager (compile off): a probe only runs forward passes.
    """
    specs = [EnvSpec(**spec) for spec in state["specs"]]
    config = AgentConfig.from_saved(state["config"], device=device, compile=False)
    agent = Agent(specs, config, seed=0)
    agent.load_state_dict(state)
    return agent


def checkpoint_adapter(checkpoint: Mapping[str, Any], env: str) -> EnvAdapter:
    """The adapter of `[envs.<env>]` in a `seal run` checkpoint's saved config (its adapter, tasks and options)."""
    text = checkpoint.get("config_toml")
    if not isinstance(text, str):
        raise SealError("the checkpoint holds no config_toml: it was not written by `seal run`")
    envs = tomllib.loads(text).get("envs", {})
    if env not in envs:
        raise SealError(f"the checkpoint's run has no env {env!r}; its envs: {', '.join(envs)}")
    table = envs[env]
    return make_adapter(
        table.get("adapter") or env, tasks=list(table.get("tasks", [])), **table.get("options", {})
    )


def cka_from_checkpoints(
    ckpt_a: str | os.PathLike[str],
    env_a: str,
    ckpt_b: str | os.PathLike[str],
    env_b: str,
    n: int = 2048,
    seed: int = 0,
) -> dict[str, float]:
    """{"translator", "trunk"}: linear CKA of env_a's agent in `ckpt_a` and env_b's in `ckpt_b` on testbed states.

    `ckpt_a` and `ckpt_b` are `seal run` checkpoints (one file for two envs of a joint run, or two
    runs' files); `env_a`, `env_b` the protocols' env names ([envs.<name>]), which the agents of
    baseline and joint runs go by. Fine-tuning runs (an aligned pseudo-env) are not supported.
    """
    agent_a, adapter_a = _load(ckpt_a, env_a)
    agent_b, adapter_b = _load(ckpt_b, env_b)
    return shared_world_cka(agent_a, env_a, adapter_a, agent_b, env_b, adapter_b, n=n, seed=seed)


def _load(path: str | os.PathLike[str], env: str) -> tuple[Agent, EnvAdapter]:
    """The agent of a `seal run` checkpoint and the adapter of its env `env`."""
    data = read_checkpoint(path)
    try:
        adapter = checkpoint_adapter(data, env)
    except SealError as exc:
        raise SealError(f"checkpoint {path}: {exc}") from None
    names = [spec["name"] for spec in data["agent"]["specs"]]
    if env not in names:
        raise SealError(
            f"checkpoint {path}: its agent has envs {names}, not {env!r} (a fine-tuning run's aligned env is not supported)"
        )
    return agent_from_state(data["agent"]), adapter
