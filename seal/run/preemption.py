"""Stopping a run at a safe point on SIGTERM and SIGINT (`checkpoint.on_signal`).

Clusters stop jobs politely: Slurm, Kubernetes and Ray send SIGTERM, wait a grace period, then
kill; a user presses Ctrl-C (SIGINT). While a run holds the handlers (`SignalStop.handling`), the
first signal is recorded and the phase loop (`seal.run.loop.PhaseLoop`) stops at a safe
point with a checkpoint of the last finished epoch:

- between epochs, or while an epoch checkpoint is being written: after that epoch (its
  checkpoint written now unless it is already on disk);
- inside an epoch (`SignalStop.epoch`): the loop finishes the epoch when the time it has left
  (the longest recent epoch minus what this one has taken) fits `checkpoint.signal_budget_s`,
  and rolls back to the epoch's start otherwise, or as soon as the budget runs out
  (`RollBack`, raised from the handler). The loop keeps what a rollback needs of every epoch
  start in memory (`seal.run.rollback.EpochMark`).

Callbacks and CSV writes inside an epoch run `protected`: a rollback decided meanwhile is raised
when they return, so no logger is left half way. The save is the ordinary atomic checkpoint
write (`saving`); a second signal during it gets the signal's default action, so the process
dies at once, before the rename: the previous checkpoint stays intact and the next resume
deletes the temporary file. The loop then raises `Preempted`, whose text is one line (what was
saved, how to resume) and whose `exit_code` is 143 for SIGTERM and 130 for SIGINT (128 + the
signal's number, what a shell reports for a process the signal killed).

Worker processes forked by the run (collection backends) inherit the handler, which does nothing
in them: the run stops them. The spawned evaluation and actor workers ignore both signals
(`seal.run.workers`). Handlers can only be installed from the main thread; elsewhere
(e.g. a Ray Tune function trainable's thread) a run keeps the process's own handling, and a
signal the process was started ignoring stays ignored. A sweep's gentle `ray.cancel` reaches a
trial as a SIGINT (Ray's `_thread.interrupt_main`), so the trial stops as on Ctrl-C; the trial
hears it even in a worker that inherited an ignored SIGINT (`hearing_cancel`).
"""

from __future__ import annotations

import collections
import contextlib
import os
import signal
import threading
import time
from collections.abc import Iterator
from types import FrameType

SIGNALS: tuple[signal.Signals, ...] = (signal.SIGTERM, signal.SIGINT)
"""The polite stops a run saves on: a scheduler's SIGTERM and a user's Ctrl-C."""


def signal_name(signum: int) -> str:
    """ "SIGTERM" for 15, "SIGINT" for 2."""
    return signal.Signals(signum).name


class Preempted(BaseException):
    """A run stopped on SIGTERM or SIGINT at a safe point; str() is the one line to print.

    A BaseException, like KeyboardInterrupt, so that no `except Exception` on the way up (a
    sweep trial's, a bench's) mistakes a stop for a failed run.
    """

    def __init__(
        self, signum: int, line: str, *, resumable: bool = True, what: str | None = None
    ) -> None:
        super().__init__(line)
        self.signum = signum
        self.line = line
        self.resumable = resumable
        """False when there is nothing to resume (the run finished, or nothing could be saved)."""
        self.what = line if what is None else what
        """The line without how to resume: what was done and saved."""

    @property
    def exit_code(self) -> int:
        """143 for SIGTERM, 130 for SIGINT: 128 + the signal's number."""
        return 128 + self.signum

    def __str__(self) -> str:
        return self.line


class RollBack(BaseException):
    """Raised by the handler inside an epoch: abandon it, the loop restores the epoch's start."""


