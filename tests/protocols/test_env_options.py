"""`[envs.<name>] options = {...}` reach the adapter, which validates them: the kitchen's
gravity_compensation loads, survives the resolved config's round trip and builds the adapter
with it; an unknown option is a one-line ConfigError naming the file, key and valid options."""

from __future__ import annotations

from pathlib import Path

import pytest

from seal.errors import ConfigError
from seal.protocols import config_to_dict, dumps_toml, load_protocol
from seal.run.phase_model import build_adapters

KITCHEN = """
[protocol]
kind = "baseline"
[envs.fk]
adapter = "franka_kitchen_dense"
tasks = ["slide-cabinet"]
options = {{ {options} }}
"""


def _write(tmp_path: Path, options: str) -> Path:
    path = tmp_path / "kitchen.toml"
    path.write_text(KITCHEN.format(options=options))
    return path


def test_options_reach_the_adapter_and_round_trip(tmp_path: Path) -> None:
    config = load_protocol(_write(tmp_path, "gravity_compensation = true"))
    assert config.envs["fk"].options == {"gravity_compensation": True}
    assert build_adapters(config)["fk"].gravity_compensation is True
    again = tmp_path / "resolved.toml"
    again.write_text(dumps_toml(config_to_dict(config)))
    assert load_protocol(again).envs["fk"].options == {"gravity_compensation": True}


def test_no_options_is_upstream(tmp_path: Path) -> None:
    config = load_protocol(_write(tmp_path, ""))
    assert config.envs["fk"].options == {}
    assert build_adapters(config)["fk"].gravity_compensation is False


def test_unknown_option_is_a_one_line_error(tmp_path: Path) -> None:
    path = _write(tmp_path, "gravity = true")
    with pytest.raises(ConfigError) as error:
        load_protocol(path)
    message = str(error.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: envs.fk.options: ")
    assert "unknown option(s) ['gravity']" in message
    assert "valid options: gravity_compensation" in message
