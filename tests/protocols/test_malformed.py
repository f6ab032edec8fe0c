"""Every malformed protocol is rejected at load: exit 2, one line naming the key, nothing written.

One defect at a time on a valid base file (which itself runs, first test), given to `seal run`.
"""

from __future__ import annotations

from pathlib import Path
from typing import get_args, get_type_hints

import pytest

from seal.cli.main import main
from seal.learner.env_backends import BACKENDS
from seal.protocols.config import TrainingConfig

BASE = """\
[protocol]
kind = "baseline"
epochs = 1
seeds = 1
device = "cpu"
threads = 1
[envs.pt]
adapter = "point"
tasks = ["east", "north"]
episode_length = 10
[agent]
hidden = [8, 8]
[replay]
capacity_per_env = 1000
[training]
warmup_steps = 0
batch_per_task = 4
collector = "sync"
[evaluation]
interval = 1
episodes = 1
threshold = 0.9
[checkpoint]
interval = 1
keep_last = 1
[logging]
tensorboard = false
[resources]
cpus = 1
[search]
num_samples = 2
"agent.actor_lr" = {dist = "loguniform", low = 1e-4, high = 1e-3}
"""


def _edit(old: str, new: str) -> str:
    assert old in BASE, old
    return BASE.replace(old, new, 1)


# (id, protocol text or bytes, extra CLI args, text the one-line error must contain)
FINETUNE = BASE.replace('kind = "baseline"', 'kind = "finetune"') + (
    '[envs.pd]\nadapter = "point_diagonal"\n[finetune]\nsource = "pt"\ntarget = "pd"\n'
)

