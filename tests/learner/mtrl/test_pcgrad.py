"""PCGrad (agent.gradient = "pcgrad"): Algorithm 1 by hand, the seeded orders, the "mean" gradient
when nothing conflicts, the per-task decomposition on a real agent, resume and what is refused."""

from __future__ import annotations

import io
import itertools

import pytest
import torch

from seal.errors import ConfigError, SealError
from seal.learner import Agent, AgentConfig, Batch, EnvSpec
from seal.learner import update as update_module
from seal.learner.config import MTRL_ARCHITECTURES
from seal.learner.losses import actor_loss, critic_loss
from seal.learner.mtrl.pcgrad import draw_orders, pcgrad, surgery
from seal.learner.update import actor_stage, batch_shares, critic_stage, draw_noise

SPEC = EnvSpec("mw", 6, 2, 3)
SMALL = {"hidden": (16, 16), "device": "cpu"}


def _batch(n: int, seed: int, task_ids: torch.Tensor | None = None) -> Batch:
    g = torch.Generator().manual_seed(seed)
    return Batch(
        torch.randn(n, SPEC.obs_dim, generator=g),
        torch.rand(n, SPEC.act_dim, generator=g) * 2 - 1,
        torch.randn(n, generator=g),
        torch.randn(n, SPEC.obs_dim, generator=g),
        (torch.rand(n, generator=g) < 0.1).float(),
        torch.randint(0, SPEC.num_tasks, (n,), generator=g) if task_ids is None else task_ids,
    )


def _agent(gradient: str = "pcgrad", seed: int = 0, **config: object) -> Agent:
    return Agent([SPEC], AgentConfig(gradient=gradient, **{**SMALL, **config}), seed=seed)


def _params(agent: Agent) -> list[torch.Tensor]:
    return [
        p.detach().clone()
        for p in (
            *agent.actor.parameters(),
            *agent.critic.parameters(),
            *agent.critic_target.parameters(),
            *agent.log_alpha.values(),
        )
    ]


# ---------------------------------------------------------------- Algorithm 1 by hand
def test_two_conflicting_gradients_are_projected_as_algorithm_1() -> None:
    # g1 = (1, 0), g2 = (-1, 1): g1 . g2 = -1 < 0.
    #   g1^PC = g1 - (-1 / ||g2||^2 = 2) g2 = (1, 0) + 0.5 (-1, 1) = (0.5, 0.5)
    #   g2^PC = g2 - (-1 / ||g1||^2 = 1) g1 = (-1, 1) + (1, 0)      = (0, 1)
    # Each projection is on the other's own gradient, never on its surgered one.
    grads = torch.tensor([[1.0, 0.0], [-1.0, 1.0]], dtype=torch.float64)
    step, conflicts = pcgrad(grads, torch.Generator().manual_seed(0))
    assert step.tolist() == [0.5, 1.5]  # (0.5, 0.5) + (0, 1)
    assert int(conflicts) == 2  # one projection each way


def test_gradients_that_do_not_conflict_pass_unchanged() -> None:
    grads = torch.tensor([[1.0, 2.0], [3.0, -1.0], [0.0, 0.0]], dtype=torch.float64)
    # g1 . g2 = 1 >= 0; the zero row (a task without samples) neither conflicts nor turns NaN
    step, conflicts = pcgrad(grads, torch.Generator().manual_seed(0))
    assert step.tolist() == [4.0, 1.0]  # the plain sum: the "mean" gradient of the rows' shares
    assert int(conflicts) == 0
    orthogonal = torch.tensor([[1.0, 0.0], [0.0, -3.0]])
    assert pcgrad(orthogonal, torch.Generator())[0].tolist() == [1.0, -3.0]  # dot 0: no projection


