"""Layer 3: run a policy on an adapter's tasks and return numbers (Appendix B's evaluation).

Evaluation is deterministic (the policy's mean action), one fresh episode after another per task,
and a task's episode succeeds if `info["success"]` is 1 at any step. Episodes of all tasks step
together through a `seal.learner.collection.Collector` seeded apart from training, so policy
inference is batched across tasks.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from seal.envs.base import EnvAdapter
from seal.errors import SealError

if TYPE_CHECKING:
    from seal.envs.alignment import Alignment
    from seal.learner.collection import Collector, Policy
    from seal.learner.critic_probe import CriticProbe
    from seal.learner.sac import Agent

PolicyFn = Callable[[str, np.ndarray, np.ndarray], np.ndarray]
"""(env name, raw observations [n, obs_dim], adapter task indices [n]) -> env actions [n, act_dim]."""


class AgentPolicy:
    """Calls `agent.act` on an environment's raw observations, through an alignment if there is one.

    Without `alignment` the agent sees raw observations and the adapter's task indices. With an
    `Alignment` (pad-and-fine-tune) observations become [padded state, aligned one-hot, goal],
    task ids become the aligned ids, the agent is addressed as `agent_env`, and its padded
    actions are cut back to the environment's own action size.
    """

    def __init__(
        self,
        agent: Agent,
        *,
        deterministic: bool,
        alignment: Alignment | None = None,
        agent_env: Mapping[str, str] | None = None,
        alignment_names: Mapping[str, str] | None = None,
    ) -> None:
        self.agent = agent
        self.deterministic = deterministic
        self.alignment = alignment
        self.agent_env = dict(agent_env or {})
        self.alignment_names = dict(
            alignment_names or {}
        )  # env name -> the alignment's (adapter) name
        from seal.learner.task_encoder import BeliefMemory

        self.memory = (
            None
            if getattr(agent, "encoders", None) is None
            else BeliefMemory(lambda env: agent.encoder(self.agent_env.get(env, env)), agent.device)
        )
        """SMT's task encoder state per running instance (agent.task_encoder = "smt_gru"), else
        None: the Collector steps it and hands this policy [obs | belief | step]."""
        if self.memory is not None and alignment is not None:
            raise SealError(
                'agent.task_encoder = "smt_gru" does not run through a pad-and-fine-tune alignment; use "one_hot" or "none" in this phase'
            )

    def agent_inputs(
        self, env: str, obs: np.ndarray, task_ids: np.ndarray
    ) -> tuple[str, np.ndarray, np.ndarray]:
        """(agent env name, agent observations, agent task ids) for raw `obs` of `env`."""
        if self.alignment is None:
            return (
                self.agent_env.get(env, env),
                np.asarray(obs, dtype=np.float32),
                np.asarray(task_ids),
            )
        name = self.alignment_names.get(env, env)
        aligned = self.alignment.transform_obs(name, obs, task_ids)
        ids = self.alignment.task_ids(name)[np.asarray(task_ids, dtype=np.intp)]
        return self.agent_env.get(env, env), aligned, ids

    def critic_q(
        self, env: str, obs: np.ndarray, task_ids: np.ndarray, actions: np.ndarray
    ) -> np.ndarray:
        """The lower twin critic's Q (N,) of raw `obs` and `env`'s own `actions` (a
        `seal.learner.critic_probe.Critic`)."""
        name, agent_obs, ids = self.agent_inputs(env, obs, task_ids)
        actions = np.asarray(actions, dtype=np.float32)
        width = self.agent.specs[name].act_dim
        if actions.shape[1] < width:  # pad-and-fine-tune: the env's own entries, zeros after
            actions = np.pad(actions, ((0, 0), (0, width - actions.shape[1])))
        return self.agent.q_values(name, agent_obs, actions, ids).min(axis=0)

    def critic_probe(self, gamma: float) -> CriticProbe:
        """A probe of this policy's episodes against the agent's own critic, discounted at `gamma`."""
        from seal.learner.critic_probe import CriticProbe

        return CriticProbe(self.critic_q, self, gamma)

    def __call__(self, env: str, obs: np.ndarray, task_ids: np.ndarray) -> np.ndarray:
        name, agent_obs, ids = self.agent_inputs(env, obs, task_ids)
        actions = np.asarray(self.agent.act(name, agent_obs, ids, self.deterministic))
        if self.alignment is not None:
            actions = self.alignment.unpad_action(self.alignment_names.get(env, env), actions)
        return actions


def evaluate(
    policy: Policy,
    adapters: Mapping[str, EnvAdapter],
    *,
    episodes: int,
    seed: int,
    tasks: Mapping[str, Sequence[str]] | None = None,
    collector: Collector | None = None,
    backend: str = "auto",
    draw: int | None = None,
    probe: CriticProbe | None = None,
    threshold: float | None = None,
    end_on_success: bool = False,
) -> dict[str, dict[str, dict[str, float]]]:
    """Success rate and mean return per task: {env: {task: {"success": s, "return": r}}}, and with
    a `probe` the critic's mean Q at the episodes' first states and what they earned ("q_start",
    "earned": `seal.learner.critic_probe`).

    `policy` should be deterministic. Pass a persistent `collector` (built with a seed of its
    own, ideally with `evaluation_replicas` replicas) to avoid rebuilding envs; otherwise one is
    built from `adapters`, `seed` and `tasks`, with several instances per task so episodes run
    in parallel. `draw` picks the set of episodes (see `Collector.evaluate`).

    With a `threshold`, a task stops once its verdict against it is settled (`EarlyDecision`,
    `evaluation.decide_early`): its numbers are over its episodes up to the one that settled it,
    "episodes" says how many, "decided_early" (1.0 or 0.0) whether that was fewer than `episodes`. `end_on_success`
    ends each episode at its first success (`evaluation.end_on_success`).
    """
    from seal.learner.collection import Collector, evaluation_replicas

    if episodes < 1:
        raise SealError(f"evaluation episodes must be >= 1, got {episodes}")
    own = collector is None
    if own:
        count = sum(
            len(tasks[env]) if tasks is not None and env in tasks else len(a.tasks)
            for env, a in adapters.items()
        )
        replicas = evaluation_replicas(episodes, count)
        collector = Collector(adapters, seed=seed, tasks=tasks, backend=backend, replicas=replicas)
    try:
        decide = None if threshold is None else EarlyDecision(episodes, threshold)
        raw = collector.evaluate(
            policy, episodes, draw=draw, probe=probe, decide=decide, end_on_success=end_on_success
        )
    finally:
        if own:
            collector.close()
    kept = ("q_start", "earned", *(() if threshold is None else ("episodes", "decided_early")))
    return {
        env: {
            task: {
                "success": float(v["success_rate"]),
                "return": float(v["mean_return"]),
                **{k: float(v[k]) for k in kept if k in v},
            }
            for task, v in per_task.items()
        }
        for env, per_task in raw.items()
    }


# Success rates are means of 0/1 outcomes; a mean that should equal the threshold (45/50 = 0.9)
# may come out a rounding error below it, and must still count as reaching it.
SUCCESS_TOLERANCE = 1e-9


def reaches(success: float, threshold: float) -> bool:
    """Whether a success rate counts as reaching `threshold` (the update-count metric's one rule)."""
    return success >= threshold - SUCCESS_TOLERANCE


class EarlyDecision:
    """When a task's first episodes settle whether all `episodes` of them reach `threshold`
    (`evaluation.decide_early`), by `reaches` itself.

    `needed` is the fewest successes of `episodes` that reach it (45 of 50 at 0.9): a task with
    that many has reached it whatever its other episodes do, and one with more than
    `episodes - needed` failures (6 of 50) cannot. Either way its success over its episodes so
    far, s / (s + f), gives the full evaluation's verdict: >= needed / episodes when reached, <=
    (needed - 1) / episodes when not.
    """

    def __init__(self, episodes: int, threshold: float) -> None:
        if episodes < 1:
            raise SealError(f"evaluation episodes must be >= 1, got {episodes}")
        if not 0.0 <= threshold <= 1.0:
            raise SealError(
                f"evaluation threshold must be a success rate in [0, 1], got {threshold}"
            )
        self.episodes, self.threshold = int(episodes), float(threshold)
        # reaches(episodes / episodes) holds for any threshold <= 1, so `needed` always exists.
        self.needed = next(s for s in range(self.episodes + 1) if self.reaches(s))

    def reaches(self, successes: int) -> bool:
        """Whether `successes` of all the episodes reach the threshold (`reaches`)."""
        return reaches(successes / self.episodes, self.threshold)

    def __call__(self, successes: np.ndarray, failures: np.ndarray) -> np.ndarray:
        """Per task, from its successes and failures so far: whether its verdict is settled."""
        successes, failures = np.asarray(successes), np.asarray(failures)
        return (successes >= self.needed) | (failures > self.episodes - self.needed)

    @property
    def fewest_episodes(self) -> int:
        """The fewest episodes that can settle a verdict: `needed` successes or one failure too many."""
        return max(1, min(self.needed, self.episodes - self.needed + 1))


def mean_success(results: Mapping[str, Mapping[str, Mapping[str, float]]]) -> float:
    """Mean success over every (env, task) of an `evaluate` result."""
    values = [v["success"] for per_task in results.values() for v in per_task.values()]
    return float(np.mean(values)) if values else 0.0


# ---------------------------------------------------------------- videos


_RENDER_PROBE = """
import mujoco
model = mujoco.MjModel.from_xml_string("<mujoco><worldbody><geom size='.1'/></worldbody></mujoco>")
renderer = mujoco.Renderer(model, 32, 32)
renderer.update_scene(mujoco.MjData(model))
renderer.render()
print("ok")
"""


def rendering_problem() -> str | None:
    """Why offscreen MuJoCo rendering fails here (None when it works).

    Probed in a child process: a failed GL context can print noise, leave broken state or even
    crash the process that tried it.
    """
    import subprocess

    try:
        probe = subprocess.run(
            [sys.executable, "-c", _RENDER_PROBE], capture_output=True, text=True, timeout=120
        )
    except (OSError, subprocess.SubprocessError) as exc:
        return f"the rendering probe could not run ({exc})"
    if probe.returncode == 0 and "ok" in probe.stdout:
        return None
    lines = [ln for ln in probe.stderr.strip().splitlines() if ln.strip()]
    errors = [ln for ln in lines if "Error" in ln or "error" in ln]
    return (errors or lines or [f"exit code {probe.returncode}"])[-1].strip()


def _check_rendering() -> None:
    """Raise SealError saying why offscreen MuJoCo rendering does not work here, if it does not."""
    problem = rendering_problem()
    if problem is not None:
        backend = os.environ.get("MUJOCO_GL", "")
        raise SealError(
            f"--video: offscreen MuJoCo rendering does not work on this machine (MUJOCO_GL={backend or 'unset'}: {problem}). "
            "It needs EGL with a GPU driver (MUJOCO_GL=egl) or OSMesa (apt-get install libosmesa6, then MUJOCO_GL=osmesa). "
            "Evaluation without --video works."
        )


def _mp4_writer() -> ModuleType:
    try:
        import imageio.v2 as imageio
        import imageio_ffmpeg  # noqa: F401 - imageio's MP4 backend
    except ImportError:
        raise SealError(
            "--video: writing MP4 needs imageio and imageio-ffmpeg (pip install imageio imageio-ffmpeg)"
        ) from None
    return imageio


def _enable_rgb_rendering(env: object, depth: int = 0) -> None:
    """Switch an env built without a render mode, and the MuJoCo envs it wraps, to "rgb_array".

    Adapters build envs for training (no render mode); a kitchen env renders through an inner
    robot env, so the attribute is set on every gym.Env reachable through a few attributes.
    """
    import gymnasium as gym

    if depth > 3 or not isinstance(env, gym.Env):
        return
    for target in {id(env): env, id(env.unwrapped): env.unwrapped}.values():
        with contextlib.suppress(AttributeError):
            target.render_mode = "rgb_array"
        for value in list(vars(target).values()):
            if isinstance(value, gym.Env) and value is not env:
                _enable_rgb_rendering(value, depth + 1)


def record_videos(
    policy: PolicyFn,
    adapters: Mapping[str, EnvAdapter],
    out_dir: str | Path,
    *,
    seed: int,
    tasks: Mapping[str, Sequence[str]] | None = None,
    episodes: int = 1,
    fps: int = 30,
) -> list[Path]:
    """One MP4 per (env, task, episode) of the deterministic policy, written under `out_dir`."""
    _check_rendering()
    imageio = _mp4_writer()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    for env_name, adapter in adapters.items():
        chosen = tuple(tasks[env_name]) if tasks and env_name in tasks else adapter.tasks
        for task in chosen:
            task_id = np.array([adapter.tasks.index(task)])
            env = adapter.make(task, seed)
            _enable_rgb_rendering(env)
            for episode in range(episodes):
                obs, _ = env.reset(seed=seed + episode)
                frames = []
                for _ in range(adapter.episode_length):
                    try:
                        frame = env.render()
                    except NotImplementedError:
                        frame = None
                    except Exception as exc:  # noqa: BLE001 - any renderer failure is the same to the user
                        raise SealError(
                            f"--video: adapter {adapter.name!r} (task {task!r}) failed to render: {type(exc).__name__}: {exc}"
                        ) from None
                    if frame is None:
                        raise SealError(
                            f"--video: adapter {adapter.name!r} (task {task!r}) does not render rgb_array frames"
                        )
                    frames.append(np.asarray(frame))
                    action = policy(env_name, np.asarray(obs)[None], task_id)[0]
                    obs, _, terminated, truncated, _ = env.step(action)
                    if terminated or truncated:
                        break
                path = out / f"{env_name}-{task}-{episode}.mp4"
                imageio.mimwrite(path, frames, fps=fps)
                written.append(path)
            env.close()
    return written
