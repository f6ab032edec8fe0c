"""[transfer] on the point env: pre-train one task, transfer to four with a lowered learning rate."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from seal.errors import ConfigError
from seal.learner.checkpoint import read_checkpoint
from seal.protocols import load_protocol
from seal.run.runner import run_seed

BODY = """
[protocol]
kind = "baseline"
epochs = {epochs}
seeds = 1
device = "cpu"
threads = 1
[envs.pt]
adapter = "point"
tasks = {tasks}
episode_length = 10
[agent]
hidden = [8, 8]
[training]
warmup_steps = {warmup}
batch_per_task = 4
collector = "sync"
[evaluation]
interval = 1
episodes = 1
[checkpoint]
interval = 1
[logging]
train_interval = 1
tensorboard = false
"""


def write(tmp_path: Path, name: str, tasks: str, epochs: int, warmup: int) -> Path:
    path = tmp_path / f"{name}.toml"
    path.write_text(BODY.format(tasks=tasks, epochs=epochs, warmup=warmup))
    return path


def test_transfer_one_task_to_four_keeps_weights_and_scales_lr(tmp_path: Path) -> None:
    # Pre-train on "east" only: 2 epochs of 10 steps with 10 gradient steps each, so the source
    # weights differ from any fresh initialisation.
    source_cfg = load_protocol(write(tmp_path, "mt1", '["east"]', epochs=2, warmup=0))
    source_run = run_seed(source_cfg, 0, tmp_path / "r" / "mt1" / "g").run_dir
    best = source_run / "checkpoints" / "best.pt"
    source = read_checkpoint(best)["agent"]
    # Transfer to the four tasks, "east" first so its one-hot id (0) is the source's. A warm-up
    # longer than the one epoch (4 tasks x 10 steps = 40 < 1000) means no gradient step happens,
    # so the run's checkpoint holds the agent exactly as the transfer left it.
    path = write(tmp_path, "mt4", '["east", "north", "west", "south"]', epochs=1, warmup=1000)
    config = load_protocol(path, [f"transfer.checkpoint={best}"])
    assert config.transfer is not None and config.transfer.lr_factor == 0.1  # the default
    run = run_seed(config, 0, tmp_path / "r" / "mt4" / "g").run_dir
    target = read_checkpoint(run / "checkpoints" / "ckpt-0000001.pt")["agent"]

    # Actor input rows: obs (4) then one-hot (source 1, target 4).
    w_src, w_new = source["actor"]["trunk.weights.0"], target["actor"]["trunk.weights.0"]
    assert w_new.shape[-2] == 8 and w_src.shape[-2] == 5
    assert torch.equal(w_new[..., :5, :], w_src)  # obs rows and the "east" column kept
    assert torch.count_nonzero(w_new[..., 5:, :]) == 0  # north, west, south columns start at zero
    for key in ("trunk.weights.1", "trunk.biases.0", "trunk.biases.1"):
        assert torch.equal(target["actor"][key], source["actor"][key]), key
    # The policy's last layer (multi-head: tasks x (2 means + 2 log-stds) outputs) is re-initialised:
    # 1 x 4 -> 4 x 4 = 16 outputs, and even the "east" head's 4 columns are not the source's.
    head_src, head_new = source["actor"]["heads.pt.weight"], target["actor"]["heads.pt.weight"]
    assert head_src.shape[-1] == 4 and head_new.shape[-1] == 16
    assert not torch.equal(head_new[..., :4], head_src)
    # Critic input rows: obs (4), one-hot (1 -> 4), action (2): 7 -> 10 rows.
    c_src, c_new = source["critic"]["trunk.weights.0"], target["critic"]["trunk.weights.0"]
    assert torch.equal(c_new[..., :5, :], c_src[..., :5, :])
    assert torch.count_nonzero(c_new[..., 5:8, :]) == 0
    assert torch.equal(c_new[..., 8:10, :], c_src[..., 5:7, :])  # action rows after the one-hot
    # One Q output per task (the default): the source's one head is copied into "east"'s (id 0).
    q_src, q_new = source["critic"]["heads.pt.weight"], target["critic"]["heads.pt.weight"]
    assert q_src.shape[-1] == 1 and q_new.shape[-1] == 4 and torch.equal(q_new[..., :1], q_src)

    # Learning rates: 3e-4 (AgentConfig default) x 0.1 = 3e-5 for actor and critic.
    assert target["lr_factor"] == pytest.approx(0.1)
    for name in ("actor_optimizers", "critic_optimizers"):
        for opt in target[name]:
            assert [g["lr"] for g in opt["param_groups"]] == [pytest.approx(3e-5)]


def test_missing_transfer_checkpoint_is_a_config_error_before_any_run_dir(tmp_path: Path) -> None:
    path = write(tmp_path, "mt4", '["east", "north"]', epochs=1, warmup=0)
    missing = tmp_path / "nope" / "best.pt"
    config = load_protocol(path, [f"transfer.checkpoint={missing}"])
    group = tmp_path / "r" / "mt4" / "g"
    with pytest.raises(ConfigError, match=r"transfer\.checkpoint.*nope/best\.pt"):
        run_seed(config, 0, group)
    assert not group.exists()
    empty = load_protocol(path, ["transfer.lr_factor=0.5"])  # [transfer] without a checkpoint
    with pytest.raises(ConfigError, match=r"transfer\.checkpoint is empty"):
        run_seed(empty, 0, group)
    assert not group.exists()
    with pytest.raises(ConfigError, match=r"transfer\.lr_factor = 0\.0"):
        load_protocol(path, ["transfer.lr_factor=0.0"])


def test_a_checkpoint_that_does_not_fit_fails_before_anything_is_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Hidden widths 8 saved, 16 asked: seal run, protocol check and sweep each refuse it in
    one line naming transfer.checkpoint, and none leaves a directory behind."""
    from seal.cli.main import main

    source = run_seed(load_protocol(write(tmp_path, "src", '["east"]', 1, 0)), 0, tmp_path / "s")
    best = source.run_dir / "checkpoints" / "best.pt"
    path = write(tmp_path, "wide", '["east", "north"]', epochs=1, warmup=0)
    path.write_text(path.read_text().replace("hidden = [8, 8]", "hidden = [16, 16]"))
    says = "transfer.checkpoint = '%s': cannot transfer input layer: saved shape (1, 5, 8) vs (1, 6, 16) here; hidden widths must match"
    config = load_protocol(path, [f"transfer.checkpoint={best}"])
    with pytest.raises(ConfigError) as info:
        run_seed(config, 0, tmp_path / "r" / "wide" / "g")
    assert says % best in str(info.value)
    capsys.readouterr()
    out = tmp_path / "r"
    for command in (
        ["run", "--out", str(out)],
        ["protocol", "check"],
        ["sweep", "--out", str(out)],
    ):
        code = main([*command, str(path), "--set", f"transfer.checkpoint={best}"])
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1 and says % best in err[0], (command, err)
    assert not out.exists()
    # The check runs on CPU, so a protocol for a GPU checks on a machine without one, and a
    # search that draws the widths leaves the fit to each trial (whose own run checks it).
    narrow = ["--set", f"transfer.checkpoint={best}", "--set", "agent.hidden=[8, 8]"]
    assert main(["protocol", "check", str(path), *narrow, "--set", 'protocol.device="cuda"']) == 0
    from seal.sweep.manifest import _load_configs

    drawn = path.with_name("drawn.toml")
    grid = '[search]\n"agent.hidden" = {dist = "grid", values = [[8, 8]]}\n'
    drawn.write_text(path.read_text() + grid)
    overrides = [f"transfer.checkpoint={best}"]
    (config,) = _load_configs([drawn], overrides, None, search=True)
    assert config.agent.hidden == (16, 16)
    with pytest.raises(ConfigError, match="hidden widths must match"):
        _load_configs([drawn], overrides, None)  # a grid sweep runs the base config
