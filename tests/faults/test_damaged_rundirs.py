"""A corpus of damaged run directories: every reader refuses in one line, or falls back.

One short `point` run is copied once per case into `<tmp>/faults/g/seed-0`, damaged in one way
(an edited or swapped config.toml, a checkpoint with a field missing or of the wrong type, a
file that is a symlink leading out, a FIFO, a device, a directory), and given to one reader:
`seal run --resume`, `seal report`, `seal.load_run`, `seal eval`, `[transfer] checkpoint`, or
`seal protocol explain` for a damaged protocol. Outcomes:

- "refused": exit 2 (`load_run`: SealError) with one line naming the file and the field, no
  traceback, and nothing written: the run directory (its lock file aside) and the files outside
  it that a link points to are byte for byte as before.
- "fallback": the damaged newest epoch checkpoint is skipped, named with its reason, the run
  resumes from the one before and ends with the rows of the undamaged run.
- "replaced": seal report writes its own file in place of a symlinked one, never through it.

docs/faults.md lists the cases with their counts.
"""

from __future__ import annotations

import os
import shutil
import stat
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd
import pytest
import torch

import seal
from seal.cli.main import main
from seal.errors import SealError
from seal.protocols import load_protocol
from seal.run.runner import run_seed
from tests.faults.point_protocol import point_protocol

EPOCHS = 4
PROTOCOL = point_protocol("faults", EPOCHS)
NEWEST, OLDER = "ckpt-0000004.pt", "ckpt-0000002.pt"
OUTSIDE_TOML = '[protocol]\nname = "elsewhere"\n'


@dataclass(frozen=True)
class Case:
    """One damage, the reader given the damaged directory, and what must happen."""

    id: str
    damage: Callable[[Path, Path], Path | None]
    """(run directory, a folder outside it) -> the file to hand the reader (eval, transfer,
    explain), or None for the run directory itself."""
    reader: str
    """resume, report, load_run, eval, transfer or explain."""
    says: str
    """What the one line (or, for a fallback, the skip message) must contain."""
    outcome: str = "refused"
    """refused, fallback or replaced."""


# ---------------------------------------------------------------- damages


def _edit_config(edit: Callable[[str], str]) -> Callable[[Path, Path], None]:
    def damage(run: Path, outside: Path) -> None:
        path = run / "config.toml"
        path.write_text(edit(path.read_text()))

    return damage


def _replace(name: str, make: Callable[[Path, Path], None]) -> Callable[[Path, Path], None]:
    """`name` in the run directory removed and made again by `make(path, outside)`."""

    def damage(run: Path, outside: Path) -> None:
        path = run / name
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink(missing_ok=True)
        make(path, outside)

    return damage


def _success(value: str) -> Callable[[Path, Path], None]:
    """metrics.csv with every row's success set to `value` (as written in the file)."""

    def damage(run: Path, outside: Path) -> None:
        path = run / "metrics.csv"
        frame = pd.read_csv(path, dtype=str, keep_default_na=False)
        frame["success"] = value
        frame.to_csv(path, index=False)

    return damage


def _link_out(target: str, directory: bool = False) -> Callable[[Path, Path], None]:
    def make(path: Path, outside: Path) -> None:
        where = outside / target
        if directory:
            where.mkdir(exist_ok=True)
            (where / "keep.txt").write_text("outside, must stay\n")
        elif not where.exists():
            where.write_text(OUTSIDE_TOML)
        path.symlink_to(where, target_is_directory=directory)

    return make


def _fifo(path: Path, outside: Path) -> None:
    os.mkfifo(path)


def _directory(path: Path, outside: Path) -> None:
    path.mkdir()


def _device(path: Path, outside: Path) -> None:
    try:
        os.mknod(path, stat.S_IFCHR | 0o600, os.makedev(1, 5))  # what /dev/zero is
    except PermissionError:
        pytest.skip("making a device node needs CAP_MKNOD")


def _checkpoint(edit: Callable[[dict[str, Any]], None], name: str = NEWEST) -> Callable:
    """A checkpoint of the run edited field by field and saved back as torch.save would."""

    def damage(run: Path, outside: Path) -> Path:
        path = run / "checkpoints" / name
        data = torch.load(path, weights_only=True)
        edit(data)
        torch.save(data, path)
        return path

    return damage


