"""One writer per directory: `DirLock`, an exclusive `flock` on the directory's `.seal.lock`
(see `seal.run.rundir` for what holds it and when)."""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path

from seal.errors import SealError
from seal.files import MIB, read_data_file

try:
    import fcntl
except ImportError:  # not POSIX: no locking
    fcntl = None  # type: ignore[assignment]

NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)
"""os.O_NOFOLLOW where the OS has it: the lock file and the CSVs are never opened through a symlink."""

LOCK_FILE = ".seal.lock"


class DirLock:
    """An exclusive, non-blocking `flock` on `<directory>/.seal.lock`, held while one process writes.

    `acquire` raises SealError naming the directory and the holder's pid and command when another
    process (or another `DirLock` in this one) holds it. The lock belongs to the open file, so
    the OS releases it when the holder exits, however it dies; the file itself stays.
    """

    def __init__(self, directory: Path) -> None:
        self.directory = Path(directory)
        self.path = self.directory / LOCK_FILE
        self._fd: int | None = None

    def acquire(self, command: Sequence[str] | None = None) -> DirLock:
        """Take the lock (creating the directory) and record this process in the lock file."""
        if fcntl is None or self._fd is not None:
            return self
        self.directory.mkdir(parents=True, exist_ok=True)
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | NOFOLLOW, 0o644)
        except OSError as exc:  # ELOOP: a symlink, which the pid would be written through
            raise SealError(
                f"{self.path}: the lock file cannot be opened ({exc.strerror}); seal makes it a "
                "regular file: remove it, then try again"
            ) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise SealError(
                f"{self.directory} is being written by another seal process ({self.holder()}); "
                "wait for it to finish or stop it, then try again"
            ) from None
        holder = {"pid": os.getpid(), "command": " ".join(command or _this_command())}
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(holder) + "\n").encode(), 0)
        self._fd = fd
        return self

    def release(self) -> None:
        """Drop the lock (idempotent)."""
        if self._fd is not None:
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None

    def holder(self) -> str:
        """ "pid N: command" of the process that last took the lock, as its lock file says."""
        try:
            data = json.loads(read_data_file(self.path, what="lock file", limit=MIB))
            return f"pid {data['pid']}: {data['command']}"
        except (SealError, ValueError, KeyError, TypeError):
            return "pid unknown"

    def __enter__(self) -> DirLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


def _this_command() -> list[str]:
    import sys

    return [Path(sys.argv[0]).name, *sys.argv[1:]] if sys.argv else []
