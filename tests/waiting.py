"""Waiting in a test for an event (a file, a row, a process's end), never for a duration.

`wait_until` polls a condition; its only time limit, `HUNG_S`, is reached by a hang alone, so
its verdict does not depend on the machine's speed."""

from __future__ import annotations

import subprocess
import time
from collections.abc import Callable

HUNG_S = 900.0
"""How long a wait goes on before it calls the step it waits for hung: far beyond any working
step (a working sweep once took 180 s to start Ray and two trials, on 2 cores beside three kitchen
runs)."""


def wait_until(
    ready: Callable[[], bool],
    what: str,
    *,
    child: subprocess.Popen | None = None,
    why: Callable[[], str] | None = None,
    limit_s: float = HUNG_S,
    poll_s: float = 0.05,
) -> None:
    """Return once `ready()` is true, polling every `poll_s`. Fail if `child` (the process that
    should make it true) ended first, saying `why()` (default: the child's piped stderr), or
    after `limit_s`."""
    deadline = time.monotonic() + limit_s
    while not ready():
        if child is not None and child.poll() is not None and not ready():  # ready, then exited
            said = why() if why is not None else _stderr(child)
            raise AssertionError(f"the child ended (exit {child.returncode}) before {what}: {said}")
        assert time.monotonic() < deadline, f"never {what} (waited {limit_s:.0f} s)"
        time.sleep(poll_s)


def _stderr(child: subprocess.Popen) -> str:
    if child.stderr is None:
        return "(its stderr was not piped)"
    text = child.stderr.read()
    return text.decode(errors="replace") if isinstance(text, bytes) else text
