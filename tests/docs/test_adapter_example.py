"""The worked adapter example of docs/adapters.md (docs/examples/my_envs.py) works as the page says."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from seal.cli.main import main
from seal.envs import make_adapter
from seal.envs.check import check_adapter

EXAMPLES = Path(__file__).resolve().parents[2] / "docs" / "examples"

PROTOCOL = """
[protocol]
name = "rail"
kind = "joint"
seeds = 1
epochs = 3
threads = 1

[envs.rail]
adapter = "my_envs:RailAdapter"

[envs.pt]
adapter = "point"
tasks = ["east"]
episode_length = 40

[agent]
architecture = "seal"
translator_hidden = [8]
latent_dim = 8
trunk_hidden = [8]

[training]
warmup_steps = 40
batch_per_task = 8
collector = "sync"

[evaluation]
interval = 3
episodes = 1

[checkpoint]
interval = 3
"""


@pytest.fixture
def examples_on_path(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.syspath_prepend(str(EXAMPLES))


@pytest.mark.usefixtures("examples_on_path")
def test_example_adapter_passes_envs_check(capsys: pytest.CaptureFixture[str]) -> None:
    adapter = make_adapter("my_envs:RailAdapter")
    assert adapter.tasks == ("push-left", "push-right")
    assert check_adapter(adapter)["ok"]
    assert main(["envs", "check", "my_envs:RailAdapter"]) == 0
    assert "rail: ok" in capsys.readouterr().out


@pytest.mark.usefixtures("examples_on_path")
def test_example_experts_solve_their_tasks() -> None:
    adapter = make_adapter("my_envs:RailAdapter")
    for task in adapter.tasks:
        env, expert = adapter.make(task, seed=0), adapter.expert(task)
        obs, _ = env.reset(seed=0)
        successes = []
        for _ in range(adapter.episode_length):
            obs, _, _, _, info = env.step(expert(obs))
            successes.append(info["success"])
        assert successes[-1] == 1.0, task


@pytest.mark.usefixtures("examples_on_path")
def test_example_adapter_trains_jointly_with_a_builtin_env(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    protocol = tmp_path / "rail.toml"
    protocol.write_text(PROTOCOL)
    args = ["run", str(protocol), "--out", str(tmp_path), "--quiet", "--json", "--no-report"]
    assert main(args) == 0
    line = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert set(line["final_success"]) == {"rail", "pt"}
