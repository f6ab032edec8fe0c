"""Tables: the update-count, changes and final-success tables `report` writes, and what it returns.

`ReportResult` is what a report wrote and the numbers behind it. A cell holds one thing. The
update-count table (Table 1, Tables 6-7) has Task rows and one column per setting, cells from
seal.metrics.format_count, and a total per environment; below it the same cells taken apart as
gradient steps x per-step batch (with Appendix B's product where it differs). The changes table
has one row per (task, column, reference): the change, its CI and the seeds behind it
(`change_sections`). The success table gives each run's last evaluation. `write_document`
writes display tables as Markdown (notes below, no line longer than `LINE_LIMIT`: wide tables are
split into several, `fit_markdown`) and LaTeX (notes in the caption); `_notes` and
`_comparability_warnings` say how to read them.
"""

from __future__ import annotations

import math
import re
import textwrap
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
    changes: pd.DataFrame = field(default_factory=pd.DataFrame)
    """One row per (task, column, reference): seal.reports.changes.change_rows (update_changes.csv)."""
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

        def plain(value: Any) -> Any:
            value = value.item() if hasattr(value, "item") else value  # numpy scalars
            return num(value) if isinstance(value, float) else value

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
            "changes": [
                {k: plain(v) for k, v in record.items()}
                for record in self.changes.to_dict(orient="records")
            ],
            "update_count_censored_tasks": censored,
            "censored_rule": self.censored,
            "skipped": self.skipped,
            "warnings": self.warnings,
        }


Section = tuple[str, pd.DataFrame, pd.DataFrame | None]
"""(heading or "", display table, its LaTeX display or None to escape the display)."""


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


def _resolved_decrease(row: Any, prefix: str) -> bool:
    pct = float(getattr(row, f"{prefix}pct_change"))
    return math.isfinite(pct) and pct < 0 and bool(getattr(row, f"{prefix}resolved"))


def _bold(row: Any) -> bool:
    """Fewer updates than every reference the row has (Single Env, its matched arm), each resolved."""
    prefixes = [p for p in ("", "matched_") if getattr(row, f"{p}reference", "")]
    return bool(prefixes) and all(_resolved_decrease(row, p) for p in prefixes)


def _cell(row: Any, style: str) -> str:
    """One update-count cell: count ± std [k/n], bold when `_bold` (the changes have a table of their own)."""
    return format_count(
        row.updates_mean,
        row.updates_std,
        int(row.reached),
        int(row.seeds),
        style=style,
        bold=_bold(row),
    )


def _steps_cell(row: Any, style: str) -> str:
    """ "1250 × 128": gradient steps to the threshold x the mean per-step batch, and C×GS×BS where it differs."""
    if int(row.reached) == 0 or not math.isfinite(row.per_step_mean):
        return "---" if style == "latex" else NEVER_REACHED
    times = r"$\times$" if style == "latex" else "×"
    text = f"{format_number(row.grad_steps_mean)} {times} {format_number(row.per_step_mean)}"
    return text + _paper_suffix(row.updates_mean, row.paper_updates_mean, int(row.reached), style)


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
    totals: pd.DataFrame | None,
    columns: list[str],
    rows: list[tuple[str, str]],
    labels: dict[str, str],
    style: str,
    cell: Any = _cell,
    censored: CensoredRule = "run-total",
) -> pd.DataFrame:
    """A display table: Task x columns, one `cell(row, style)` each; with `totals`, a total row per env.

    A total row shows the count alone: `_total_cell` of the total with its references cleared
    (its changes are rows of the changes table).
    """
    cells = {(r.column, r.env, r.task): r for r in counts.itertuples(index=False)}
    esc = _escape_latex if style == "latex" else (lambda s: s)
    records = []
    for env, task in rows:
        record = {"Task": esc(f"{task} ({labels[env]})")}
        for column in columns:
            row = cells.get((column, env, task))
            record[esc(column)] = "" if row is None else cell(row, style)
        records.append(record)
    if totals is None:
        return pd.DataFrame.from_records(records)
    total_rows = {(t.column, t.env): t for t in totals.itertuples(index=False)}
    for env in dict.fromkeys(env for env, _ in rows):
        record = {"Task": esc(f"Total ({labels[env]})")}
        for column in columns:
            total = total_rows.get((column, env))
            record[esc(column)] = (
                ""
                if total is None
                else _total_cell(
                    total._replace(reference="", matched_reference=""), style, censored
                )
            )
        records.append(record)
    return pd.DataFrame.from_records(records)


CHANGE_COLUMNS = ("Arm", "vs", "Change", "95% CI", "n")
"""The changes table's columns, under one heading per task (a total's section adds "tasks")."""


def _seeds_text(n_column: int, n_reference: int, paired: bool) -> str:
    return str(n_column) if paired else f"{n_column} vs {n_reference}"


