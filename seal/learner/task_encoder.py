"""SMT's task-embedding network (Cho et al. 2024, App. D): a VariBAD encoder with a task decoder.

Under hard-tasks-first scheduling the policy never sees the one-hot ids of tasks outside the
training pool, so SMT tells the policy the task from experience: a GRU E_phi reads the episode's
history {s_i, a_i-1, r_i} and outputs a belief over a latent task m, and the policy is pi(a | s, m).
Three decoders train it (VariBAD's ELBO, Zintgraf et al. 2020, plus SMT's task term): reward
D_r(s, a, s', m), next state D_s(s, a, m) and task id D_T(s, a, s', m) (cross-entropy).

How it meets the rest of SEAL (each choice, with its source, in docs/hyperparameters.md):
- The belief is (mean, log-variance) of a diagonal Gaussian, as VariBAD passes it; the policy and
  the critics both take it in place of the one-hot. At t = 0 it is the prior: the encoder's output
  from a zero GRU state (VariBAD's `prior`), before any step is read.
- Collection carries the GRU state per env instance (`BeliefMemory`, stepped by the Collector) and
  hands the policy, the replay and the probes the observation [obs | belief | episode step].
- The replay stores that observation: the belief an update trains on is the one collection saw,
  made by the encoder as it was then (staleness: up to the replay's age; VariBAD's policy also
  trains on beliefs it does not back-propagate into). RL gradients do not reach the encoder.
- The encoder trains on whole stored episodes, found in the replay by their step column: every
  `encoder_interval` updates, `encoder_episodes` episodes, `encoder_elbo_steps` beliefs each,
  each decoding `encoder_decode_steps` transitions drawn from the whole episode (past and future).
- An SMT reset redraws the policy and critics only; the encoder, decoders and their Adam stay.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

if TYPE_CHECKING:
    from seal.learner.config import AgentConfig

# VariBAD's embeddings of the encoder's inputs (state_embedding_size, action_, reward_).
EMBED = {"obs": 32, "action": 16, "reward": 16}
# Loss names of one encoder step, per env, in the order `elbo` returns them.
LOSSES = ("reward", "state", "task", "kl", "task_accuracy")


def _mlp(widths: tuple[int, ...], out: int) -> nn.Sequential:
    """ReLU layers of `widths` (the first is the input), then a linear map to `out`."""
    layers: list[nn.Module] = []
    for a, b in zip(widths, widths[1:], strict=False):
        layers += [nn.Linear(a, b), nn.ReLU()]
    layers.append(nn.Linear(widths[-1], out))
    return nn.Sequential(*layers)


class TaskEncoder(nn.Module):
    """One environment's encoder E_phi and its three decoders."""

    def __init__(self, obs_dim: int, act_dim: int, num_tasks: int, config: AgentConfig) -> None:
        super().__init__()
        self.obs_dim, self.act_dim, self.latent = obs_dim, act_dim, config.encoder_latent
        self.embed_obs = nn.Linear(obs_dim, EMBED["obs"])
        self.embed_action = nn.Linear(act_dim, EMBED["action"])
        self.embed_reward = nn.Linear(1, EMBED["reward"])
        self.gru = nn.GRU(sum(EMBED.values()), config.encoder_gru, batch_first=True)
        # SMT §5's two hidden layers of 400 sit after the GRU, mapping its state to the belief
        # (VariBAD's encoder_layers_after_gru; its layers before the GRU are the embeddings).
        widths = (config.encoder_gru, *config.encoder_hidden)
        self.after = _mlp(widths, 2 * config.encoder_latent)
        hidden = config.decoder_hidden
        latent = config.encoder_latent
        self.reward_decoder = _mlp((2 * obs_dim + act_dim + latent, *hidden), 1)
        self.state_decoder = _mlp((obs_dim + act_dim + latent, *hidden), obs_dim)
        self.task_decoder = _mlp((2 * obs_dim + act_dim + latent, *hidden), num_tasks)

    def reset_parameters(self, generator: torch.Generator) -> None:
        """nn.Linear's and nn.GRU's default U(+-1/sqrt(fan)) draws, from `generator` (on CPU)."""
        with torch.no_grad():
            for module in self.modules():
                if isinstance(module, nn.Linear):
                    bound = 1.0 / module.in_features**0.5
                    module.weight.uniform_(-bound, bound, generator=generator)
                    module.bias.uniform_(-bound, bound, generator=generator)
                elif isinstance(module, nn.GRU):
                    bound = 1.0 / module.hidden_size**0.5
                    for p in module.parameters():
                        p.uniform_(-bound, bound, generator=generator)

    def belief(self, hidden: torch.Tensor) -> torch.Tensor:
        """[mean | log-variance] (..., 2 * latent) of GRU states (..., gru)."""
        return self.after(hidden)

    def initial(self, n: int, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
        """(zero GRU states (n, gru), the prior belief (n, 2 * latent)) of n fresh episodes."""
        hidden = torch.zeros(n, self.gru.hidden_size, device=device)
        return hidden, self.belief(hidden)

    def _embed(
        self, obs: torch.Tensor, actions: torch.Tensor, rewards: torch.Tensor
    ) -> torch.Tensor:
        return torch.cat(
            (
                F.relu(self.embed_obs(obs)),
                F.relu(self.embed_action(actions)),
                F.relu(self.embed_reward(rewards.unsqueeze(-1))),
            ),
            dim=-1,
        )

    def step(
        self,
        hidden: torch.Tensor,
        next_obs: torch.Tensor,
        actions: torch.Tensor,
        rewards: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Read one step (a_t, r_t, s_t+1) of n episodes: (new GRU states, beliefs at t + 1)."""
        x = self._embed(next_obs, actions, rewards).unsqueeze(1)
        _, h = self.gru(x, hidden.unsqueeze(0).contiguous())
        h = h.squeeze(0)
        return h, self.belief(h)

    def sequence(
        self, next_obs: torch.Tensor, actions: torch.Tensor, rewards: torch.Tensor
    ) -> torch.Tensor:
        """Beliefs (B, T + 1, 2 * latent) of B episodes of T steps: the prior, then after each step."""
        x = self._embed(next_obs, actions, rewards)
        hidden = torch.zeros(1, x.shape[0], self.gru.hidden_size, device=x.device)
        out, _ = self.gru(x, hidden)
        return self.belief(torch.cat((hidden.transpose(0, 1), out), dim=1))


class Episodes(NamedTuple):
    """B stored episodes padded to T steps: raw obs (B, T, o), actions (B, T, a), rewards (B, T),
    raw next obs (B, T, o), lengths (B,) and task ids (B,), on the replay's device."""

    obs: torch.Tensor
    actions: torch.Tensor
    rewards: torch.Tensor
    next_obs: torch.Tensor
    lengths: torch.Tensor
    task_ids: torch.Tensor


def gaussian_kl(
    mean: torch.Tensor, logvar: torch.Tensor, mean0: torch.Tensor, logvar0: torch.Tensor
) -> torch.Tensor:
    """KL(N(mean, e^logvar) || N(mean0, e^logvar0)), summed over the last dim."""
    return 0.5 * (
        logvar0 - logvar + (logvar.exp() + (mean - mean0) ** 2) / logvar0.exp() - 1.0
    ).sum(-1)


def elbo(
    encoder: TaskEncoder,
    episodes: Episodes,
    config: AgentConfig,
    generator: torch.Generator,
) -> tuple[torch.Tensor, torch.Tensor]:
    """(the weighted negative ELBO, the values of `LOSSES`) of one batch of episodes.

    Each episode's beliefs m_0..m_T come from the encoder with its current weights. For
    `encoder_elbo_steps` of them (uniform over 0..length), a reparameterised sample decodes
    `encoder_decode_steps` transitions of the same episode (uniform over the whole episode): reward
    and next state by mean squared error, the task id by cross-entropy. The KL term is
    KL(q_t || q_t-1) at every step, with q_-1 = N(0, I), as VariBAD's default.
    """
    device = episodes.obs.device
    lat = encoder.latent
    beliefs = encoder.sequence(episodes.next_obs, episodes.actions, episodes.rewards)
    mean, logvar = beliefs[..., :lat], beliefs[..., lat:]
    b, horizon = episodes.rewards.shape
    # KL to the previous posterior, over steps 0..length of each episode.
    prev_mean = torch.cat((torch.zeros_like(mean[:, :1]), mean[:, :-1]), dim=1)
    prev_logvar = torch.cat((torch.zeros_like(logvar[:, :1]), logvar[:, :-1]), dim=1)
    kl = gaussian_kl(mean, logvar, prev_mean, prev_logvar)  # (B, T + 1)
    valid = torch.arange(horizon + 1, device=device)[None, :] <= episodes.lengths[:, None]
    kl = (kl * valid).sum() / valid.sum()
    lengths = episodes.lengths.to(torch.float32).cpu()

    def draw(shape: tuple[int, int], upper: torch.Tensor) -> torch.Tensor:
        u = torch.rand(*shape, generator=generator)
        return torch.minimum((u * upper[:, None]).long(), upper[:, None].long() - 1).to(device)

    e, d = config.encoder_elbo_steps, config.encoder_decode_steps
    at = draw((b, e), lengths + 1)  # which beliefs (0..length)
    k = draw((b, d), lengths)  # which transitions
    rows = torch.arange(b, device=device)[:, None]
    noise = torch.randn(b, e, lat, generator=generator).to(device)
    z = mean[rows, at] + (0.5 * logvar[rows, at]).exp() * noise  # (B, E, L)
    z = z[:, :, None, :].expand(b, e, d, lat)

    def pick(x: torch.Tensor) -> torch.Tensor:  # (B, T, ...) -> (B, E, D, ...)
        x = x[rows, k]
        return x[:, None].expand(b, e, *x.shape[1:])

    s, a, r, s2 = (
        pick(x) for x in (episodes.obs, episodes.actions, episodes.rewards, episodes.next_obs)
    )
    reward_loss = (
        (encoder.reward_decoder(torch.cat((s, a, s2, z), -1)).squeeze(-1) - r).pow(2).mean()
    )
    state_loss = (encoder.state_decoder(torch.cat((s, a, z), -1)) - s2).pow(2).mean()
    logits = encoder.task_decoder(torch.cat((s, a, s2, z), -1))
    target = episodes.task_ids[:, None, None].expand(b, e, d)
    task_loss = F.cross_entropy(logits.reshape(-1, logits.shape[-1]), target.reshape(-1))
    accuracy = (logits.argmax(-1) == target).float().mean()
    w_r, w_s, w_t = config.decoder_weights
    loss = w_r * reward_loss + w_s * state_loss + w_t * task_loss + config.encoder_kl_weight * kl
    values = torch.stack((reward_loss, state_loss, task_loss, kl, accuracy)).detach()
    return loss, values


class BeliefMemory:
    """Each env instance's GRU state and belief while a Collector runs its episodes.

    The Collector calls `start` after a reset and `advance` after every step, before it asks for
    the next actions; `augment` gives [obs | belief | step] for the policy, the probes and the
    replay, `last` the (before, after) columns of the last step for the replay's obs and next obs.
    `encoder_of(env)` is the TaskEncoder of the collector's env `env` (None: no encoding for it).
    """

    def __init__(self, encoder_of: Callable[[str], TaskEncoder], device: torch.device) -> None:
        self.encoder_of, self.device = encoder_of, device
        self._hidden: dict[str, torch.Tensor] = {}
        self._extra: dict[str, np.ndarray] = {}  # (n, belief + 1): belief, then the step
        self._last: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def _grow(self, env: str, upto: int, hidden: int, width: int) -> None:
        n = self._extra[env].shape[0] if env in self._extra else 0
        if upto <= n:
            return
        h = torch.zeros(upto, hidden, device=self.device)
        x = np.zeros((upto, width), np.float32)
        if n:
            h[:n], x[:n] = self._hidden[env], self._extra[env]
        self._hidden[env], self._extra[env] = h, x

    def start(self, env: str, run: np.ndarray) -> None:
        """Instances `run` of `env` begin an episode: zero GRU state, the prior's belief, step 0."""
        encoder = self.encoder_of(env)
        with torch.inference_mode():
            hidden, belief = encoder.initial(len(run), self.device)
        self._grow(env, int(run.max()) + 1, hidden.shape[1], belief.shape[1] + 1)
        self._hidden[env][run] = hidden
        self._extra[env][run, :-1] = belief.cpu().numpy()
        self._extra[env][run, -1] = 0.0

    def advance(
        self,
        env: str,
        run: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        next_obs: np.ndarray,
    ) -> None:
        """Instances `run` took `actions`, earned `rewards` and see `next_obs`: read the step."""
        before = self._extra[env][run].copy()
        with torch.inference_mode():
            hidden, belief = self.encoder_of(env).step(
                self._hidden[env][run],
                torch.as_tensor(np.asarray(next_obs, np.float32), device=self.device),
                torch.as_tensor(np.asarray(actions, np.float32), device=self.device),
                torch.as_tensor(np.asarray(rewards, np.float32), device=self.device),
            )
        self._hidden[env][run] = hidden
        self._extra[env][run, :-1] = belief.cpu().numpy()
        self._extra[env][run, -1] += 1.0
        self._last[env] = (before, self._extra[env][run].copy())

    def augment(self, env: str, run: np.ndarray, obs: np.ndarray) -> np.ndarray:
        """[obs | belief | step] (n, obs_dim + belief + 1) of instances `run`."""
        return np.concatenate((np.asarray(obs, np.float32), self._extra[env][run]), axis=1)

    def last(self, env: str) -> tuple[np.ndarray, np.ndarray]:
        """The (before, after) [belief | step] columns of `env`'s last `advance`."""
        return self._last[env]
