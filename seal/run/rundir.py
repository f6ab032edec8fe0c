"""The run directory: the one on-disk format that `seal report`, `seal.load_run` and sweeps read.

    reports/<protocol>/<group-id>/seed-<n>/
        config.toml        the resolved protocol (loads back with `seal run`)
        provenance.json    git_sha, packages, command, device, cpu (model and count), seed,
                           start/end time, protocol, kind, group, phase_names, update_threads
                           (the threads and the rule's inputs)
        metrics.csv        one row per evaluation and task (METRICS_COLUMNS)
        train.csv          long format: seed,phase,epoch,grad_steps,env,key,value (TRAIN_COLUMNS);
                           each evaluation adds its critic probe (eval_q/<task>, eval_earned/<task>,
                           eval_q_ratio/<task>: seal.learner.critic_probe), an asynchronous one when
                           its results come in (so among the training rows where timing puts them);
                           with [logging] drift, each env's drift/<piece> (seal.learner.drift)
        scheduler.csv      the scheduler's timeline, when it has one
        tb/<phase>/        TensorBoard events, one run per phase ([logging] tensorboard; seal.run.loggers)
        wandb/             Weights & Biases files and run_id ([logging] wandb)
        checkpoints/       ckpt-<epoch>.pt (last K, phase-prefixed for finetune) and best.pt
        .seal.lock         the writer's lock file (`seal.run.dirlock.DirLock`): pid and command of the last writer

Crash safety: CSV rows are appended and fsync'ed; JSON and TOML are written atomically (temp file,
then rename). A checkpoint records the number of rows of every CSV at the moment it was taken,
so resuming truncates each CSV back to that row count: no duplicate and no missing rows.

One writer at a time: `seal run`, `--resume`, sweep trials (on the seed directory) and `seal
report` (on the directory it writes tables/ and plots/ into) hold an exclusive `flock` on the
directory's `.seal.lock` while they write; a second writer is refused at once with the holder's
pid and command. The OS drops the lock when its process dies, so a killed run never blocks.

Files from elsewhere: a run directory is read as data (`seal.files`). `RunDir.open` refuses, in
one line and before anything is written, a directory whose config.toml is not a regular file
inside it of at most CONFIG_LIMIT bytes, whose CSVs or provenance.json are not regular files, or
where anything seal writes through (a CSV it appends to, checkpoints/, tb/, the lock file) is a
symlink leading out of it. JSON and TOML are replaced by rename, which replaces a link rather
than writing through it, and the CSVs and the lock file are opened with O_NOFOLLOW.
"""

from __future__ import annotations

import contextlib
import csv
import datetime as _dt
import hashlib
import io
import json
import os
import re
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, TypedDict

from seal.errors import SealError
from seal.files import MIB, check_inside, check_regular_file, read_data_file
from seal.run.dirlock import LOCK_FILE, NOFOLLOW

METRICS_COLUMNS: tuple[str, ...] = (
    "seed",
    "phase",
    "epoch",
    "env",
    "task",
    "success",
    "return",
    "grad_steps",
    "env_steps",
    "updates",
    "batch",  # the task's samples per update in force this epoch (0: no update this epoch)
    "wall_s",
)
TRAIN_COLUMNS: tuple[str, ...] = ("seed", "phase", "epoch", "grad_steps", "env", "key", "value")
CSV_FILES: tuple[str, ...] = ("metrics.csv", "train.csv", "scheduler.csv")
CONFIG_LIMIT = MIB
"""The largest config.toml a reader takes (a resolved protocol is a few KiB)."""
WRITTEN_THROUGH: tuple[str, ...] = (
    *CSV_FILES,
    "config.toml",
    "provenance.json",
    "checkpoints",
    "tb",
    "wandb",
    "tables",
    "plots",
)
"""What a resumed run writes into or through: none may be a symlink leading out of the run."""

