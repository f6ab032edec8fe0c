"""The Checkpointer callback: when the loop's hooks fire around its writes, and what it writes."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from seal.learner.checkpoint import read_checkpoint
from seal.protocols import load_protocol
from seal.protocols.config import ProtocolConfig
from seal.run.checkpoint_fields import PhaseStateFields
from seal.run.loop import LoopCallback, PhaseLoop
from seal.run.runner import run_seed
from seal.run.state import PhaseState
from seal.run.workers import PendingEvaluation, PendingFields
from tests.protocols.test_runner import BASELINE_ENVS, protocol


def _config(tmp_path: Path, epochs: int) -> ProtocolConfig:
    """test_runner's tiny baseline (a checkpoint every 2 epochs), without TensorBoard."""
    path = protocol(tmp_path, BASELINE_ENVS, kind="baseline", epochs=epochs)
    return load_protocol(path, ["logging.tensorboard=false"])


class _Recorder(LoopCallback):
    """Records each hook with the checkpoint files that exist when it fires."""

    def __init__(self) -> None:
        self.events: list[tuple[str, int, frozenset[str]]] = []

    def _record(self, hook: str, loop: PhaseLoop) -> None:
        folder = loop.owner.rundir.checkpoints
        files = frozenset(p.name for p in folder.iterdir())
        self.events.append((hook, loop.state.epoch, files))

    def on_evaluation(self, loop: PhaseLoop) -> None:
        self._record("on_evaluation", loop)

    def on_checkpoint(self, loop: PhaseLoop) -> None:
        self._record("on_checkpoint", loop)

    def on_epoch_end(self, loop: PhaseLoop) -> None:
        self._record("on_epoch_end", loop)


def test_callbacks_flush_before_the_checkpoint_is_written_and_see_best_after(
    tmp_path: Path,
) -> None:
    # 3 epochs, a checkpoint every 2 and after the last: epochs 2 and 3.
    config = _config(tmp_path, epochs=3)
    recorder = _Recorder()
    result = run_seed(config, 0, tmp_path / "g", callbacks=[recorder])
    by_hook = {(hook, epoch): files for hook, epoch, files in recorder.events}
    # The first evaluation always beats the initial best (-1): best.pt is there before anyone hears of it.
    assert "best.pt" in by_hook[("on_evaluation", 1)]
    for epoch in (2, 3):
        ckpt = f"ckpt-{epoch:07d}.pt"
        # on_checkpoint (the loggers flush there) comes before the write, on_epoch_end after it.
        assert ckpt not in by_hook[("on_checkpoint", epoch)]
        assert ckpt in by_hook[("on_epoch_end", epoch)]
    assert ("on_checkpoint", 1) not in by_hook
    files = sorted(p.name for p in (result.run_dir / "checkpoints").iterdir())
    assert files == ["best.pt", "ckpt-0000002.pt", "ckpt-0000003.pt"]
    # Checkpoint seconds and calls are counted for `seal bench --protocol`.
    timing = result.timing["train"]
    assert timing["calls"]["checkpoint"] == 2 and timing["seconds"]["checkpoint"] > 0


def test_checkpoint_fields(tmp_path: Path) -> None:
    config = _config(tmp_path, epochs=2)
    run = run_seed(config, 0, tmp_path / "g").run_dir
    common = {"config_toml", "seed", "phase", "phase_envs", "epoch", "best", "mean_success"}
    reserved = {"seal_checkpoint", "agent", "replay", "scheduler", "runner"}
    epoch = read_checkpoint(run / "checkpoints" / "ckpt-0000002.pt")
    assert set(epoch) == common | reserved
    assert (epoch["phase"], epoch["phase_envs"], epoch["epoch"], epoch["best"]) == (
        "train",
        ["pt"],
        2,
        False,
    )
    assert epoch["replay"] is not None and epoch["scheduler"] is not None
    assert set(epoch["runner"]) == {
        "phase_index",
        "state",
        "rows",
        "torch_rng",
        "py_rng",
        "finished_phases",
        "pending_evaluations",
    }
    assert epoch["runner"]["pending_evaluations"] == []  # synchronous evaluation leaves none
    assert epoch["runner"]["state"]["anchor_epoch"] == 2
    assert set(epoch["runner"]["state"]) == set(PhaseStateFields.__annotations__)
    assert epoch["runner"]["rows"]["metrics.csv"] == 2 * 2  # two evaluations of two tasks
    best = read_checkpoint(run / "checkpoints" / "best.pt")
    assert set(best) == common | reserved and best["best"] is True
    assert best["replay"] is None and best["scheduler"] is None and best["runner"] is None
    assert best["mean_success"] == epoch["mean_success"]


def test_the_checkpoint_typeddicts_name_the_dataclasses_fields() -> None:
    """The TypedDicts that type a checkpoint's counters and pending evaluations keep their
    dataclasses' keys (a field added to one and not the other fails here)."""
    names = {f.name for f in dataclasses.fields(PhaseState)}
    assert set(PhaseStateFields.__annotations__) == names
    assert set(PhaseState().fields()) == names
    assert set(PendingFields.__annotations__) == {
        f.name for f in dataclasses.fields(PendingEvaluation)
    }


def test_resume_deletes_torn_checkpoint_files(tmp_path: Path) -> None:
    from seal.learner.checkpoint import atomic_save

    config = _config(tmp_path, epochs=2)
    run = run_seed(config, 0, tmp_path / "g").run_dir
    folder = run / "checkpoints"
    # What a kill during atomic_save leaves: its temporary file, never renamed (a big one when it
    # holds the replay).
    saved = atomic_save({"x": 1}, folder / "scratch.pt")
    torn = folder / ".ckpt-0000004.pt.k2j3h4.tmp"
    saved.rename(torn)
    run_seed(config, 0, tmp_path / "g", resume=True)
    assert not torn.exists()
    assert sorted(p.name for p in folder.iterdir()) == ["best.pt", "ckpt-0000002.pt"]
