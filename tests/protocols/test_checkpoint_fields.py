"""The checks a checkpoint's fields pass before anything uses them (`checkpoint_fields.check_*`).

The corpus (tests/faults/test_damaged_rundirs.py) damages them field by field through the CLIs;
here: what seal run writes passes, a checkpoint from before an optional field passes, and the
phase names the checks know are the runners'.
"""

from __future__ import annotations

import copy
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from seal.errors import SealError
from seal.learner.checkpoint import read_checkpoint
from seal.protocols import load_protocol
from seal.run.checkpoint_fields import (
    PHASE_NAMES,
    check_epoch_checkpoint,
    check_run_checkpoint,
)
from seal.run.phase_model import plan_phases
from seal.run.runner import run_seed
from tests.protocols.test_runner import BASELINE_ENVS, protocol


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    tmp = tmp_path_factory.mktemp("fields")
    path = protocol(tmp, BASELINE_ENVS, kind="baseline", epochs=2)
    run = run_seed(load_protocol(path, ["logging.tensorboard=false"]), 0, tmp / "g").run_dir
    folder = run / "checkpoints"
    return {
        "epoch": read_checkpoint(folder / "ckpt-0000002.pt"),
        "best": read_checkpoint(folder / "best.pt"),
        "path": folder / "ckpt-0000002.pt",
    }


def test_what_seal_run_writes_passes(checkpoints: dict[str, Any]) -> None:
    check_run_checkpoint(checkpoints["epoch"], "epoch")
    check_run_checkpoint(checkpoints["best"], "best")
    check_epoch_checkpoint(checkpoints["epoch"], "epoch", ["train"], 0)


def test_a_checkpoint_from_before_an_optional_counter_passes(checkpoints: dict[str, Any]) -> None:
    """`NotRequired` keys may be absent: read from the annotations, since Python 3.11's
    `__required_keys__` counts them required under `from __future__ import annotations`."""
    old = copy.deepcopy(checkpoints["epoch"])
    for key in (
        "log_sums",
        "log_updates",
        "seconds",
        "calls",
        "demos",
        "evaluated_at",
        "evaluations",
    ):
        del old["runner"]["state"][key]
    check_epoch_checkpoint(old, "old", ["train"], 0)
    del old["runner"]["state"]["epoch"]  # a required one
    with pytest.raises(SealError, match=r"^checkpoint old: field runner.state.epoch is missing"):
        check_epoch_checkpoint(old, "old", ["train"], 0)


def test_an_epoch_checkpoint_is_the_runs_own(checkpoints: dict[str, Any]) -> None:
    data = checkpoints["epoch"]
    with pytest.raises(SealError, match=r"field phase = 'train'; expected one of this run's"):
        check_epoch_checkpoint(data, "c", ["pretrain", "finetune"], 0)
    with pytest.raises(SealError, match=r"field seed = 0; expected 3, this run's seed"):
        check_epoch_checkpoint(data, "c", ["train"], 3)


def test_the_phase_names_are_the_runners() -> None:
    baseline = SimpleNamespace(
        kind="baseline", envs={"a": None}, protocol=SimpleNamespace(epochs=1)
    )
    finetune = SimpleNamespace(
        kind="finetune",
        finetune=SimpleNamespace(source="a", target="b", pretrain_epochs=1, finetune_epochs=1),
    )
    names = {p.name for config in (baseline, finetune) for p in plan_phases(config)}  # type: ignore[arg-type]
    assert names == set(PHASE_NAMES)


def test_messages_are_one_line_whatever_the_key(checkpoints: dict[str, Any]) -> None:
    data = copy.deepcopy(checkpoints["epoch"])
    data["runner"]["rows"]["odd\nname"] = "x"
    with pytest.raises(SealError) as caught:
        check_epoch_checkpoint(data, Path("c"), ["train"], 0)
    assert "\n" not in str(caught.value) and "field runner.rows['odd\\nname'] = 'x'" in str(
        caught.value
    )
