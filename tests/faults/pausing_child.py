"""`seal run` in a child process that can stop inside a checkpoint's atomic write (run as a script).

    python pausing_child.py MARKER N seal-run-args...

With N > 0, the N-th epoch checkpoint's save is held after its temporary file is written and
fsynced, just before the rename: the child creates MARKER and sleeps until the test kills it,
exactly where a kill inside `atomic_save` leaves a full temporary file and no new checkpoint.
With N = 0 the child runs `seal run` unchanged, except that its last epoch never ends: it sleeps
there until the test kills it, so a kill at any delay lands on a run still going, however fast the
machine (issue 55). Nothing before that point changes.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

from holds import hold_in_the_last_epoch  # this folder, on sys.path for a script

import seal.learner.checkpoint as checkpoint
from seal.cli.main import main


def _pause_in_nth_checkpoint(marker: Path, nth: int) -> None:
    real_replace = os.replace
    seen = 0

    def replace(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
        nonlocal seen
        if Path(dst).name.startswith("ckpt-"):
            seen += 1
            if seen == nth:
                marker.write_text(str(dst))
                time.sleep(600)
        real_replace(src, dst)

    # atomic_save calls os.replace through the module's `os`; give it a namespace of its own.
    class _Os:
        def __getattr__(self, name: str) -> object:
            return getattr(os, name)

    patched = _Os()
    patched.replace = replace  # type: ignore[attr-defined]
    checkpoint.os = patched  # type: ignore[assignment]


if __name__ == "__main__":
    marker, nth = Path(sys.argv[1]), int(sys.argv[2])
    if nth > 0:
        _pause_in_nth_checkpoint(marker, nth)
    else:
        hold_in_the_last_epoch()
    sys.exit(main(sys.argv[3:]))
