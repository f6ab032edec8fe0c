"""MkDocs hooks: pages generated from the sources they document, so the two cannot drift.

- `kitchen.md` is `envs/franka_kitchen_dense/README.md`, the kitchen's own documentation. The
  pages link to it by its path in the repository, so the link works on GitHub too; the site's
  links point at the generated page.
- `<!-- include-python: PATH -->` becomes the Python file at docs/PATH as a code block (so the
  worked adapter example on the page is the file its test runs).
- In `protocols.md`, `<!-- protocol-keys -->` becomes one table per protocol TOML table, built
  from the config dataclasses' field docstrings through `seal.typed_config.field_docs`, the same
  function `seal protocol explain` reads.
"""

from __future__ import annotations

import dataclasses
import html
import re
from pathlib import Path
from typing import Any

from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parents[1]
KITCHEN_README = ROOT / "envs" / "franka_kitchen_dense" / "README.md"
DOCS = ROOT / "docs"
MARKER = "<!-- protocol-keys -->"
INCLUDE = re.compile(r"<!-- include-python: (\S+) -->")
KITCHEN_LINK = "](../envs/franka_kitchen_dense/README.md"


def on_files(files: Files, config: Any) -> Files:
    """Add the kitchen page, generated from the kitchen adapter's README."""
    files.append(File.generated(config, "kitchen.md", content=KITCHEN_README.read_text()))
    return files


def on_page_markdown(markdown: str, page: Any, config: Any, files: Files) -> str:
    """Fill the protocol-keys marker of protocols.md and the include-python markers."""

    def include(match: re.Match[str]) -> str:
        return "```python\n" + (DOCS / match.group(1)).read_text().rstrip() + "\n```"

    markdown = INCLUDE.sub(include, markdown).replace(KITCHEN_LINK, "](kitchen.md")
    if MARKER not in markdown:
        return markdown
    return markdown.replace(MARKER, protocol_keys_markdown())


def _default(field: dataclasses.Field) -> Any:
    if field.default is not dataclasses.MISSING:
        return field.default
    if field.default_factory is not dataclasses.MISSING:
        return field.default_factory()
    return None


def _text(text: str) -> str:
    """Docstring prose as Markdown text: HTML and link brackets escaped, so `<name>` and
    `[table]:` print as written."""
    return html.escape(" ".join(text.split()), quote=False).replace("[", "\\[").replace("|", "\\|")


def _cell(text: str) -> str:
    """A docstring as one Markdown table cell: its paragraphs joined by blank lines."""
    paragraphs = [_text(p) for p in text.strip().split("\n\n")]
    return "<br><br>".join(p for p in paragraphs if p)


def _table(title: str, cls: type) -> str:
    from seal.protocols.toml_io import toml_value
    from seal.typed_config import field_docs

    docs = field_docs(cls)
    intro = _text((cls.__doc__ or "").split("\n\n")[0])
    lines = [f"### `{title}`", "", intro, "", "| key | default | meaning |", "|---|---|---|"]
    for field in dataclasses.fields(cls):
        default = _default(field)
        shown = "(none)" if default is None else toml_value(default)
        lines.append(f"| `{field.name}` | `{shown}` | {_cell(docs.get(field.name, ''))} |")
    return "\n".join(lines) + "\n"


def protocol_keys_markdown() -> str:
    """Every key of every protocol table with its default and its field docstring."""
    from seal.learner.config import AgentConfig
    from seal.protocols import config as pc
    from seal.schedulers.registry import SCHEDULER_CONFIGS

    tables: list[tuple[str, type]] = [
        ("[protocol]", pc.ProtocolTable),
        ("[envs.<name>]", pc.EnvConfig),
        ("[agent]", AgentConfig),
        ("[replay]", pc.ReplayConfig),
        ("[training]", pc.TrainingConfig),
        ("[evaluation]", pc.EvaluationConfig),
        *((f'[scheduler] kind = "{kind}"', cls) for kind, cls in SCHEDULER_CONFIGS.items()),
        ("[finetune]", pc.FinetuneConfig),
        ("[transfer]", pc.TransferConfig),
        ("[checkpoint]", pc.CheckpointConfig),
        ("[logging]", pc.LoggingConfig),
    ]
    return "\n".join(_table(title, cls) for title, cls in tables)