def _set(*keys_and_value: Any) -> Callable[[dict[str, Any]], None]:
    *keys, value = keys_and_value

    def edit(data: dict[str, Any]) -> None:
        node = data
        for key in keys[:-1]:
            node = node[key]
        node[keys[-1]] = value

    return edit


def _drop(*keys: str) -> Callable[[dict[str, Any]], None]:
    def edit(data: dict[str, Any]) -> None:
        node = data
        for key in keys[:-1]:
            node = node[key]
        del node[keys[-1]]

    return edit


def _newest(make: Callable[[Path, Path], None]) -> Callable[[Path, Path], Path]:
    """The newest epoch checkpoint replaced by what `make` puts there (a link, FIFO, folder)."""

    def damage(run: Path, outside: Path) -> Path:
        path = run / "checkpoints" / NEWEST
        if make is _link_out_checkpoint:
            shutil.copy(path, outside / NEWEST)  # a valid checkpoint, but another directory's
        path.unlink()
        make(path, outside)
        return path

    return damage


def _link_out_checkpoint(path: Path, outside: Path) -> None:
    path.symlink_to(outside / NEWEST)


def _protocol(text: str | bytes | None) -> Callable[[Path, Path], Path]:
    """A protocol file outside the run (for explain); None: a FIFO."""

    def damage(run: Path, outside: Path) -> Path:
        path = outside / "protocol.toml"
        if text is None:
            os.mkfifo(path)
        elif isinstance(text, bytes):
            path.write_bytes(text)
        else:
            path.write_text(text)
        return path

    return damage


def _then(first: Callable, second: Callable) -> Callable[[Path, Path], Path | None]:
    def damage(run: Path, outside: Path) -> Path | None:
        first(run, outside)
        return second(run, outside)

    return damage


def _pad(text: str) -> str:
    return text + ("# padding to over a mebibyte\n" * 40_000)


def _deep(text: str) -> str:
    return "deep = " + "[" * 400 + "]" * 400 + "\n" + text


def _at(name: str) -> Callable[[Path, Path], Path]:
    return lambda run, outside: run / name


def _link_out_best(path: Path, outside: Path) -> None:
    shutil.copy(path.parent / OLDER, outside / "best.pt")  # a valid checkpoint, elsewhere
    path.symlink_to(outside / "best.pt")


GARBAGE_TOML = "[protocol\nname = = 1"
BAD_ADAPTER = PROTOCOL.replace('adapter = "point"', 'adapter = ".x:Y"')
EMPTY_MODULE = PROTOCOL.replace('adapter = "point"', 'adapter = ":Y"')
BAD_ADAPTER_CONFIG = "[protocol]\nname = 'x'\n[envs.pt]\nadapter = '.x:Y'\n"

# ---------------------------------------------------------------- the corpus

