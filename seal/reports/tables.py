"""Tables: the update-count and final-success tables `report` writes, and what it returns.

`ReportResult` is what a report wrote and the numbers behind it. The update-count table (Table 1,
Tables 6-7) has Task rows and one column per setting, cells from seal.metrics.format_count with
Appendix B's product beside them where it differs, and a total per environment; the success
table gives each run's last evaluation. `_write_table` writes a display table as Markdown (notes
below) and LaTeX (notes in the caption); `_notes` and `_comparability_warnings` say how to read it.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from seal.metrics import (
    NEVER_REACHED,
    CensoredRule,
    format_ci,
    format_count,
    format_number,
    format_percent,
    format_total,
)
from seal.reports.groups import _ENV_RANK, BASELINE_COLUMN, _Group


@dataclass
class ReportResult:
    """What `report` wrote and the numbers behind it."""

    out_dir: Path
    """Where tables/ and plots/ were written."""
    threshold: float
    """Success threshold used for the update-count metric."""
    tables: dict[str, Path]
    """Table files by name, e.g. "update_counts.md"."""
    plots: list[Path]
    """PNG files written."""
    update_counts: pd.DataFrame
    """Per (column, env, task): updates_mean/std (millions), grad/env steps, reached, seeds, pct_change."""
    per_seed: pd.DataFrame
    """Per (column, env, task, seed): the first evaluation reaching the threshold (seal.metrics.first_reach)."""
    totals: pd.DataFrame
    """Per (column, env): updates_total (under `censored`), tasks_reached, tasks, censored_tasks."""
    groups: list[Path]
    """The group directories reported on."""
    skipped: list[str] = field(default_factory=list)
    """Notes on what could not be drawn (e.g. no critic_loss rows in train.csv)."""
    warnings: list[str] = field(default_factory=list)
    """Settings that differ between the groups compared (agent.shared_update, critic_sharing, reward versions)."""
    censored: CensoredRule = "run-total"
    """How the totals count a censored task (`seal.metrics.CensoredRule`)."""

    def to_json(self) -> dict[str, Any]:
        """Paths and update-count numbers as plain JSON values (NaN -> null)."""

        def num(value: float | None) -> float | None:
            return (
                None
                if value is None or (isinstance(value, float) and not math.isfinite(value))
                else value
            )

        counts: dict[str, dict[str, dict[str, dict[str, float | None]]]] = {}
        for row in self.update_counts.itertuples(index=False):
            counts.setdefault(row.column, {}).setdefault(row.env, {})[row.task] = {
                "mean": num(float(row.updates_mean)),
                "std": num(float(row.updates_std)),
                "reached": int(row.reached),
                "seeds": int(row.seeds),
                "grad_steps": num(float(row.grad_steps_mean)),
                "env_steps": num(float(row.env_steps_mean)),
                "pct_change": num(float(row.pct_change)),
                "paper_updates": num(float(row.paper_updates_mean)),
                "per_step": num(float(row.per_step_mean)),
                "pct_change_ci95": [num(float(row.pct_ci_low)), num(float(row.pct_ci_high))],
                "resolved": bool(row.resolved),
            }
        totals: dict[str, dict[str, float | None]] = {}
        censored: dict[str, dict[str, int]] = {}
        for row in self.totals.itertuples(index=False):
            totals.setdefault(row.column, {})[row.env] = num(float(row.updates_total))
            censored.setdefault(row.column, {})[row.env] = int(row.censored_tasks)
        return {
            "out_dir": str(self.out_dir),
            "threshold": self.threshold,
            "groups": [str(g) for g in self.groups],
            "tables": {name: str(p) for name, p in self.tables.items()},
            "plots": [str(p) for p in self.plots],
            "update_counts": counts,
            "update_count_totals": totals,
            "update_count_censored_tasks": censored,
            "censored_rule": self.censored,
            "skipped": self.skipped,
            "warnings": self.warnings,
        }


def _row_order(frame: pd.DataFrame) -> list[tuple[str, str]]:
    """(env, task) rows: Meta-World first, then the kitchen, then others; tasks in logged order."""
    env_labels = dict(zip(frame["env"], frame["env_label"], strict=False))
    envs = list(dict.fromkeys(frame["env"]))
    envs.sort(key=lambda e: _ENV_RANK.get(env_labels[e], len(_ENV_RANK)))
    rows = []
    for env in envs:
        tasks = dict.fromkeys(frame.loc[frame["env"] == env, "task"])
        rows.extend((env, task) for task in tasks)
    return rows


def _escape_latex(text: str) -> str:
    return re.sub(r"([_&%#$])", r"\\\1", text)


def _ci(row: Any, prefix: str = "") -> tuple[float, float]:
    """A row's CI of its change against the reference of `prefix`, as fractions."""
    return (
        float(getattr(row, f"{prefix}pct_ci_low")) / 100,
        float(getattr(row, f"{prefix}pct_ci_high")) / 100,
    )


