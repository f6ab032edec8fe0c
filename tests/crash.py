"""A loop callback that stands in for a kill, shared by the resume tests."""

from __future__ import annotations

from seal.run.loop import LoopCallback, PhaseLoop


class CrashAfter(LoopCallback):
    """Stands in for a kill: the run stops after epoch `at`, files as they are."""

    def __init__(self, at: int) -> None:
        self.at = at

    def on_epoch_end(self, loop: PhaseLoop) -> None:
        if loop.state.epoch == self.at:
            raise KeyboardInterrupt
