"""The adapter registry: built-in names, import paths, and the errors a user sees."""

from __future__ import annotations

import sys

import pytest

from seal.envs import BUILTIN_ADAPTERS, adapter_class, make_adapter
from seal.envs.metaworld import MetaWorldAdapter
from seal.envs.point import PointAdapter
from seal.envs.registry import check_options
from seal.errors import SealError, UnknownNameError


def test_builtin_names_resolve() -> None:
    assert list(BUILTIN_ADAPTERS) == [
        "metaworld",
        "franka_kitchen_dense",
        "point",
        "point_view",
        "point_diagonal",
    ]
    assert adapter_class("metaworld") is MetaWorldAdapter
    assert adapter_class("point") is PointAdapter
    assert adapter_class("seal.envs.point:PointAdapter") is PointAdapter  # the same, by import path


def test_make_adapter_passes_tasks_and_options() -> None:
    adapter = make_adapter("point", tasks=["south", "east"], episode_length=7)
    assert adapter.tasks == ("south", "east") and adapter.episode_length == 7
    assert make_adapter("metaworld", tasks="mt3").tasks == ("reach-v3", "push-v3", "pick-place-v3")


def test_unknown_adapter_lists_the_valid_ones() -> None:
    with pytest.raises(UnknownNameError) as info:
        adapter_class("pointt")
    assert (
        str(info.value)
        == "unknown adapter 'pointt'; valid: metaworld, franka_kitchen_dense, point, point_view, point_diagonal, package.module:Class"
    )


def test_bad_import_paths() -> None:
    with pytest.raises(
        SealError,
        match=r"cannot import module 'nowhere' \(No module named 'nowhere'; is nowhere "
        r"installed, or the folder that holds nowhere on PYTHONPATH\?\); valid: metaworld, ",
    ):
        adapter_class("nowhere:Adapter")
    with pytest.raises(
        SealError, match=r"seal.envs.point.PointEnv is not a seal.envs.EnvAdapter subclass"
    ):
        adapter_class("seal.envs.point:PointEnv")  # a class, but not an adapter
    # A module that acts on import is never imported for a name read from a file:
    for path in ("antigravity:X", "os.path:X", "this:X"):
        with pytest.raises(
            SealError, match=r"is in Python's standard library, which holds no adapter;"
        ):
            adapter_class(path)
    assert "antigravity" not in sys.modules and "this" not in sys.modules
    # Nor a package's command line: importing PIL.__main__ prints Pillow's report, certifi's
    # parses seal's own arguments.
    for path in ("PIL.__main__:X", "certifi.__main__:X"):
        with pytest.raises(SealError, match=r"is a package's command line \(__main__\)"):
            adapter_class(path)
        assert path.partition(":")[0] not in sys.modules


def test_bad_tasks_and_options() -> None:
    with pytest.raises(SealError, match=r"task list \['east', 'east'\] repeats a task"):
        make_adapter("point", tasks=["east", "east"])
    with pytest.raises(SealError, match=r"adapter 'point' takes no option\(s\) \['frame_skip'\]"):
        make_adapter("point", frame_skip=2)
    with pytest.raises(SealError, match="episode_length must be >= 1, got 0"):
        make_adapter("point", episode_length=0)
    for bad in ("x", True, 2.5):  # --option values parse as TOML: any type can arrive
        with pytest.raises(SealError, match="episode_length must be an integer, got"):
            make_adapter("point", episode_length=bad)
    with pytest.raises(SealError, match="option 'tasks' is not an adapter option"):
        check_options({"tasks": ["east"], "goal_scale": 2})  # Python: "got multiple values"


def test_env_maps_resolve_and_refuse_like_adapters() -> None:
    from seal.envs import env_map
    from seal.envs.testbed import ORACLE_MAP

    assert env_map("testbed_oracle") is ORACLE_MAP
    assert env_map("seal.envs.testbed:ORACLE_MAP") is ORACLE_MAP  # the same, by import path
    for bad, says in [
        (":X", "env map ':X': module '' is not an absolute import path; valid: testbed_oracle"),
        (".x:X", "env map '.x:X': module '.x' is not an absolute import path"),
        (
            "seal.envs.testbed:",
            "env map 'seal.envs.testbed:': '' after the ':' is not a Python name",
        ),
        (
            "seal.envs.point:PointAdapter",
            "seal.envs.point.PointAdapter is not a seal.envs.base.EnvMap",
        ),
        ("nowhere:MAP", "env map 'nowhere:MAP': cannot import module 'nowhere'"),
    ]:
        with pytest.raises(SealError) as info:
            env_map(bad)
        assert says in str(info.value)