CASES: list[tuple[str, str | bytes, list[str], str]] = [
    (
        "not-utf8",
        BASE.encode() + b"# caf\xe9\n",
        [],
        f"not UTF-8 text (byte 0xe9 on line {BASE.count(chr(10)) + 1})",
    ),
    ("bad-toml", BASE + "[protocol\n", [], "not valid TOML"),
    (
        "unknown-table",
        BASE + "[trainning]\nwarmup_steps = 1\n",
        [],
        "[trainning] is not a valid table",
    ),
    ("protocol-key", _edit("epochs = 1", "epocs = 1"), [], "protocol.epocs is not a valid key"),
    (
        "protocol-kind",
        _edit('kind = "baseline"', 'kind = "solo"'),
        [],
        "protocol.kind = 'solo' is not valid",
    ),
    ("seeds-zero", _edit("seeds = 1", "seeds = 0"), [], "protocol.seeds = 0 is out of range"),
    (
        "env-key",
        _edit("episode_length = 10", "episode_len = 10"),
        [],
        "envs.pt.episode_len is not a valid key",
    ),
    ("env-adapter", _edit('adapter = "point"', 'adapter = "pointt"'), [], "envs.pt.adapter"),
    ("env-task", _edit('"north"]', '"nort"]'), [], "'nort'"),
    # An empty env name ran, then no report could read its metrics.csv.
    ("env-name-empty", _edit("[envs.pt]", '[envs.""]'), [], "the env name '' is not valid"),
    ("env-name-space", _edit("[envs.pt]", '[envs."p t"]'), [], "the env name 'p t' is not valid"),
    # Both were tracebacks when the run directory was made (embedded null byte; name too long).
    ("name-nul", _edit('kind = "baseline"', 'kind = "baseline"\nname = "a\\u0000b"'), [], "NUL"),
    (
        "name-long",
        _edit('kind = "baseline"', f'kind = "baseline"\nname = "{"a" * 256}"'),
        [],
        "at most 255 bytes",
    ),
    (
        "joint-one-env",
        _edit('kind = "baseline"', 'kind = "joint"'),
        [],
        'kind = "joint" needs at least two',
    ),
    ("agent-key", _edit("hidden = [8, 8]", "hiden = [8, 8]"), [], "agent.hiden is not a valid key"),
    ("agent-type", _edit("hidden = [8, 8]", 'hidden = "wide"'), [], "agent.hidden"),
    ("agent-lr", _edit("hidden = [8, 8]", "hidden = [8, 8]\nactor_lr = 0"), [], "agent.actor_lr"),
    (
        "replay-zero",
        _edit("capacity_per_env = 1000", "capacity_per_env = 0"),
        [],
        "replay.capacity_per_env = 0 is out of range",
    ),
    (
        "collector",
        _edit('collector = "sync"', 'collector = "threads"'),
        [],
        "training.collector = 'threads' is not valid",
    ),
    (
        "int-as-float",
        _edit("batch_per_task = 4", "batch_per_task = 4.5"),
        [],
        "training.batch_per_task = 4.5 has the wrong type",
    ),
    (
        "threshold",
        _edit("threshold = 0.9", "threshold = 1.5"),
        [],
        "evaluation.threshold = 1.5 is out of range",
    ),
    (
        "threshold-nan",
        _edit("threshold = 0.9", "threshold = nan"),
        [],
        "evaluation.threshold = nan is not valid; expected a finite number",
    ),
    (
        "keep-last",
        _edit("keep_last = 1", "keep_last = 0"),
        [],
        "checkpoint.keep_last = 0 is out of range",
    ),
    (
        "logging-type",
        _edit("tensorboard = false", 'tensorboard = "no"'),
        [],
        "logging.tensorboard = 'no' has the wrong type",
    ),
    ("scheduler-kind", BASE + '[scheduler]\nkind = "smtt"\n', [], "scheduler.kind"),
    (
        "transfer-lr",
        BASE + '[transfer]\ncheckpoint = "x.pt"\nlr_factor = 0\n',
        [],
        "transfer.lr_factor = 0 is out of range; valid: > 0",
    ),
    (
        "transfer-missing",
        BASE + '[transfer]\ncheckpoint = "missing.pt"\n',
        [],
        "transfer.checkpoint = 'missing.pt'",
    ),
    (
        "transfer-map",
        BASE + '[transfer]\ncheckpoint = "x.pt"\nmap = ":X"\n',
        [],
        "transfer: map: env map ':X': module '' is not an absolute import path; valid: testbed_oracle",
    ),
    (
        "env-option-repeats",
        BASE,
        ["--set", 'envs.pt.options={tasks=["west"]}'],
        "envs.pt.options: option 'tasks' is not an adapter option: it is the env's own key",
    ),
    (
        "replay-below-tasks",
        BASE,
        ["--set", "replay.capacity_per_env=1"],
        "replay.capacity_per_env = 1 is below the 2 tasks of envs.pt",
    ),
    (
        "replay-too-big",
        BASE,
        ["--set", "replay.capacity_per_env=1000000000000"],
        "replay.capacity_per_env = 1000000000000: the run needs an estimated 44,703",
    ),
    # Would fail only when the first evaluation builds its policy, after the run directory:
    (
        "finetune-smt-gru",
        FINETUNE,
        ["--set", 'agent.task_encoder="smt_gru"'],
        'agent.task_encoder = "smt_gru" does not run through a pad-and-fine-tune alignment',
    ),
    # Would fail only when fine-tuning starts, after the whole pre-training:
    (
        "finetune-lr",
        BASE + "[finetune]\nlr_factor = 0.0\n",
        [],
        "finetune.lr_factor = 0.0 is out of range; valid: > 0",
    ),
    (
        "resources-key",
        _edit("cpus = 1", "cpuz = 2"),
        [],
        "resources.cpuz is not a valid key; valid keys: cpus, gpus",
    ),
    ("resources-value", _edit("cpus = 1", "cpus = 0"), [], "resources.cpus = 0 is not valid"),
    ("search-option", _edit("num_samples = 2", "num_sample = 2"), [], "search.num_sample"),
    (
        "search-key",
        _edit('"agent.actor_lr"', '"agent.actor_lrr"'),
        [],
        "agent.actor_lrr is not a valid key",
    ),
    (
        "search-table",
        _edit('"agent.actor_lr"', '"agnt.actor_lr"'),
        [],
        "[agnt] is not a valid table",
    ),
    (
        "search-range",
        _edit(
            '{dist = "loguniform", low = 1e-4, high = 1e-3}',
            '{dist = "uniform", low = -1.0, high = 1e-3}',
        ),
        [],
        "agent.actor_lr",
    ),
    (
        "search-dist",
        _edit('dist = "loguniform"', 'dist = "normal"'),
        [],
        "search.agent.actor_lr.dist = 'normal' is not valid",
    ),
    ("set-syntax", BASE, ["--set", "epochs=3"], "must look like table.key=value"),
    ("set-key", BASE, ["--set", "protocol.epoch=3"], "protocol.epoch is not a valid key"),
    (
        "set-type",
        BASE,
        ["--set", "protocol.epochs=many"],
        "protocol.epochs = 'many' has the wrong type",
    ),
    ("seeds-flag", BASE, ["--seeds", "one"], "--seeds 'one'"),
    ("seeds-range", BASE, ["--seeds", "3-1"], "--seeds '3-1'"),
    (
        "device-unknown",
        BASE,
        ["--set", 'protocol.device="tpu"'],
        "protocol.device = 'tpu' is not a device name; valid: auto, cpu, cuda, cuda:<index>",
    ),
    ("agent-device", BASE, ["--set", 'agent.device="cuda:x"'], "agent.device = 'cuda:x' is not"),
    ("seeds-twice", BASE, ["--seeds", "2,0-2"], "--seeds '2,0-2' lists seed 2 more than once"),
    ("seeds-empty", BASE, ["--seeds="], "--seeds '': expected N, A-B or A,B"),
    ("scale-zero", BASE, ["--scale", "0"], "--scale 0"),
    ("scale-nan", BASE, ["--scale", "nan"], "--scale nan"),
    ("scale-word", BASE, ["--scale", "half"], "--scale"),
    # Scheduler values that passed the check and failed (or did something else) in the run:
    (
        "scheduler-absent-huge",
        BASE + '[scheduler]\nkind = "constant"\nratios = {pt = 0.5, g = 0.5}\n',
        ["--set", "scheduler.absent={g=1000000000000}"],
        "scheduler.absent.g = 1000000000000: expected a task count of at most 1,000",
    ),
    (
        "scheduler-absent-only",
        BASE + '[scheduler]\nkind = "constant"\nratios = {pt = 0.0, g = 1.0}\nabsent = {g = 4}\n',
        [],
        "scheduler.ratios = {'pt': 0.0, 'g': 1.0}: no env of this run (pt) has a share > 0",
    ),
    (
        "scheduler-negative-preset-limit",
        BASE + '[scheduler]\nkind = "curriculum_v2"\npreset = "sequential"\n',
        ["--set", "scheduler.max_phase_env_steps=-5", "--scale", "0.5"],
        "scheduler.max_phase_env_steps = -5: must be >= 0 (0 = no limit)",
    ),
    (
        "scheduler-order-beside-phases",
        BASE + '[scheduler]\nkind = "curriculum_v2"\norder = ["bogus"]\n'
        '[[scheduler.phases]]\ntasks = ["east"]\n',
        [],
        "scheduler.order = ['bogus']: applies only to a preset, not to scheduler.phases",
    ),
    (
        "scheduler-start-fraction-beside-start",
        BASE + '[scheduler]\nkind = "stepped"\nstart = {pt = 1.0}\nstart_fraction = 0.7\n',
        [],
        "scheduler.start_fraction = 0.7: applies only to a preset, not to scheduler.start",
    ),
    (
        "scheduler-task-twice",
        BASE + '[scheduler]\nkind = "curriculum_v1"\n[[scheduler.phases]]\nenv_steps = 100\n'
        'weights = {"pt/east" = 1, east = 5, north = 1}\n',
        [],
        "scheduler.phases[0].weights: 'pt/east' and 'east' both name task pt/east",
    ),
]