def changes_display(changes: pd.DataFrame, labels: dict[str, str], style: str) -> pd.DataFrame:
    """`seal.reports.changes.change_rows` as a display table: Task, CHANGE_COLUMNS and tasks
    (shared tasks of a total, else ""); a resolved change (CI and seeds) in bold."""
    esc = _escape_latex if style == "latex" else (lambda s: s)
    records = []
    for row in changes.itertuples(index=False):
        change = format_percent(row.pct_change)
        ci = format_ci((row.pct_ci_low / 100, row.pct_ci_high / 100))
        if row.resolved:
            change, ci = (
                (rf"\textbf{{{change}}}", rf"\textbf{{{ci}}}")
                if style == "latex"
                else (f"**{change}**", f"**{ci}**")
            )
        records.append(
            {
                "Task": esc(f"{row.task} ({labels.get(row.env, row.env)})"),
                "Arm": esc(row.column),
                "vs": esc(row.vs),
                "Change": change.replace("%", r"\%") if style == "latex" else change,
                "95% CI": ci,
                "n": _seeds_text(row.n_column, row.n_reference, row.paired),
                "tasks": str(row.shared_tasks) if row.task == "Total" else "",
            }
        )
    return pd.DataFrame.from_records(records, columns=["Task", *CHANGE_COLUMNS, "tasks"])


def change_sections(changes: pd.DataFrame, latex: pd.DataFrame | None = None) -> list[Section]:
    """`changes_display` tables as `write_document` sections: one per task (the heading), one
    row per (arm, reference); the "tasks" column only where a row has one (a total's)."""
    sections: list[Section] = []
    for task, rows in changes.groupby("Task", sort=False):
        keep = list(CHANGE_COLUMNS) + (["tasks"] if (rows["tasks"] != "").any() else [])
        tex = (
            None
            if latex is None
            else latex.loc[rows.index, keep].reset_index(drop=True).rename(columns=_escape_latex)
        )
        sections.append((str(task), rows[keep].reset_index(drop=True), tex))
    return sections


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


LINE_LIMIT = 100
"""No line of a Markdown table or of its notes is longer than this many characters."""


def _markdown(frame: pd.DataFrame) -> str:
    return frame.to_markdown(index=False, disable_numparse=True)


def _column_chunks(display: pd.DataFrame, limit: int) -> list[list[int]]:
    """Column positions of the tables `display` is split into so that each renders within
    `limit` characters a line: the first column in every one, the others in order, greedily."""
    chunks: list[list[int]] = []
    current: list[int] = []
    for position in range(1, display.shape[1]):
        trial = [*current, position]
        rendered = _markdown(display.iloc[:, [0, *trial]])
        if current and max(len(line) for line in rendered.splitlines()) > limit:
            chunks.append(current)
            current = [position]
        else:
            current = trial
    chunks.append(current)
    return [[0, *chunk] for chunk in chunks]


def fit_markdown(display: pd.DataFrame, limit: int = LINE_LIMIT) -> str:
    """`display` as Markdown; when a line would pass `limit` characters, as several tables of
    its columns, the first column repeated in each (a single column wider than that stays)."""
    return "\n\n".join(
        _markdown(display.iloc[:, chunk]) for chunk in _column_chunks(display, limit)
    )


def wrap_notes(notes: Sequence[str], width: int = LINE_LIMIT) -> str:
    """Notes as a Markdown list, each wrapped at `width` characters."""
    return "".join(
        textwrap.fill(
            note,
            width,
            initial_indent="- ",
            subsequent_indent="  ",
            break_long_words=False,
            break_on_hyphens=False,
        )
        + "\n"
        for note in notes
    )


def _latex_caption(text: str) -> str:
    caption = _escape_latex(text).replace("±", r"$\pm$").replace(">=", r"$\geq$")
    caption = caption.replace(NEVER_REACHED, "---").replace("×", r"$\times$")
    # pandas writes \caption{ before the first line.
    return textwrap.fill(
        caption, LINE_LIMIT - len(r"\caption{"), break_long_words=False, break_on_hyphens=False
    )


def markdown_document(title: str, sections: Sequence[Section], notes: Sequence[str]) -> str:
    """The title, each section's table under its heading (`fit_markdown`), then the notes."""
    parts = [f"# {title}"]
    for heading, display, _ in sections:
        parts.append((f"**{heading}**\n\n" if heading else "") + fit_markdown(display))
    return "\n\n".join(parts) + "\n\n" + wrap_notes(notes)


def write_document(
    stem: Path, title: str, sections: Sequence[Section], notes: Sequence[str]
) -> dict[str, Path]:
    """Markdown (the sections under their headings, then the notes) and LaTeX (one table per
    section and column chunk; the title and notes in the first caption) of display tables."""
    tex_parts: list[str] = []
    for heading, display, latex in sections:
        latex_frame = (
            latex if latex is not None else display.map(_escape_latex).rename(columns=_escape_latex)
        )
        for chunk in _column_chunks(display, LINE_LIMIT):
            caption = (
                f"{title}. {' '.join(notes)}"
                if not tex_parts
                else (heading or f"{title} (continued)")
            )
            frame = latex_frame.iloc[:, chunk]
            tex_parts.append(
                frame.to_latex(
                    index=False,
                    escape=False,
                    caption=_latex_caption(caption),
                    column_format="l" + "r" * (frame.shape[1] - 1),
                )
            )
    md = stem.with_suffix(".md")
    md.write_text(markdown_document(title, sections, notes))
    tex = stem.with_suffix(".tex")
    tex.write_text("\n".join(tex_parts))
    return {md.name: md, tex.name: tex}


def _write_table(
    display: pd.DataFrame,
    stem: Path,
    title: str,
    notes: list[str],
    latex: pd.DataFrame | None = None,
) -> dict[str, Path]:
    """Markdown (with notes) and LaTeX (notes in the caption) versions of one display table."""
    return write_document(stem, title, [("", display, latex)], notes)
