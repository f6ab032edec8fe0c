"""The runs an experiment finds under its output directory, and what they were made with.

`seal bench --learn ... --reuse` takes a finished run of (arm, seed) only if its saved config
resolves as the protocol does today (`finished_run`: every key of COMPARED_TABLES, a key added
since counting as its default), continues an unfinished one that saved a checkpoint with its
replay (`unfinished_run`), and the tables say which code versions and agent keys the runs they
set against each other differ in (`code_versions`, `versions_note`, `agent_mismatches`).
`last_checkpoint` is what a pre-training run hands on to its fine-tune arm.
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from seal.errors import SealError
from seal.experiments.arms import Arm


def last_checkpoint(run_dir: Path) -> Path:
    """The newest epoch checkpoint (ckpt-<epoch>.pt) of a finished run: what a pre-training hands on."""
    found = sorted(
        (run_dir / "checkpoints").glob("ckpt-*.pt"), key=lambda p: int(p.stem.rsplit("-", 1)[1])
    )
    if not found:
        raise SealError(f"{run_dir}: no checkpoints/ckpt-<epoch>.pt to start the next arm from")
    return found[-1]


COMPARED_TABLES = ("envs", "agent", "replay", "training", "evaluation", "scheduler")
"""The resolved tables a reused run must share with the protocol as it resolves now."""


def _tables(resolved: Mapping[str, Any]) -> dict[str, Any]:
    out = {t: resolved.get(t, {}) for t in COMPARED_TABLES}
    out["epochs"] = resolved["protocol"]["epochs"]
    return out


def _same_tables(saved: Mapping[str, Any], want: Mapping[str, Any]) -> bool:
    """Whether a run's saved tables are today's: a key of [agent], [replay], [training] or
    [evaluation] that the run predates counts as the same when today's value is that key's default
    (a key added since, which keeps the old behaviour)."""
    from seal.learner.config import AgentConfig
    from seal.protocols.config import EvaluationConfig, ReplayConfig, TrainingConfig

    filled = dict(saved)
    for table, cls in (
        ("agent", AgentConfig),
        ("replay", ReplayConfig),
        ("training", TrainingConfig),
        ("evaluation", EvaluationConfig),
    ):
        if table not in saved:
            continue
        defaults = _defaults(cls)
        old = AgentConfig.upgrade(saved[table]) if table == "agent" else dict(saved[table])
        for key, value in want.get(table, {}).items():
            if key not in old and key in defaults:
                old[key] = defaults[key]
                if old[key] != value:
                    return False
        filled[table] = old
    return filled == want


def _defaults(cls: type) -> dict[str, Any]:
    """A config dataclass's field defaults as config.toml holds them (tuples as lists)."""
    import dataclasses

    out = {}
    for f in dataclasses.fields(cls):
        if f.default is not dataclasses.MISSING:
            value = f.default
        elif f.default_factory is not dataclasses.MISSING:
            value = f.default_factory()
        else:
            continue
        out[f.name] = list(value) if isinstance(value, tuple) else value
    return out


def resolved_tables(arm: Arm, overrides: Sequence[str] = ()) -> tuple[str, dict[str, Any]]:
    """(protocol name, the tables a run of `arm` saves in its config.toml), as the code resolves them now."""
    from seal.protocols import load_protocol
    from seal.protocols.loader import config_to_dict
    from seal.protocols.toml_io import dumps_toml

    config = load_protocol(arm.protocol, overrides)
    # Through TOML, as the runner writes config.toml, so that both sides compare alike.
    return config.name, _tables(tomllib.loads(dumps_toml(config_to_dict(config))))


def finished_run(arm: Arm, seed: int, out: Path, overrides: Sequence[str] = ()) -> Path | None:
    """The newest finished run of (arm, seed) under `out` whose saved config equals today's resolution, else None.

    Defaults of the learner can change between two runs (a new default init, say); a run is
    reused only if every resolved key of COMPARED_TABLES is the same, so arms never mix them.
    """
    from seal import load_run

    name, want = resolved_tables(arm, overrides)
    # Group directories start with their creation time, so the newest sorts last.
    for run in sorted(out.glob(f"{name}/*/seed-{seed}"), reverse=True):
        if not (run / "metrics.csv").is_file() or not (run / "config.toml").is_file():
            continue
        if not _same_tables(_tables(tomllib.loads((run / "config.toml").read_text())), want):
            continue
        loaded = load_run(run)
        epochs = loaded.metrics["epoch"]
        # Finished: all its epochs, or ended early (evaluation.stop_when_reached) with an end time.
        if loaded.provenance.get("end_time") or (
            not epochs.empty and int(epochs.max()) >= want["epochs"]
        ):
            return run
    return None


def finished_runs(
    jobs: Sequence[tuple[Arm, int]], out: Path, overrides: Sequence[str] = ()
) -> dict[tuple[str, int], Path]:
    """`--no-run`: (arm name, seed) -> the finished run `finished_run` takes, for the jobs that
    have one; the rest are left out."""
    found = {(a.name, s): finished_run(a, s, out, overrides) for a, s in jobs}
    return {key: path for key, path in found.items() if path is not None}


def unfinished_run(arm: Arm, seed: int, out: Path, overrides: Sequence[str] = ()) -> Path | None:
    """The newest run of (arm, seed) under `out` with today's resolved config that did not finish
    but saved an epoch checkpoint with its replay to go on from (`seal run --resume`), else None."""
    name, want = resolved_tables(arm, overrides)
    for run in sorted(out.glob(f"{name}/*/seed-{seed}"), reverse=True):
        if not (run / "config.toml").is_file() or not any((run / "checkpoints").glob("ckpt-*.pt")):
            continue
        saved = tomllib.loads((run / "config.toml").read_text())
        if saved.get("checkpoint", {}).get("save_replay", True) and _same_tables(
            _tables(saved), want
        ):
            return run
    return None


def agent_mismatches(
    agents: Mapping[tuple[str, int], Mapping[str, Any]], chosen: Sequence[Arm]
) -> list[str]:
    """Agent keys, other than shared_update, that differ between runs set against each other."""
    problems = []
    for arm in chosen:
        base = arm.alone or arm.name
        for (name, seed), agent in agents.items():
            if name != arm.name:
                continue
            ref = agents[(base, 0)]
            keys = sorted(
                k
                for k in set(agent) | set(ref)
                if k != "shared_update" and agent.get(k) != ref.get(k)
            )
            problems += [
                f"{name} seed {seed} vs {base} seed 0: agent.{k} = {agent.get(k)!r} vs {ref.get(k)!r}"
                for k in keys
            ]
    return problems


def code_versions(shas: Mapping[tuple[str, int], str | None]) -> dict[str, list[str]]:
    """The code versions (provenance git_sha) the runs were made with, each with its runs; one key when consistent.

    A learner change without a config key (a loss's scale, say) is invisible to
    `finished_run`; runs of different commits should not be set against each other.
    """
    out: dict[str, list[str]] = {}
    for (arm, seed), sha in sorted(shas.items()):
        out.setdefault(sha or "unknown", []).append(f"{arm}/seed-{seed}")
    return out


def versions_note(versions: Mapping[str, Sequence[str]]) -> str | None:
    """ "runs made with N code versions: <sha>: <runs>; ..." when `code_versions` found several, else None."""
    if len(versions) <= 1:
        return None
    listed = "; ".join(f"{sha}: {', '.join(runs)}" for sha, runs in versions.items())
    return f"runs made with {len(versions)} code versions: {listed}"