# A row as written, one type per column ("return" is a keyword, hence the functional form).
MetricsRow = TypedDict(
    "MetricsRow",
    {
        "seed": int,
        "phase": str,
        "epoch": int,
        "env": str,
        "task": str,
        "success": float,
        "return": float,
        "grad_steps": int,
        "env_steps": int,
        "updates": float,
        "batch": int,
        "wall_s": float,
    },
)
"""One metrics.csv row: one task at one evaluation (METRICS_COLUMNS)."""


class TrainRow(TypedDict):
    """One train.csv row: one logged value's mean over an interval (TRAIN_COLUMNS)."""

    seed: int
    phase: str
    epoch: int
    grad_steps: int
    env: str
    """"" for values that belong to no env."""
    key: str
    value: float


CsvRow = Mapping[str, object]
"""A row of one of the CSV files: column -> cell (a MetricsRow, a TrainRow, a scheduler timeline row)."""


def atomic_write_text(path: Path, text: str) -> None:
    """Write `text` to `path` atomically: a crash leaves the old file or the new one, never half."""
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        with open(tmp, "w") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)  # a full disk leaves no half-written temporary file behind
        raise


def new_group_id(config_text: str, now: _dt.datetime | None = None) -> str:
    """A group id: UTC timestamp plus the first 6 hex digits of the config's hash, e.g. 20261122-041503-a1b2c3."""
    now = now or _dt.datetime.now(_dt.UTC)
    return now.strftime("%Y%m%d-%H%M%S-") + hashlib.sha256(config_text.encode()).hexdigest()[:6]


class CsvLog:
    """An append-only CSV with a header, one fsync per batch of rows; can be cut back to N rows."""

    def __init__(self, path: Path, columns: Sequence[str]) -> None:
        self.path = path
        self.columns = tuple(columns)
        if not path.exists():
            atomic_write_text(path, ",".join(self.columns) + "\n")

    def append(self, rows: Iterable[CsvRow]) -> None:
        """Append rows (dicts keyed by column) and fsync, so a kill loses no row already returned."""
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=self.columns, lineterminator="\n")
        for row in rows:
            writer.writerow({k: _fmt(v) for k, v in row.items()})
        if not buf.tell():
            return
        try:
            # O_NOFOLLOW: a CSV swapped for a symlink is refused (ELOOP), never appended through.
            fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | NOFOLLOW, 0o644)
            with open(fd, "a") as fh:
                fh.write(buf.getvalue())
                fh.flush()
                os.fsync(fh.fileno())
        except OSError as exc:
            exc.filename = exc.filename or str(self.path)  # a full disk's error names the CSV
            raise

    def num_rows(self) -> int:
        """Data rows (header excluded); a partial last line from a crash is not counted."""
        with open(self.path, "rb") as fh:
            data = fh.read()
        return max(0, data.count(b"\n") - 1)

    def truncate(self, rows: int) -> None:
        """Keep the header and the first `rows` data rows (drops anything written after a checkpoint)."""
        with open(self.path, "rb") as fh:
            lines = fh.read().split(b"\n")
        complete = lines[:-1]  # the part after the last newline is empty or a torn row
        kept = complete[: rows + 1]
        atomic_write_text(self.path, b"\n".join(kept).decode() + "\n")


def _fmt(value: object) -> object:
    if isinstance(value, float):
        return repr(
            value
        )  # round-trips exactly, so resumed rows compare equal to uninterrupted ones
    return value


