"""`seal run` in a child process that can hold still at a chosen point, for a signal to find it there.

    python signal_child.py MARKER WHERE N SECONDS seal-run-args...

WHERE is where the child creates MARKER and holds until a signal has come and been handled, then
SECONDS more (a handler that stops the run ends the hold at once):

- ``none``: nowhere, `seal run` runs unchanged;
- ``paced``: nowhere, but every epoch sleeps SECONDS after its collection and again before its
  evaluation, so that a test's seeded delay lands inside the epoch it aims at on any machine;
  and its last epoch never ends before a signal comes (a test starved by a loaded machine finds
  the run still going, issue 55);
- ``evaluation``: at the start of the N-th evaluation;
- ``epoch-end``: at the end of the N-th epoch's work, its collection in the replay (with
  `training.overlap` too), before its training curves and evaluation;
- ``checkpoint``: inside the N-th epoch checkpoint's atomic write, its temporary file written
  and fsynced, before the rename;
- ``signal-save``: inside the write of the checkpoint saved after a signal (the one a second
  signal must abort), before the rename; its last epoch never ends before a signal, as ``paced``.
"""

from __future__ import annotations

import os
import signal
import sys
import time
from pathlib import Path

from holds import hold_in_the_last_epoch  # this folder, on sys.path for a script

import seal.learner.checkpoint as checkpoint
import seal.run.evaluation as evaluation
import seal.run.loop as phase
from seal.cli.main import main


def _hold(marker: Path, seconds: float, text: str) -> None:
    """Create the marker, then hold until a signal has come and been handled (600 s at most: only
    a test that never signals reaches it), then `seconds` more. A hold of a fixed duration was
    missed by a test starved on a loaded machine (issue 55)."""
    came: list[int] = []
    originals = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}

    def handler(sig: int, frame: object) -> None:
        came.append(sig)
        original = originals[signal.Signals(sig)]
        if callable(original):
            original(sig, frame)
        elif original == signal.SIG_DFL:  # the default action: die by the signal
            signal.signal(sig, signal.SIG_DFL)
            os.kill(os.getpid(), sig)

    for s in originals:
        signal.signal(s, handler)
    staged = marker.with_name(marker.name + ".tmp")
    staged.write_text(text)
    os.replace(staged, marker)  # the marker appears with its text
    try:
        deadline = time.monotonic() + 600
        while not came and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(seconds)
    finally:
        for s, original in originals.items():
            if signal.getsignal(s) is handler:  # the run's own changes to its handlers stay
                signal.signal(s, original)


def _at_epoch_end(marker: Path, nth: int, seconds: float) -> None:
    real_end, seen = phase.PhaseLoop._end_epoch, 0

    def end_epoch(loop: phase.PhaseLoop) -> bool:
        nonlocal seen
        seen += 1
        if seen == nth:
            _hold(marker, seconds, f"end of epoch {nth}")
        return real_end(loop)

    phase.PhaseLoop._end_epoch = end_epoch  # type: ignore[method-assign]


def _paced(seconds: float) -> None:
    real_evaluate, real_train = evaluation.evaluate, phase.PhaseLoop._train

    def evaluate(*args: object, **kwargs: object) -> object:
        time.sleep(seconds)
        return real_evaluate(*args, **kwargs)  # type: ignore[arg-type]

    def train(loop: phase.PhaseLoop, *args: object) -> None:
        time.sleep(seconds)
        real_train(loop, *args)  # type: ignore[arg-type]

    evaluation.evaluate = evaluate  # type: ignore[assignment]
    phase.PhaseLoop._train = train  # type: ignore[method-assign]


def _in_evaluation(marker: Path, nth: int, seconds: float) -> None:
    real_evaluate, seen = evaluation.evaluate, 0

    def evaluate(*args: object, **kwargs: object) -> object:
        nonlocal seen
        seen += 1
        if seen == nth:
            _hold(marker, seconds, f"evaluation {nth}")
        return real_evaluate(*args, **kwargs)  # type: ignore[arg-type]

    evaluation.evaluate = evaluate  # type: ignore[assignment]


def _in_checkpoint_write(marker: Path, nth: int, seconds: float, after_signal: bool) -> None:
    real_replace, seen = os.replace, 0

    def replace(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
        nonlocal seen
        if Path(dst).name.startswith("ckpt-"):
            seen += 1
            # After a signal the run saves with the signals' default actions (a second one kills).
            saving_at_signal = signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
            if saving_at_signal if after_signal else seen == nth:
                _hold(marker, seconds, str(dst))
        real_replace(src, dst)

    # atomic_save calls os.replace through the module's `os`; give it a namespace of its own.
    class _Os:
        def __getattr__(self, name: str) -> object:
            return getattr(os, name)

    patched = _Os()
    patched.replace = replace  # type: ignore[attr-defined]
    checkpoint.os = patched  # type: ignore[assignment]


if __name__ == "__main__":
    # A run started from a terminal: Ctrl-C reaches it. A test runner launched in the background
    # of a shell without job control (`(cmd &)`, nohup) ignores SIGINT, children inherit that, and
    # `seal run` rightly leaves an ignored SIGINT ignored: every SIGINT test would then wait for
    # a signal the child never sees.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    marker, where, nth, seconds = (
        Path(sys.argv[1]),
        sys.argv[2],
        int(sys.argv[3]),
        float(sys.argv[4]),
    )
    if where == "evaluation":
        _in_evaluation(marker, nth, seconds)
    elif where == "epoch-end":
        _at_epoch_end(marker, nth, seconds)
    elif where == "paced":
        _paced(seconds)
        hold_in_the_last_epoch()
    elif where in ("checkpoint", "signal-save"):
        _in_checkpoint_write(marker, nth, seconds, after_signal=where == "signal-save")
        if where == "signal-save":  # its first signal comes after a row seen, not at a hold
            hold_in_the_last_epoch()
    elif where != "none":
        raise SystemExit(f"signal_child.py: unknown WHERE {where!r}")
    sys.exit(main(sys.argv[5:]))
