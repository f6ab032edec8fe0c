"""The loop's loggers: TensorBoard events and the optional wandb run mirror the CSV scalars."""

from __future__ import annotations

import sys
import time
import types
from pathlib import Path
from typing import Any

import pandas as pd
import pytest

from seal.errors import SealError
from seal.protocols import load_protocol
from seal.run.runner import run_seed
from tests.protocols.test_runner import BASELINE_ENVS, protocol


def _config(tmp_path: Path, logging: str) -> Any:
    path = protocol(tmp_path, BASELINE_ENVS, kind="baseline", epochs=3, warmup=20, batch=4)
    text = path.read_text().replace("train_interval = 1\n", f"train_interval = 1\n{logging}\n")
    path.write_text(text)
    return load_protocol(path)


def _events(run: Path, phase: str = "train") -> dict[str, list[tuple[int, float]]]:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(run / "tb" / phase))
    acc.Reload()
    return {t: [(e.step, e.value) for e in acc.Scalars(t)] for t in acc.Tags()["scalars"]}


def _same(events: list[tuple[int, float]], steps: Any, values: Any) -> None:
    assert [s for s, _ in events] == list(steps)
    assert [v for _, v in events] == pytest.approx(list(values), rel=1e-6)


def test_tensorboard_logger_mirrors_metrics_and_train_csv(tmp_path: Path) -> None:
    run = run_seed(_config(tmp_path, ""), 0, tmp_path / "g").run_dir
    events = _events(run)
    metrics, train = pd.read_csv(run / "metrics.csv"), pd.read_csv(run / "train.csv")
    for task in ("east", "north"):
        rows = metrics[metrics["task"] == task]
        _same(events[f"eval/pt/{task}/success"], rows["grad_steps"], rows["success"])
        assert len(events[f"eval/pt/{task}/return"]) == len(rows)
    assert [s for s, _ in events["charts/pt/mean_success"]] == [10, 20, 30]
    critic = train[train["key"] == "critic_loss"]
    _same(events["losses/pt/critic_loss"], critic["grad_steps"], critic["value"])
    assert "charts/pt/mean_q" in events and "charts/pt/alpha/east" in events


def test_tensorboard_off_writes_no_events(tmp_path: Path) -> None:
    config = _config(tmp_path, "tensorboard = false")
    run = run_seed(config, 0, tmp_path / "g").run_dir
    assert not (run / "tb").exists()


class _FakeRun:
    def __init__(self, log: list[dict[str, Any]]) -> None:
        self.logged = log
        self.finished = False

    def define_metric(self, *args: Any, **kwargs: Any) -> None:
        pass

    def log(self, data: dict[str, Any]) -> None:
        self.logged.append(dict(data))

    def finish(self) -> None:
        self.finished = True


def _fake_wandb(monkeypatch: pytest.MonkeyPatch) -> tuple[list[dict[str, Any]], list[Any]]:
    inits: list[dict[str, Any]] = []
    logged: list[dict[str, Any]] = []
    runs: list[_FakeRun] = []

    def init(**kwargs: Any) -> _FakeRun:
        inits.append(kwargs)
        runs.append(_FakeRun(logged))
        return runs[-1]

    monkeypatch.setitem(sys.modules, "wandb", types.SimpleNamespace(init=init))
    monkeypatch.setenv("WANDB_MODE", "")
    return inits, [logged, runs]