def _change(pct: float, ci: tuple[float, float], label: str = "") -> str:
    """ "-27.1% [-40.2, -9.8] vs X" (the CI where finite, " vs X" where labelled)."""
    text = format_percent(None if math.isnan(pct) else pct)
    if math.isfinite(ci[0]) and math.isfinite(ci[1]):
        text += f" {format_ci(ci)}"
    return f"{text} vs {label}" if label else text


def _decomposition(row: Any) -> str:
    """ " · 1250 steps × 64" : gradient steps to the threshold x the mean per-step batch."""
    if int(row.reached) == 0 or not math.isfinite(row.per_step_mean):
        return ""
    return f" · {format_number(row.grad_steps_mean)} steps × {format_number(row.per_step_mean)}"


def _cell(row: Any, show_pct: bool, style: str) -> str:
    """One update-count cell: count ± std, its changes with CIs, [k/n], C×GS×BS, steps × batch."""
    pct = None if math.isnan(row.pct_change) else float(row.pct_change)
    matched = getattr(row, "matched_reference", "")
    bold = pct is not None and pct < 0 and bool(row.resolved)
    ci, vs, also = (_ci(row) if show_pct else None), "", ""
    if matched and show_pct:
        # Against both references, each labelled; bold only for fewer updates than both, resolved.
        bold = bold and row.matched_pct_change < 0 and bool(row.matched_resolved)
        also = "; " + _change(row.matched_pct_change, _ci(row, "matched_"), "matched")
        vs = BASELINE_COLUMN
    elif matched and math.isfinite(row.matched_pct_change):
        # No Single Env in the report: the change against the batch-matched alone arm only.
        pct, show_pct, vs = float(row.matched_pct_change), True, "matched"
        bold, ci = pct < 0 and bool(row.matched_resolved), _ci(row, "matched_")
    cell = format_count(
        row.updates_mean,
        row.updates_std,
        int(row.reached),
        int(row.seeds),
        pct,
        show_pct,
        style,
        bold=bold,
        ci=ci,
        vs=vs,
        also=also.replace("%", r"\%") if style == "latex" else also,
    )
    cell += _paper_suffix(row.updates_mean, row.paper_updates_mean, int(row.reached), style)
    decomposition = _decomposition(row)
    if style == "latex":
        decomposition = decomposition.replace("×", r"$\times$").replace("·", r"$\cdot$")
    return cell + decomposition


def _total_cell(total: Any, style: str, censored: CensoredRule = "run-total") -> str:
    """ "0.38 (2/2 tasks)", "≥ 0.9 (1/2 tasks, 1 censored)" where a task is censored (its run
    total counted), with the change of the shared tasks' total and its stratified CI."""
    n_censored = int(total.censored_tasks)
    bound = censored == "run-total" and n_censored > 0
    text = (
        f"{format_total(float(total.updates_total), bound, 'latex' if style == 'latex' else 'plain')} "
        f"({int(total.tasks_reached)}/{int(total.tasks)} tasks"
        + (f", {n_censored} censored)" if bound else ")")
    )
    changes = []
    for prefix, label in (("", BASELINE_COLUMN), ("matched_", "matched")):
        if not getattr(total, f"{prefix}reference", "") or not getattr(
            total, f"{prefix}shared_tasks", 0
        ):
            continue
        shared = int(getattr(total, f"{prefix}shared_tasks"))
        changes.append(
            _change(float(getattr(total, f"{prefix}pct_change")), _ci(total, prefix), label)
            + f" on {shared} shared task{'s' if shared != 1 else ''}"
        )
    if changes:
        text += " (" + "; ".join(changes) + ")"
    return text.replace("%", r"\%") if style == "latex" else text