class SignalStop:
    """The SIGTERM and SIGINT handlers of one run, and the loop's safe points (module docstring).

    `budget_s`: `checkpoint.signal_budget_s`. An instance that never installed its handlers
    (`active` false) is never `requested`, so a loop runs with it exactly as without.
    """

    def __init__(self, budget_s: float = 0.0) -> None:
        self.budget_s = float(budget_s)
        self.signum: int | None = None
        """The first signal received (None: none yet)."""
        self.received_at = 0.0
        """time.monotonic() at the first signal."""
        self.rollback_reason = ""
        """Why the epoch under way was rolled back (empty: it was not)."""
        self.note = ""
        """What the loop did at the stop and what it saved (set by the loop when it saved)."""
        self.during_epoch = False
        """Whether the first signal came during an epoch's work (else between epochs or in a save)."""
        self.count = 0
        """Signals received (a sweep's driver stops waiting for its trials at the second)."""
        self.active = False
        """Whether the handlers are installed (the loop keeps epoch marks only then)."""
        self._pid = os.getpid()
        self._lock = threading.Lock()
        self._in_epoch = False
        self._epoch_started = 0.0
        self._estimate_s: float | None = None
        self._protected = 0
        self._saving = False
        self._expired = False
        self._timer: threading.Timer | None = None
        self._recent: collections.deque[float] = collections.deque(maxlen=10)

    @property
    def requested(self) -> bool:
        """Whether a signal asked the run to stop."""
        return self.signum is not None

    @property
    def name(self) -> str:
        """The first signal's name ("SIGTERM", "SIGINT"); empty before one came."""
        return signal_name(self.signum) if self.signum is not None else ""

    # ------------------------------------------------------------ installing
    @contextlib.contextmanager
    def handling(self) -> Iterator[SignalStop]:
        """Hold the SIGTERM and SIGINT handlers for the block, then restore the previous ones.

        Outside the main thread nothing is installed (Python allows handlers only there), and a
        signal the process was started ignoring stays ignored (a shell's background job's SIGINT).
        """
        if threading.current_thread() is not threading.main_thread():
            yield self
            return
        previous = {
            s: signal.getsignal(s) for s in SIGNALS if signal.getsignal(s) is not signal.SIG_IGN
        }
        for s in previous:
            signal.signal(s, self._on_signal)
        self.active = bool(previous)
        try:
            yield self
        finally:
            self.active = False
            with self._lock:
                self._in_epoch = False
                self._cancel_timer()
            for s, handler in previous.items():
                signal.signal(s, handler if handler is not None else signal.SIG_DFL)

    # ------------------------------------------------------------ the loop's safe points
    @contextlib.contextmanager
    def epoch(self) -> Iterator[None]:
        """One epoch's work, ended by `epoch_done`: a signal before that lets it finish within the
        budget or raises `RollBack`; one after it stops the loop after the epoch."""
        estimate = max(self._recent) if self._recent else None
        with self._lock:
            self._in_epoch, self._estimate_s = True, estimate
            self._epoch_started = time.monotonic()
        try:
            if self.requested and not self.during_epoch:
                # Came while the epoch was being set up: it has not started, roll it back.
                self.during_epoch, self.rollback_reason = True, "it had not begun"
                raise RollBack
            yield
        finally:
            self.epoch_done()
        self._recent.append(time.monotonic() - self._epoch_started)

    def epoch_done(self) -> None:
        """The epoch's work is done (the loop's last statement in it): no rollback after this."""
        with self._lock:
            self._in_epoch = False
            self._cancel_timer()

    @contextlib.contextmanager
    def protected(self) -> Iterator[None]:
        """A callback or a file write inside an epoch: a rollback decided meanwhile waits for its end."""
        self._protected += 1
        try:
            yield
        finally:
            self._protected -= 1
        if not self._protected and self.rollback_reason and self._in_epoch:
            raise RollBack

    @contextlib.contextmanager
    def saving(self) -> Iterator[None]:
        """An epoch checkpoint's write: a signal lets it finish, a signal after that one kills at once."""
        self._saving = True
        if self.requested:
            self._default_actions()
        try:
            yield
        finally:
            self._saving = False

    def time_since_signal(self) -> float:
        """Seconds since the first signal."""
        return time.monotonic() - self.received_at

    # ------------------------------------------------------------ the handler
    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        if os.getpid() != self._pid:
            return  # a worker forked by the run: the run stops it
        self.count += 1
        if self._saving:
            self._default_actions()  # the next signal aborts the save at once
        expired, self._expired = self._expired, False
        if self.signum is None:
            self.signum, self.received_at = signum, time.monotonic()
            if self._saving or not self._in_epoch:
                return  # the loop stops after the epoch it is closing
            self.during_epoch = True
            left = self._time_left()
            if self.budget_s <= 0:
                reason = "checkpoint.signal_budget_s = 0"
            elif left is None or left <= self.budget_s:
                self._arm_timer()
                return  # finish the epoch
            else:
                reason = f"finishing it would take ~{left:.1f} s, over checkpoint.signal_budget_s = {self.budget_s:g}"
        elif self._saving or not self._in_epoch or self.rollback_reason:
            return
        elif expired:
            reason = f"it was not finished within checkpoint.signal_budget_s = {self.budget_s:g} s"
        else:
            reason = f"a second {signal_name(signum)} came"
        self.rollback_reason = reason
        if not self._protected:
            raise RollBack

    def _time_left(self) -> float | None:
        """Estimated seconds the epoch under way still needs (None: no epoch measured yet)."""
        if self._estimate_s is None:
            return None
        return max(0.0, self._estimate_s - (time.monotonic() - self._epoch_started))

    def _arm_timer(self) -> None:
        """Roll back when the budget runs out before the epoch ends: the timer sends the signal
        again to the main thread, whose handler then raises `RollBack`. A real signal, unlike
        `_thread.interrupt_main`, also cuts short a blocking call (a sleep, a pipe read)."""
        main = threading.main_thread().ident
        assert main is not None

        def expire() -> None:
            with self._lock:  # epoch_done takes it too: no signal once the epoch is done
                if not self._in_epoch or self._saving or self.signum is None:
                    return
                self._expired = True
                signal.pthread_kill(main, self.signum)

        self._timer = threading.Timer(self.budget_s, expire)
        self._timer.daemon = True
        self._timer.start()

    def _cancel_timer(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _default_actions(self) -> None:
        if threading.current_thread() is threading.main_thread():
            for s in SIGNALS:
                if signal.getsignal(s) == self._on_signal:
                    signal.signal(s, signal.SIG_DFL)


@contextlib.contextmanager
def hearing_cancel() -> Iterator[None]:
    """SIGINT heard for the block, in a Ray task: Ray's gentle cancel (`ray.cancel(force=False)`)
    is `_thread.interrupt_main()`, which does nothing in a process that ignores SIGINT, and a Ray
    worker inherits that from a driver started as a shell's background job (`nohup seal bench
    ... &`). The run would then neither hear the stop nor save, and be cut off after the grace
    period. Python's default handler is set for the block (the run's `SignalStop` takes over from
    it) and the ignoring restored after; elsewhere the block runs unchanged."""
    if (
        threading.current_thread() is not threading.main_thread()
        or signal.getsignal(signal.SIGINT) is not signal.SIG_IGN
    ):
        yield
        return
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def ignore_signals() -> None:
    """In a worker process: leave SIGTERM and SIGINT to the run, which stops its workers itself."""
    for s in SIGNALS:
        signal.signal(s, signal.SIG_IGN)