def test_wandb_logger_init_args_logged_keys_and_resume_id(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import os

    inits, (logged, runs) = _fake_wandb(monkeypatch)
    config = _config(tmp_path, 'wandb = "offline"\ntensorboard = false')
    run = run_seed(config, 0, tmp_path / "g").run_dir
    (init,) = inits
    assert init["mode"] == "offline" and os.environ["WANDB_MODE"] == "offline"
    assert init["dir"] == str(run / "wandb") and init["resume"] == "allow"
    assert init["id"] == (run / "wandb" / "run_id").read_text().strip()
    assert runs[0].finished
    keys = set().union(*logged)
    assert {"eval/pt/east/success", "charts/pt/mean_success", "losses/pt/critic_loss"} <= keys
    assert [d["grad_steps"] for d in logged if "charts/pt/mean_success" in d] == [10, 20, 30]
    # A resumed (here: already finished) run continues the same wandb run.
    run_seed(config, 0, tmp_path / "g", resume=True)
    assert len(inits) == 2 and inits[1]["id"] == init["id"]


def test_wandb_missing_is_one_line_error_naming_the_extra(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "wandb", None)
    config = _config(tmp_path, 'wandb = "online"\ntensorboard = false')
    with pytest.raises(SealError, match=r'pip install -e "\.\[wandb\]"') as info:
        run_seed(config, 0, tmp_path / "g")
    assert "\n" not in str(info.value)


def test_wandb_offline_run_files_hold_the_logged_keys(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    pytest.importorskip("wandb")
    for key in ("WANDB_API_KEY", "WANDB_BASE_URL", "WANDB_PROJECT", "WANDB_ENTITY"):
        monkeypatch.delenv(key, raising=False)
    monkeypatch.setenv("WANDB_MODE", "offline")
    config = _config(tmp_path, 'wandb = "offline"\ntensorboard = false')
    run = run_seed(config, 0, tmp_path / "g").run_dir
    run_id = (run / "wandb" / "run_id").read_text().strip()
    (folder,) = (run / "wandb" / "wandb").glob(f"offline-run-*-{run_id}")
    (data,) = folder.glob("*.wandb")
    blob = data.read_bytes()
    for key in (b"eval/pt/east/success", b"charts/pt/mean_success", b"losses/pt/critic_loss"):
        assert key in blob


def test_resume_purges_tensorboard_events_past_the_checkpoint(tmp_path: Path) -> None:
    config = _config(tmp_path, "")
    run = run_seed(config, 0, tmp_path / "g").run_dir
    first = _events(run)
    # As if killed after epoch 3's events but before its checkpoint: resume from epoch 2's.
    (run / "checkpoints" / "ckpt-0000003.pt").unlink()
    # Event files are read in name order, events.out.tfevents.<second>.<host>.<pid>.<n>, where
    # <n> counts writers in this process: within one second writer 10 would be read before
    # writer 9, and the resumed run's purge before the events it purges. A resumed run is a new
    # process started later; here, start it in the next second.
    time.sleep(1.0 - time.time() % 1.0)
    run_seed(config, 0, tmp_path / "g", resume=True)
    events = _events(run)
    assert [s for s, _ in events["charts/pt/mean_success"]] == [10, 20, 30]
    assert events["eval/pt/east/success"] == first["eval/pt/east/success"]
    metrics = pd.read_csv(run / "metrics.csv")
    east = metrics[metrics["task"] == "east"]
    _same(events["eval/pt/east/success"], east["grad_steps"], east["success"])


@pytest.mark.parametrize("resume_in", ["finetune", "pretrain"])
def test_each_phase_is_its_own_tensorboard_run_and_a_resume_purges_only_what_is_rewritten(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, resume_in: str
) -> None:
    """Pretrain (3 epochs of 2 point tasks) then finetune (2 epochs of 1 task, 8 steps each):
    resumed from finetune epoch 1, or from pretrain's last checkpoint (all of finetune again),
    every phase's events are the CSV's once, and pretrain's are untouched."""
    from tests.protocols.test_runner import FINETUNE_ENVS, HERE

    monkeypatch.syspath_prepend(str(HERE))  # the second adapter lives beside test_runner
    path = protocol(tmp_path, FINETUNE_ENVS, kind="finetune", batch=4)
    text = path.read_text().replace("interval = 2\nkeep_last = 2", "interval = 1\nkeep_last = 9")
    path.write_text(text)  # a checkpoint every epoch, all kept
    config = load_protocol(path)
    run = run_seed(config, 0, tmp_path / "g").run_dir
    assert sorted(p.name for p in (run / "tb").iterdir()) == ["finetune", "pretrain"]
    pretrain = _events(run, "pretrain")
    assert [s for s, _ in pretrain["charts/a/mean_success"]] == [10, 20, 30]
    assert [s for s, _ in _events(run, "finetune")["charts/b/mean_success"]] == [8, 16]
    doomed = ["ckpt-finetune-0000002.pt"]
    if resume_in == "pretrain":
        doomed += [p.name for p in (run / "checkpoints").glob("ckpt-finetune-*.pt")]
    for name in set(doomed):
        (run / "checkpoints" / name).unlink()
    time.sleep(1.0 - time.time() % 1.0)  # event files sort by second (see the test above)
    run_seed(config, 0, tmp_path / "g", resume=True)
    assert _events(run, "pretrain") == pretrain
    finetune = _events(run, "finetune")
    metrics = pd.read_csv(run / "metrics.csv")
    west = metrics[metrics["phase"] == "finetune"]
    _same(finetune["eval/b/west/success"], west["grad_steps"], west["success"])
    assert [s for s, _ in finetune["charts/b/mean_success"]] == [8, 16]