def _run(
    tmp_path: Path,
    text: str | bytes,
    args: list[str],
    capsys: pytest.CaptureFixture[str],
    check: bool = False,
) -> tuple[int, list[str], Path]:
    path = tmp_path / "p.toml"
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    out = tmp_path / "reports"
    capsys.readouterr()
    run = ["run", str(path), "--out", str(out), "--quiet", "--no-report"]
    try:
        code = main(["protocol", "check", str(path), *args] if check else [*run, *args])
    except SystemExit as exc:  # argparse rejects a flag's type itself
        code = int(exc.code or 0)
    return code, capsys.readouterr().err.strip().splitlines(), out


def test_the_base_file_runs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, err, out = _run(tmp_path, BASE, [], capsys)
    assert code == 0, err
    assert len(list(out.glob("p/*/seed-0/metrics.csv"))) == 1


def _checkable(case: tuple[str, str | bytes, list[str], str]) -> bool:
    """`seal protocol check` takes the file, --set and --scale (not --seeds or --out)."""
    return not case[2] or case[2][0] in ("--set", "--scale")


@pytest.mark.parametrize(
    ("command", "text", "args", "expected"),
    [(cmd, *c[1:]) for c in CASES for cmd in ("run", "check") if cmd == "run" or _checkable(c)],
    ids=[
        f"{cmd}-{c[0]}" for c in CASES for cmd in ("run", "check") if cmd == "run" or _checkable(c)
    ],
)
def test_each_defect_is_one_line_exit_2_and_nothing_written(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    command: str,
    text: str | bytes,
    args: list[str],
    expected: str,
) -> None:
    """`seal run` refuses each defect before writing; `seal protocol check` refuses it too."""
    code, err, out = _run(tmp_path, text, args, capsys, check=command == "check")
    assert code == 2
    assert len(err) == 1, err
    assert expected in err[0], err[0]
    assert "Traceback" not in err[0]
    if not args or args[0] == "--set":
        assert str(tmp_path / "p.toml") in err[0]  # the file is named
    assert not out.exists()