CASES = [
    # config.toml on --resume
    Case(
        "resume/config-bad-syntax",
        _edit_config(lambda t: t + "[protocol\n"),
        "resume",
        "config.toml: not valid TOML",
    ),
    Case(
        "resume/config-not-utf8",
        _replace("config.toml", lambda p, o: p.write_bytes(b'[protocol]\nname = "caf\xe9"\n')),
        "resume",
        "not UTF-8",
    ),
    Case(
        "resume/config-symlink-out",
        _replace("config.toml", _link_out("system.toml")),
        "resume",
        "symlink leading out of",
    ),
    Case("resume/config-fifo", _replace("config.toml", _fifo), "resume", "FIFO"),
    Case(
        "resume/config-directory", _replace("config.toml", _directory), "resume", "is a directory"
    ),
    Case("resume/config-device", _replace("config.toml", _device), "resume", "character device"),
    Case("resume/config-over-1-mib", _edit_config(_pad), "resume", "at most 1,048,576 bytes"),
    Case(
        "resume/config-nested-too-deep",
        _edit_config(_deep),
        "resume",
        "more than 32 levels deep; at most 32 are valid",
    ),
    Case(
        "resume/config-adapter-relative",
        _edit_config(lambda t: t.replace('adapter = "point"', 'adapter = ".x:Y"')),
        "resume",
        "envs.pt.adapter: adapter '.x:Y': module '.x' is not an absolute import path",
    ),
    Case(
        "resume/config-adapter-empty-module",
        _edit_config(lambda t: t.replace('adapter = "point"', 'adapter = ":Y"')),
        "resume",
        "module '' is not an absolute import path",
    ),
    # what --resume writes through
    Case(
        "resume/metrics-symlink-out",
        _replace("metrics.csv", _link_out("metrics.csv")),
        "resume",
        "metrics.csv is a symlink leading out of",
    ),
    Case("resume/metrics-fifo", _replace("metrics.csv", _fifo), "resume", "metrics.csv is a FIFO"),
    Case(
        "resume/checkpoints-symlink-out",
        _replace("checkpoints", _link_out("ckpts", directory=True)),
        "resume",
        "checkpoints is a symlink leading out of",
    ),
    Case(
        "resume/tb-phase-symlink-out",
        _replace("tb", lambda p, o: (p.mkdir(), _link_out("tb", directory=True)(p / "train", o))),
        "resume",
        "tb/train is a symlink leading out of",
    ),
    Case(
        "resume/lock-symlink-out",
        _replace(".seal.lock", _link_out("lock.txt")),
        "resume",
        "lock file is a symlink leading out of",
    ),
    Case(
        "resume/provenance-not-json",
        _replace("provenance.json", lambda p, o: p.write_text("{not json")),
        "resume",
        "provenance.json: not valid JSON",
    ),
    Case(
        "resume/provenance-resumes-not-a-list",
        _replace("provenance.json", lambda p, o: p.write_text('{"resumes": 3}')),
        "resume",
        "field resumes = 3",
    ),
    # a damaged newest epoch checkpoint on --resume: skipped, the one before resumes
    Case(
        "fallback/no-config_toml",
        _checkpoint(_drop("config_toml")),
        "resume",
        "field config_toml is missing",
        "fallback",
    ),
    Case(
        "fallback/garbage-config_toml",
        _checkpoint(_set("config_toml", GARBAGE_TOML)),
        "resume",
        "field config_toml (the run's config): not valid TOML",
        "fallback",
    ),
    Case(
        "fallback/unknown-phase",
        _checkpoint(_set("phase", "warmup")),
        "resume",
        "field phase = 'warmup'; expected one of this run's phases: train",
        "fallback",
    ),
    Case(
        "fallback/no-runner",
        _checkpoint(_drop("runner")),
        "resume",
        "field runner is missing",
        "fallback",
    ),
    Case(
        "fallback/runner-none",
        _checkpoint(_set("runner", None)),
        "resume",
        "field runner = None; expected a table",
        "fallback",
    ),
    Case(
        "fallback/epoch-a-string",
        _checkpoint(_set("runner", "state", "epoch", "4")),
        "resume",
        "field runner.state.epoch = '4'; expected an integer",
        "fallback",
    ),
    Case(
        "fallback/unknown-counter",
        _checkpoint(_set("runner", "state", "bogus", 1)),
        "resume",
        "field runner.state.bogus is not a field seal run writes",
        "fallback",
    ),
    Case(
        "fallback/rows-negative",
        _checkpoint(_set("runner", "rows", "metrics.csv", -1)),
        "resume",
        "field runner.rows['metrics.csv'] = -1",
        "fallback",
    ),
    Case(
        "fallback/torch-rng-floats",
        _checkpoint(_set("runner", "torch_rng", torch.zeros(3))),
        "resume",
        "field runner.torch_rng = a torch.float32 tensor of shape [3]",
        "fallback",
    ),
    Case(
        "fallback/python-rng-garbage",
        _checkpoint(_set("runner", "py_rng", [3, [1, 2], None])),
        "resume",
        "field runner.py_rng",
        "fallback",
    ),
    Case(
        "fallback/agent-no-actor",
        _checkpoint(_drop("agent", "actor")),
        "resume",
        "field agent.actor is missing",
        "fallback",
    ),
    Case(
        "fallback/replay-not-tensors",
        _checkpoint(_set("replay", "envs", "pt", "obs", [1.0])),
        "resume",
        "field replay.envs['pt']['obs'] = [1.0]; expected a tensor",
        "fallback",
    ),
    Case(
        "fallback/scheduler-state-of-another-scheduler",
        _checkpoint(_set("scheduler", {"bogus": 1})),
        "resume",
        "field scheduler does not fit this run's 'ratio' scheduler (KeyError: 'credit')",
        "fallback",
    ),
    Case(
        "fallback/another-seed",
        _checkpoint(_set("seed", 7)),
        "resume",
        "field seed = 7; expected 0, this run's seed",
        "fallback",
    ),
    Case(
        "fallback/format-a-tensor",
        _checkpoint(_set("seal_checkpoint", torch.ones(2))),
        "resume",
        "not a seal checkpoint (format tensor(",
        "fallback",
    ),
    Case(
        "fallback/symlink-out",
        _newest(_link_out_checkpoint),
        "resume",
        "checkpoint is a symlink leading out of",
        "fallback",
    ),
    Case("fallback/fifo", _newest(_fifo), "resume", "checkpoint is a FIFO", "fallback"),
    Case(
        "resume/checkpoint-a-directory",
        _newest(_directory),
        "resume",
        "checkpoints/ckpt-0000004.pt is a directory",
    ),
    # seal report and seal.load_run
    Case(
        "report/config-bad-syntax",
        _edit_config(lambda t: t + "[protocol\n"),
        "report",
        "config.toml: not valid TOML",
    ),
    Case("report/config-over-1-mib", _edit_config(_pad), "report", "at most 1,048,576 bytes"),
    Case(
        "report/protocol-not-a-table",
        _edit_config(lambda t: 'protocol = "text"\n' + t.replace("[protocol]", "[protocol_was]")),
        "report",
        "protocol = 'text'; expected a table",
    ),
    Case(
        "report/adapter-a-list",
        _edit_config(lambda t: t.replace('adapter = "point"', "adapter = [1]")),
        "report",
        "envs.pt.adapter = [1]; expected an adapter name",
    ),
    Case(
        "report/threshold-a-string",
        _edit_config(lambda t: t.replace("threshold = 0.9", 'threshold = "high"')),
        "report",
        "evaluation.threshold = 'high'",
    ),
    Case("report/metrics-fifo", _replace("metrics.csv", _fifo), "report", "metrics.csv is a FIFO"),
    Case(
        "report/metrics-symlink-out",
        _replace("metrics.csv", _link_out("metrics.csv")),
        "report",
        "metrics.csv is a symlink leading out of",
    ),
    Case(
        "report/metrics-success-all-nan",
        _success("nan"),
        "report",
        "metrics.csv: line 2 has success = nan; expected a success rate, a finite number in [0, 1]",
    ),
    Case(
        "report/metrics-success-above-one",
        _success("2.5"),
        "report",
        "metrics.csv: line 2 has success = 2.5; expected a success rate",
    ),
    Case(
        "report/provenance-seed-a-string",
        _replace("provenance.json", lambda p, o: p.write_text('{"seed": "zero"}')),
        "report",
        "field seed = 'zero'",
    ),
    Case(
        "report/tables-symlink-out",
        _replace("tables", _link_out("tables", directory=True)),
        "report",
        "tables/ folder is a symlink leading out of",
    ),
    Case(
        "report/plots-symlink-out",
        _replace("plots", _link_out("plots", directory=True)),
        "report",
        "plots/ folder is a symlink leading out of",
    ),
    Case(
        "report/update-counts-md-symlink-out",
        _replace(
            "tables",
            lambda p, o: (p.mkdir(), _link_out("update_counts.md")(p / "update_counts.md", o)),
        ),
        "report",
        "update_counts.md",
        "replaced",
    ),
    Case(
        "load_run/config-symlink-out",
        _replace("config.toml", _link_out("system.toml")),
        "load_run",
        "symlink leading out of",
    ),
    Case(
        "load_run/config-fifo",
        _replace("config.toml", _fifo),
        "load_run",
        "config.toml: the run config is a FIFO",
    ),
    Case(
        "load_run/provenance-fifo",
        _replace("provenance.json", _fifo),
        "load_run",
        "provenance.json: the provenance is a FIFO",
    ),
    Case(
        "load_run/train-directory",
        _replace("train.csv", _directory),
        "load_run",
        "train.csv is a directory",
    ),
    # seal eval
    Case(
        "eval/no-config_toml",
        _checkpoint(_drop("config_toml")),
        "eval",
        "field config_toml is missing",
    ),
    Case(
        "eval/garbage-config_toml",
        _checkpoint(_set("config_toml", GARBAGE_TOML)),
        "eval",
        "field config_toml (the run's config): not valid TOML",
    ),
    Case(
        "eval/config_toml-adapter-relative",
        _checkpoint(_set("config_toml", BAD_ADAPTER_CONFIG)),
        "eval",
        "field config_toml: envs.pt.adapter: adapter '.x:Y'",
    ),
    Case(
        "eval/unknown-phase",
        _checkpoint(_set("phase", "warmup")),
        "eval",
        "field phase = 'warmup'; expected one of train, pretrain, finetune",
    ),
    Case("eval/no-runner", _checkpoint(_drop("runner")), "eval", "field runner is missing"),
    Case(
        "eval/specs-a-string",
        _checkpoint(_set("agent", "specs", "pt")),
        "eval",
        "field agent.specs = 'pt'; expected a list",
    ),
    Case(
        "eval/actor-wrong-shape",
        _checkpoint(
            lambda d: d["agent"]["actor"].update({k: torch.zeros(1) for k in d["agent"]["actor"]})
        ),
        "eval",
        "field agent does not fit the agent its saved config builds",
    ),
    Case("eval/fifo", _newest(_fifo), "eval", "checkpoint is a FIFO"),
    Case(
        "eval/best-symlink-out",
        _then(_replace("checkpoints/best.pt", _link_out_best), _at("checkpoints/best.pt")),
        "eval",
        "checkpoint is a symlink leading out of",
    ),
    Case(
        "eval/directory",
        _then(_replace("checkpoints/best.pt", _directory), _at("checkpoints/best.pt")),
        "eval",
        "checkpoint is a directory",
    ),
    # [transfer] checkpoint: refused before any run directory exists
    Case(
        "transfer/no-config_toml",
        _checkpoint(_drop("config_toml"), "best.pt"),
        "transfer",
        "transfer.checkpoint = '{path}': checkpoint {path}: field config_toml is missing",
    ),
    Case(
        "transfer/garbage-config_toml",
        _checkpoint(_set("config_toml", GARBAGE_TOML), "best.pt"),
        "transfer",
        "field config_toml (the run's config): not valid TOML",
    ),
    Case(
        "transfer/unknown-phase",
        _checkpoint(_set("phase", "warmup"), "best.pt"),
        "transfer",
        "field phase = 'warmup'",
    ),
    Case(
        "transfer/no-runner",
        _checkpoint(_drop("runner"), "best.pt"),
        "transfer",
        "field runner is missing",
    ),
    Case(
        "transfer/actor-not-tensors",
        _checkpoint(_set("agent", "actor", {"w": 1.5}), "best.pt"),
        "transfer",
        "field agent.actor['w'] = 1.5; expected a tensor",
    ),
    Case(
        "transfer/fifo",
        _then(_replace("checkpoints/best.pt", _fifo), _at("checkpoints/best.pt")),
        "transfer",
        "checkpoint is a FIFO",
    ),
    # seal protocol explain of a damaged protocol
    Case(
        "explain/adapter-relative",
        _protocol(BAD_ADAPTER),
        "explain",
        "envs.pt.adapter: adapter '.x:Y': module '.x' is not an absolute import path",
    ),
    Case(
        "explain/adapter-empty-module",
        _protocol(EMPTY_MODULE),
        "explain",
        "envs.pt.adapter: adapter ':Y': module '' is not an absolute import path",
    ),
    Case("explain/fifo", _protocol(None), "explain", "protocol file is a FIFO"),
    Case(
        "explain/nested-too-deep",
        _protocol(_deep(PROTOCOL)),
        "explain",
        "more than 32 levels deep; at most 32 are valid",
    ),
    Case(
        "explain/key-with-a-newline",
        _protocol(PROTOCOL + '[envs."p\\nt"]\nadapter = "point"\n'),
        "explain",
        "the env name 'p\\nt' is not valid",
    ),
]


