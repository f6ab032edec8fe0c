"""`check_adapter` and `seal envs`: good adapters pass, deliberately broken ones fail, bad input exits 2."""

from __future__ import annotations

import importlib.util
import inspect
import json
import pathlib
import subprocess
import sys
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from seal.cli.main import main
from seal.envs import EnvAdapter
from seal.envs.check import check_adapter
from seal.envs.metaworld import MetaWorldAdapter
from seal.envs.point import PointAdapter

# ---- deliberately broken point adapters: each breaks one promise -------------------------------


class _Patch(gym.Wrapper):
    """Applies `patch(obs, reward, terminated, truncated, info, t)` to every step."""

    def __init__(self, env: gym.Env, patch: Any) -> None:
        super().__init__(env)
        self._patch, self._t = patch, 0

    def reset(self, **kwargs: Any) -> Any:
        self._t = 0
        return self.env.reset(**kwargs)

    def step(self, action: np.ndarray) -> Any:
        self._t += 1
        return self._patch(*self.env.step(action), self._t)


def _broken(name: str, patch: Any) -> type[PointAdapter]:
    def make(self: PointAdapter, task: str, seed: int) -> gym.Env:
        return _Patch(PointAdapter.make(self, task, seed), patch)

    return type(name, (PointAdapter,), {"make": make, "name": f"broken_{name}"})


def _always_success(o, r, te, tr, info, t):  # noqa: ANN001, ANN202
    return o, r, te, tr, {**info, "success": 1.0}


def _bool_success(o, r, te, tr, info, t):  # noqa: ANN001, ANN202
    return o, r, te, tr, {**info, "success": bool(info["success"])}


def _reward_ignores_goal(o, r, te, tr, info, t):  # noqa: ANN001, ANN202
    return o, -1.0, te, tr, info


def _nan_after_ten_steps(o, r, te, tr, info, t):  # noqa: ANN001, ANN202
    return (o * np.nan if t > 10 else o), r, te, tr, info


def _terminates(o, r, te, tr, info, t):  # noqa: ANN001, ANN202
    return o, r, t == 5, tr, info


AlwaysSuccessPoint = _broken("AlwaysSuccessPoint", _always_success)
BoolSuccessPoint = _broken("BoolSuccessPoint", _bool_success)
RewardIgnoresGoalPoint = _broken("RewardIgnoresGoalPoint", _reward_ignores_goal)
NaNPoint = _broken("NaNPoint", _nan_after_ten_steps)
TerminatingPoint = _broken("TerminatingPoint", _terminates)


class SeedIgnoringPoint(PointAdapter):
    """Like upstream Meta-World: reset(seed=...) ignores the seed, and make ignores it too."""

    name = "broken_seed_ignoring"

    def make(self, task: str, seed: int) -> gym.Env:
        env = super().make(task, seed)
        env.reset = lambda seed=None, options=None, _reset=env.reset: _reset(seed=None)  # type: ignore[method-assign]
        env._seed(int(np.random.SeedSequence().entropy % 2**31))
        return env


class FixedStartPoint(PointAdapter):
    """Every episode starts at the same point whatever the seed."""

    name = "broken_fixed_start"

    def make(self, task: str, seed: int) -> gym.Env:
        return _FixedStart(super().make(task, seed))


class _FixedStart(gym.Wrapper):
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> Any:
        return self.env.reset(seed=0)


# ---- check_adapter -----------------------------------------------------------------------------


def test_point_passes_with_the_documented_structure(point_adapter: PointAdapter) -> None:
    report = check_adapter(point_adapter)
    assert set(report) == {"adapter", "ok", "tasks"}
    assert report["adapter"] == "point" and report["ok"] is True
    assert list(report["tasks"]) == ["east", "north", "west", "south"]
    for result in report["tasks"].values():
        assert result["ok"] is True and result["errors"] == []
        assert result["steps_checked"] == 50  # a full episode, truncated at 50
        assert result["scripted_success"] == 1.0 and result["success_at_reset"] == 0.0
    json.dumps(report)  # JSON-ready


@pytest.mark.parametrize(
    ("adapter_cls", "expected_error"),
    [
        (AlwaysSuccessPoint, "semantic check failed"),
        (RewardIgnoresGoalPoint, "semantic check failed"),
        (BoolSuccessPoint, "step 1: info['success'] is False, expected 0.0 or 1.0"),
        (NaNPoint, "step 11: observation has NaN or inf at indices [0, 1, 2, 3]"),
        (TerminatingPoint, "step 5: terminated=True, but episodes end only by truncation"),
        (
            SeedIgnoringPoint,
            "two envs made and reset with seed 0 give different first observations",
        ),
        (FixedStartPoint, "seeds 1..3 give the same first observation as seed 0"),
    ],
)
def test_broken_point_adapters_fail(adapter_cls: type[EnvAdapter], expected_error: str) -> None:
    report = check_adapter(adapter_cls(tasks=["east"]))
    result = report["tasks"]["east"]
    assert report["ok"] is False and result["ok"] is False
    assert expected_error in result["errors"]