def _update_count_table(
    counts: pd.DataFrame,
    totals: pd.DataFrame,
    columns: list[str],
    rows: list[tuple[str, str]],
    labels: dict[str, str],
    style: str,
    censored: CensoredRule = "run-total",
) -> pd.DataFrame:
    """The display table: Task x columns, cells from seal.metrics.format_count, total rows per env."""
    has_baseline = set(counts.loc[counts["column"] == BASELINE_COLUMN, "env"])
    cells = {(r.column, r.env, r.task): r for r in counts.itertuples(index=False)}
    total_rows = {(t.column, t.env): t for t in totals.itertuples(index=False)}
    esc = _escape_latex if style == "latex" else (lambda s: s)
    records = []
    for env, task in rows:
        record = {"Task": esc(f"{task} ({labels[env]})")}
        for column in columns:
            row = cells.get((column, env, task))
            if row is None:
                record[esc(column)] = ""
                continue
            show_pct = column != BASELINE_COLUMN and env in has_baseline
            record[esc(column)] = _cell(row, show_pct, style)
        records.append(record)
    for env in dict.fromkeys(env for env, _ in rows):
        record = {"Task": esc(f"Total ({labels[env]})")}
        for column in columns:
            total = total_rows.get((column, env))
            record[esc(column)] = "" if total is None else _total_cell(total, style, censored)
        records.append(record)
    return pd.DataFrame.from_records(records)


PAPER_GAP = 0.005
"""Show C x GS x BS beside the exact count when they differ by more than this fraction."""


def _paper_suffix(exact: float, paper: float, reached: int, style: str) -> str:
    """ " {C×GS×BS: x}" when the paper's product differs from the exact count (changing batches)."""
    if (
        reached == 0
        or not math.isfinite(paper)
        or abs(paper - exact) <= PAPER_GAP * max(exact, 1e-12)
    ):
        return ""
    times = r"$\times$" if style == "latex" else "×"
    open_, close = (r"\{", r"\}") if style == "latex" else ("{", "}")
    return f" {open_}C{times}GS{times}BS: {format_number(paper)}{close}"


# Settings that change what an update count measures: a report comparing groups that differ in
# them compares different experiments, and says so.
COMPARABILITY_KEYS: tuple[tuple[str, str], ...] = (
    ("agent", "shared_update"),
    ("agent", "critic_sharing"),
)


def _comparability_warnings(groups: Sequence[_Group]) -> list[str]:
    """One line per setting (agent.shared_update, agent.critic_sharing, reward versions) that differs between groups."""
    seen: dict[str, dict[str, list[str]]] = {}
    for group in groups:
        run = group.runs[0]
        for table, key in COMPARABILITY_KEYS:
            value = run.config.get(table, {}).get(key)
            if value is not None:
                seen.setdefault(f"{table}.{key}", {}).setdefault(str(value), []).append(group.name)
        versions = run.provenance.get("reward_versions") or {}
        # Only adapters the run has: older runs recorded the kitchen's version whatever they ran.
        adapters = {
            (table.get("adapter") or name) if isinstance(table, dict) else name
            for name, table in run.config.get("envs", {}).items()
        }
        for env, version in versions.items() if isinstance(versions, dict) else ():
            if env not in adapters:
                continue
            seen.setdefault(f"reward version of {env}", {}).setdefault(str(version), []).append(
                group.name
            )
    return [
        f"groups differ in {what}: "
        + "; ".join(f"{value} in {', '.join(names)}" for value, names in values.items())
        for what, values in seen.items()
        if len(values) > 1
    ]


