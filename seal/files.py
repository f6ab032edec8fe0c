"""Files from elsewhere, read as data: a run directory's config, CSVs, JSON and checkpoints.

A run directory gets copied, shared, unpacked from an archive and damaged, so a file in it may
be a symlink leading out of it (to a system file, or to another run), a FIFO that would block a
reader forever, a device that never ends, a directory, or far larger than its format allows.
`open_data_file` opens a file only when it is a regular file (inside `within`, when given),
without blocking on a FIFO and without opening a device at all, and refuses anything else with a
one-line `SealError` naming the file and what is valid. `check_inside` holds an existing path to
its directory without opening it: the writers' side (a path they write through must not lead
out of the directory they write) and that of readers that open files themselves (pandas).
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import BinaryIO

from seal.errors import SealError

MIB = 1 << 20


def _inside(path: Path, within: Path) -> tuple[bool, str]:
    """(whether `path`, every link followed, lies inside `within`, where it leads)."""
    root, real = os.path.realpath(within), os.path.realpath(path)
    return os.path.commonpath([root, real]) == root, real


def _kind(mode: int) -> str:
    """What a non-regular file is, in words."""
    for test, name in (
        (stat.S_ISDIR, "a directory"),
        (stat.S_ISFIFO, "a FIFO (named pipe)"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISSOCK, "a socket"),
    ):
        if test(mode):
            return name
    return "not a regular file"


def open_data_file(
    path: str | os.PathLike[str],
    *,
    what: str = "file",
    within: str | os.PathLike[str] | None = None,
    limit: int | None = None,
) -> BinaryIO:
    """`path` opened for reading in binary mode, once it is known to be a regular file.

    `what` names the file in messages ("run config", "checkpoint"); `within`: the directory it
    must lie in with every symlink followed; `limit`: its largest size in bytes. SealError, with
    nothing opened, for a missing file, a symlink leading out of `within`, anything but a regular
    file, or a file over `limit`.
    """
    path = Path(path)
    if within is not None:
        inside, real = _inside(path, Path(within))
        if not inside:
            raise SealError(
                f"{path}: the {what} is a symlink leading out of {within} (to {real}); "
                f"a run directory's files must lie inside it: replace the link with the file"
            )
    try:
        before = os.stat(path)  # a device or FIFO is refused before it is opened
    except FileNotFoundError:
        raise SealError(f"{path}: no such {what}") from None
    except OSError as exc:
        raise SealError(f"{path}: the {what} cannot be read ({exc.strerror})") from None
    if not stat.S_ISREG(before.st_mode):
        raise SealError(f"{path}: the {what} is {_kind(before.st_mode)}; expected a regular file")
    try:
        # O_NONBLOCK: a FIFO swapped in since the stat must not block the open.
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise SealError(f"{path}: the {what} cannot be read ({exc.strerror})") from None
    opened = os.fstat(fd)
    if (opened.st_dev, opened.st_ino) != (before.st_dev, before.st_ino) or not stat.S_ISREG(
        opened.st_mode
    ):
        os.close(fd)
        raise SealError(f"{path}: the {what} changed while it was opened; try again")
    if limit is not None and opened.st_size > limit:
        os.close(fd)
        raise SealError(
            f"{path}: the {what} is {opened.st_size:,} bytes; at most {limit:,} bytes "
            f"({limit / MIB:g} MiB) are valid"
        )
    os.set_blocking(fd, True)
    return os.fdopen(fd, "rb")


def read_data_file(
    path: str | os.PathLike[str],
    *,
    what: str = "file",
    within: str | os.PathLike[str] | None = None,
    limit: int | None = None,
) -> bytes:
    """The bytes of `path`, checked as `open_data_file` does."""
    with open_data_file(path, what=what, within=within, limit=limit) as fh:
        data = fh.read(limit + 1 if limit is not None else -1)
    if limit is not None and len(data) > limit:  # it grew after the check
        raise SealError(f"{path}: the {what} is over {limit:,} bytes, the most that is valid")
    return data


def check_regular_file(path: str | os.PathLike[str], what: str = "file") -> None:
    """SealError if `path` (its links followed) is not a regular file: a FIFO would block the
    reader forever, a device never end."""
    try:
        mode = os.stat(path).st_mode
    except OSError as exc:
        raise SealError(f"{path}: the {what} cannot be read ({exc.strerror})") from None
    if not stat.S_ISREG(mode):
        raise SealError(f"{path}: the {what} is {_kind(mode)}; expected a regular file")


def check_inside(
    path: str | os.PathLike[str], within: str | os.PathLike[str], what: str = "file"
) -> None:
    """SealError if `path` exists and, its symlinks followed, leads out of `within`.

    Writers call it before they write through an existing path (append to a CSV, make files in
    a folder): a link to somewhere else is refused rather than written through.
    """
    path = Path(path)
    if not os.path.lexists(path):
        return
    inside, real = _inside(path, Path(within))
    if not inside:
        raise SealError(
            f"{path}: the {what} is a symlink leading out of {within} (to {real}); seal reads "
            f"and writes only inside the directory: remove the link, then try again"
        )


def check_output_dir(path: str | os.PathLike[str], what: str = "--out") -> Path:
    """`path` as a directory to write under (it need not exist yet), or a one-line SealError: an
    empty name (which would write into the working directory) or a path through a file."""
    if not str(path).strip():
        raise SealError(f"{what} {str(path)!r}: expected a directory name")
    out = Path(path)
    too_long = [p for p in out.parts if len(os.fsencode(p)) > 255]  # NAME_MAX of common filesystems
    if too_long:
        raise SealError(
            f"{what} {path}: the name {too_long[0][:40]}... is {len(os.fsencode(too_long[0]))} "
            "bytes long; a file or folder name holds at most 255"
        )
    for existing in (out, *out.parents):
        if existing.exists():
            if not existing.is_dir():
                mode = existing.stat().st_mode
                kind = "a file" if stat.S_ISREG(mode) else _kind(mode)
                raise SealError(
                    f"{what} {path}: {existing} is {kind}, not a directory; give a directory "
                    "to write under"
                )
            break
    return out
