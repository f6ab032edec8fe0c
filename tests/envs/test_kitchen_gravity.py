"""The kitchen adapter's `gravity_compensation` option: off (default) the arm sags exactly as
upstream's does; on, a zero action holds the gripper within 1 cm over 50 steps. Unknown options
and non-boolean values are one-line errors naming the valid ones."""

from __future__ import annotations

import contextlib
import io

import numpy as np
import pytest
from franka_kitchen_dense.adapter import FrankaKitchenDenseAdapter

from seal.envs import make_adapter
from seal.errors import SealError

with contextlib.redirect_stderr(io.StringIO()):
    from gymnasium_robotics.envs.franka_kitchen.kitchen_env import KitchenEnv

STEPS = 50


def _tcp_path(gravity_compensation: bool) -> np.ndarray:
    """Gripper (end_effector site) positions at reset and after each of 50 zero-action steps."""
    adapter = make_adapter(
        "franka_kitchen_dense", tasks=["microwave"], gravity_compensation=gravity_compensation
    )
    env = adapter.make("microwave", seed=0)
    env.reset(seed=0)
    raw = env.unwrapped
    path = [raw.data.site_xpos[raw._tcp_id].copy()]
    for _ in range(STEPS):
        env.step(np.zeros(9, dtype=np.float32))
        path.append(raw.data.site_xpos[raw._tcp_id].copy())
    env.close()
    return np.array(path)


def test_gravity_compensation_holds_the_gripper() -> None:
    path = _tcp_path(True)
    drift = float(np.linalg.norm(path[-1] - path[0]))
    assert drift < 0.01  # measured 3.7 mm: only the observation noise the controller integrates


def test_without_it_the_arm_sags_exactly_as_upstream() -> None:
    path = _tcp_path(False)
    upstream = KitchenEnv(terminate_on_tasks_completed=False, remove_task_when_completed=False)
    upstream.reset(seed=0)
    site = upstream.model.site("end_effector").id
    expected = [upstream.data.site_xpos[site].copy()]
    for _ in range(STEPS):
        upstream.step(np.zeros(9))
        expected.append(upstream.data.site_xpos[site].copy())
    upstream.close()
    np.testing.assert_array_equal(path, np.array(expected))
    assert float(np.linalg.norm(path[-1] - path[0])) > 0.1  # measured 0.336 m in 50 steps


def test_the_option_compiles_gravcomp_into_the_robot_bodies_only() -> None:
    env = FrankaKitchenDenseAdapter(tasks=["kettle"], gravity_compensation=True).make("kettle", 0)
    model = env.unwrapped.model
    compensated = {model.body(b).name for b in np.flatnonzero(model.body_gravcomp)}
    assert compensated == {f"panda0_link{i}" for i in range(8)} | {
        "panda0_leftfinger",
        "panda0_rightfinger",
    }
    assert model.ngravcomp == 10
    env.close()
    off = FrankaKitchenDenseAdapter(tasks=["kettle"]).make("kettle", 0)
    assert off.unwrapped.model.ngravcomp == 0  # off by default: upstream's model
    off.close()


def test_unknown_options_and_bad_values_are_one_line_errors() -> None:
    with pytest.raises(SealError) as unknown:
        FrankaKitchenDenseAdapter(gravity_compenstion=True)
    message = str(unknown.value)
    assert "\n" not in message
    assert "unknown option(s) ['gravity_compenstion']" in message
    assert "valid options: gravity_compensation (true or false" in message
    with pytest.raises(SealError, match="gravity_compensation must be true or false, got 'yes'"):
        FrankaKitchenDenseAdapter(gravity_compensation="yes")
    with pytest.raises(SealError, match="""reward_version must be "v2", "v3" or "v4", got 'v9'"""):
        FrankaKitchenDenseAdapter(reward_version="v9")


def test_the_expert_told_of_gravity_compensation_still_solves_the_slide() -> None:
    from franka_kitchen_dense.experts import policy

    adapter = FrankaKitchenDenseAdapter(tasks=["slide-cabinet"], gravity_compensation=True)
    env = adapter.make("slide-cabinet", 0)
    obs, _ = env.reset(seed=0)
    successes = []
    for _ in range(120):
        obs, _, _, _, info = env.step(policy(obs, "slide-cabinet", gravity_compensation=True))
        successes.append(info["success"])
    env.close()
    assert 1.0 in successes


@pytest.mark.parametrize(
    ("option", "message"),
    [
        (
            "gravity=true",
            "seal envs: error: adapter 'franka_kitchen_dense': unknown option(s) ['gravity']; "
            "valid options: gravity_compensation (true or false, default false), "
            'reward_version ("v2", "v3" or "v4", default "v4"), gamma (reward v4\'s approach-term '
            "discount in (0, 1], default 0.99; must equal agent.gamma)",
        ),
        (
            "gravity",
            "seal envs: error: --option 'gravity' must look like key=value "
            "(e.g. gravity_compensation=true)",
        ),
    ],
)
def test_cli_check_option_errors_are_one_line(
    capsys: pytest.CaptureFixture[str], option: str, message: str
) -> None:
    from seal.cli.main import main

    assert main(["envs", "check", "franka_kitchen_dense", "--option", option]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err == message + "\n"
