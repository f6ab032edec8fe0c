"""SMT's task encoder meets the replay and the agent: its training, its data and its state.

`TaskEncoding` is the part of an `Agent` with agent.task_encoder = "smt_gru": one
`seal.learner.task_encoder.TaskEncoder` per env, their Adam and random streams, the index of whole
episodes in the replay (`EpisodeIndex`, found by each row's step column) that the encoder trains
on (`update`), and the optional rewrite of the replay's stored beliefs with today's encoder
(`refresh`). An SMT reset of the agent leaves all of it as it is.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, cast

import numpy as np
import torch
from torch import nn

from seal.errors import SealError
from seal.learner.task_encoder import LOSSES, Episodes, TaskEncoder, elbo
from seal.seeding import stream

if TYPE_CHECKING:
    from seal.learner.config import AgentConfig, EnvSpec
    from seal.learner.replay import MultiTaskReplay


class EpisodeIndex:
    """Where each whole episode of one env lies in the replay, found by the step column.

    A task's ring holds its steps in the order collected (one training instance per task), so an
    episode is a run of rows from one whose step is 0 to the next such row. Rows before a task's
    first step-0 row belong to an episode the ring has partly overwritten and are skipped.
    Rebuilt when the replay's positions or sizes change (once an epoch, at the flush).
    """

    def __init__(self) -> None:
        self._key: bytes = b""
        self.tasks = np.zeros(0, np.int64)
        self.starts = np.zeros(0, np.int64)  # physical row of each episode's first step
        self.lengths = np.zeros(0, np.int64)

    def refresh(self, replay: MultiTaskReplay, env: str) -> None:
        key = replay.size[env].tobytes() + replay.position[env].tobytes()
        if key == self._key:
            return
        steps_col = replay.storage[env]["obs"][..., -1]
        cap = replay.capacity_per_task[env]
        tasks, starts, lengths = [], [], []
        for task, (size, position) in enumerate(
            zip(replay.size[env], replay.position[env], strict=True)
        ):
            if size == 0:
                continue
            base = 0 if size < cap else int(position)
            order = (base + np.arange(size)) % cap
            steps = steps_col[task, torch.from_numpy(order).to(steps_col.device)].cpu().numpy()
            first = np.flatnonzero(steps == 0)
            if first.size == 0:
                continue
            ends = np.append(first[1:], size)
            tasks.append(np.full(first.size, task))
            starts.append(order[first])
            lengths.append(ends - first)
        self._key = key
        if tasks:
            self.tasks, self.starts, self.lengths = map(np.concatenate, (tasks, starts, lengths))

    def sample(
        self,
        replay: MultiTaskReplay,
        env: str,
        count: int,
        generator: torch.Generator,
        obs_dim: int,
    ) -> Episodes:
        """`count` episodes drawn uniformly (with replacement) by `generator`."""
        self.refresh(replay, env)
        if self.starts.size == 0:
            cap = replay.capacity_per_task[env]
            raise SealError(
                f"task encoder: the replay holds no whole episode of {env!r} ({int(replay.size[env].sum())} rows, "
                f"{cap} per task): it trains on whole episodes, so replay.capacity_per_env must give each task "
                "at least one episode's steps (capacity_per_env / tasks >= the episode length)"
            )
        pick = torch.randint(0, self.starts.size, (count,), generator=generator).numpy()
        tasks, starts, lengths = self.tasks[pick], self.starts[pick], self.lengths[pick]
        horizon = int(lengths.max())
        cap = replay.capacity_per_task[env]
        offsets = np.minimum(
            np.arange(horizon)[None, :], lengths[:, None] - 1
        )  # pad: repeat the last
        rows = (starts[:, None] + offsets) % cap
        store = replay.storage[env]
        device = store["obs"].device
        t = torch.from_numpy(np.repeat(tasks[:, None], horizon, axis=1)).to(device)
        r = torch.from_numpy(rows).to(device)
        return Episodes(
            store["obs"][t, r][..., :obs_dim],
            store["actions"][t, r],
            store["rewards"][t, r],
            store["next_obs"][t, r][..., :obs_dim],
            torch.from_numpy(lengths).to(device),
            torch.from_numpy(tasks).to(device),
        )


def refresh_beliefs(
    encoder: TaskEncoder,
    replay: MultiTaskReplay,
    env: str,
    index: EpisodeIndex,
    obs_dim: int,
    chunk: int = 256,
) -> int:
    """Overwrite the beliefs stored with `env`'s whole episodes by `encoder`'s of today; returns
    the rows rewritten. Rows of an episode the ring has partly overwritten keep theirs."""
    index.refresh(replay, env)
    store = replay.storage[env]
    cap = replay.capacity_per_task[env]
    device = store["obs"].device
    width = store["obs"].shape[-1] - 1  # the belief ends where the step column starts
    rewritten = 0
    for first in range(0, index.starts.size, chunk):
        tasks = index.tasks[first : first + chunk]
        starts, lengths = index.starts[first : first + chunk], index.lengths[first : first + chunk]
        horizon = int(lengths.max())
        offsets = np.minimum(np.arange(horizon)[None, :], lengths[:, None] - 1)
        t = torch.from_numpy(np.repeat(tasks[:, None], horizon, axis=1)).to(device)
        r = torch.from_numpy((starts[:, None] + offsets) % cap).to(device)
        with torch.no_grad():
            beliefs = encoder.sequence(
                store["next_obs"][t, r][..., :obs_dim],
                store["actions"][t, r],
                store["rewards"][t, r],
            )
        valid = torch.from_numpy(np.arange(horizon)[None, :] < lengths[:, None]).to(device)
        t, r = t[valid], r[valid]
        store["obs"][t, r, obs_dim:width] = beliefs[:, :-1][valid]
        store["next_obs"][t, r, obs_dim:width] = beliefs[:, 1:][valid]
        rewritten += int(valid.sum())
    return rewritten


class TaskEncoding:
    """The task encoders of an agent's envs, their Adam, random streams and episode indexes.

    `keys` maps env names to the agent's module keys. Weights are drawn on CPU from
    (seed, "init", "encoder", env) unless `draw` is False (shapes only: the memory estimate).
    """

    def __init__(
        self,
        specs: Sequence[EnvSpec],
        keys: Mapping[str, str],
        config: AgentConfig,
        seed: int,
        device: torch.device,
        draw: bool = True,
    ) -> None:
        self.config, self.keys = config, dict(keys)
        self.specs = {s.name: s for s in specs}
        self.modules = nn.ModuleDict(
            {keys[s.name]: TaskEncoder(s.obs_dim, s.act_dim, s.num_tasks, config) for s in specs}
        )
        self.last_refresh = 0
        """The agent's `num_updates` when the replay's beliefs were last recomputed (`refresh`)."""
        if not draw:
            return
        for name in self.specs:
            self.encoder(name).reset_parameters(stream(seed, "init", "encoder", name))
        self.modules.to(device)
        self.optimizer = torch.optim.Adam(
            self.modules.parameters(), lr=config.encoder_lr, eps=config.adam_eps
        )
        # On CPU: the episode and decode draws index host arrays.
        self.generators = {n: stream(seed, "encoder", n) for n in self.specs}
        self.episodes = {n: EpisodeIndex() for n in self.specs}

    def encoder(self, name: str) -> TaskEncoder:
        """Env `name`'s encoder."""
        return cast(TaskEncoder, self.modules[self.keys[name]])

    def update(
        self, replay: MultiTaskReplay, num_updates: int
    ) -> tuple[tuple[str, ...], torch.Tensor] | None:
        """One step of every env's encoder on whole episodes from `replay` when `num_updates` is
        a multiple of config.encoder_interval, else None: (log names, values), as
        `Agent.update_on_device` returns them.

        The logs are `losses/<env>/encoder_{reward,state,task,kl}` and
        `charts/<env>/encoder_task_accuracy`, each times the interval, so that their mean over
        updates is the mean over encoder steps.
        """
        config = self.config
        if num_updates % config.encoder_interval:
            return None
        names, losses, values = [], [], []
        for name, spec in self.specs.items():
            if not replay.size[name].any():  # an env with no data yet (a ratio of 0) waits
                continue
            generator = self.generators[name]
            episodes = self.episodes[name].sample(
                replay, name, config.encoder_episodes, generator, spec.obs_dim
            )
            loss, logged = elbo(self.encoder(name), episodes, config, generator)
            losses.append(loss)
            values.append(logged * config.encoder_interval)
            names += [
                f"charts/{name}/encoder_{k}"
                if k == "task_accuracy"
                else f"losses/{name}/encoder_{k}"
                for k in LOSSES
            ]
        if not losses:
            return None
        self.optimizer.zero_grad(set_to_none=True)
        torch.stack(losses).sum().backward()
        if config.max_grad_norm:
            nn.utils.clip_grad_norm_(self.modules.parameters(), config.max_grad_norm)
        self.optimizer.step()
        return tuple(names), torch.cat(values)

    def refresh(self, replay: MultiTaskReplay, num_updates: int) -> int:
        """Recompute the replay's stored beliefs with today's encoders when
        config.encoder_refresh_interval updates have passed since the last time; returns the rows
        rewritten (0: not due, or never)."""
        interval = self.config.encoder_refresh_interval
        if not interval or num_updates < self.last_refresh + interval:
            return 0
        self.last_refresh = num_updates
        return sum(
            refresh_beliefs(self.encoder(n), replay, n, self.episodes[n], s.obs_dim)
            for n, s in self.specs.items()
        )

    def state_dict(self) -> dict[str, object]:
        """Weights, Adam state, random streams and the last refresh (the agent state's keys)."""
        return {
            "encoder": self.modules.state_dict(),
            "encoder_optimizer": self.optimizer.state_dict(),
            "encoder_rng": {n: g.get_state() for n, g in self.generators.items()},
            "encoder_refreshed": self.last_refresh,
        }

    def load_state_dict(self, state: Mapping[str, object]) -> None:
        """Restore `state_dict`'s keys of an agent state."""
        if "encoder" not in state:
            raise SealError(
                'agent state has no task encoder, but this agent has agent.task_encoder = "smt_gru"'
            )
        self.modules.load_state_dict(cast(dict[str, torch.Tensor], state["encoder"]))
        self.optimizer.load_state_dict(cast(dict[str, object], state["encoder_optimizer"]))
        rng = cast(dict[str, torch.Tensor], state["encoder_rng"])
        for n, g in self.generators.items():
            g.set_state(rng[n])
        self.last_refresh = int(cast(int, state.get("encoder_refreshed", 0)))
