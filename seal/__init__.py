"""SEAL: multi-task RL that transfers skills across environments with different state and action spaces."""

from __future__ import annotations

__version__ = "0.1.0"


def load_run(path):  # noqa: ANN001, ANN201 - thin re-export, documented in seal.reports
    """The metrics and training logs of a run directory as pandas DataFrames (see seal.reports.load_run)."""
    from seal.reports import load_run as _load_run

    return _load_run(path)