# ---------------------------------------------------------------- the test


@pytest.fixture(scope="module")
def protocol(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("protocol") / "faults.toml"
    path.write_text(PROTOCOL)
    return path


@pytest.fixture(scope="module")
def reference(protocol: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An undamaged run: checkpoints at epochs 2 and 4, best.pt, tables and plots."""
    run = run_seed(load_protocol(protocol), 0, tmp_path_factory.mktemp("ref") / "g").run_dir
    assert main(["report", str(run)]) == 0
    return run


def _snapshot(root: Path) -> dict[str, object]:
    """Every entry under `root` (not following links): its kind, link target or bytes."""
    out: dict[str, object] = {}
    for path in sorted(root.rglob("*")):
        name = str(path.relative_to(root))
        if path.name == ".seal.lock":
            continue  # it records the last process that took the lock, by design
        mode = path.lstat().st_mode
        if stat.S_ISLNK(mode):
            out[name] = ("link", os.readlink(path))
        elif stat.S_ISREG(mode):
            out[name] = path.read_bytes()
        else:
            out[name] = stat.S_IFMT(mode)
    return out


def _read(protocol: Path, case: Case, run: Path, given: Path | None, tmp: Path) -> tuple[int, str]:
    """Hand the damaged run (or file) to the case's reader: (exit code, stderr or message)."""
    if case.reader == "load_run":
        try:
            seal.load_run(run)
        except SealError as exc:
            return 2, str(exc)
        return 0, ""
    if case.reader == "resume":
        argv = ["run", str(protocol), "--resume", str(run), "--quiet", "--no-report"]
    elif case.reader == "report":
        argv = ["report", str(run)]
    elif case.reader == "eval":
        argv = ["eval", str(given), "--episodes", "1"]
    elif case.reader == "transfer":
        with_transfer = tmp / "with_transfer.toml"
        with_transfer.write_text(PROTOCOL + f'[transfer]\ncheckpoint = "{given}"\n')
        argv = ["run", str(with_transfer), "--out", str(tmp / "new"), "--quiet", "--no-report"]
    else:
        argv = ["protocol", "explain", str(given)]
    return main(argv), ""


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_a_damaged_run_directory_is_refused_in_one_line_or_falls_back(
    case: Case,
    protocol: Path,
    reference: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    run = shutil.copytree(reference, tmp_path / "faults" / "g" / "seed-0", symlinks=True)
    outside = tmp_path / "outside"
    outside.mkdir()
    given = case.damage(run, outside)
    before, around = _snapshot(run), _snapshot(outside)
    capsys.readouterr()
    code, message = _read(protocol, case, run, given, tmp_path)
    err = message or capsys.readouterr().err
    says = case.says.format(path=given)
    assert "Traceback" not in err
    if case.outcome == "refused":
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 1, err
        assert says in lines[0], lines[0]
        assert _snapshot(run) == before, "a refused reader wrote into the run directory"
        assert not (tmp_path / "new").exists()
    elif case.outcome == "fallback":
        assert code == 0, err
        skipped = run / "checkpoints" / NEWEST
        assert f"skipping {skipped}: " in err and says in err, err
        assert f"resuming from {run / 'checkpoints' / OLDER}" in err
        got, want = pd.read_csv(run / "metrics.csv"), pd.read_csv(reference / "metrics.csv")
        pd.testing.assert_frame_equal(got.drop(columns="wall_s"), want.drop(columns="wall_s"))
    else:  # replaced: the link became a file of the report's own
        assert code == 0, err
        assert (run / "tables" / says).is_file() and not (run / "tables" / says).is_symlink()
    assert _snapshot(outside) == around, "a reader wrote through a link out of the run directory"


def test_the_corpus_has_every_kind_of_case() -> None:
    kinds = {c.reader for c in CASES}
    assert kinds == {"resume", "report", "load_run", "eval", "transfer", "explain"}
    assert len(CASES) >= 30 and len({c.id for c in CASES}) == len(CASES)
