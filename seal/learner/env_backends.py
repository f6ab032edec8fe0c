"""How a `Collector`'s env instances step: its backends, and what "auto" picks.

An instance is one gymnasium env of one (environment, task), seeded by `instance_seed`. A backend
steps a set of instances together: ``sync`` in this process, ``subproc-batched`` and
``inline-batched`` over worker processes that each own a round-robin share (`_deal`), and
``gym-async``, gymnasium's `AsyncVectorEnv`, one process per instance. The module docstring of
`seal.learner.collection` says when each is used; same seed, identical transitions on every one.
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
from typing import cast

import gymnasium as gym
import numpy as np

from seal.envs.base import EnvAdapter
from seal.errors import SealError

BACKENDS = ("auto", "sync", "subproc-batched", "inline-batched", "gym-async")
# inline-batched: how long the main process spins for a worker's answer (and a worker for the next
# message) before sleeping on the pipe; waking a sleeping process costs ~0.1-0.5 ms here.
INLINE_SPIN_S = 0.002


def instance_seed(seed: int, env: str, task: str, replica: int = 0) -> int:
    """The seed of the (env, task) instance: stable across processes, backends and task subsets.

    Replica 0 is a Collector's one instance per task; replicas >= 1 are evaluation copies.
    """
    # crc32, not hash(): Python's str hash is salted per process.
    key: tuple[int, ...] = (zlib.crc32(env.encode()), zlib.crc32(task.encode()))
    if replica:
        key = (*key, int(replica))
    return int(np.random.SeedSequence(seed, spawn_key=key).generate_state(1, np.uint32)[0])


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
