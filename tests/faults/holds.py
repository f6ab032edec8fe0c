"""What the fault tests' child scripts share (imported by them as scripts: their folder is on sys.path)."""

from __future__ import annotations

import time

import seal.run.loop as phase


def hold_in_the_last_epoch() -> None:
    """The run's last epoch sleeps before its end until a signal's handling cuts the sleep short
    (or the test kills the child), so a signal or kill sent after a seeded delay finds the run
    still going, however fast the machine (issue 55). Nothing before that point changes."""
    real_end = phase.PhaseLoop._end_epoch

    def end_epoch(loop: phase.PhaseLoop) -> bool:
        if loop.state.epoch + 1 >= loop.phase.epochs:
            time.sleep(600)
        return real_end(loop)

    phase.PhaseLoop._end_epoch = end_epoch  # type: ignore[method-assign]