def test_three_tasks_in_a_given_order() -> None:
    # g1 = (1, 0), g2 = (-1, 1), g3 = (-1, -2); ||g1||^2 = 1, ||g2||^2 = 2, ||g3||^2 = 5.
    # Task 1 visits 2 then 3: (1, 0) -> + 0.5 g2 = (0.5, 0.5); . g3 = -1.5 -> + 0.3 g3 = (0.2, -0.1)
    # Task 2 visits 1 then 3: (-1, 1) -> + g1 = (0, 1); . g3 = -2 -> + 0.4 g3 = (-0.4, 0.2)
    # Task 3 visits 1 then 2: (-1, -2) -> + g1 = (0, -2); . g2 = -2 -> + g2 = (-1, -1)
    grads = torch.tensor([[1.0, 0.0], [-1.0, 1.0], [-1.0, -2.0]], dtype=torch.float64)
    step, conflicts = surgery(grads, torch.tensor([[1, 2], [0, 2], [0, 1]]))
    torch.testing.assert_close(step, torch.tensor([-1.2, -0.9], dtype=torch.float64))
    assert int(conflicts) == 6
    # Task 1 visits 3 then 2 instead: (1, 0) -> + 0.2 g3 = (0.8, -0.4); . g2 = -1.2 -> + 0.6 g2
    # = (0.2, 0.2): the order matters.
    step, conflicts = surgery(grads, torch.tensor([[2, 1], [0, 2], [0, 1]]))
    torch.testing.assert_close(step, torch.tensor([-1.2, -0.6], dtype=torch.float64))
    assert int(conflicts) == 6


def test_the_order_is_seeded_and_drawn_for_each_task() -> None:
    grads = torch.tensor([[1.0, 0.0], [-1.0, 1.0], [-1.0, -2.0]], dtype=torch.float64)
    first = pcgrad(grads, torch.Generator().manual_seed(7))
    again = pcgrad(grads, torch.Generator().manual_seed(7))
    assert torch.equal(first[0], again[0]) and torch.equal(first[1], again[1])
    results = {
        tuple(pcgrad(grads, torch.Generator().manual_seed(s))[0].tolist()) for s in range(20)
    }
    assert len(results) > 1  # the order-dependent case above: two seeds, two results
    # Each row is an order of the other tasks, each task's drawn apart (the paper's Algorithm 1),
    # so all 2 x 2 x 2 combinations of three tasks' orders come up.
    g = torch.Generator().manual_seed(0)
    seen = set()
    for _ in range(200):
        orders = draw_orders(3, g)
        assert orders.shape == (3, 2)
        for i, row in enumerate(orders.tolist()):
            assert sorted(row) == [t for t in range(3) if t != i]
        seen.add(tuple(map(tuple, orders.tolist())))
    assert len(seen) == 8


# ---------------------------------------------------------------- on a real agent
def test_per_task_parameters_are_the_heads() -> None:
    agent = _agent()
    for net, slots in ((agent.actor, agent.actor_slots), (agent.critic, agent.critic_slots)):
        components = net.components()
        params = slots.parameters_of(["mw"])
        flags = slots.per_task_of(["mw"])
        per_task = {id(p) for p, f in zip(params, flags, strict=True) if f}
        shared = {id(p) for p, f in zip(params, flags, strict=True) if not f}
        assert per_task == {id(p) for p in components["head.mw"]}
        assert shared == {id(p) for p in components["trunk"]}


def test_no_conflict_gives_the_mean_gradient(monkeypatch: pytest.MonkeyPatch) -> None:
    # Surgery forced off (each task's row kept as it is): the critic's and the actor's gradients,
    # clipped (max_grad_norm 1), and three whole updates are those of gradient = "mean".
    def no_conflict(grads: torch.Tensor, generator: torch.Generator) -> tuple[torch.Tensor, ...]:
        return grads.sum(0), torch.zeros((), dtype=torch.int64)

    monkeypatch.setattr(update_module, "pcgrad", no_conflict)
    mean, surgered = _agent("mean"), _agent("pcgrad")
    assert surgered.config.max_grad_norm == 1.0
    for agent in (mean, surgered):
        agent.update({"mw": _batch(30, 0)})  # Adam states, and a second critic to differ from
    batch = _batch(30, 1)
    stage_grads = []
    for agent in (mean, surgered):
        inputs = agent.inputs({"mw": batch})
        noise, weights = draw_noise(agent, inputs), batch_shares(inputs)
        critic = critic_stage(agent, ["mw"], inputs, noise, weights)
        actor = actor_stage(agent, ["mw"], inputs, noise, weights)
        stage_grads.append((critic.grads, actor.grads, actor.alpha_grads))
    for ours, theirs in zip(*stage_grads, strict=True):
        assert len(ours) == len(theirs)
        for a, b in zip(ours, theirs, strict=True):
            torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-7)
    for seed in (1, 2, 3):
        logs = [agent.update({"mw": _batch(30, seed)}) for agent in (mean, surgered)]
        assert logs[1].pop("charts/mw/pcgrad_conflicts/critic") == 0.0
        assert logs[1].pop("charts/mw/pcgrad_conflicts/actor") == 0.0
        assert logs[0] == pytest.approx(logs[1], rel=1e-5, abs=1e-6)
    for a, b in zip(_params(mean), _params(surgered), strict=True):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)


