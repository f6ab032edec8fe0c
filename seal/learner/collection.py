"""Vectorised experience collection: every (environment, task) instance steps together.

A `Collector` owns one gymnasium env per (environment, task) instance, built by the adapter with a
seed derived from (collector seed, environment name, task name). Each call to `collect_episodes`
runs one full episode on every active instance; at every step it makes one policy call per
environment over all of that environment's running instances (batched inference), steps them
all, and hands the transitions to a sink such as `MultiTaskReplay.add`.

Backends (same seed -> identical transitions on every backend; `tests/learner/test_collection.py`):

- ``sync``: one process steps every env in turn.
- ``subproc-batched``: `num_workers` processes, each stepping a round-robin share of all
  instances (of every environment) per message (one pipe round trip per worker per step).
- ``inline-batched``: like ``subproc-batched``, but the main process steps one share itself
  (`num_workers - 1` worker processes), so on 2 cores two processes are busy instead of three.
- ``gym-async``: the reference design, gymnasium's `AsyncVectorEnv` (one process per env
  instance) per environment; it can only step all instances of an environment together.
- ``auto``: ``inline-batched`` with one share per CPU when there are >= 2 CPUs and splitting a
  step of all instances over the shares saves >= 1 ms of CPU (each env's step cost probed on a
  throwaway env at start), else ``sync``. `seal bench` (collect_mt10_speedup / collect_fk_speedup) measures every
  backend against a plain loop: on this 2-core machine inline-batched was the fastest (MT10 and
  kitchens), the one-process-per-env reference the slowest of the parallel designs.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import signal
import time
import traceback
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
from typing import TYPE_CHECKING, Protocol, cast

import gymnasium as gym
import numpy as np

from seal.envs.base import EnvAdapter
from seal.errors import SealError, UnknownNameError
from seal.learner.critic_probe import CriticProbe
from seal.learner.evaluation_waves import Decide, Played, evaluate_in_waves

if TYPE_CHECKING:
    from seal.learner.task_encoder import BeliefMemory

BACKENDS = ("auto", "sync", "subproc-batched", "inline-batched", "gym-async")
# inline-batched: how long the main process spins for a worker's answer (and a worker for the next
# message) before sleeping on the pipe; waking a sleeping process costs ~0.1-0.5 ms here.
INLINE_SPIN_S = 0.002


class Policy(Protocol):
    """Maps one environment's running instances to actions: (env, obs [n, obs_dim], task_ids [n]) -> [n, act_dim]."""

    def __call__(self, env: str, obs: np.ndarray, task_ids: np.ndarray) -> np.ndarray: ...


class TransitionSink(Protocol):
    """Receives one step of one environment's running instances, e.g. `MultiTaskReplay.add`."""

    def __call__(
        self,
        env: str,
        task_ids: np.ndarray,
        obs: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        next_obs: np.ndarray,
        terminations: np.ndarray,
    ) -> object: ...


def instance_seed(seed: int, env: str, task: str, replica: int = 0) -> int:
    """The seed of the (env, task) instance: stable across processes, backends and task subsets.

    Replica 0 is a Collector's one instance per task; replicas >= 1 are evaluation copies.
    """
    # crc32, not hash(): Python's str hash is salted per process.
    key: tuple[int, ...] = (zlib.crc32(env.encode()), zlib.crc32(task.encode()))
    if replica:
        key = (*key, int(replica))
    return int(np.random.SeedSequence(seed, spawn_key=key).generate_state(1, np.uint32)[0])


# evaluation_replicas: at most this many evaluation instances in all (memory: a Meta-World env
# holds ~25 MB, a kitchen env ~100 MB), and about this many per worker process/share.
EVAL_MAX_INSTANCES = 64
EVAL_INSTANCES_PER_WORKER = 4


