"""Every env a built-in adapter makes passes gymnasium's own `check_env`.

`skip_render_check=True`: gymnasium's render check re-makes each env in every declared render
mode, including "human", which needs a display that CI machines lack (the kitchen's GLFW viewer
aborts the process there); rendering is checked by `seal eval --video`'s own probe instead.
"""

from __future__ import annotations

import re
import warnings

import pytest
from gymnasium.utils.env_checker import check_env

from seal.envs import make_adapter
from seal.envs.registry import BUILTIN_ADAPTERS

# Gymnasium's advice, not a defect: unbounded Box observations, and checking a wrapped env.
ADVICE = re.compile(r"Box observation space .*infinity|different from the unwrapped version")


def _cases() -> list[tuple[str, str]]:
    cases = []
    for name in BUILTIN_ADAPTERS:
        adapter = make_adapter(name)  # each adapter's default task list (Meta-World: MT10)
        cases.extend((name, task) for task in adapter.tasks)
    return cases


@pytest.mark.parametrize(("adapter", "task"), _cases())
def test_check_env_passes(adapter: str, task: str) -> None:
    env = make_adapter(adapter).make(task, seed=0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env, skip_render_check=True)
    env.close()
    # check_env reports real defects (an observation outside its space, a non-bool terminated,
    # an inf reward, a wrong dtype) as warnings too; only its advice is allowed here.
    defects = [str(w.message) for w in caught if not ADVICE.search(str(w.message))]
    assert not defects, defects