def test_always_success_is_caught_at_reset() -> None:
    result = check_adapter(AlwaysSuccessPoint(tasks=["north"]))["tasks"]["north"]
    assert result["api_ok"] is True and result["semantic_ok"] is False
    assert result["success_at_reset"] == 1.0


@pytest.mark.slow
def test_broken_adapters_of_the_kitchen_fixtures_fail() -> None:
    path = pathlib.Path(__file__).with_name("broken_adapters.py")
    assert path.exists(), "the kitchen's broken-adapter fixtures are missing"
    spec = importlib.util.spec_from_file_location("broken_adapters", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    classes = [
        c
        for _, c in inspect.getmembers(module, inspect.isclass)
        if issubclass(c, EnvAdapter)
        and c.__module__ == module.__name__
        and not inspect.isabstract(c)
    ]
    assert classes, "broken_adapters.py defines no adapter"
    for cls in classes:
        report = check_adapter(cls(tasks=cls.all_tasks[:1]))
        (result,) = report["tasks"].values()
        assert report["ok"] is False and result["ok"] is False, cls.__name__
        # failed for the lie, not because the fixture itself crashed
        assert not any(e.startswith("API check raised") for e in result["errors"]), result["errors"]
        assert "semantic_error" not in result, result["semantic_error"]


def test_metaworld_reach_passes_with_scripted_success() -> None:
    report = check_adapter(MetaWorldAdapter(tasks=["reach-v3"]))
    result = report["tasks"]["reach-v3"]
    assert report["ok"] is True, result["errors"]
    assert result["scripted_success"] >= 0.8 and result["episodes"] == 10
    assert result["steps_checked"] == 500


# ---- CLI ---------------------------------------------------------------------------------------


def test_cli_check_point_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["envs", "check", "point", "--json"]) == 0
    out, err = capsys.readouterr()
    report = json.loads(out)
    assert report["ok"] is True and set(report["tasks"]) == {"east", "north", "west", "south"}
    assert err == ""  # no progress lines with --json


def test_cli_check_prints_progress_and_fails_broken_adapter(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["envs", "check", f"{__name__}:AlwaysSuccessPoint", "--tasks", "west"]) == 1
    out, err = capsys.readouterr()
    assert "checking broken_AlwaysSuccessPoint west" in err
    assert "FAIL west" in out and "broken_AlwaysSuccessPoint: NOT ok" in out


def test_cli_lists_adapters(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["envs", "--json"]) == 0
    adapters = json.loads(capsys.readouterr().out)["adapters"]
    assert adapters["point"] == {
        "tasks": ["east", "north", "west", "south"],
        "obs_dim": 4,
        "act_dim": 2,
        "episode_length": 50,
    }
    assert {k: adapters["metaworld"][k] for k in ("obs_dim", "act_dim", "episode_length")} == {
        "obs_dim": 39,
        "act_dim": 4,
        "episode_length": 500,
    }
    assert len(adapters["metaworld"]["tasks"]) == 10
    assert "franka_kitchen_dense" in adapters  # listed, or listed with its import error
    assert main(["envs"]) == 0
    assert "point: obs_dim 4, act_dim 2, episode_length 50" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            ["envs", "check", "nope"],
            "seal envs: error: unknown adapter 'nope'; valid: metaworld, franka_kitchen_dense, point, point_view, point_diagonal, package.module:Class",
        ),
        (
            ["envs", "check", "point", "--tasks", "up"],
            "seal envs: error: unknown point task 'up'; valid: east, north, west, south",
        ),
        (
            ["envs", "check", "metaworld", "--tasks", "reach-v2"],
            "seal envs: error: unknown metaworld task 'reach-v2'; valid: assembly-v3,",
        ),
        (
            ["envs", "check", "no_such_pkg.mod:Cls"],
            "seal envs: error: adapter 'no_such_pkg.mod:Cls': cannot import module 'no_such_pkg.mod'",
        ),
        (
            ["envs", "check", "seal.envs.point:Nope"],
            "seal envs: error: adapter 'seal.envs.point:Nope': seal.envs.point.Nope is not a seal.envs.EnvAdapter subclass",
        ),
    ],
)
def test_cli_bad_input_exits_2_with_one_line(
    capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    assert main(argv) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.startswith(message) and err.count("\n") == 1
    assert "valid:" in err or "built-in adapters:" in err


def test_a_negative_seed_is_refused_not_blamed_on_the_tasks(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["envs", "check", "point", "--seed", "-1"]) == 2  # not "NOT ok" on every task
    assert capsys.readouterr().err == "seal envs: error: --seed -1: must be >= 0\n"


def test_cli_bad_input_has_no_traceback_from_the_shell() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "seal.cli.main", "envs", "check", "nope.mod:X"],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 2
    assert "Traceback" not in done.stderr and done.stderr.count("\n") == 1
    assert "valid: metaworld, franka_kitchen_dense, point" in done.stderr
