"""Every relative link in the repository's Markdown opens on GitHub: its file exists and its
`#anchor` is one of that file's headings, slugged as GitHub slugs them (the function the site's
mkdocs.yml uses too, so one link works in both places)."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest
from pymdownx.slugs import slugify

ROOT = Path(__file__).resolve().parents[2]
LINK = re.compile(r"\]\(([^)\s]+)\)")
FENCE = re.compile(r"^```.*?^```", re.S | re.M)
HEADING = re.compile(r"^#{1,6}\s+(.+?)\s*#*\s*$", re.M)
# mkdocstrings (`::: module`) and the protocol-keys marker make headings only the site has.
GENERATED = re.compile(r"^::: |<!-- protocol-keys -->", re.M)
github_slug = slugify(case="lower")


def markdown_files() -> list[Path]:
    listed = subprocess.run(
        ["git", "ls-files", "*.md"], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout.split()
    return [ROOT / name for name in listed]


def anchors(path: Path) -> set[str] | None:
    """The heading anchors of a Markdown file, or None when the site generates some of them."""
    text = FENCE.sub("", path.read_text())
    if GENERATED.search(text):
        return None
    plain = (re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", h) for h in HEADING.findall(text))
    return {github_slug(h.replace("`", ""), "-") for h in plain}


def broken_links(path: Path) -> list[str]:
    text = FENCE.sub("", path.read_text())
    broken = []
    for target in LINK.findall(text):
        if re.match(r"[a-z]+:", target):
            continue  # http:, https:, mailto:
        file_part, _, anchor = target.partition("#")
        linked = (path.parent / file_part).resolve() if file_part else path
        if not linked.exists():
            broken.append(f"{target}: no file {file_part}")
            continue
        if anchor and linked.suffix == ".md":
            known = anchors(linked)
            if known is not None and anchor not in known:
                broken.append(f"{target}: no heading slugs to #{anchor} in {linked.name}")
    return broken


def test_the_slug_is_githubs() -> None:
    """GitHub keeps each hyphen of `--learn` and drops the backticks and parentheses."""
    heading = "Learning evidence (`seal bench --learn kitchen`)".replace("`", "")
    assert github_slug(heading, "-") == "learning-evidence-seal-bench---learn-kitchen"
    assert anchors(ROOT / "envs" / "franka_kitchen_dense" / "README.md") >= {
        "learning-evidence-seal-bench---learn-kitchen",
        "which-critic-is-the-default-issue-54s-learner-test",
    }


def test_a_missing_file_and_a_missing_heading_are_found(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text("# Top\n\n[a](other.md) [b](#top) [c](#nowhere) [d](https://x.org/y)\n")
    assert [b.split(":")[0] for b in broken_links(page)] == ["other.md", "#nowhere"]


@pytest.mark.parametrize("path", markdown_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(path: Path) -> None:
    assert broken_links(path) == []
