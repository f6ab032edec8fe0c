"""Resume after a real SIGKILL: no duplicate or missing evaluations, and the same rows as without the kill."""

from __future__ import annotations

import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from seal.cli.main import main
from seal.protocols import load_protocol
from seal.run.runner import run_seed
from tests.waiting import wait_until

PROTOCOL = """
[protocol]
name = "killme"
kind = "joint"
epochs = 24
seeds = 1
device = "cpu"
threads = 1
[envs.a]
adapter = "point"
tasks = ["east", "north"]
episode_length = 10
[envs.b]
adapter = "point"
tasks = ["west"]
episode_length = 8
[agent]
translator_hidden = [8]
latent_dim = 8
trunk_hidden = [8]
[training]
warmup_steps = 10
batch_per_task = 8
collector = "sync"
[evaluation]
interval = 1
episodes = 2
[checkpoint]
interval = 3
keep_last = 2
[logging]
# Logged every 4 epochs, checkpointed every 3: most checkpoints fall between two train.csv rows,
# so resuming must restore the partial sums of the agent's logs too.
train_interval = 4
[scheduler]
kind = "stepped"
start = { a = 0.9, b = 0.1 }
interval = 4
"""


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "seal.cli.main", *args]


def _env() -> dict[str, str]:
    return {**os.environ, "OMP_NUM_THREADS": "1"}