class RunDir:
    """Writer for one seed's run directory. Create with `RunDir.create(...)` or `RunDir.open(...)`."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.checkpoints = self.path / "checkpoints"
        self.metrics = CsvLog(self.path / "metrics.csv", METRICS_COLUMNS)
        self.train = CsvLog(self.path / "train.csv", TRAIN_COLUMNS)
        self._scheduler: CsvLog | None = None

    @classmethod
    def create(cls, path: Path, config_toml: str, provenance: Mapping[str, Any]) -> RunDir:
        """Make a fresh run directory with config.toml and provenance.json; refuses an existing one."""
        path = Path(path)
        if (path / "config.toml").exists():
            raise SealError(
                f"run directory {path} already exists; use --resume {path} to continue it"
            )
        (path / "checkpoints").mkdir(parents=True, exist_ok=True)
        atomic_write_text(path / "config.toml", config_toml)
        run = cls(path)
        run.write_provenance(provenance)
        return run

    @classmethod
    def open(cls, path: Path) -> RunDir:
        """An existing run directory (for resume)."""
        cls.check(path)
        return cls(Path(path))

    @staticmethod
    def check(path: Path) -> None:
        """SealError unless `path` is a run directory whose layout a writer may use; it writes
        nothing (opening one makes the CSVs it lacks)."""
        path = Path(path)
        if not os.path.lexists(path / "config.toml"):
            raise SealError(
                f"--resume {path}: not a run directory (no config.toml); run directories look like reports/<protocol>/<group>/seed-<n>"
            )
        check_layout(path)

    # ------------------------------------------------------------ metadata
    def read_provenance(self) -> dict[str, Any]:
        """provenance.json as a dict ({} if missing); SealError naming it if it is not a JSON
        object (or its "resumes" not a list)."""
        data = read_provenance(self.path)
        if not isinstance(data.get("resumes", []), list):
            raise SealError(
                f"{self.path / 'provenance.json'}: field resumes = {data['resumes']!r}; expected a "
                "list of the run's resumes"
            )
        return data

    def write_provenance(self, provenance: Mapping[str, Any]) -> None:
        """Replace provenance.json atomically."""
        atomic_write_text(
            self.path / "provenance.json", json.dumps(dict(provenance), indent=2) + "\n"
        )

    def update_provenance(self, **fields: Any) -> None:
        """Set some provenance fields (e.g. end_time) atomically."""
        data = self.read_provenance()
        data.update(fields)
        self.write_provenance(data)

    # ------------------------------------------------------------ logs
    def log_eval(self, rows: Iterable[MetricsRow]) -> None:
        """Append evaluation rows (METRICS_COLUMNS)."""
        self.metrics.append(rows)

    def log_train(self, rows: Iterable[TrainRow]) -> None:
        """Append train.csv rows (TRAIN_COLUMNS)."""
        self.train.append(rows)

    def log_scheduler(self, rows: Sequence[CsvRow]) -> None:
        """Append scheduler timeline rows; the columns are the first row's keys."""
        if not rows:
            return
        if self._scheduler is None:
            self._scheduler = CsvLog(self.path / "scheduler.csv", tuple(rows[0].keys()))
        self._scheduler.append(rows)

    # ------------------------------------------------------------ resume bookkeeping
    def row_counts(self) -> dict[str, int]:
        """Rows in every CSV now (stored in checkpoints, so resume can cut back to them)."""
        counts = {"metrics.csv": self.metrics.num_rows(), "train.csv": self.train.num_rows()}
        sched = self.path / "scheduler.csv"
        counts["scheduler.csv"] = CsvLog(sched, ()).num_rows() if sched.exists() else 0
        return counts

    def truncate_to(self, counts: Mapping[str, int]) -> None:
        """Cut every CSV back to the row counts a checkpoint recorded.

        SealError, cutting nothing, if a CSV holds fewer complete rows than recorded (rows the
        checkpoint counts on are lost, so resuming from it would leave a gap).
        """
        for name in CSV_FILES:
            p, want = self.path / name, int(counts.get(name, 0))
            have = CsvLog(p, ()).num_rows() if p.exists() else 0
            if have < want:
                raise SealError(
                    f"{p} has {have} complete rows, fewer than the {want} the checkpoint recorded"
                )
        for name in CSV_FILES:
            p = self.path / name
            if p.exists():
                rows = int(counts.get(name, 0))
                log = CsvLog(p, ())
                if name == "scheduler.csv" and rows == 0:
                    p.unlink()  # rewritten with its header on the next timeline row
                    continue
                log.truncate(rows)

    def checkpoint_path(self, epoch: int, phase: str | None = None) -> Path:
        """checkpoints/ckpt-<epoch>.pt, or ckpt-<phase>-<epoch>.pt when a run has several phases."""
        stem = f"ckpt-{phase}-{epoch:07d}" if phase else f"ckpt-{epoch:07d}"
        return self.checkpoints / f"{stem}.pt"

    def best_path(self, phase: str | None = None) -> Path:
        """checkpoints/best.pt (best-<phase>.pt for a run with several phases)."""
        return self.checkpoints / (f"best-{phase}.pt" if phase else "best.pt")

    def epoch_checkpoints(self) -> list[Path]:
        """Epoch checkpoints, oldest first (by modification order of their names: phase, then epoch)."""
        found = [p for p in self.checkpoints.glob("ckpt-*.pt")]
        return sorted(found, key=lambda p: p.lstat().st_mtime_ns)  # lstat: a dangling link too

    def prune(self, keep_last: int) -> None:
        """Delete all but the newest `keep_last` epoch checkpoints."""
        for p in self.epoch_checkpoints()[:-keep_last]:
            p.unlink(missing_ok=True)

    def latest_checkpoint(self) -> Path | None:
        """The newest epoch checkpoint, or None."""
        found = self.epoch_checkpoints()
        return found[-1] if found else None


