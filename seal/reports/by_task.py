"""The final-success table in SMT Table 1's layout: one row per column (learner), one column per
task id of an environment, then the average; cells are percent, mean ± sample std over seeds.

The average is taken per seed over the env's tasks, then its mean ± std over seeds (so its std is
the spread of whole runs, as SMT's "69.4 ± 0.8"). A note maps each task id to its name.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import pandas as pd

from seal.reports.tables import write_document


def _cell(values: pd.Series) -> str:
    mean = 100.0 * float(values.mean())
    if len(values) < 2:
        return f"{mean:.1f}"
    return f"{mean:.1f} ± {100.0 * float(values.std()):.1f}"


def by_task_tables(
    metrics: pd.DataFrame,
    columns: Sequence[str],
    rows: Sequence[tuple[str, str]],
    labels: dict[str, str],
) -> tuple[pd.DataFrame, list[tuple[str, pd.DataFrame]], list[str]]:
    """(long numbers, one (env label, display) per env, the task-id notes) of each run's last
    evaluation."""
    last_epoch = metrics.groupby(["column", "env", "seed"])["epoch"].transform("max")
    final = metrics[metrics["epoch"] == last_epoch]
    long_rows, sections, notes = [], [], []
    for env in dict.fromkeys(env for env, _ in rows):
        tasks = [task for e, task in rows if e == env]
        notes.append(
            f"{labels[env]} task ids: " + ", ".join(f"{i} = {t}" for i, t in enumerate(tasks))
        )
        records = []
        for column in columns:
            mine = final[(final["column"] == column) & (final["env"] == env)]
            if mine.empty:
                continue
            record = {"Algorithm": column}
            for i, task in enumerate(tasks):
                values = mine.loc[mine["task"] == task, "success"]
                record[str(i)] = _cell(values) if len(values) else ""
                long_rows.append(
                    {
                        "column": column,
                        "env": env,
                        "task_id": i,
                        "task": task,
                        "success_mean": float(values.mean()) if len(values) else float("nan"),
                        "success_std": float(values.std()) if len(values) > 1 else float("nan"),
                        "seeds": len(values),
                    }
                )
            per_seed = mine[mine["task"].isin(tasks)].groupby("seed")["success"].mean()
            record["Average"] = _cell(per_seed)
            long_rows.append(
                {
                    "column": column,
                    "env": env,
                    "task_id": -1,
                    "task": "Average",
                    "success_mean": float(per_seed.mean()),
                    "success_std": float(per_seed.std()) if len(per_seed) > 1 else float("nan"),
                    "seeds": len(per_seed),
                }
            )
            records.append(record)
        if records:
            sections.append((labels[env], pd.DataFrame.from_records(records)))
    return pd.DataFrame.from_records(long_rows), sections, notes


def write_by_task(
    tables_dir: Path,
    metrics: pd.DataFrame,
    columns: Sequence[str],
    rows: Sequence[tuple[str, str]],
    labels: dict[str, str],
) -> dict[str, Path]:
    """success_by_task.{csv,md,tex} under `tables_dir`."""
    long, sections, notes = by_task_tables(metrics, columns, rows, labels)
    path = tables_dir / "success_by_task.csv"
    long.to_csv(path, index=False)
    notes = [
        "Success (%) at each run's last evaluation by task id; mean ± sample std over seeds. "
        "Average: each seed's mean over the tasks, then mean ± std over seeds (SMT Table 1's layout).",
        *notes,
    ]
    written = write_document(
        tables_dir / "success_by_task",
        "Final success by task id (%)",
        [(heading, display, None) for heading, display in sections],
        notes,
    )
    return {path.name: path, **written}
