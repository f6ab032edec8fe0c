"""docs/tutorial.ipynb runs top to bottom on two tiny quickstart groups (with and without demos)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from seal.cli.main import main

ROOT = Path(__file__).resolve().parents[2]
NOTEBOOK = ROOT / "docs" / "tutorial.ipynb"
# The quickstart shrunk to seconds: 3 epochs of 20-step episodes, an evaluation every epoch.
TINY = [
    "envs.mw.episode_length=20",
    "envs.fk.episode_length=20",
    "training.warmup_steps=20",
    "evaluation.episodes=1",
    "agent.translator_hidden=[8]",
    "agent.latent_dim=8",
    "agent.trunk_hidden=[8]",
    "agent.critic_hidden=[8]",
    "replay.capacity_per_env=1000",
    "protocol.threads=1",
    "training.collector=sync",
]


def _tiny_group(out: Path, demos: int, capsys: pytest.CaptureFixture[str]) -> Path:
    args = ["run", str(ROOT / "protocols" / "quickstart.toml"), "--scale", "0.02", "--seeds", "0"]
    args += ["--out", str(out), "--quiet", "--json", "--no-report"]
    for item in [*TINY, f"training.demo_episodes={demos}"]:
        args += ["--set", item]
    assert main(args) == 0
    run = Path(json.loads(capsys.readouterr().out.strip().splitlines()[-1])["run_dir"])
    return run.parent


@pytest.mark.slow
def test_tutorial_notebook_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    groups = [_tiny_group(tmp_path / "reports", d, capsys) for d in (1, 0)]
    monkeypatch.setenv("SEAL_TUTORIAL_GROUPS", os.pathsep.join(map(str, groups)))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    client = nbclient.NotebookClient(
        notebook, timeout=None, kernel_name="python3", resources={"metadata": {"path": tmp_path}}
    )
    client.execute()
    outputs = [o for cell in notebook.cells for o in cell.get("outputs", [])]
    assert not [o for o in outputs if o.get("output_type") == "error"]
    text = "\n".join(str(o.get("data", {}).get("text/plain", "")) for o in outputs)
    assert "demos 1" in text and "demos 0" in text  # both groups reached the comparison
