"""Meta-World v3 as a SEAL adapter: goal-observable tasks, seeded goal sampling, 500-step episodes.

Each env is built through metaworld's own gymnasium registration ("Meta-World/goal_observable")
and holds the task's 50 benchmark goals (`metaworld.MT1(task, seed=goal_seed)`, drawn as the
MT10 benchmark draws them). The goal set belongs to the adapter, not to the env seed, so training
and evaluation envs (which collectors seed apart) see the same 50 goals, as in Meta-World's MT10
protocol. Every reset picks one of them with a generator seeded by `make(task, seed)` or
`reset(seed=...)`, so runs are reproducible although upstream `reset(seed=...)` ignores its seed.

Observation (39 floats, upstream order):

| slice   | content                                                        | layout  |
|---------|----------------------------------------------------------------|---------|
| [0:3]   | hand (end-effector) position                                   | robot   |
| [3]     | gripper opening, normalised to [0, 1]                          | robot   |
| [4:18]  | object 1 position + quaternion, object 2 (zeros when absent)    | objects |
| [18:22] | hand position and gripper opening of the previous frame        | robot   |
| [22:36] | objects of the previous frame                                  | objects |
| [36:39] | goal position                                                  | goal    |

The alignment's state block is `obs_layout.state`, robot then objects: [0:4, 18:22, 4:18, 22:36].
"""

from __future__ import annotations

import functools
import warnings
from collections.abc import Callable, Sequence
from typing import Any, ClassVar

import gymnasium as gym
import metaworld  # importing it registers the "Meta-World/..." gymnasium ids
import numpy as np
from metaworld.env_dict import ALL_V3_ENVIRONMENTS, MT10_V3, MT50_V3

from seal.envs.base import EnvAdapter, ObsLayout
from seal.errors import SealError, UnknownNameError

# Upstream SawyerXYZEnv.max_path_length: stepping past it raises, and rewards are tuned for it.
MAX_EPISODE_LENGTH = 500

_LAYOUT = ObsLayout.from_slices(
    robot=[slice(0, 4), slice(18, 22)],
    objects=[slice(4, 18), slice(22, 36)],
    goal=[slice(36, 39)],
)


@functools.lru_cache(maxsize=256)
def _benchmark_goals(task: str, goal_seed: int) -> tuple[metaworld.Task, ...]:
    """The task's 50 benchmark goals (metaworld `Task`s); cached, as drawing them costs ~0.5 s."""
    return tuple(metaworld.MT1(task, seed=goal_seed).train_tasks)