def test_an_out_that_is_not_a_directory_is_one_line_and_nothing_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "a.pt").write_text("not a directory")
    for out, says in [
        (tmp_path / "a.pt", f"--out {tmp_path / 'a.pt'}: {tmp_path / 'a.pt'} is a file, not a"),
        (tmp_path / "a.pt" / "deeper", f"{tmp_path / 'a.pt'} is a file, not a directory"),
        ("", "--out '': expected a directory name"),  # else runs would land in the working dir
        (tmp_path / ("x" * 300), "is 300 bytes long; a file or folder name holds at most 255"),
        ("/proc/seal-out", "cannot create the run directory (No such file or directory"),
    ]:
        code, err, _ = _run(tmp_path, BASE, ["--out", str(out)], capsys)
        assert code == 2 and len(err) == 1 and says in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.pt", "p.toml"]


def test_every_collection_backend_is_a_valid_collector() -> None:
    assert set(get_args(get_type_hints(TrainingConfig)["collector"])) == set(BACKENDS)


def test_finetune_defaults_the_task_encoder_by_architecture(tmp_path: Path) -> None:
    from seal.errors import ConfigError
    from seal.protocols import load_protocol

    path = tmp_path / "ft.toml"
    path.write_text(FINETUNE)
    assert load_protocol(path).agent.task_encoder == "none"  # the aligned obs carries the id
    paco = ['agent.architecture="paco"']
    assert load_protocol(path, paco).agent.task_encoder == "one_hot"  # the only one it runs with
    with pytest.raises(ConfigError, match="agent.task_encoder must be \"one_hot\", got 'none'"):
        load_protocol(path, [*paco, 'agent.task_encoder="none"'])  # said, not defaulted


def test_protocol_check_of_a_gpu_protocol_on_a_machine_without_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "p.toml"
    path.write_text(BASE)
    capsys.readouterr()
    assert main(["protocol", "check", str(path), "--set", 'protocol.device="cuda:99"']) == 0
    out = capsys.readouterr().out
    assert out.startswith(
        f"{path}: ok (protocol 'p', kind baseline, envs pt); memory not checked: "
    )
    assert "device 'cuda:99' requested but this machine has" in out
