"""What a `seal run` checkpoint holds: the fields it adds to `seal.learner.checkpoint`'s own.

An epoch checkpoint (ckpt-*.pt, `EpochCheckpoint`) is the point a resume continues from; best.pt
(`BestCheckpoint`) is a policy. The `Checkpointer` (`seal.run.checkpointing`) writes them,
the loop (`seal.run.loop`) restores from an epoch checkpoint, and the run
(`seal.run.runner`) reads both; this module imports none of them.

A checkpoint is a file from elsewhere, so its fields are checked before anything uses them:
`check_run_checkpoint` (`seal eval`, `[transfer]`) and `check_epoch_checkpoint` (`--resume`)
hold a file's fields to the TypedDicts below (every required key there, every value of its
declared type, down to the agent's and the replay's states), then check what the types cannot
say (the saved config is TOML, the phase is one of the run's, the RNG states load). A field that
fails is a one-line SealError naming the file, the field and what is valid.
"""

from __future__ import annotations

import functools
import random
import types
import typing
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NotRequired, TypedDict, cast

import torch

from seal.errors import SealError

if TYPE_CHECKING:
    from seal.learner.agent_state import AgentState
    from seal.learner.replay import ReplayState
    from seal.run.workers import PendingFields


class PhaseStateFields(TypedDict):
    """`PhaseState.fields()`: a phase's counters as a checkpoint holds them (see `PhaseState` for
    each key; tests/protocols/test_checkpointing.py holds the keys to its fields). A checkpoint
    written before a key was kept lacks it, and `PhaseState(**fields)` gives it its default."""

    epoch: int
    grad_steps: int
    env_steps: dict[str, list[int]]
    best_mean_success: float
    wall_s: float
    anchor_epoch: int
    last_success: dict[str, dict[str, float]]
    reached: dict[str, dict[str, float]]
    timeline_rows: int
    log_sums: NotRequired[dict[str, float]]
    log_updates: NotRequired[int]
    seconds: NotRequired[dict[str, float]]
    calls: NotRequired[dict[str, int]]
    demos: NotRequired[dict[str, dict[str, float]]]
    collected_lengths: NotRequired[dict[str, int]]
    evaluated_at: NotRequired[int]
    evaluations: NotRequired[int]


class RunnerFields(TypedDict):
    """An epoch checkpoint's "runner" field: what resume needs besides the agent, replay and scheduler."""

    phase_index: int
    state: PhaseStateFields
    """The phase's `PhaseState`."""
    rows: dict[str, int]
    """CSV file -> its rows when the checkpoint was taken (`RunDir.row_counts`)."""
    torch_rng: torch.Tensor
    py_rng: tuple[Any, ...]
    """random.getstate(), typed as the standard library types it (lists instead of tuples once read back)."""
    finished_phases: dict[str, PhaseStateFields]
    """Phase name -> its final `PhaseState`."""
    pending_evaluations: list[PendingFields]
    """`PendingEvaluation.fields` of the asynchronous evaluations not yet written (resume re-runs them)."""
    drift_start: NotRequired[dict[str, dict[str, torch.Tensor]]]
    """With logging.drift: each env's pieces at the phase's start (`seal.learner.drift`), which resume measures from."""


class CheckpointFields(TypedDict):
    """The fields `seal run` adds to every checkpoint, beside `seal.learner.checkpoint`'s own."""

    config_toml: str
    seed: int
    phase: str
    phase_envs: list[str]
    epoch: int
    best: bool
    mean_success: float
    """The phase's best mean success so far."""


class EpochFields(CheckpointFields):
    """An epoch checkpoint's (ckpt-*.pt) fields."""

    scheduler: dict[str, Any]
    """`Scheduler.state_dict()`: each scheduler's own keys."""
    runner: RunnerFields


class BestFields(CheckpointFields):
    """best.pt's fields (no scheduler, no runner, no replay: it is a policy, not a resume point)."""

    scheduler: None
    runner: None


class EpochCheckpoint(EpochFields):
    """An epoch checkpoint as `read_checkpoint` returns it: the point a resume continues from."""

    seal_checkpoint: int
    agent: AgentState
    """`Agent.state_dict()`."""
    replay: ReplayState | None
    """`MultiTaskReplay.state_dict()` (None with checkpoint.save_replay = false)."""


class BestCheckpoint(BestFields):
    """best.pt as `read_checkpoint` returns it."""

    seal_checkpoint: int
    agent: AgentState
    replay: None


RunCheckpoint = EpochCheckpoint | BestCheckpoint
"""A checkpoint `seal run` writes, either kind (`seal eval` takes both)."""