def test_one_task_in_the_batch_gives_the_mean_update() -> None:
    # The real surgery: the other tasks' rows are zero, so nothing conflicts.
    mean, surgered = _agent("mean"), _agent("pcgrad")
    for seed in range(3):
        batch = _batch(20, seed, task_ids=torch.full((20,), 1))
        logs = [agent.update({"mw": batch}) for agent in (mean, surgered)]
        assert logs[1].pop("charts/mw/pcgrad_conflicts/critic") == 0.0
        assert logs[1].pop("charts/mw/pcgrad_conflicts/actor") == 0.0
        assert logs[0] == pytest.approx(logs[1], rel=1e-5, abs=1e-6)
    for a, b in zip(_params(mean), _params(surgered), strict=True):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)


def test_the_update_is_pcgrad_of_each_tasks_share_computed_apart() -> None:
    # Each task's row computed directly: the "mean" loss of its samples alone times n_t / N, on
    # the trunk; the stage's trunk gradient is pcgrad of those rows with the agent's generator,
    # its heads' the "mean" gradient. Clipping off, so the gradients are compared as they are.
    agent = _agent(max_grad_norm=0.0)
    agent.update({"mw": _batch(30, 0)})
    batch = _batch(30, 1)
    assert set(batch.task_ids.tolist()) == {0, 1, 2}
    inputs = agent.inputs({"mw": batch})
    noise, weights = draw_noise(agent, inputs), batch_shares(inputs)
    env, ids, n = inputs["mw"], batch.task_ids, batch.obs.shape[0]

    def critic(rows: torch.Tensor) -> torch.Tensor:
        sub = Batch(*(x[rows] for x in batch))
        terms = critic_loss(
            agent.qf("mw", sub.task_ids),
            agent.qf_target("mw", sub.task_ids),
            agent.policy("mw", sub.task_ids),
            sub,
            env.obs[rows],
            env.next_obs[rows],
            env.alpha,
            noise["mw"].critic[rows],
            agent.config.gamma,
        )
        return 0.5 * (terms.qf1_loss + terms.qf2_loss)

    def actor(rows: torch.Tensor) -> torch.Tensor:
        loss, _ = actor_loss(
            agent.policy("mw", ids[rows]),
            agent.qf("mw", ids[rows]),
            env.obs[rows],
            ids[rows],
            env.alpha,
            noise["mw"].actor[rows],
        )
        return loss

    generator = agent.pcgrad_generators["mw"]
    for stage, net, loss_of, slots in (
        (critic_stage, agent.critic, critic, agent.critic_slots),
        (actor_stage, agent.actor, actor, agent.actor_slots),
    ):
        trunk, heads = net.components()["trunk"], net.components()["head.mw"]
        rows = []
        for t in range(SPEC.num_tasks):
            mask = ids == t
            share = loss_of(mask) * (mask.sum() / n)
            rows.append(torch.cat([g.flatten() for g in torch.autograd.grad(share, trunk)]))
        everything = torch.ones(n, dtype=torch.bool)
        expected_heads = torch.autograd.grad(loss_of(everything), heads)
        same_orders = torch.Generator().set_state(generator.get_state())
        expected_trunk, conflicts = pcgrad(torch.stack(rows), same_orders)
        out = stage(agent, ["mw"], inputs, noise, weights)
        assert int(out.conflicts) > 0  # the tasks do conflict here
        assert torch.equal(out.conflicts, conflicts)
        grads = dict(zip(map(id, slots.parameters_of(["mw"])), out.grads, strict=True))
        got_trunk = torch.cat([grads[id(p)].flatten() for p in trunk])
        torch.testing.assert_close(got_trunk, expected_trunk, rtol=1e-5, atol=1e-7)
        for p, expected in zip(heads, expected_heads, strict=True):
            torch.testing.assert_close(grads[id(p)], expected, rtol=1e-5, atol=1e-7)
        if stage is critic_stage:
            slots.step(["mw"], out.grads, agent.adam_cache)  # the actor's against this critic


