"""Errors a user can act on. The CLI prints them as one line and exits with code 2."""

from __future__ import annotations


class SealError(Exception):
    """A problem with the user's input: the message names what is wrong and what would be valid."""


class SealWarning(UserWarning):
    """Something a user chose that works but deserves a word (e.g. an older reward version); the
    CLI prints it as one line, "seal: warning: ...", once per process."""


class ConfigError(SealError):
    """A protocol file or override is invalid: names the file, the `table.key` and the valid values."""


class UnknownNameError(SealError):
    """An adapter, task or import path that does not exist."""

    def __init__(self, kind: str, name: str, valid: list[str] | tuple[str, ...]) -> None:
        self.kind, self.name, self.valid = kind, name, list(valid)
        shown = (
            ", ".join(self.valid) if len(self.valid) <= 60 else ", ".join(self.valid[:60]) + ", ..."
        )
        super().__init__(f"unknown {kind} {name!r}; valid: {shown}")


class TrainingDivergedError(RuntimeError):
    """A loss became NaN or inf: names the step and the last good checkpoint.

    `what` is the message without the checkpoint, for a caller that knows a better one (a run's
    newest checkpoint, where the agent has saved none yet in this phase)."""

    def __init__(self, what: str, checkpoint: str | None) -> None:
        super().__init__(f"{what}; last good checkpoint: {checkpoint or 'none saved yet'}")
        self.what = what