@pytest.mark.slow
def test_sigkill_then_resume_matches_uninterrupted_run(tmp_path: Path) -> None:
    path = tmp_path / "killme.toml"
    path.write_text(PROTOCOL)
    # The uninterrupted reference, in this process.
    reference = run_seed(load_protocol(path), 0, tmp_path / "ref").run_dir

    # The same protocol in a child process, killed with SIGKILL at a random point after its
    # second checkpoint (epoch 6) and well before its end (epoch 24).
    out = tmp_path / "out"
    # The child holds in its last epoch (tests/faults/pausing_child.py with N = 0), so the kill
    # lands on a run still going however fast the machine is (issue 55).
    holding = Path(__file__).resolve().parents[1] / "faults" / "pausing_child.py"
    child = subprocess.Popen(
        [sys.executable, str(holding), str(out / "paused"), "0"]
        + ["run", str(path), "--out", str(out), "--quiet", "--no-report"],
        env=_env(),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    second = "killme/*/seed-0/checkpoints/ckpt-0000006.pt"
    wait_until(lambda: any(out.glob(second)), "its second checkpoint", child=child)
    run_dir = next(out.glob(second)).parents[1]
    # The kill delay is drawn from a fixed seed and printed, so a failure names the delay that
    # caused it (rerun with SEAL_KILL_SEED=<seed> to try another point).
    seed = int(os.environ.get("SEAL_KILL_SEED", "0"))
    delay = random.Random(seed).uniform(0.0, 0.4)
    print(f"SIGKILL {delay:.3f} s after the epoch-6 checkpoint (SEAL_KILL_SEED={seed})")
    time.sleep(delay)
    child.send_signal(signal.SIGKILL)
    child.wait()
    assert child.returncode == -signal.SIGKILL
    assert (
        json.loads((run_dir / "provenance.json").read_text())["end_time"] is None
    )  # really cut short
    killed_rows = len(pd.read_csv(run_dir / "metrics.csv"))
    assert killed_rows < 24 * 3, f"the child finished before the kill ({delay:.3f} s)"

    resumed = subprocess.run(
        # FILE left out: the run resumes from its saved config alone.
        _cli("run", "--resume", str(run_dir), "--quiet", "--no-report", "--json"),
        env=_env(),
        capture_output=True,
        text=True,
    )
    assert resumed.returncode == 0, resumed.stderr
    assert json.loads(resumed.stdout.strip().splitlines()[-1])["run_dir"] == str(run_dir)

    got = pd.read_csv(run_dir / "metrics.csv")
    want = pd.read_csv(reference / "metrics.csv")
    # Exactly one evaluation row per (epoch, env, task): none missing, none duplicated.
    assert not got.duplicated(["phase", "epoch", "env", "task"]).any()
    assert len(got) == len(want) == 24 * 3
    # On CPU with the same seed, every row equals the uninterrupted run's (wall time aside), so
    # training continued from the saved step with the saved replay, RNG and scheduler states.
    pd.testing.assert_frame_equal(got.drop(columns="wall_s"), want.drop(columns="wall_s"))
    pd.testing.assert_frame_equal(
        pd.read_csv(run_dir / "train.csv"), pd.read_csv(reference / "train.csv")
    )
    assert json.loads((run_dir / "provenance.json").read_text())["end_time"]


def test_resume_refuses_a_directory_that_is_not_a_run(tmp_path: Path) -> None:
    path = tmp_path / "killme.toml"
    path.write_text(PROTOCOL)
    bad = subprocess.run(
        _cli("run", str(path), "--resume", str(tmp_path)),
        env=_env(),
        capture_output=True,
        text=True,
    )
    assert bad.returncode == 2 and "--resume" in bad.stderr and "Traceback" not in bad.stderr


def test_resume_needs_no_file_and_refuses_options_it_would_drop(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "killme.toml"
    path.write_text(PROTOCOL)
    other = tmp_path / "other.toml"
    other.write_text(PROTOCOL.replace('name = "killme"', 'name = "other"'))
    out = tmp_path / "out"
    quiet = ["--quiet", "--no-report"]
    assert main(["run", str(path), "--out", str(out), "--set", "protocol.epochs=3", *quiet]) == 0
    (run,) = out.glob("killme/*/seed-0")
    before = (run / "metrics.csv").read_bytes()
    capsys.readouterr()
    for argv, says in [
        (["--resume", str(run), "--set", "protocol.epochs=6"], "--set cannot change a resumed"),
        (["--resume", str(run), "--out", "x", "--seeds", "1"], "--seeds, --out cannot change"),
        ([str(other), "--resume", str(run)], "is of protocol 'killme', not 'other'"),
        ([], "give a protocol FILE (or --resume RUN_DIR)"),
    ]:
        assert main(["run", *argv, *quiet]) == 2, argv
        err = capsys.readouterr().err
        assert says in err and err.count("\n") == 1, err
    assert (run / "metrics.csv").read_bytes() == before
    assert not (tmp_path / "x").exists()
    # Without FILE, the run goes on from its saved config (here: it had finished, so no row is added).
    assert main(["run", "--resume", str(run), "--json", *quiet]) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["run_dir"] == str(run)
    assert (run / "metrics.csv").read_bytes() == before
    # With FILE, what differs from the saved config is named (here the run's own --set), and the
    # run still goes on with its saved config.
    assert main(["run", str(path), "--resume", str(run), *quiet]) == 0
    assert capsys.readouterr().err.startswith(
        f"seal: warning: --resume {run}: {path} differs from the run's saved config in "
        "protocol.epochs (3 saved, 24 in it); the run goes on with its saved config"
    )
    assert (run / "metrics.csv").read_bytes() == before

    # A finished run kept without its checkpoints (a record) is refused, not run again over its
    # rows; a run directory whose config does not read gets no files.
    shutil.rmtree(run / "checkpoints")
    assert main(["run", "--resume", str(run), *quiet]) == 2
    assert "finished at" in capsys.readouterr().err
    assert (run / "metrics.csv").read_bytes() == before
    assert not (run / "checkpoints").exists()
    broken = tmp_path / "broken" / "seed-0"
    broken.mkdir(parents=True)
    (broken / "config.toml").write_text("[protocol\n")
    assert main(["run", "--resume", str(broken), *quiet]) == 2
    assert "config.toml: not valid TOML" in capsys.readouterr().err
    assert [p.name for p in broken.iterdir()] == ["config.toml"]