def check_layout(run: Path) -> None:
    """SealError, in one line, if `run` is not safe to resume into (see the module docstring):
    config.toml a regular file inside it, at most CONFIG_LIMIT bytes; the CSVs and
    provenance.json regular files; nothing seal writes through a symlink leading out of it."""
    read_data_file(run / "config.toml", what="run config", within=run, limit=CONFIG_LIMIT)
    for name in WRITTEN_THROUGH:
        check_inside(run / name, run, what=name)
    if (run / "tb").is_dir():  # TensorBoard writes into tb/<phase>/
        for entry in (run / "tb").iterdir():
            check_inside(entry, run, what=f"tb/{entry.name}")
    if (run / "checkpoints").is_dir():
        # A damaged checkpoint (a link out, a FIFO) is skipped by the resume and replaced by
        # rename when written again; only a directory in its place cannot be replaced.
        for entry in (run / "checkpoints").iterdir():
            written = entry.name.startswith(("ckpt-", "best")) and entry.suffix == ".pt"
            if written and entry.is_dir() and not entry.is_symlink():
                raise SealError(
                    f"{entry}: checkpoints/{entry.name} is a directory; seal writes checkpoints "
                    "there as files: remove it, then try again"
                )
    check_inside(run / LOCK_FILE, run, what="lock file")
    for name in (*CSV_FILES, "provenance.json"):
        if os.path.lexists(run / name):
            check_regular_file(run / name, what=name)


def read_provenance(run: Path) -> dict[str, Any]:
    """A run's provenance.json ({} if absent), read as data; SealError unless a JSON object."""
    p = Path(run) / "provenance.json"
    if not os.path.lexists(p):
        return {}
    raw = read_data_file(p, what="provenance", within=run, limit=16 * MIB)
    try:
        data = json.loads(raw)
    except (ValueError, RecursionError) as exc:  # UnicodeDecodeError is a ValueError
        raise SealError(f"{p}: not valid JSON ({str(exc)[:200]})") from None
    if not isinstance(data, dict):
        raise SealError(f"{p}: expected a JSON object, got {type(data).__name__}")
    return data


def seed_dir(group_dir: Path, seed: int) -> Path:
    """<group>/seed-<n>."""
    return Path(group_dir) / f"seed-{seed}"


def parse_seed_dir(path: Path) -> int | None:
    """The seed of a seed-<n> folder, else None."""
    m = re.fullmatch(r"seed-(\d+)", Path(path).name)
    return int(m.group(1)) if m else None