PHASE_NAMES = ("train", "pretrain", "finetune")
"""Every phase name a run has (`seal.run.phase_model.plan_phases`; a test holds them equal)."""

_CLOSED: tuple[type, ...] = (PhaseStateFields,)
"""TypedDicts whose readers take no other key: a phase's counters become `PhaseState(**fields)`."""


class _Invalid(Exception):
    """One field that does not hold what its TypedDict says: its path and what would be valid."""

    def __init__(self, where: str, found: object, expected: str) -> None:
        super().__init__(where)
        self.where, self.found, self.expected = where, found, expected


@functools.cache
def _type_names() -> dict[str, object]:
    """The names the TypedDicts' annotations use under TYPE_CHECKING, for `get_type_hints`."""
    from seal.learner.agent_state import AgentState
    from seal.learner.replay import ReplayState
    from seal.run.rundir import MetricsRow
    from seal.run.workers import PendingFields

    return {
        "AgentState": AgentState,
        "ReplayState": ReplayState,
        "PendingFields": PendingFields,
        "MetricsRow": MetricsRow,
    }


@functools.cache
def _fields_of(tp: type) -> tuple[dict[str, object], list[str]]:
    """A TypedDict's field types and its required keys.

    Not `__required_keys__`: under `from __future__ import annotations` Python 3.11 counts a
    `NotRequired` field as required there, so the annotations are read here instead.
    """
    hints = typing.get_type_hints(tp, localns=_type_names(), include_extras=True)
    fields: dict[str, object] = {}
    required = []
    for key, hint in hints.items():
        if typing.get_origin(hint) is NotRequired:
            hint = typing.get_args(hint)[0]
        else:
            required.append(key)
        fields[key] = hint
    return fields, required


def _describe(tp: object) -> str:
    """A type as the message names it."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_describe(a) for a in args)
    if tp is type(None):
        return "none"
    if typing.is_typeddict(tp):
        return "a table"
    if origin is dict:
        return f"a table of {_describe(args[1])}" if args else "a table"
    if origin in (list, tuple, Sequence):
        return "a list"
    names = {int: "an integer", float: "a number", bool: "true or false", str: "a string"}
    return names.get(tp, "a tensor" if tp is torch.Tensor else getattr(tp, "__name__", str(tp)))


def _shown(value: object) -> str:
    """A found value, short: tensors by dtype and shape, everything else by a clipped repr."""
    if isinstance(value, torch.Tensor):
        return f"a {value.dtype} tensor of shape {list(value.shape)}"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _check(value: object, tp: object, where: str) -> None:
    """Raise _Invalid at the first part of `value` that is not of type `tp`."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if tp in (Any, object):
        return
    if origin is typing.Annotated:
        _check(value, args[0], where)
        return
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return
        others = [a for a in args if a is not type(None)]
        if len(others) == 1:  # X | None holding something: the message says where X fails
            _check(value, others[0], where)
            return
        for option in args:
            try:
                _check(value, option, where)
                return
            except _Invalid:
                continue
        raise _Invalid(where, value, _describe(tp))
    if typing.is_typeddict(tp):
        if not isinstance(value, dict):
            raise _Invalid(where, value, "a table")
        hints, required = _fields_of(cast("type", tp))
        for key in required:
            if key not in value:
                raise _Invalid(f"{where}.{key}" if where else key, None, "missing")
        if tp in _CLOSED:
            extra = sorted(str(k) for k in value if k not in hints)
            if extra:
                raise _Invalid(f"{where}.{extra[0]}", None, "unknown:" + ", ".join(hints))
        for key, hint in hints.items():
            if key in value:
                _check(value[key], hint, f"{where}.{key}" if where else key)
        return
    if origin is dict:
        if not isinstance(value, dict):
            raise _Invalid(where, value, _describe(tp))
        for key, item in value.items():
            _check(key, args[0], f"{where} (a key)")
            _check(item, args[1], f"{where}[{key!r}]")
        return
    if origin in (list, tuple):  # torch.save keeps tuples; lists stand for tuples once read back
        if not isinstance(value, (list, tuple)):
            raise _Invalid(where, value, _describe(tp))
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(value) != len(args):
                raise _Invalid(where, value, f"a list of {len(args)} items")
            for i, (item, hint) in enumerate(zip(value, args, strict=True)):
                _check(item, hint, f"{where}[{i}]")
            return
        for i, item in enumerate(value):
            _check(item, args[0] if args else Any, f"{where}[{i}]")
        return
    if tp is type(None):
        ok = value is None
    elif tp is bool:
        ok = isinstance(value, bool)
    elif tp is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif tp is float:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    elif isinstance(tp, type):
        ok = isinstance(value, tp)
    else:
        ok = True  # a form this checker does not know: its reader checks it
    if not ok:
        raise _Invalid(where, value, _describe(tp))