def test_resume_draws_the_same_orders() -> None:
    original = _agent(seed=0)
    for seed in range(2):
        original.update({"mw": _batch(30, seed)})
    buffer = io.BytesIO()
    torch.save(original.state_dict(), buffer)
    buffer.seek(0)
    state = torch.load(buffer, weights_only=False)
    assert "pcgrad/mw" in state["rng"]
    resumed = _agent(seed=1)  # other weights and streams: everything comes from the state
    resumed.load_state_dict(state)
    assert torch.equal(
        resumed.pcgrad_generators["mw"].get_state(), original.pcgrad_generators["mw"].get_state()
    )
    for seed in (2, 3):
        logs = [agent.update({"mw": _batch(30, seed)}) for agent in (original, resumed)]
        assert logs[0] == logs[1]
    for a, b in zip(_params(original), _params(resumed), strict=True):
        assert torch.equal(a, b)
    # The saved orders matter: the same state with another "pcgrad" stream ends elsewhere.
    state["rng"]["pcgrad/mw"] = torch.Generator().manual_seed(12345).get_state()
    other = _agent(seed=0)
    other.load_state_dict(state)
    for seed in (2, 3):
        assert other.update({"mw": _batch(30, seed)})["charts/mw/pcgrad_conflicts/critic"] > 0
    pairs = zip(_params(original), _params(other), strict=True)
    assert any(not torch.equal(a, b) for a, b in pairs)


def test_mean_agents_save_no_pcgrad_stream() -> None:
    agent = _agent("mean")
    assert agent.pcgrad_generators == {}
    assert not any(k.startswith("pcgrad/") for k in agent.state_dict()["rng"])
    assert not any("pcgrad" in k for k in agent.update({"mw": _batch(12, 0)}))


@pytest.mark.parametrize(
    ("shared_update", "critic_sharing"),
    list(itertools.product(("weighted", "sequential", "per_env"), ("per_env", "shared"))),
)
def test_a_one_env_seal_agent_takes_every_shared_update(
    shared_update: str, critic_sharing: str
) -> None:
    config = AgentConfig(
        architecture="seal",
        gradient="pcgrad",
        shared_update=shared_update,
        critic_sharing=critic_sharing,
        translator_hidden=(8,),
        latent_dim=8,
        trunk_hidden=(8,),
        critic_hidden=(8,),
        device="cpu",
    )
    agent = Agent([SPEC], config, seed=0)
    # shared: the translator and the trunk; per task: the heads (per_env: the critic's own head)
    for net, slots in ((agent.actor, agent.actor_slots), (agent.critic, agent.critic_slots)):
        params, flags = slots.parameters_of(["mw"]), slots.per_task_of(["mw"])
        per_task = [p for p, f in zip(params, flags, strict=True) if f]
        inner = net.nets["mw"] if critic_sharing == "per_env" and net is agent.critic else net
        assert per_task == inner.components()["head.mw"]
        assert len(per_task) < len(params)
    logs = agent.update({"mw": _batch(12, 0)})
    assert "charts/mw/pcgrad_conflicts/actor" in logs


@pytest.mark.parametrize("architecture", MTRL_ARCHITECTURES)
def test_a_task_conditioned_network_keeps_its_head_component_per_task(architecture: str) -> None:
    tiny = {"soft_width": 8, "soft_embedding": 8, "care_embedding": 8, "care_encoder_hidden": (8,)}
    agent = _agent(architecture=architecture, **tiny)
    for net, slots in ((agent.actor, agent.actor_slots), (agent.critic, agent.critic_slots)):
        params, flags = slots.parameters_of(["mw"]), slots.per_task_of(["mw"])
        per_task = {id(p) for p, f in zip(params, flags, strict=True) if f}
        assert per_task == {id(p) for p in net.components()["head.mw"]}
    logs = agent.update({"mw": _batch(12, 0)})
    assert "charts/mw/pcgrad_conflicts/critic" in logs


# ---------------------------------------------------------------- refused
def test_refused_combinations_in_one_line() -> None:
    with pytest.raises(ConfigError, match='gradient = "pcgrad" runs eager') as compiled:
        _agent(compile=True)
    two = [SPEC, EnvSpec("fk", 4, 1, 2)]
    config = AgentConfig(architecture="seal", gradient="pcgrad", device="cpu")
    with pytest.raises(SealError, match="tasks of one environment, got 2 \\(mw, fk\\)") as several:
        Agent(two, config, seed=0)
    for error in (compiled, several):
        assert "\n" not in str(error.value)