def evaluation_replicas(episodes: int, tasks: int, workers: int | None = None) -> int:
    """Env instances per task for evaluating `episodes` episodes of `tasks` tasks at once."""
    workers = _cpu_count() if workers is None else max(1, int(workers))
    tasks = max(1, int(tasks))
    # Replicas: enough for ~4 instances per worker (parallel steps, bigger policy batches), never
    # more than `episodes` nor 64 instances in all; then as few rounds as that allows, evened out.
    most = min(episodes, max(1, EVAL_MAX_INSTANCES // tasks))
    wanted = min(most, max(1, -(-EVAL_INSTANCES_PER_WORKER * workers // tasks)))
    rounds = -(-episodes // wanted)
    return max(1, -(-episodes // rounds))


@dataclass
class EpisodeStats:
    """Per-instance results of one `collect_episodes` call; arrays are indexed like `tasks[env]`.

    Inactive instances have `active == False`, return 0, success False and length 0.
    """

    tasks: dict[str, tuple[str, ...]]
    active: dict[str, np.ndarray]
    returns: dict[str, np.ndarray]
    successes: dict[str, np.ndarray]
    lengths: dict[str, np.ndarray]

    @property
    def env_steps(self) -> int:
        """Env steps taken in these episodes, over all instances."""
        return int(sum(int(v.sum()) for v in self.lengths.values()))

    def per_task(self) -> dict[tuple[str, str], dict[str, float]]:
        """{(env, task): {"return", "success", "length"}} for the active instances."""
        out: dict[tuple[str, str], dict[str, float]] = {}
        for env, tasks in self.tasks.items():
            for i, task in enumerate(tasks):
                if self.active[env][i]:
                    out[(env, task)] = {
                        "return": float(self.returns[env][i]),
                        "success": float(self.successes[env][i]),
                        "length": float(self.lengths[env][i]),
                    }
        return out


@dataclass(frozen=True)
class _Instance:
    env: str
    task: str
    seed: int
    adapter: EnvAdapter = field(repr=False)

    def make(self) -> gym.Env:
        return self.adapter.make(self.task, self.seed)


# One environment's step results for its running instances, in the order they were asked for:
# (next_obs [k, obs_dim], rewards [k], terminated [k], truncated [k], success [k]).
StepArrays = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
# Per environment: which of its instances (indices into Collector.tasks[env]) to address.
Selection = dict[str, np.ndarray]
# Per environment: reset seeds of the selected instances (same order as the Selection).
Seeds = dict[str, np.ndarray]
# The messages between the main process and a share of the instances (a worker's pipe or
# _InlineConn): (command, payload) one way, ("ok", answer) or ("error", traceback) back.
# env -> (the share's local indices to reset, their reset seeds or None)
ResetRequest = dict[str, tuple[np.ndarray, np.ndarray | None]]
StepRequest = dict[str, tuple[np.ndarray, np.ndarray]]  # env -> (local indices, their actions)
Request = tuple[str, ResetRequest | StepRequest | None]  # "reset", "step", "close" or "ready"
Answer = dict[str, np.ndarray] | dict[str, StepArrays] | None  # observations, steps, nothing
Reply = tuple[str, Answer | str]


class _EnvGroup:
    """The live envs of some instances of one environment, stepped in one process."""

    def __init__(self, instances: Sequence[_Instance]) -> None:
        self.instances = list(instances)
        self.envs = [inst.make() for inst in instances]
        self.first = [True] * len(instances)

    def reset(
        self, local: Sequence[int] | np.ndarray, seeds: Sequence[int] | np.ndarray | None = None
    ) -> np.ndarray:
        out = []
        for n, j in enumerate(local):
            # The first reset repeats the instance seed (make() already used it); later resets
            # pass None, so each episode continues the env's own RNG stream. Explicit `seeds`
            # (evaluation episodes) override both.
            if seeds is not None:
                seed: int | None = int(seeds[n])
            else:
                seed = self.instances[j].seed if self.first[j] else None
            obs, _ = self.envs[j].reset(seed=seed)
            self.first[j] = False
            out.append(obs)
        return np.stack(out)

    def step(self, local: Sequence[int] | np.ndarray, actions: np.ndarray) -> StepArrays:
        k = len(local)
        rew, term, trunc, succ = np.empty(k), np.empty(k, bool), np.empty(k, bool), np.empty(k)
        obs = []
        for n, (j, a) in enumerate(zip(local, actions, strict=True)):
            o, rew[n], term[n], trunc[n], info = self.envs[j].step(a)
            succ[n] = info["success"]
            obs.append(o)
        return np.stack(obs), rew, term, trunc, succ

    def close(self) -> None:
        for env in self.envs:
            env.close()
        self.envs = []


# ---------------------------------------------------------------- backends
class _Backend:
    """Steps the instances of several environments; `step_async` then `step_wait`, as gymnasium."""

    def reset(self, sel: Selection, seeds: Seeds | None = None) -> dict[str, np.ndarray]:
        """Reset the selected instances, with `seeds[env]` (one per selected instance) if given."""
        raise NotImplementedError

    def step_async(self, sel: Selection, actions: dict[str, np.ndarray]) -> None:
        raise NotImplementedError

    def step_wait(self) -> dict[str, StepArrays]:
        raise NotImplementedError

    def close(self) -> None:
        pass


class _SyncBackend(_Backend):
    def __init__(self, groups: Mapping[str, Sequence[_Instance]]) -> None:
        self.groups = {env: _EnvGroup(insts) for env, insts in groups.items()}
        self._pending: tuple[Selection, dict[str, np.ndarray]] | None = None

    def reset(self, sel: Selection, seeds: Seeds | None = None) -> dict[str, np.ndarray]:
        return {
            env: self.groups[env].reset(idx, None if seeds is None else seeds[env])
            for env, idx in sel.items()
        }

    def step_async(self, sel: Selection, actions: dict[str, np.ndarray]) -> None:
        self._pending = (sel, actions)

    def step_wait(self) -> dict[str, StepArrays]:
        assert self._pending is not None
        sel, actions = self._pending
        self._pending = None
        return {env: self.groups[env].step(idx, actions[env]) for env, idx in sel.items()}

    def close(self) -> None:
        for group in self.groups.values():
            group.close()


def _handle(
    live: dict[str, _EnvGroup], cmd: str, payload: ResetRequest | StepRequest | None
) -> Answer:
    """Execute one reset/step/close message on the envs of one worker (or of the main process)."""
    if cmd == "reset":
        resets = cast("ResetRequest", payload)
        return {env: live[env].reset(local, seeds) for env, (local, seeds) in resets.items()}
    if cmd == "step":
        steps = cast("StepRequest", payload)
        return {env: live[env].step(local, acts) for env, (local, acts) in steps.items()}
    if cmd == "close":
        for group in live.values():
            group.close()
        return None
    raise ValueError(f"unknown command {cmd!r}")


def exit_with_parent(parent: int) -> None:
    """Have the kernel kill this process when its parent dies (Linux), so a kill -9 leaves no orphan.

    Every spawned worker calls it, at every level: a process killed this way never runs
    multiprocessing's exit handler, which is what would have stopped its own daemonic workers.
    """
    with contextlib.suppress(OSError, AttributeError):
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    if os.getppid() != parent:  # the parent died before prctl took effect
        os._exit(1)


def _worker_main(
    conn: Connection, groups: dict[str, list[_Instance]], spin_s: float = 0.0, parent: int = 0
) -> None:
    """A worker process: owns a batch of envs of each environment and answers reset/step messages.

    With `spin_s` > 0 it polls for the next message that long before sleeping on the pipe.
    `parent`: the pid of the process that started it (`exit_with_parent`); 0 = not a process.
    """
    if parent:
        exit_with_parent(parent)
    try:
        live = {env: _EnvGroup(insts) for env, insts in groups.items()}
        conn.send(("ok", None))
    except BaseException:  # noqa: BLE001 - reported to the parent, which raises it
        conn.send(("error", traceback.format_exc()))
        return
    while True:
        if spin_s:
            deadline = time.perf_counter() + spin_s
            while not conn.poll(0) and time.perf_counter() < deadline:
                pass
        try:
            cmd, payload = conn.recv()
        except EOFError:
            return
        try:
            conn.send(("ok", _handle(live, cmd, payload)))
        except BaseException:  # noqa: BLE001
            conn.send(("error", traceback.format_exc()))
        if cmd == "close":
            return


class _InlineConn:
    """The main process's own share of envs, behind the same send/recv calls as a worker's pipe.

    `send` only stores the message; `recv` executes it. The backend sends to every worker before
    it receives from any, so this share steps while the worker processes step theirs.
    """

    def __init__(self, groups: dict[str, list[_Instance]]) -> None:
        self.live = {env: _EnvGroup(insts) for env, insts in groups.items()}
        self._message: Request | None = ("ready", None)

    def send(self, message: Request) -> None:
        self._message = message

    def recv(self) -> Reply:
        assert self._message is not None
        cmd, payload = self._message
        self._message = None
        return ("ok", None if cmd == "ready" else _handle(self.live, cmd, payload))

    def poll(self, timeout: float = 0.0) -> bool:
        return True

    def close(self) -> None:
        pass


def _deal(groups: Mapping[str, Sequence[_Instance]], shares: int) -> dict[str, np.ndarray]:
    """Per env, the share of each of its instances: round-robin over all instances in env order."""
    owner: dict[str, np.ndarray] = {}
    k = 0
    for env, insts in groups.items():
        owner[env] = (k + np.arange(len(insts))) % shares
        k += len(insts)
    return owner


class _SubprocBatchedBackend(_Backend):
    """`num_workers` shares, dealt round-robin over all instances in environment order (instance
    k of the concatenated lists lives in share k % num_workers), so two envs of one task each
    still step in parallel and unequal environments spread evenly.

    Each share is a worker process, except share 0 with `inline=True`, which the main process
    steps itself between sending the workers their actions and reading their answers. One
    message per worker per step carries the actions of all its running instances (of every
    environment) and one answer returns their results as arrays, so the pipe cost is paid per
    worker, not per env.
    """

    def __init__(
        self,
        groups: Mapping[str, Sequence[_Instance]],
        num_workers: int,
        start_method: str,
        inline: bool = False,
    ) -> None:
        ctx = mp.get_context(start_method)
        total = sum(len(v) for v in groups.values())
        self.num_workers = w_count = max(1, min(num_workers, total))
        self.inline = inline
        # Per env: each instance's share, and its index within that share's group of the env.
        self._owner = _deal(groups, w_count)
        self._local: dict[str, np.ndarray] = {}
        shares: list[dict[str, list[_Instance]]] = [{} for _ in range(w_count)]
        for env, insts in groups.items():
            local = []
            for inst, w in zip(insts, self._owner[env], strict=True):
                local.append(len(shares[w].setdefault(env, [])))
                shares[w][env].append(inst)
            self._local[env] = np.array(local, dtype=np.int64)
        self.conns: list[Connection | _InlineConn] = []
        self.procs: list[BaseProcess | None] = []
        # Workers first: they build their envs while the main process builds its own share.
        for w in range(1 if inline else 0, w_count):
            parent, child = ctx.Pipe()
            # Inline: main + workers are as many processes as shares, so a worker may spin while
            # the main process prepares the next actions without taking a core from anyone.
            spin = INLINE_SPIN_S if inline else 0.0
            proc = ctx.Process(
                target=_worker_main,
                args=(child, shares[w], spin, os.getpid()),
                daemon=True,
                name=f"seal-collect-{w}",
            )
            proc.start()
            child.close()
            self.conns.append(parent)
            self.procs.append(proc)
        try:
            if inline:
                self.conns.insert(0, _InlineConn(shares[0]))
                self.procs.insert(0, None)
            for w in range(w_count):
                self._receive(w)
        except BaseException:
            self.close()  # no worker outlives a failed start
            raise
        self._pending: tuple[Selection, dict[int, dict[str, np.ndarray]]] | None = None

    def _receive(self, w: int) -> Answer:
        conn = self.conns[w]
        if self.inline and w > 0:
            # The main process has finished its own share and has nothing else to do: spin
            # briefly rather than sleep, since waking a sleeping process costs ~0.1-0.5 ms here.
            deadline = time.perf_counter() + INLINE_SPIN_S
            while not conn.poll(0) and time.perf_counter() < deadline:
                pass
        try:
            status, payload = conn.recv()
        except EOFError:
            proc = self.procs[w]
            code = proc.exitcode if proc is not None else None
            raise RuntimeError(f"collection worker {w} died (exit code {code})") from None
        if status != "ok":
            raise RuntimeError(f"collection worker {w} failed:\n{payload}")
        return cast("Answer", payload)

    def _split(self, sel: Selection) -> dict[int, dict[str, np.ndarray]]:
        """Per worker, per env: which rows of the selection it owns (positions into sel[env])."""
        out: dict[int, dict[str, np.ndarray]] = {}
        for env, idx in sel.items():
            owner = self._owner[env][idx]
            for w in np.unique(owner):
                out.setdefault(int(w), {})[env] = np.flatnonzero(owner == w)
        return out

    def _send(
        self,
        cmd: str,
        sel: Selection,
        actions: dict[str, np.ndarray] | None,
        seeds: Seeds | None = None,
    ) -> dict[int, dict[str, np.ndarray]]:
        split = self._split(sel)
        for w, rows_by_env in split.items():
            if actions is None:
                payload: ResetRequest | StepRequest = {
                    env: (
                        self._local[env][sel[env][rows]],
                        None if seeds is None else np.asarray(seeds[env])[rows],
                    )
                    for env, rows in rows_by_env.items()
                }
            else:
                payload = {
                    env: (self._local[env][sel[env][rows]], actions[env][rows])
                    for env, rows in rows_by_env.items()
                }
            self.conns[w].send((cmd, payload))
        return split

    def reset(self, sel: Selection, seeds: Seeds | None = None) -> dict[str, np.ndarray]:
        split = self._send("reset", sel, None, seeds)
        out: dict[str, np.ndarray] = {}
        for w, rows_by_env in split.items():
            answer = cast("dict[str, np.ndarray]", self._receive(w))
            for env, rows in rows_by_env.items():
                if env not in out:
                    out[env] = np.empty((len(sel[env]), *answer[env].shape[1:]), answer[env].dtype)
                out[env][rows] = answer[env]
        return out

    def step_async(self, sel: Selection, actions: dict[str, np.ndarray]) -> None:
        self._pending = (sel, self._send("step", sel, actions))

    def step_wait(self) -> dict[str, StepArrays]:
        assert self._pending is not None
        sel, split = self._pending
        self._pending = None
        out: dict[str, list[np.ndarray]] = {}
        for w, rows_by_env in split.items():
            answer = cast("dict[str, StepArrays]", self._receive(w))
            for env, rows in rows_by_env.items():
                if env not in out:
                    out[env] = [
                        np.empty((len(sel[env]), *a.shape[1:]), a.dtype) for a in answer[env]
                    ]
                for dst, src in zip(out[env], answer[env], strict=True):
                    dst[rows] = src
        return {env: tuple(arrs) for env, arrs in out.items()}  # type: ignore[misc]

    def close(self) -> None:
        for w, conn in enumerate(self.conns):
            try:
                conn.send(("close", None))
                self._receive(w)
            except (BrokenPipeError, EOFError, RuntimeError, OSError):
                pass
            conn.close()
        for proc in self.procs:
            if proc is None:
                continue
            proc.join(timeout=5)
            if proc.is_alive():
                proc.terminate()
        self.conns, self.procs = [], []


class _GymAsyncBackend(_Backend):
    """One `gymnasium.vector.AsyncVectorEnv` per environment: the one-process-per-env reference."""

    def __init__(self, groups: Mapping[str, Sequence[_Instance]], start_method: str) -> None:
        self.groups = {env: list(insts) for env, insts in groups.items()}
        self.vec: dict[str, gym.vector.AsyncVectorEnv] = {}
        for env, insts in self.groups.items():
            # DISABLED autoreset: the collector decides when episodes start, as on the other
            # backends; observation_mode "different" because tasks may bound their spaces differently.
            self.vec[env] = gym.vector.AsyncVectorEnv(
                [inst.make for inst in insts],
                context=start_method,
                autoreset_mode=gym.vector.AutoresetMode.DISABLED,
                observation_mode="different",
            )
        self.first = {env: True for env in self.groups}
        self._pending: list[str] = []

    def _check_whole(self, sel: Selection, what: str) -> None:
        for env, idx in sel.items():
            if not np.array_equal(idx, np.arange(len(self.groups[env]))):
                raise SealError(
                    f"collection backend 'gym-async' must {what} all instances of environment {env!r} "
                    "together (a partial task mask or an early termination asked otherwise); "
                    "use backend 'sync' or 'subproc-batched'"
                )

    def reset(self, sel: Selection, seeds: Seeds | None = None) -> dict[str, np.ndarray]:
        self._check_whole(sel, "reset")
        out: dict[str, np.ndarray] = {}
        for env in sel:
            if seeds is not None:
                env_seeds: list[int] | None = [int(s) for s in seeds[env]]
            elif self.first[env]:
                env_seeds = [inst.seed for inst in self.groups[env]]
            else:
                env_seeds = None
            self.first[env] = False
            obs, _ = self.vec[env].reset(seed=env_seeds)
            out[env] = np.array(obs)
        return out

    def step_async(self, sel: Selection, actions: dict[str, np.ndarray]) -> None:
        self._check_whole(sel, "step")
        for env in sel:  # every environment's actions go out before any answer is awaited
            self.vec[env].step_async(actions[env])
        self._pending = list(sel)

    def step_wait(self) -> dict[str, StepArrays]:
        out: dict[str, StepArrays] = {}
        for env in self._pending:
            obs, rew, term, trunc, info = self.vec[env].step_wait()
            out[env] = (
                np.array(obs),
                np.asarray(rew, float),
                np.asarray(term, bool),
                np.asarray(trunc, bool),
                np.asarray(info["success"], float),
            )
        self._pending = []
        return out

    def close(self) -> None:
        for vec in self.vec.values():
            vec.close()
        self.vec = {}


# auto uses worker processes only when splitting one step of all instances over the shares saves
# at least this much CPU time (the whole step's cost minus the costliest share's): a pipe round
# trip and its wake-ups cost ~0.2-1 ms, so a split that saves less gains little. MT10 on 2 shares
# saves ~2 ms a step and the kitchens ~15 ms; `point` (~10 us a step) and the quickstart's training
# pair run in one process. That pair (one kitchen and one Meta-World env) saves only the ~0.5 ms
# Meta-World step: 0.39-0.40 s per episode in two processes against 0.40-0.41 s in one
# (`python scripts/collection_split_seconds.py`, 2026-11-24, two runs).
AUTO_PARALLEL_MIN_SAVING_S = 1e-3


def _step_costs(instance: _Instance, steps: int) -> np.ndarray:
    """CPU seconds of each of `steps` random-action steps of a throwaway env of `instance`'s task."""
    env = instance.make()
    try:
        env.reset(seed=instance.seed)
        rng = np.random.default_rng(instance.seed)
        space = env.action_space
        costs = []
        for _ in range(steps):
            action = rng.uniform(space.low, space.high).astype(space.dtype)
            start = time.process_time()  # CPU time: a busy machine does not inflate it
            _, _, terminated, truncated, _ = env.step(action)
            costs.append(time.process_time() - start)
            if terminated or truncated:
                env.reset()
    finally:
        env.close()
    return np.asarray(costs)


def _probe_step_seconds(instance: _Instance, steps: int = 10) -> float:
    """Median CPU seconds of one random-action step of a throwaway env of `instance`'s task."""
    return float(np.median(_step_costs(instance, steps)))


def step_seconds(adapter: EnvAdapter, task: str, steps: int = 100, seed: int = 0) -> float:
    """Mean CPU seconds of one random-action step of `task` (a throwaway env; resets not counted).

    CPU time of this process, so other jobs on the machine do not inflate it (they can still
    slow it through shared caches and clock speed).
    """
    instance = _Instance(adapter.name, task, instance_seed(seed, adapter.name, task), adapter)
    return float(np.mean(_step_costs(instance, steps)))


def _auto_backend(
    groups: Mapping[str, Sequence[_Instance]], workers: int
) -> tuple[str, float | None]:
    """("inline-batched" or "sync", probed cost of one step of all instances or None): see
    AUTO_PARALLEL_MIN_SAVING_S. Each env's instances are costed by one probe of its first."""
    total = sum(len(g) for g in groups.values())
    if workers < 2 or total < 2:
        return "sync", None
    cost = {env: _probe_step_seconds(g[0]) for env, g in groups.items() if g}
    shares = np.zeros(min(workers, total))
    for env, owner in _deal(groups, len(shares)).items():
        np.add.at(shares, owner, cost.get(env, 0.0))
    return choose_backend(float(shares.sum() - shares.max())), float(shares.sum())


def choose_backend(saving_s: float) -> str:
    """What "auto" picks when splitting a step over the shares saves `saving_s` (>= 2 workers)."""
    return "inline-batched" if saving_s >= AUTO_PARALLEL_MIN_SAVING_S else "sync"


def auto_backend(
    adapters: Mapping[str, EnvAdapter], seed: int = 0, num_workers: int | None = None
) -> str:
    """The backend `Collector(..., backend="auto")` would pick for all tasks of `adapters`."""
    groups = {
        env: [_Instance(env, t, instance_seed(seed, env, t), a) for t in a.tasks]
        for env, a in adapters.items()
    }
    return _auto_backend(groups, _cpu_count() if num_workers is None else num_workers)[0]


def _cpu_count() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


# ---------------------------------------------------------------- collector
class Collector:
    """Steps every (environment, task) instance together with batched policy inference.

    `adapters` maps environment names to adapters; `tasks` optionally restricts an environment to
    a subset of its adapter's tasks (task ids stay the adapter's indices, i.e. one-hot positions).
    A separate Collector with another seed serves evaluation (its own env instances and seeds).
    `env_steps[env]` counts env steps per task (indexed like `self.tasks[env]`).

    `replicas` > 1 builds that many instances of every task (see `evaluation_replicas`), so
    `evaluate` runs that many episodes of each task at once; `collect_episodes` uses replica 0,
    and replica 0's seeds are those of a one-replica Collector.
    """

    def __init__(
        self,
        adapters: Mapping[str, EnvAdapter],
        seed: int,
        tasks: Mapping[str, Sequence[str]] | None = None,
        backend: str = "auto",
        num_workers: int | None = None,
        start_method: str | None = None,
        replicas: int = 1,
    ) -> None:
        if backend not in BACKENDS:
            raise UnknownNameError("collection backend", backend, BACKENDS)
        if not adapters:
            raise SealError("Collector needs at least one environment adapter")
        self.adapters = dict(adapters)
        self.seed = int(seed)
        self.tasks: dict[str, tuple[str, ...]] = {}
        for env, adapter in self.adapters.items():
            chosen = tuple(adapter.tasks if tasks is None or env not in tasks else tasks[env])
            for task in chosen:
                if task not in adapter.tasks:
                    raise UnknownNameError(f"{env} task", task, adapter.tasks)
            self.tasks[env] = chosen
        if tasks is not None:
            for env in tasks:
                if env not in self.adapters:
                    raise UnknownNameError(
                        "environment in collector tasks", env, list(self.adapters)
                    )
        self.task_ids = {
            env: np.array([self.adapters[env].tasks.index(t) for t in ts], dtype=np.int64)
            for env, ts in self.tasks.items()
        }
        self.env_steps = {env: np.zeros(len(ts), dtype=np.int64) for env, ts in self.tasks.items()}
        if int(replicas) < 1:
            raise SealError(f"Collector replicas must be >= 1, got {replicas}")
        self.replicas = int(replicas)
        # Instance r * len(tasks) + i is replica r of task i: replica 0's indices are the tasks'.
        self._instance_ids = {
            env: np.tile(ids, self.replicas) for env, ids in self.task_ids.items()
        }
        self._draws = 0
        groups = {
            env: [
                _Instance(env, task, instance_seed(self.seed, env, task, r), self.adapters[env])
                for r in range(self.replicas)
                for task in ts
            ]
            for env, ts in self.tasks.items()
        }
        self._action_rng = {
            env: np.random.default_rng(
                np.random.SeedSequence(self.seed, spawn_key=(zlib.crc32(env.encode()), 1))
            )
            for env in self.tasks
        }
        workers = _cpu_count() if num_workers is None else int(num_workers)
        if workers < 1:
            raise SealError(f"Collector num_workers must be >= 1, got {num_workers}")
        self.step_cost_s: float | None = None
        """auto only: probed CPU seconds of one step of every instance, in one process."""
        if backend == "auto":
            backend, self.step_cost_s = _auto_backend(groups, workers)
        # fork: workers start in ~0.1 s and need nothing pickled; they never touch torch, so
        # forking a process that has started torch threads is safe here.
        method = start_method or ("fork" if "fork" in mp.get_all_start_methods() else "spawn")
        self.backend_name = backend
        if backend == "sync":
            self._backend: _Backend = _SyncBackend(groups)
        elif backend == "subproc-batched":
            self._backend = _SubprocBatchedBackend(groups, workers, method)
        elif backend == "inline-batched":
            self._backend = _SubprocBatchedBackend(groups, workers, method, inline=True)
        else:
            self._backend = _GymAsyncBackend(groups, method)

    # ------------------------------------------------------------ episodes
    def collect_episodes(
        self,
        policy: Policy | None,
        active: Mapping[str, Sequence[bool] | np.ndarray] | None = None,
        random_actions: bool = False,
        sink: TransitionSink | None = None,
    ) -> EpisodeStats:
        """Run one full episode on every active instance; return per-instance return, success, length.

        `random_actions` samples uniformly from each action space (warm-up) instead of calling
        `policy`. Each step's transitions go to `sink(env, task_ids, obs, actions, rewards,
        next_obs, terminations)`, where terminations hold `terminated` only: a truncated episode
        is bootstrapped from its last observation, a terminated one is not.
        """
        if policy is None and not random_actions:
            raise SealError("collect_episodes needs a policy unless random_actions=True")
        if self._backend is None:
            raise SealError("this Collector is closed")
        mask = self._active_mask(active)
        running: Selection = {env: np.flatnonzero(m) for env, m in mask.items() if m.any()}
        returns, successes, lengths = self._run(running, None, policy, random_actions, sink)
        n = {env: len(ts) for env, ts in self.tasks.items()}
        returns = {env: v[: n[env]] for env, v in returns.items()}
        successes = {env: v[: n[env]] for env, v in successes.items()}
        lengths = {env: v[: n[env]] for env, v in lengths.items()}
        return EpisodeStats(dict(self.tasks), mask, returns, successes, lengths)

    def _run(
        self,
        running: Selection,
        seeds: Seeds | None,
        policy: Policy | None,
        random_actions: bool,
        sink: TransitionSink | None,
        probe: CriticProbe | None = None,
        end_on_success: bool = False,
    ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, np.ndarray]]:
        """One episode on each selected instance: per-instance (returns, successes, lengths).
        A `probe` sees every episode's first state and action and every step; `end_on_success`
        ends an episode after its first successful step (not a termination: a probe bootstraps it)."""
        size = {env: len(ids) for env, ids in self._instance_ids.items()}
        returns = {env: np.zeros(k) for env, k in size.items()}
        successes = {env: np.zeros(k, dtype=bool) for env, k in size.items()}
        lengths = {env: np.zeros(k, dtype=np.int64) for env, k in size.items()}
        # A policy with a task encoder (`seal.learner.task_encoder.BeliefMemory`) sees, and the
        # probe and the sink get, observations with the belief and the episode step appended.
        memory: BeliefMemory | None = getattr(policy, "memory", None)
        obs = self._backend.reset(running, seeds)
        if memory is not None:
            for env, run in running.items():
                memory.start(env, run)
        seen = self._seen(memory, running, obs)
        actions = self._actions(policy, random_actions, running, seen)
        if probe is not None:
            probe.start(size)
            for env, run in running.items():
                probe.first(env, run, self._instance_ids[env][run], seen[env], actions[env])
        self._backend.step_async(running, actions)
        t = 0
        while running:
            results = self._backend.step_wait()
            t += 1
            if memory is not None:
                for env, (next_obs, rewards, *_) in results.items():
                    memory.advance(env, running[env], actions[env], rewards, next_obs)
            # Decide who keeps running and send their next actions before the bookkeeping of
            # this step, so worker processes step while the sink (replay) copies data.
            step_running, step_obs, step_actions = running, obs, actions
            running, obs = {}, {}
            dones: dict[str, np.ndarray] = {}
            for env, (next_obs, _, terminated, truncated, success) in results.items():
                # An env that forgets to truncate at its episode length is cut there anyway.
                done = terminated | truncated | (t >= self.adapters[env].episode_length)
                if end_on_success:
                    done = done | (success > 0.5)
                dones[env] = done
                if not done.all():
                    running[env] = step_running[env][~done]
                    obs[env] = next_obs[~done]
            if running:
                actions = self._actions(
                    policy, random_actions, running, self._seen(memory, running, obs)
                )
                self._backend.step_async(running, actions)
            for env, (next_obs, rewards, terminated, _, success) in results.items():
                run = step_running[env]
                before = step_obs[env]
                if memory is not None:  # [obs | belief | step] before and after the step
                    extra_before, extra_after = memory.last(env)
                    before = np.concatenate((np.asarray(before, np.float32), extra_before), axis=1)
                    next_obs = np.concatenate(
                        (np.asarray(next_obs, np.float32), extra_after), axis=1
                    )
                returns[env][run] += rewards
                if probe is not None:
                    probe.step(env, run, rewards, next_obs, terminated)
                successes[env][run] |= success > 0.5
                lengths[env][run] += 1
                if self.replicas == 1:
                    self.env_steps[env][run] += 1
                else:  # replicas of one task may step together
                    np.add.at(self.env_steps[env], run % len(self.tasks[env]), 1)
                if sink is not None:
                    sink(
                        env,
                        self._instance_ids[env][run],
                        before,
                        step_actions[env],
                        rewards,
                        next_obs,
                        terminated,
                    )
        return returns, successes, lengths

    @staticmethod
    def _seen(
        memory: BeliefMemory | None, running: Selection, obs: dict[str, np.ndarray]
    ) -> dict[str, np.ndarray]:
        """What the policy sees of the running instances: raw obs, or [obs | belief | step]."""
        if memory is None:
            return obs
        return {env: memory.augment(env, run, obs[env]) for env, run in running.items()}

    def _actions(
        self,
        policy: Policy | None,
        random_actions: bool,
        running: Selection,
        obs: dict[str, np.ndarray],
    ) -> dict[str, np.ndarray]:
        """One batched policy call (or uniform sample) per environment over its running instances."""
        out: dict[str, np.ndarray] = {}
        for env, run in running.items():
            space = self.adapters[env].action_space
            if random_actions:
                out[env] = (
                    self._action_rng[env]
                    .uniform(space.low, space.high, size=(len(run), *space.shape))
                    .astype(space.dtype)
                )
            else:
                assert policy is not None
                out[env] = np.asarray(
                    policy(env, obs[env], self._instance_ids[env][run]), dtype=space.dtype
                )
        return out

    def evaluate(
        self,
        policy: Policy,
        episodes: int,
        active: Mapping[str, Sequence[bool] | np.ndarray] | None = None,
        draw: int | None = None,
        probe: CriticProbe | None = None,
        decide: Decide | None = None,
        end_on_success: bool = False,
    ) -> dict[str, dict[str, dict[str, float]]]:
        """Mean success rate and return over `episodes` episodes per task: {env: {task: {...}}}.

        With a `probe` (`seal.learner.critic_probe`), also the means of its `q_start` and `earned`.

        Pass a deterministic policy and use a Collector seeded apart from the training one.
        Episode e of a task resets with `evaluation_waves.episode_seed(seed, env, task, draw, e)`,
        so the results do not depend on the backend or on `replicas`; `draw` (default: this
        Collector's count of `evaluate` calls) picks a fresh set of episodes. The `replicas`
        instances of each task run episodes `replicas` at a time, in waves
        (`seal.learner.evaluation_waves`); with `decide` (`seal.evaluation.EarlyDecision`) a task
        whose verdict is settled stops after its wave, and `end_on_success` ends every episode at
        its first success.
        """
        if episodes < 1:
            raise SealError(f"evaluate: episodes must be >= 1, got {episodes}")
        if policy is None:
            raise SealError("evaluate needs a policy")
        if self._backend is None:
            raise SealError("this Collector is closed")
        draw = self._draws if draw is None else int(draw)
        self._draws += 1

        def play(running: Selection, seeds: Seeds) -> Played:
            returns, successes, _ = self._run(
                running, seeds, policy, False, None, probe, end_on_success
            )
            played: Played = {}
            for env, run in running.items():
                played[env] = {"return": returns[env][run], "success": successes[env][run]}
                if probe is not None:
                    ids = self._instance_ids[env][run]
                    played[env]["q_start"], played[env]["earned"] = probe.finish(env, run, ids)
            return played

        return evaluate_in_waves(
            play,
            self.tasks,
            self._active_mask(active),
            seed=self.seed,
            draw=draw,
            episodes=episodes,
            replicas=self.replicas,
            # gym-async can only reset whole environments: spare episodes, results dropped.
            whole=isinstance(self._backend, _GymAsyncBackend),
            decide=decide,
        )

    def _active_mask(
        self, active: Mapping[str, Sequence[bool] | np.ndarray] | None
    ) -> dict[str, np.ndarray]:
        mask = {env: np.ones(len(ts), dtype=bool) for env, ts in self.tasks.items()}
        if active is None:
            return mask
        for env, m in active.items():
            if env not in self.tasks:
                raise UnknownNameError("environment in active mask", env, list(self.tasks))
            arr = np.asarray(m, dtype=bool)
            if arr.shape != mask[env].shape:
                raise SealError(
                    f"active mask for {env!r} has shape {arr.shape}; expected ({len(self.tasks[env])},) for tasks {list(self.tasks[env])}"
                )
            mask[env] = arr
        return mask

    @property
    def total_env_steps(self) -> int:
        """Env steps over every instance since this Collector was built."""
        return int(sum(int(v.sum()) for v in self.env_steps.values()))

    def close(self) -> None:
        """Close every env and stop worker processes."""
        backend = getattr(self, "_backend", None)
        if backend is not None:
            backend.close()
            self._backend = None  # type: ignore[assignment]

    def __enter__(self) -> Collector:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        with contextlib.suppress(Exception):  # interpreter shutdown may have torn down modules
            self.close()