def _refuse(path: str | Path, where: str, found: object, expected: str) -> SealError:
    if expected == "missing":
        return SealError(
            f"checkpoint {path}: field {where} is missing; it was not written by seal run"
        )
    if expected.startswith("unknown:"):
        return SealError(
            f"checkpoint {path}: field {where} is not a field seal run writes; valid: "
            + expected.removeprefix("unknown:")
        )
    return SealError(f"checkpoint {path}: field {where} = {_shown(found)}; expected {expected}")


def _holds(data: Mapping[str, Any], schema: type, path: str | Path) -> None:
    try:
        _check(dict(data), schema, "")
    except _Invalid as bad:
        raise _refuse(path, bad.where, bad.found, bad.expected) from None


def saved_config_table(data: Mapping[str, Any], path: str | Path) -> dict[str, Any]:
    """The checkpoint's `config_toml` parsed (SealError naming the field if it is not TOML)."""
    from seal.protocols.toml_io import parse_toml

    try:
        return parse_toml(str(data["config_toml"]), "")
    except SealError as exc:
        why = str(exc).removeprefix(": ")
        raise SealError(f"checkpoint {path}: field config_toml (the run's config): {why}") from None


def check_run_checkpoint(data: Mapping[str, Any], path: str | Path) -> RunCheckpoint:
    """`data` (from `read_checkpoint(path)`) as a `seal run` checkpoint of either kind, checked.

    best.pt (runner = none) is held to `BestCheckpoint`, an epoch checkpoint to
    `EpochCheckpoint`; the saved config must parse as TOML and the phase be a phase name.
    SealError naming the file and the first field that fails.
    """
    runner = data.get("runner", ...)
    if runner is ...:
        raise _refuse(path, "runner", None, "missing")
    _holds(data, BestCheckpoint if runner is None else EpochCheckpoint, path)
    saved_config_table(data, path)
    if data["phase"] not in PHASE_NAMES:
        raise _refuse(path, "phase", data["phase"], "one of " + ", ".join(PHASE_NAMES))
    return cast("RunCheckpoint", data)


def check_epoch_checkpoint(
    data: Mapping[str, Any], path: str | Path, phases: Sequence[str], seed: int
) -> EpochCheckpoint:
    """`data` as an epoch checkpoint this run (its `phases` by name, its `seed`) can resume from.

    On top of `EpochCheckpoint`'s types: the saved config is TOML, the phase and phase index are
    this run's, the seed is this run's, the row counts are not negative, and the RNG states load.
    """
    _holds(data, EpochCheckpoint, path)
    saved_config_table(data, path)
    runner = data["runner"]
    if data["phase"] not in phases:
        raise _refuse(
            path, "phase", data["phase"], "one of this run's phases: " + ", ".join(phases)
        )
    index = runner["phase_index"]
    if not 0 <= index < len(phases) or phases[index] != data["phase"]:
        raise _refuse(
            path,
            "runner.phase_index",
            index,
            f"{phases.index(data['phase'])} (phase {data['phase']!r})",
        )
    if data["seed"] != seed:
        raise _refuse(
            path, "seed", data["seed"], f"{seed}, this run's seed (another seed's checkpoint?)"
        )
    unknown = sorted(set(runner["finished_phases"]) - set(phases[:index]))
    if unknown:
        raise _refuse(
            path,
            "runner.finished_phases",
            unknown,
            "phases before this one: " + (", ".join(phases[:index]) or "none"),
        )
    for name, rows in runner["rows"].items():
        if rows < 0:
            raise _refuse(path, f"runner.rows[{name!r}]", rows, "a row count >= 0")
    try:
        torch.Generator().set_state(runner["torch_rng"])
    except (RuntimeError, TypeError, ValueError):
        raise _refuse(
            path, "runner.torch_rng", runner["torch_rng"], "torch.get_rng_state()'s bytes"
        ) from None
    try:
        random.Random().setstate(_as_tuples(runner["py_rng"]))
    except (TypeError, ValueError, OverflowError):
        raise _refuse(
            path, "runner.py_rng", runner["py_rng"], "random.getstate()'s value"
        ) from None
    return cast("EpochCheckpoint", data)


def _as_tuples(state: object) -> object:
    """random.getstate() after a round trip through torch.save (lists back to tuples)."""
    if isinstance(state, list | tuple):
        return tuple(_as_tuples(s) for s in state)
    return state