def _notes(threshold: float, with_change: bool, censored: CensoredRule = "run-total") -> list[str]:
    pct = f"{threshold:.0%}"
    notes = [
        f"Millions of each task's transitions consumed by gradient updates until its first evaluation "
        f"with success >= {pct} (Appendix B). Mean ± sample std over the seeds that reached it; "
        f"[k/n] = seeds that reached it / seeds run.",
    ]
    if censored == "run-total":
        notes += [
            f"{NEVER_REACHED} = never reached {pct} in any seed. A task some seed never brought to "
            f"{pct} is censored: in that seed it counts at its run total (all it consumed), the "
            f"least reaching {pct} would have cost.",
            "Total = sum over tasks of the mean over all seeds, censored seeds at their run totals; "
            "≥ x = the total holds a censored task, so it is a lower bound; (k/N tasks) = tasks "
            "reached by any seed, c censored = tasks censored in some seed (update_counts.csv: "
            "task Total, updates_total, censored_tasks; `seal report --censored zero` counts them as 0).",
        ]
    else:
        notes += [
            f"{NEVER_REACHED} = never reached {pct} in any seed; counted as 0 in the totals "
            f"(--censored zero).",
            "Total = sum of the per-task means over the seeds that reached each task (never-reached "
            "tasks count 0, so a total with a censored task flatters it); (k/N tasks) = tasks "
            "reached by any seed.",
        ]
    if with_change:
        notes.insert(
            2,
            f"(±x%) = change against {BASELINE_COLUMN} for the same task; bold = fewer updates, "
            f"resolved (its CI excludes 0); "
            f"n/a = the baseline or this column never reached it.",
        )
    return notes


def _success_tables(
    metrics: pd.DataFrame, columns: list[str], rows: list[tuple[str, str]], labels: dict[str, str]
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Final success per (column, env, task): numbers (long) and display (Task x columns)."""
    last_epoch = metrics.groupby(["column", "env", "seed"])["epoch"].transform("max")
    final = metrics[metrics["epoch"] == last_epoch]
    long = (
        final.groupby(["column", "env", "task"], sort=False)["success"]
        .agg(success_mean="mean", success_std="std", seeds="count")
        .reset_index()
    )
    cells = {(r.column, r.env, r.task): r for r in long.itertuples(index=False)}
    records = []
    for env, task in rows:
        record = {"Task": f"{task} ({labels[env]})"}
        for column in columns:
            row = cells.get((column, env, task))
            if row is None:
                record[column] = ""
                continue
            text = f"{row.success_mean:.2f}"
            if math.isfinite(row.success_std):
                text += f" ± {row.success_std:.2f}"
            record[column] = text
        records.append(record)
    for env in dict.fromkeys(env for env, _ in rows):
        record = {"Task": f"Mean ({labels[env]})"}
        for column in columns:
            env_rows = long[(long["column"] == column) & (long["env"] == env)]
            record[column] = (
                "" if env_rows.empty else f"{float(env_rows['success_mean'].mean()):.2f}"
            )
        records.append(record)
    return long, pd.DataFrame.from_records(records)


def _write_table(
    display: pd.DataFrame,
    stem: Path,
    title: str,
    notes: list[str],
    latex: pd.DataFrame | None = None,
) -> dict[str, Path]:
    """Markdown (with notes) and LaTeX (notes in the caption) versions of a display table."""
    md = stem.with_suffix(".md")
    md.write_text(
        f"# {title}\n\n{display.to_markdown(index=False, disable_numparse=True)}\n\n"
        + "".join(f"- {n}\n" for n in notes)
    )
    tex = stem.with_suffix(".tex")
    latex_frame = (
        latex if latex is not None else display.map(_escape_latex).rename(columns=_escape_latex)
    )
    caption = (
        _escape_latex(title + ". " + " ".join(notes))
        .replace("±", r"$\pm$")
        .replace(">=", r"$\geq$")
    )
    caption = caption.replace(NEVER_REACHED, "---")
    tex.write_text(
        latex_frame.to_latex(
            index=False,
            escape=False,
            caption=caption,
            column_format="l" + "r" * (latex_frame.shape[1] - 1),
        )
    )
    return {md.name: md, tex.name: tex}
