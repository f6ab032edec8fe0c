"""Every env a built-in adapter makes passes gymnasium's own `check_env`.

`skip_render_check=True`: gymnasium's render check re-makes each env in every declared render
mode, including "human", which needs a display that CI machines lack (the kitchen's GLFW viewer
aborts the process there); rendering is checked by `seal eval --video`'s own probe instead.
"""

from __future__ import annotations

import warnings

import pytest
from gymnasium.utils.env_checker import check_env

from seal.envs import make_adapter
from seal.envs.registry import BUILTIN_ADAPTERS


def _cases() -> list[tuple[str, str]]:
    cases = []
    for name in BUILTIN_ADAPTERS:
        adapter = make_adapter(name)  # each adapter's default task list (Meta-World: MT10)
        cases.extend((name, task) for task in adapter.tasks)
    return cases


@pytest.mark.parametrize(("adapter", "task"), _cases())
def test_check_env_passes(adapter: str, task: str) -> None:
    env = make_adapter(adapter).make(task, seed=0)
    with warnings.catch_warnings():
        # Gymnasium's advice (unbounded Box spaces, checking the unwrapped env) is not an error.
        warnings.simplefilter("ignore", UserWarning)
        check_env(env, skip_render_check=True)
    env.close()
