"""protocol.threads: the "auto" rule on stated inputs, what `seal protocol explain` prints, and a
sweep trial's cap."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

import seal.device
from seal.cli.main import main
from seal.device import (
    CORES_PER_UPDATE_THREAD,
    WORK_PER_UPDATE_THREAD,
    choose_threads,
    torch_threads,
    update_threads,
    usable_cores,
)
from seal.errors import SealError
from seal.protocols import load_protocol
from seal.sweep.trials import TrialRecord, execute_trial

ROOT = Path(__file__).resolve().parents[1]
QUICKSTART = (315_806, 256)
"""The quickstart's update: actor and critic parameters, transitions per gradient step."""
PAPER = (2_373_100, 2_560)
"""protocols/high_fk.toml's: MT10 and the 10 kitchens, 400-wide, 128 per task."""


def test_the_rule_on_stated_inputs() -> None:
    assert (CORES_PER_UPDATE_THREAD, WORK_PER_UPDATE_THREAD) == (2, 2e8)
    # The quickstart (8.0e7 of parameters x batch) is under one thread's work on any machine.
    for cores in (1, 2, 4, 16, 64):
        assert update_threads(*QUICKSTART, cores) == 1
    # Paper scale (6.05e9, 30 threads' work): one thread per 2 cores, up to the work's 30.
    assert [update_threads(*PAPER, c) for c in (1, 2, 3, 4, 16, 64, 128)] == [1, 1, 1, 2, 8, 30, 30]
    # Exactly at the threshold: 2e8 is one thread's work, 4e8 two's.
    assert update_threads(1_000_000, 200, 8) == 1
    assert update_threads(1_000_000, 400, 8) == 2
    assert update_threads(1_000_000, 399, 8) == 1


def test_a_fixed_setting_is_capped_at_the_cores_and_zero_is_kept() -> None:
    assert choose_threads(4, *QUICKSTART, cores=2).threads == 2
    assert choose_threads(1, *PAPER, cores=64).threads == 1
    kept = choose_threads(0, *PAPER, cores=64)
    assert kept.threads == 0 and kept.describe().startswith("torch's default")
    auto = choose_threads("auto", *PAPER, cores=16)
    assert (auto.threads, auto.parameters, auto.batch, auto.cores) == (8, *PAPER, 16)
    assert auto.describe().startswith(
        "8 (auto: 2,373,100 parameters x batch 2,560, 16 usable cores;"
    )
    assert "capped at 2 cores" in choose_threads(4, *QUICKSTART, cores=2).describe()
    with pytest.raises(SealError, match="protocol.threads = 'many'"):
        choose_threads("many", *QUICKSTART, cores=2)


def test_usable_cores_are_the_affinity_mask(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(seal.device.os, "sched_getaffinity", lambda _pid: {0, 3, 5, 7})
    assert usable_cores() == 4
    assert choose_threads("auto", *PAPER).cores == 4


def test_explain_prints_the_choice_and_its_inputs(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(seal.device.os, "sched_getaffinity", lambda _pid: set(range(16)))
    assert main(["protocol", "explain", str(ROOT / "protocols" / "quickstart.toml")]) == 0
    out = capsys.readouterr().out
    assert 'threads = "auto"' in out
    assert "# update threads: 1 (auto: 315,806 parameters x batch 256, 16 usable cores;" in out
    assert main(["protocol", "explain", str(ROOT / "protocols" / "high_fk.toml")]) == 0
    assert "# update threads: 8 (auto: 2,373,100 parameters x batch 2,560, 16 usable cores;" in (
        capsys.readouterr().out
    )


def test_a_sweep_trial_starts_no_more_threads_than_its_cores(tmp_path: Path) -> None:
    # A trial of 1 CPU (Resources.threads = 1) whose protocol asks for 4 threads runs on 1: the
    # run's provenance records the torch threads its updates were given.
    path = tmp_path / "tiny.toml"
    path.write_text(
        '[protocol]\nname = "tiny"\nkind = "baseline"\nseeds = 1\nepochs = 1\ndevice = "cpu"\n'
        "threads = 4\n\n"
        '[envs.point]\nadapter = "point"\ntasks = ["east"]\nepisode_length = 5\n\n'
        "[agent]\nhidden = [8]\n\n[replay]\ncapacity_per_env = 100\n\n"
        '[training]\nwarmup_steps = 0\nbatch_per_task = 4\ncollector = "sync"\n\n'
        "[evaluation]\nepisodes = 1\n\n[logging]\ntensorboard = false\n"
    )
    run_dir = tmp_path / "sweep" / "tiny" / "seed-0"
    record = TrialRecord(trial="tiny", protocol="tiny", seed=0, run_dir=str(run_dir))
    with torch_threads(None):  # the trial sets this process's threads; put them back after
        record = execute_trial(load_protocol(path), record, threads=1)
    assert record.status == "finished", record.error
    provenance = json.loads((run_dir / "provenance.json").read_text())
    assert provenance["device_name"] == "cpu (1 threads)"
    assert provenance["update_threads"].startswith("1 (protocol.threads = 4, capped at 1 core;")


def test_matmul_precision_is_set_for_cuda_runs_only() -> None:
    """protocol.matmul_precision reaches torch on a CUDA device and never on the CPU (where "high"
    may mean a bfloat16-based algorithm); the setting is global, so it is restored here."""
    from seal.device import apply_matmul_precision

    before = torch.get_float32_matmul_precision()
    try:
        torch.set_float32_matmul_precision("highest")
        apply_matmul_precision(torch.device("cpu"), "high")
        assert torch.get_float32_matmul_precision() == "highest"
        apply_matmul_precision(torch.device("cuda"), "high")  # setting the flag needs no GPU
        assert torch.get_float32_matmul_precision() == "high"
    finally:
        torch.set_float32_matmul_precision(before)


def test_matmul_precision_refuses_what_torch_would_round_to_bfloat16(tmp_path: Path) -> None:
    """The key offers no "medium" (bfloat16 matmuls): the error names the file, key and choices."""
    toml = (ROOT / "protocols" / "quickstart.toml").read_text()
    path = tmp_path / "p.toml"
    path.write_text(toml.replace("[protocol]\n", '[protocol]\nmatmul_precision = "medium"\n', 1))
    with pytest.raises(SealError) as info:
        load_protocol(path)
    message = str(info.value)
    assert str(path) in message and "protocol.matmul_precision = 'medium'" in message
    assert "'highest', 'high'" in message
