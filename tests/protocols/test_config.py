"""Protocol TOML schema: defaults, overrides, --scale, explain, round trip, and bad input of every kind."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from seal.cli.main import main
from seal.errors import ConfigError
from seal.protocols import config_to_dict, dumps_toml, explain, load_protocol
from seal.protocols.loader import config_from_dict
from seal.protocols.toml_io import parse_override
from seal.schedulers.base import scale_duration

PROTOCOLS = Path(__file__).resolve().parents[2] / "protocols"

BASELINE = """
[protocol]
kind = "baseline"
[envs.pt]
adapter = "point"
tasks = ["east", "north"]
"""

JOINT = """
[protocol]
kind = "joint"
epochs = 5000
[envs.a]
adapter = "point"
tasks = ["east"]
[envs.b]
adapter = "point"
tasks = ["west", "south"]
[scheduler]
kind = "stepped"
start = { a = 0.9, b = 0.1 }
interval = 1000
"""

FINETUNE = """
[protocol]
kind = "finetune"
[envs.mw]
adapter = "metaworld"
tasks = ["reach-v3", "drawer-close-v3"]
[envs.pt]
adapter = "point"
[finetune]
source = "mw"
target = "pt"
"""


def write(tmp_path: Path, text: str, name: str = "proto.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_defaults_are_issue_4_paper_scale(tmp_path: Path) -> None:
    config = load_protocol(write(tmp_path, BASELINE))
    # issue 4's table: 10,000 epochs, eval every 100 epochs with 50 episodes, threshold 0.9, 2 seeds;
    # issue 3's: warm-up 4,000 env steps per env, 128 transitions per task, replay 1e6 per env.
    assert (config.protocol.epochs, config.protocol.seeds) == (10_000, 2)
    assert (
        config.evaluation.interval,
        config.evaluation.episodes,
        config.evaluation.threshold,
    ) == (100, 50, 0.9)
    assert (
        config.training.warmup_steps,
        config.training.batch_per_task,
        config.training.grad_steps_per_epoch,
    ) == (4000, 128, -1)
    assert config.replay.capacity_per_env == 1_000_000
    assert config.name == "proto"  # the file's stem
    assert config.envs["pt"].episode_length == 50  # resolved from the point adapter's default
    assert config.agent.architecture == "mtmhsac" and config.agent.hidden == (400, 400, 400)
    assert config.seeds == [0, 1]


def test_joint_defaults_to_seal_networks_and_task_sets_expand(tmp_path: Path) -> None:
    config = load_protocol(write(tmp_path, JOINT))
    assert config.agent.architecture == "seal"
    mt = load_protocol(
        write(
            tmp_path,
            FINETUNE.replace('tasks = ["reach-v3", "drawer-close-v3"]', 'tasks = "mt3"'),
            "ft.toml",
        )
    )
    assert mt.envs["mw"].tasks == ("reach-v3", "push-v3", "pick-place-v3")
    assert (
        mt.finetune.pretrain_epochs == 10_000 and mt.finetune.finetune_epochs == 10_000
    )  # 0 -> [protocol].epochs


def test_set_overrides_parse_values_as_toml(tmp_path: Path) -> None:
    path = write(tmp_path, BASELINE)
    config = load_protocol(
        path,
        [
            "protocol.epochs=7",
            "envs.pt.tasks=['south']",
            "protocol.device=cpu",
            "agent.hidden=[8, 8]",
            "evaluation.threshold=0.5",
        ],
    )
    assert config.protocol.epochs == 7
    assert config.envs["pt"].tasks == ("south",)
    assert config.protocol.device == "cpu"  # not valid TOML: taken as a string
    assert config.agent.hidden == (8, 8)
    assert config.evaluation.threshold == 0.5
    assert parse_override("a.b=true") == (["a", "b"], True)
    with pytest.raises(ConfigError, match="table.key=value"):
        load_protocol(path, ["epochs=3"])


def test_scale_multiplies_durations_only(tmp_path: Path) -> None:
    config = load_protocol(
        write(tmp_path, JOINT),
        ["evaluation.interval=100", "logging.train_interval=10", "checkpoint.interval=100"],
        scale=0.01,
    )
    # 5000 x 0.01 = 50 epochs; 100 x 0.01 = 1; 10 x 0.01 = 0.1 -> floor 1; 1000 x 0.01 = 10.
    assert config.protocol.epochs == 50
    assert config.evaluation.interval == 1
    assert config.logging.train_interval == 1
    assert config.checkpoint.interval == 1
    assert config.scheduler.interval == 10
    # Per-epoch quantities are untouched.
    assert config.training.batch_per_task == 128
    assert config.training.grad_steps_per_epoch == -1
    assert config.evaluation.episodes == 50
    assert config.envs["a"].episode_length == 50
    assert scale_duration(3, 0.5) == 2 and scale_duration(1, 0.001) == 1


def test_resolved_config_round_trips_through_toml(tmp_path: Path) -> None:
    for text in (BASELINE, JOINT, FINETUNE):
        config = load_protocol(write(tmp_path, text))
        again = config_from_dict(
            tomllib.loads(dumps_toml(config_to_dict(config))), str(tmp_path / "proto.toml")
        )
        assert again == config


def test_explain_prints_values_with_docs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    text = explain(load_protocol(write(tmp_path, JOINT)))
    assert "epochs = 5000    # Epochs per phase" in text
    assert "[scheduler]" in text and 'kind = "stepped"' in text
    assert main(["protocol", "explain", str(tmp_path / "proto.toml"), "--scale", "0.1"]) == 0
    assert "epochs = 500 " in capsys.readouterr().out


def test_every_shipped_protocol_is_valid_and_paper_scale() -> None:
    expected = {
        "baseline_mw",
        "baseline_fk",
        "finetune_fk_to_mw",
        "finetune_mw_to_fk",
        "joint_50_50",
        "high_fk",
        "high_mw",
        "quickstart",
    }
    found = {p.stem for p in PROTOCOLS.glob("*.toml")}
    assert expected <= found
    for name in expected - {"quickstart"}:
        config = load_protocol(PROTOCOLS / f"{name}.toml")
        assert config.protocol.epochs == 10_000 and config.protocol.seeds == 2
        assert config.evaluation.episodes == 50 and config.evaluation.interval == 100
    paper_scale = {p.stem for p in PROTOCOLS.glob("*.toml") if "GPU-scale" in p.read_text()}
    assert expected - {"quickstart"} <= paper_scale
    for name in paper_scale:
        # The header states the run's cost: a `seal bench --protocol` measurement where one was
        # made (with its projection per seed), else an estimate in GPU-hours labelled as one.
        text = (PROTOCOLS / f"{name}.toml").read_text().split("[protocol]")[0]
        header = " ".join(line.lstrip("#").strip() for line in text.splitlines())  # unwrapped
        measured = (
            f"seal bench --protocol protocols/{name}.toml" in header and "h per seed" in header
        )
        assert measured or "Estimate, not a measurement" in header and "GPU-hours" in header, name
    assert load_protocol(PROTOCOLS / "high_fk.toml").scheduler.preset == "high_fk"


# ---------------------------------------------------------------- bad input: key named, nothing written

BAD_CASES = [
    # (kind's base protocol, a change, the text the error must contain)
    (BASELINE, ("[protocol]", "[protocol]\nepoch = 3"), "protocol.epoch is not a valid key"),
    (BASELINE, ('kind = "baseline"', 'kind = "baseline"\nseeds = "two"'), "protocol.seeds"),
    (
        BASELINE,
        ('kind = "baseline"', 'kind = "baseline"\nepochs = 0'),
        "protocol.epochs = 0 is out of range",
    ),
    (BASELINE, ('tasks = ["east", "north"]', 'tasks = ["east", "up"]'), "envs.pt.tasks"),
    (BASELINE, ('adapter = "point"', 'adapter = "pointy"'), "envs.pt.adapter"),
    (
        BASELINE,
        ("[protocol]", "[evaluation]\nthreshold = 1.5\n[protocol]"),
        "evaluation.threshold = 1.5 is out of range",
    ),
    (BASELINE, ("[protocol]", "[agent]\nhidden = [400, -1]\n[protocol]"), "agent"),
    (BASELINE, ("[protocol]", "[traning]\nx = 1\n[protocol]"), "[traning] is not a valid table"),
    (JOINT, ('kind = "stepped"', 'kind = "steped"'), "scheduler.kind"),
    (JOINT, ("start = { a = 0.9, b = 0.1 }", "start = { a = 0.9, c = 0.1 }"), "scheduler.start"),
    (JOINT, ('tasks = ["east"]\n[envs.b]', 'tasks = ["east"]\n[envs.bb]'), "scheduler"),
    (FINETUNE, ('target = "pt"', 'target = "kitchen"'), "finetune.target"),
    (FINETUNE, ("[finetune]", "[finetune]\nlr_factor = -1.0"), "finetune.lr_factor"),
    (
        FINETUNE,
        ('tasks = ["reach-v3", "drawer-close-v3"]', 'tasks = ["reach-v9"]'),
        "envs.mw.tasks",
    ),
]


@pytest.mark.parametrize(("base", "change", "message"), BAD_CASES)
def test_bad_protocol_is_rejected_naming_key_and_file_and_nothing_is_written(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    base: str,
    change: tuple[str, str],
    message: str,
) -> None:
    assert change[0] in base
    path = write(tmp_path, base.replace(change[0], change[1], 1), "bad.toml")
    with pytest.raises(ConfigError) as info:
        load_protocol(path)
    assert message in str(info.value) and str(path) in str(info.value)
    out = tmp_path / "reports"
    assert main(["run", str(path), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not out.exists()  # no run directory on bad input


def test_kind_specific_structure_errors(tmp_path: Path) -> None:
    two_envs = BASELINE + '[envs.other]\nadapter = "point"\n'
    with pytest.raises(ConfigError, match="baseline.*exactly one"):
        load_protocol(write(tmp_path, two_envs))
    with pytest.raises(ConfigError, match="joint.*at least two"):
        load_protocol(write(tmp_path, BASELINE.replace("baseline", "joint")))
    with pytest.raises(ConfigError, match="needs a \\[finetune\\] table"):
        load_protocol(write(tmp_path, FINETUNE.split("[finetune]")[0]))
    with pytest.raises(ConfigError, match="only valid with kind"):
        load_protocol(write(tmp_path, BASELINE + '[finetune]\nsource = "pt"\n'))
    with pytest.raises(ConfigError, match="no such protocol file"):
        load_protocol(tmp_path / "missing.toml")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_protocol(write(tmp_path, "[protocol\n"))


def test_a_byte_order_mark_is_read_past(tmp_path: Path) -> None:
    """A UTF-8 file that starts with a byte-order mark (some Windows editors write one) loads as
    the same file without it; tomllib alone refused it as "Invalid statement" at line 1."""
    text = (PROTOCOLS / "learn" / "point.toml").read_bytes()
    marked = tmp_path / "point.toml"
    marked.write_bytes(b"\xef\xbb\xbf" + text)
    plain = load_protocol(PROTOCOLS / "learn" / "point.toml")
    assert config_to_dict(load_protocol(marked)) == config_to_dict(plain)