class MetaWorldTaskEnv(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """One Meta-World task: a seeded choice among its benchmark goals at each reset, float success.

    The only wrapper around the raw env (no TimeLimit, checker or checkpoint layers): truncation
    comes from upstream's own `max_path_length`, which is set to the episode length. It records
    its constructor arguments, so `env.spec.make()` rebuilds it (gymnasium's `check_env` does).
    """

    def __init__(
        self, env: gym.Env, goals: tuple[metaworld.Task, ...], seed: int, episode_length: int
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(
            self, goals=goals, seed=seed, episode_length=episode_length
        )
        raw = env.unwrapped
        super().__init__(raw)
        self._raw = raw
        self._goals = goals
        self._raw.max_path_length = episode_length
        # Upstream sets observation_space while the goal is still hidden (goal bounds 0); the
        # cached sawyer_observation_space is recomputed with the goal observable.
        self.observation_space = raw.sawyer_observation_space
        self.action_space = raw.action_space
        self._seed(seed)

    def _seed(self, seed: int) -> None:
        self._goal_rng = np.random.default_rng(seed)
        self._raw.seed(seed)  # also seeds the action and observation spaces

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start an episode on a goal drawn from the seeded generator; `seed` restarts that generator."""
        if seed is not None:
            self._seed(seed)
        self._raw.set_task(self._goals[int(self._goal_rng.integers(len(self._goals)))])
        return self._raw.reset()

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Upstream step with `info["success"]` as a float 0.0/1.0 (upstream mixes bool and float)."""
        obs, reward, terminated, truncated, info = self._raw.step(action)
        info["success"] = float(info["success"])
        return obs, float(reward), terminated, truncated, info


class MetaWorldAdapter(EnvAdapter):
    """Meta-World v3 tasks (names keep "-v3"), goal observable; task sets "mt3", "mt10", "mt50".

    Without `tasks`, the adapter holds MT10, the set the SEAL paper uses.
    """

    name: ClassVar[str] = "metaworld"
    all_tasks: ClassVar[tuple[str, ...]] = tuple(ALL_V3_ENVIRONMENTS)
    task_sets: ClassVar[dict[str, tuple[str, ...]]] = {
        "mt3": ("reach-v3", "push-v3", "pick-place-v3"),
        "mt10": tuple(MT10_V3),
        "mt50": tuple(MT50_V3),
    }
    default_episode_length: ClassVar[int] = MAX_EPISODE_LENGTH

    def __init__(
        self,
        tasks: Sequence[str] | str | None = None,
        episode_length: int | None = None,
        goal_seed: int = 0,
        **options: Any,
    ) -> None:
        """`goal_seed` fixes the 50 benchmark goals of every task (Meta-World's benchmark seed)."""
        super().__init__(tasks=tasks, episode_length=episode_length, **options)
        self.goal_seed = int(goal_seed)
        if self.episode_length > MAX_EPISODE_LENGTH:
            raise SealError(
                f"adapter 'metaworld': episode_length {self.episode_length} exceeds upstream's "
                f"max_path_length; valid: 1..{MAX_EPISODE_LENGTH}"
            )

    @classmethod
    def resolve_tasks(cls, tasks: Sequence[str] | str | None) -> tuple[str, ...]:
        """Like EnvAdapter.resolve_tasks, but no tasks means MT10 rather than all 50."""
        return super().resolve_tasks("mt10" if tasks is None else tasks)

    @property
    def observation_space(self) -> gym.spaces.Box:
        # Bounds differ between tasks (hand and goal spaces); the shared space is unbounded.
        return gym.spaces.Box(-np.inf, np.inf, shape=(39,), dtype=np.float64)

    @property
    def action_space(self) -> gym.spaces.Box:
        # End-effector xyz displacement and gripper effort, as upstream.
        return gym.spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)

    @property
    def obs_layout(self) -> ObsLayout:
        return _LAYOUT

    def make(self, task: str, seed: int) -> gym.Env:
        """The goal-observable env of `task`; `seed` fixes which of the 50 goals each reset takes."""
        self._check_task(task)
        env = gym.make(
            "Meta-World/goal_observable", env_name=task, seed=seed, disable_env_checker=True
        )
        goals = _benchmark_goals(task, self.goal_seed)
        return MetaWorldTaskEnv(env, goals, seed, self.episode_length)

    def expert(self, task: str) -> Callable[[np.ndarray], np.ndarray] | None:
        """metaworld's scripted policy for `task` (`metaworld.policies.ENV_POLICY_MAP`), or None."""
        from metaworld.policies import ENV_POLICY_MAP

        self._check_task(task)
        if task not in ENV_POLICY_MAP:
            return None
        get_action = ENV_POLICY_MAP[task]().get_action

        def act(obs: np.ndarray) -> np.ndarray:
            with warnings.catch_warnings():
                # The experts' gains trip metaworld's "constant(s) may be too high" warning; the
                # env clips the xyz action to [-1, 1] anyway.
                warnings.simplefilter("ignore", UserWarning)
                return np.clip(get_action(obs), -1.0, 1.0).astype(np.float32)

        return act

    def semantic_check(self, task: str, seed: int = 0, episodes: int = 10) -> dict[str, Any]:
        """Run metaworld's scripted expert for `task` through this adapter; ok when it succeeds >= 80%.

        An episode counts as a success when `info["success"]` is 1 at any step, as in
        metaworld's own evaluation; the episode stops there to save time.
        """
        act = self.expert(task)
        if act is None:
            return {"ok": True, "semantic_check": f"metaworld ships no scripted expert for {task}"}
        env = self.make(task, seed)
        successes, steps_to_success = 0, []
        for _ in range(episodes):
            obs, _ = env.reset()  # continues the generator seeded by make: a new goal each time
            for t in range(self.episode_length):
                obs, _, terminated, truncated, info = env.step(act(obs))
                if info["success"] == 1.0:
                    successes += 1
                    steps_to_success.append(t + 1)
                    break
                if terminated or truncated:
                    break
        env.close()
        rate = successes / episodes
        return {
            "ok": rate >= 0.8,
            "scripted_success": rate,
            "episodes": episodes,
            "mean_steps_to_success": float(np.mean(steps_to_success)) if steps_to_success else None,
        }

    def _check_task(self, task: str) -> None:
        if task not in self.all_tasks:
            raise UnknownNameError("metaworld task", task, list(self.all_tasks))
