"""SMT's task encoder (agent.task_encoder = "smt_gru", issue 56): prior, collection, storage,
training, reset semantics and resume."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
import torch

from seal.envs.point import PointAdapter, PointEnv
from seal.evaluation import AgentPolicy
from seal.learner import AgentConfig, EnvSpec
from seal.learner.collection import Collector
from seal.learner.replay import MultiTaskReplay
from seal.learner.sac import Agent
from seal.protocols import load_protocol
from seal.run.runner import resume_run, run_seed
from tests.crash import CrashAfter

SMALL: dict[str, Any] = dict(
    hidden=(16, 16),
    task_encoder="smt_gru",
    multi_head_policy=False,
    multi_head_critic=False,
    encoder_gru=16,
    encoder_hidden=(16,),
    decoder_hidden=(16, 16),
    encoder_elbo_steps=4,
    encoder_decode_steps=8,
    encoder_episodes=8,
    device="cpu",
)
SPEC = EnvSpec("pt", 4, 2, 4)
PROTOCOL = Path(__file__).resolve().parents[2] / "protocols" / "learn" / "point_smt_gru.toml"


def _collect(agent: Agent, episodes: int, seed: int = 0) -> tuple[MultiTaskReplay, AgentPolicy]:
    """`episodes` episodes of every point task (12 steps) by the stochastic policy, into a replay."""
    width = SPEC.obs_dim + agent.config.obs_extra
    replay = MultiTaskReplay([EnvSpec("pt", width, 2, 4)], capacity=4 * 12 * episodes)
    policy = AgentPolicy(agent, deterministic=False)
    with Collector({"pt": PointAdapter(episode_length=12)}, seed=seed, backend="sync") as col:
        for _ in range(episodes):
            col.collect_episodes(policy, sink=replay.add)
    return replay, policy


def _rows(replay: MultiTaskReplay, task: int) -> dict[str, np.ndarray]:
    size = int(replay.size["pt"][task])
    return {f: v[task, :size].numpy() for f, v in replay.storage["pt"].items()}


def test_the_first_belief_is_the_prior_and_stored_beliefs_are_the_encoders_over_the_episode() -> (
    None
):
    agent = Agent([SPEC], AgentConfig(**SMALL), seed=0)
    lat2 = agent.config.belief_dim
    replay, _ = _collect(agent, episodes=2)
    encoder = agent.encoder("pt")
    with torch.no_grad():
        _, prior = encoder.initial(1, torch.device("cpu"))
    for task in range(4):
        rows = _rows(replay, task)
        obs, next_obs = rows["obs"], rows["next_obs"]
        assert obs.shape == (24, 4 + lat2 + 1)
        # The step column counts 0..11 twice; the next observation is one step on.
        np.testing.assert_array_equal(obs[:, -1], np.tile(np.arange(12), 2))
        np.testing.assert_array_equal(next_obs[:, -1], obs[:, -1] + 1)
        for start in (0, 12):
            episode = slice(start, start + 12)
            # t = 0: the prior's belief (the same map of a zero GRU state; a batch of another
            # size may round the last bit differently).
            np.testing.assert_allclose(obs[start, 4:-1], prior[0].numpy(), rtol=0, atol=1e-6)
            # Within an episode the next observation's belief is the next row's.
            np.testing.assert_array_equal(next_obs[episode][:-1, 4:-1], obs[episode][1:, 4:-1])
            # What an update trains on is what the encoder (unchanged since) makes of the
            # stored episode, run as one sequence: the same m, up to the GRU kernels' rounding.
            with torch.no_grad():
                seq = encoder.sequence(
                    torch.from_numpy(next_obs[None, episode, :4]),
                    torch.from_numpy(rows["actions"][None, episode]),
                    torch.from_numpy(rows["rewards"][None, episode]),
                )[0].numpy()
            np.testing.assert_allclose(obs[episode, 4:-1], seq[:-1], atol=1e-5)
            np.testing.assert_allclose(next_obs[episode, 4:-1], seq[1:], atol=1e-5)
    # And a sampled batch carries those stored beliefs to the update unchanged.
    batch = replay.sample({"pt": np.array([8, 8, 8, 8])})["pt"]
    stored = replay.storage["pt"]["obs"].reshape(-1, 4 + lat2 + 1).numpy()
    for row in batch.obs.numpy():
        assert (stored == row).all(axis=1).any()


def test_act_without_the_belief_says_how_to_add_it() -> None:
    agent = Agent([SPEC], AgentConfig(**SMALL), seed=0)
    with pytest.raises(Exception, match=r"\(N, 13\).*BeliefMemory"):
        agent.act("pt", np.zeros((1, 4), np.float32), np.array([0]))


@pytest.mark.slow
def test_training_lowers_the_elbo_and_the_task_decoder_beats_chance() -> None:
    torch.manual_seed(0)
    agent = Agent([SPEC], AgentConfig(**SMALL, encoder_lr=3e-3), seed=0)
    replay, _ = _collect(agent, episodes=8)
    history = []
    for _ in range(400):
        agent.num_updates += 1  # update_encoder runs every encoder_interval (1) updates
        names, values = agent.update_encoder(replay)
        history.append(dict(zip(names, values.tolist(), strict=True)))
    frame = pd.DataFrame(history)

    def loss(rows: pd.DataFrame) -> float:
        return float(
            rows[[f"losses/pt/encoder_{k}" for k in ("reward", "state", "task", "kl")]]
            .sum(axis=1)
            .mean()
        )

    first, last = frame.iloc[:50], frame.iloc[-50:]
    # Measured (seed 0, this CPU): 1.70 over the first 50 steps, 1.13 over the last 50.
    assert loss(last) < 0.8 * loss(first), (loss(first), loss(last))
    # 4 tasks: chance is 0.25 (sd of a 50-step mean of 256 decodes each: ~0.004). The rewards
    # (minus the distance to the task's goal) tell them apart; the prior's decodes cannot.
    assert last["charts/pt/encoder_task_accuracy"].mean() > 0.35, last.mean()


def test_an_smt_reset_keeps_the_encoder_and_its_adam_and_redraws_policy_and_critics() -> None:
    agent = Agent([SPEC], AgentConfig(**SMALL), seed=0)
    replay, _ = _collect(agent, episodes=2)
    for _ in range(3):
        agent.update(replay.sample({"pt": np.array([4, 4, 4, 4])}))
        agent.num_updates  # noqa: B018
        agent.update_encoder(replay)
    encoder = {k: v.clone() for k, v in agent.encoders.state_dict().items()}
    adam = agent.task_encoding.optimizer.state_dict()
    adam = {k: {n: t.clone() for n, t in s.items()} for k, s in adam["state"].items()}
    actor = [p.clone() for p in agent.actor.parameters()]
    critic = [p.clone() for p in agent.critic.parameters()]
    agent.reset_parameters()
    for k, v in agent.encoders.state_dict().items():
        assert torch.equal(v, encoder[k]), k
    after = agent.task_encoding.optimizer.state_dict()["state"]
    assert after.keys() == adam.keys() and adam
    for k, s in adam.items():
        for n, t in s.items():
            assert torch.equal(after[k][n], t), (k, n)
    assert not any(
        torch.equal(a, b)
        for a, b in zip(actor, agent.actor.parameters(), strict=True)
        if a.numel() > 1
    )
    assert not any(
        torch.equal(a, b)
        for a, b in zip(critic, agent.critic.parameters(), strict=True)
        if a.numel() > 1
    )
    assert all(not s for s in (o.state for o in agent.actor_optimizers))


class _StillPoint(PointAdapter):
    """Point whose every episode starts at the origin: east and west see the same states under
    the same actions and differ only in their rewards."""

    def make(self, task: str, seed: int) -> PointEnv:
        env = super().make(task, seed)
        reset = env.reset

        def at_origin(**kwargs: Any) -> tuple[np.ndarray, dict[str, Any]]:
            reset(**kwargs)
            env.pos = np.zeros(2)
            return np.zeros(4), {}

        env.reset = at_origin  # type: ignore[method-assign]
        return env


class _Spy:
    """Records what a policy with a task encoder is asked, and what it answers."""

    def __init__(self, policy: AgentPolicy) -> None:
        self.policy, self.memory = policy, policy.memory
        self.calls: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

    def __call__(self, env: str, obs: np.ndarray, task_ids: np.ndarray) -> np.ndarray:
        actions = self.policy(env, obs, task_ids)
        self.calls.append((obs.copy(), task_ids.copy(), actions.copy()))
        return actions


@pytest.mark.parametrize("how", ["evaluate", "collect_episodes"])
def test_the_belief_tells_tasks_apart_that_the_state_does_not(how: str) -> None:
    # torch's init: metaworld-algorithms' U(+-1e-3) policy head would keep both actions near 0.
    agent = Agent([SPEC], AgentConfig(**SMALL, init="torch"), seed=0)
    spy = _Spy(AgentPolicy(agent, deterministic=True))
    adapter = _StillPoint(tasks=["east", "west"], episode_length=3)
    with Collector({"pt": adapter}, seed=0, backend="sync") as col:
        if how == "evaluate":
            col.evaluate(spy, episodes=1)
        else:
            col.collect_episodes(spy)
    (obs0, ids0, act0), (obs1, _, act1), _ = spy.calls
    np.testing.assert_array_equal(ids0, [0, 1])
    # t = 0: the same state and the prior's belief, so the same action for east and west.
    np.testing.assert_array_equal(obs0[0], obs0[1])
    np.testing.assert_array_equal(act0[0], act0[1])
    # t = 1: the same state again (same start, same action), but the rewards differed, so the
    # belief, and with it the action, differs: no one-hot, no per-task head.
    np.testing.assert_array_equal(obs1[0, :4], obs1[1, :4])
    assert not np.array_equal(obs1[0, 4:-1], obs1[1, 4:-1])
    # An untrained encoder moves its belief a little (measured: 3e-5 here), far above float32
    # rounding of actions near 0.1 (~1e-8), and t = 0 showed them bitwise equal.
    assert np.abs(act1[0] - act1[1]).max() > 1e-6, act1


def test_a_checkpoint_holds_the_encoder_and_a_round_trip_updates_bitwise(tmp_path: Path) -> None:
    from seal.learner.checkpoint import read_checkpoint, save_checkpoint

    config = AgentConfig(**SMALL)
    agent = Agent([SPEC], config, seed=0)
    replay, _ = _collect(agent, episodes=2)
    counts = {"pt": np.array([4, 4, 4, 4])}
    agent.update(replay.sample(counts))
    agent.update_encoder(replay)
    path = save_checkpoint(tmp_path / "ckpt.pt", agent, replay, {})
    expected = agent.update(replay.sample(counts))
    expected_encoder = agent.update_encoder(replay)
    resumed = Agent([SPEC], config, seed=5)
    width = SPEC.obs_dim + config.obs_extra
    resumed_replay = MultiTaskReplay([EnvSpec("pt", width, 2, 4)], capacity=4 * 12 * 2, seed=5)
    saved = read_checkpoint(path)
    resumed.load_state_dict(saved["agent"])
    resumed_replay.load_state_dict(saved["replay"])
    assert resumed.update(resumed_replay.sample(counts)) == expected
    got_encoder = resumed.update_encoder(resumed_replay)
    assert got_encoder is not None and expected_encoder is not None
    assert got_encoder[0] == expected_encoder[0]
    assert torch.equal(got_encoder[1], expected_encoder[1])
    for a, b in zip(agent.encoders.parameters(), resumed.encoders.parameters(), strict=True):
        assert torch.equal(a, b)


TINY_RUN = [
    "protocol.epochs=5",
    "protocol.threads=1",
    "envs.pt.episode_length=10",
    "training.warmup_steps=40",
    "evaluation.interval=1",
    "evaluation.stop_when_reached=false",
    "checkpoint.interval=2",
    "logging.tensorboard=false",
]


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["sync", "async"])
def test_a_run_killed_and_resumed_writes_the_rows_of_one_uninterrupted(
    tmp_path: Path, mode: str
) -> None:
    overrides = [*TINY_RUN, f'evaluation.mode="{mode}"']
    reference = run_seed(load_protocol(PROTOCOL, overrides), 0, tmp_path / "ref").run_dir
    with pytest.raises(KeyboardInterrupt):
        run_seed(
            load_protocol(PROTOCOL, overrides), 0, tmp_path / "killed", callbacks=[CrashAfter(at=3)]
        )
    (run_dir,) = (tmp_path / "killed").glob("seed-0")
    resume_run(run_dir)
    for name in ("metrics.csv", "train.csv"):
        got, want = (pd.read_csv(d / name) for d in (run_dir, reference))
        if "wall_s" in want:
            got, want = got.drop(columns="wall_s"), want.drop(columns="wall_s")
        order = [c for c in ("phase", "epoch", "grad_steps", "env", "key", "task") if c in want]
        got, want = (
            f.sort_values(order, kind="stable").reset_index(drop=True) for f in (got, want)
        )
        pd.testing.assert_frame_equal(got, want)
    train = pd.read_csv(reference / "train.csv")
    assert {"encoder_reward", "encoder_task", "encoder_kl", "encoder_task_accuracy"} <= set(
        train["key"]
    )


def test_a_refresh_rewrites_the_stored_beliefs_with_todays_encoder() -> None:
    agent = Agent([SPEC], AgentConfig(**SMALL, encoder_refresh_interval=3), seed=0)
    replay, _ = _collect(agent, episodes=2)
    before = replay.storage["pt"]["obs"].clone()
    assert agent.refresh_beliefs(replay) == 0  # not due: no update yet
    for _ in range(3):
        agent.num_updates += 1
        agent.update_encoder(replay)
    assert agent.refresh_beliefs(replay) == 4 * 24  # every stored row: 2 whole episodes a task
    assert agent.refresh_beliefs(replay) == 0  # due again 3 updates on
    after = replay.storage["pt"]["obs"]
    # Observations and steps untouched; beliefs now the trained encoder's over each episode.
    assert torch.equal(after[..., :4], before[..., :4])
    assert torch.equal(after[..., -1], before[..., -1])
    assert not torch.equal(after[..., 4:-1], before[..., 4:-1])
    rows = _rows(replay, 2)
    with torch.no_grad():
        seq = (
            agent.encoder("pt")
            .sequence(
                torch.from_numpy(rows["next_obs"][12:24, :4][None]),
                torch.from_numpy(rows["actions"][12:24][None]),
                torch.from_numpy(rows["rewards"][12:24][None]),
            )[0]
            .numpy()
        )
    np.testing.assert_allclose(rows["obs"][12:24, 4:-1], seq[:-1], atol=1e-6)
    np.testing.assert_allclose(rows["next_obs"][12:24, 4:-1], seq[1:], atol=1e-6)
    assert agent.state_dict()["encoder_refreshed"] == 3


def test_the_old_one_hot_key_is_refused_in_a_protocol_and_read_in_a_saved_run(
    tmp_path: Path,
) -> None:
    from seal.errors import ConfigError
    from seal.protocols.loader import config_from_dict, upgrade_saved

    raw = {
        "protocol": {"name": "old", "kind": "baseline"},
        "envs": {"pt": {"adapter": "point"}},
        "agent": {"one_hot": False, "hidden": [8]},
    }
    with pytest.raises(
        ConfigError,
        match=r'agent\.one_hot no longer exists; use agent\.task_encoder .*false is "none"',
    ):
        config_from_dict(raw, "old.toml")
    # A run's own config.toml or checkpoint from before the rename reads back as it ran.
    assert config_from_dict(upgrade_saved(raw)).agent.task_encoder == "none"
    assert AgentConfig.from_saved({"one_hot": True}).task_encoder == "one_hot"
