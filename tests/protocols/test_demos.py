"""training.demo_episodes (scripted experts seed the replay) and evaluation.stop_when_reached."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from seal.cli.main import main
from seal.envs import make_adapter
from seal.learner.checkpoint import read_checkpoint
from seal.protocols import load_protocol
from seal.run.runner import run_seed

# reach-v3 with 20-step episodes: 2 demonstration episodes, then 1 epoch of random warm-up.
REACH = """
[protocol]
kind = "baseline"
epochs = 1
seeds = 1
device = "cpu"
threads = 1
[envs.mw]
adapter = "metaworld"
tasks = ["reach-v3"]
episode_length = 20
[agent]
hidden = [8, 8]
[training]
warmup_steps = 20
batch_per_task = 4
collector = "sync"
demo_episodes = 2
[evaluation]
interval = 1
episodes = 1
"""


def test_demonstrations_are_the_experts_actions_and_do_not_count_as_env_steps(
    tmp_path: Path,
) -> None:
    path = tmp_path / "reach.toml"
    path.write_text(REACH)
    run = run_seed(load_protocol(path), 0, tmp_path / "g").run_dir
    payload = read_checkpoint(run / "checkpoints" / "ckpt-0000001.pt")
    state = payload["runner"]["state"]
    # 2 episodes x 20 steps of the expert, then the epoch's 20 random warm-up steps: the replay
    # holds 60 transitions, but the env-step counter (and with it the warm-up) counts only 20.
    assert state["demos"]["mw"]["episodes"] == 2
    assert state["demos"]["mw"]["env_steps"] == 40
    assert state["env_steps"] == {"mw": [20]}
    replay = payload["replay"]["envs"]["mw"]
    assert replay["size"].tolist() == [60]
    # The first 40 stored actions are what metaworld's scripted policy does on the stored observations.
    expert = make_adapter("metaworld", tasks=["reach-v3"], episode_length=20).expert("reach-v3")
    obs = replay["obs"][0, :40].numpy()
    actions = replay["actions"][0, :40].numpy()
    np.testing.assert_allclose(actions, np.stack([expert(o) for o in obs]), atol=1e-6)
    # ...and they are not random: the expert's xyz actions point at the goal (obs[36:39]).
    to_goal = obs[:, 36:39] - obs[:, 0:3]
    cosine = np.sum(actions[:, :3] * to_goal, 1) / (
        np.linalg.norm(actions[:, :3], axis=1) * np.linalg.norm(to_goal, axis=1) + 1e-9
    )
    assert np.median(cosine) > 0.9
    # Demonstrations are data, counted as consumed only when sampled: the warm-up ends with the
    # epoch's 20 env steps, then 20 gradient steps of batch 4 consume 80 transitions, not 80 + 40.
    assert pd.read_csv(run / "metrics.csv")["updates"].tolist() == [80 / 1e6]


def test_demo_episodes_without_an_expert_is_a_one_line_load_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "point.toml"
    path.write_text(
        REACH.replace('adapter = "metaworld"', 'adapter = "point"').replace(
            'tasks = ["reach-v3"]', 'tasks = ["east", "north"]'
        )
    )
    assert main(["run", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "training.demo_episodes = 2" in err and "'point'" in err and "east, north" in err
    assert not (tmp_path / "out").exists()


POINT = """
[protocol]
kind = "baseline"
epochs = 10
seeds = 1
device = "cpu"
threads = 1
[envs.pt]
adapter = "point"
tasks = ["east", "north"]
episode_length = 10
[agent]
hidden = [8, 8]
[training]
warmup_steps = 0
batch_per_task = 4
collector = "sync"
[evaluation]
interval = 2
episodes = 2
threshold = 0.0
stop_when_reached = {stop}
[checkpoint]
interval = 5
"""


@pytest.mark.parametrize("stop", [True, False])
def test_stop_when_reached_ends_the_phase_at_the_first_evaluation_where_all_tasks_reached(
    tmp_path: Path, stop: bool
) -> None:
    # threshold 0: every task "reaches" at the first evaluation (epoch 2), so with the stop the run
    # ends there, with a checkpoint at epoch 2 though the checkpoint interval is 5.
    path = tmp_path / "point.toml"
    path.write_text(POINT.format(stop="true" if stop else "false"))
    run = run_seed(load_protocol(path), 0, tmp_path / "g").run_dir
    metrics = pd.read_csv(run / "metrics.csv")
    last = 2 if stop else 10
    assert int(metrics["epoch"].max()) == last
    assert sorted(metrics["epoch"].unique()) == list(range(2, last + 1, 2))
    assert (run / "checkpoints" / f"ckpt-{last:07d}.pt").is_file()
    if stop:
        # Resuming a stopped run trains no further: the stop is derived from the saved state.
        from seal.run.runner import resume_run

        resume_run(run)
        assert int(pd.read_csv(run / "metrics.csv")["epoch"].max()) == 2


JOINT = (
    REACH.replace('kind = "baseline"', 'kind = "joint"')
    + """
[envs.other]
adapter = "metaworld"
tasks = ["drawer-close-v3"]
episode_length = 20
"""
)


def test_an_env_without_demonstrations_warms_up_as_in_a_run_without_any(tmp_path: Path) -> None:
    # mw puts 2 expert episodes in its replay (training.demo_episodes), other none
    # (envs.other.demo_episodes = 0). Set against a run with no demonstrations at all, other's
    # replay holds the very same warm-up transitions: its resets were not spent on mw's experts.
    with_demos = tmp_path / "with.toml"
    with_demos.write_text(JOINT + "demo_episodes = 0\n")
    without = tmp_path / "without.toml"
    without.write_text(JOINT.replace("demo_episodes = 2", "demo_episodes = 0"))
    replays = {}
    for path in (with_demos, without):
        run = run_seed(load_protocol(path), 0, tmp_path / path.stem).run_dir
        payload = read_checkpoint(run / "checkpoints" / "ckpt-0000001.pt")
        replays[path.stem] = payload["replay"]["envs"]
    assert list(payload["runner"]["state"]["demos"]) == []
    assert replays["with"]["mw"]["size"].tolist() == [60]
    assert replays["with"]["other"]["size"].tolist() == [20]
    for key in ("obs", "actions", "rewards"):
        assert torch.equal(replays["with"]["other"][key], replays["without"]["other"][key])
