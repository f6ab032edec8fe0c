"""Every `seal` command in the repository's Markdown code blocks parses with today's `seal` (its
subcommand and flags exist, its values have their types) and names protocol files that exist,
so a reader who copies one does not meet an option a later change renamed or removed.

A synopsis is read as its first choice: `[--x]` groups are dropped, `a|b` is `a`, `<name>` is
`name`, and `...` is dropped. The commands are only parsed, never run."""

from __future__ import annotations

import argparse
import re
import shlex

import pytest

from seal.cli.main import build_parser
from tests.docs.test_links import FENCE, ROOT, markdown_files

FENCED = re.compile(r"^```[^\n]*\n(.*?)^```", re.S | re.M)
INDENTED = re.compile(r"(?:^(?: {4}|\t)[^\n]*\n)+", re.M)
INLINE = re.compile(r"`(?:[\w./~-]*/)?seal ([a-z]+(?:\s[^`]*)?)`")
COMMAND = re.compile(
    r"^(?:\$ )?(?:[A-Z_]+=\S* )*(?:cd \S+ && )?(?:[\w./~-]*/)?seal (?=[a-z]+(?:\s|$))(.*)$"
)


def documented_commands() -> list[tuple[str, str]]:
    """(where, the command's arguments) of every `seal ...` line in a code block, with its
    continuation lines joined and its trailing comment dropped."""
    found = []
    for path in markdown_files():
        text = path.read_text()
        blocks = FENCED.findall(text) + [m.group(0) for m in INDENTED.finditer(text)]
        for block in blocks:
            joined = re.sub(r"\\\n\s*", " ", block)
            for line in joined.splitlines():
                match = COMMAND.match(line.strip())
                if match:
                    found.append((f"{path.relative_to(ROOT)}: {line.strip()}", match.group(1)))
    return found


def first_choice(args: str, groups: bool = False) -> list[str]:
    """The argument list a synopsis stands for, read as its first choice, its optional groups
    left out (or, with `groups`, kept)."""
    args = re.sub(r"\s+#(?=\s).*$", "", args)  # a trailing comment
    group = re.compile(r"\s*\[(?!['\"])([^\[\]'\"]*)\]")  # innermost first; not TOML lists
    while group.search(args):
        args = group.sub(lambda m: " " + m.group(1).split(" | ")[0] if groups else "", args)
    args = re.split(r"\s(?:&&?|;|\|\|?|[12]?>>?)(?:\s|$)", args + " ")[0]  # the shell's part
    args = re.sub(r"<([^<>]+)>", lambda m: re.sub(r"\W+", "_", m.group(1)), args)
    words = [w for w in shlex.split(args) if w != "..." and w != "…"]
    return [w.split("|")[0] if "|" in w and " " not in w else w for w in words]


def strict_parser() -> argparse.ArgumentParser:
    """`seal`'s parser without abbreviations, so that a renamed option's old prefix fails."""
    parser = build_parser()
    stack = [parser]
    while stack:
        p = stack.pop()
        p.allow_abbrev = False
        for action in p._actions:
            if isinstance(action, argparse._SubParsersAction):
                stack.extend(action.choices.values())
    return parser


def inline_commands() -> list[tuple[str, str]]:
    """(where, arguments) of every `seal ...` code span in prose that gives an option, other
    than quoted messages ("seal run --resume: skipping ...")."""
    found = []
    for path in markdown_files():
        text = FENCE.sub("", path.read_text())
        for match in INLINE.finditer(text):
            args = " ".join(match.group(1).split())
            if "--" in args and ": " not in args:
                found.append((f"{path.relative_to(ROOT)}: `seal {args}`", args))
    return found


COMMANDS = documented_commands()
INLINE_COMMANDS = inline_commands()


def test_the_docs_hold_commands() -> None:
    # The README's and docs' examples: 68 in code blocks and 182 in prose when this was written.
    assert len(COMMANDS) >= 50 and len(INLINE_COMMANDS) >= 100


@pytest.mark.parametrize(("where", "args"), COMMANDS, ids=[w for w, _ in COMMANDS])
def test_each_documented_command_parses(
    where: str, args: str, capsys: pytest.CaptureFixture[str]
) -> None:
    for argv in dict.fromkeys(tuple(first_choice(args, groups)) for groups in (False, True)):
        try:
            parsed = strict_parser().parse_args(list(argv))
        except SystemExit as exc:
            err = capsys.readouterr().err.strip()
            pytest.fail(f"{where}\n  parsed as {list(argv)}: {err} ({exc.code})")
        for value in vars(parsed).values():
            for item in value if isinstance(value, list) else [value]:
                if isinstance(item, str) and re.fullmatch(r"protocols/[\w/.-]+\.toml", item):
                    assert (ROOT / item).is_file(), f"{where}: {item} does not exist"


@pytest.mark.parametrize(("where", "args"), INLINE_COMMANDS, ids=[w for w, _ in INLINE_COMMANDS])
def test_each_option_named_in_prose_exists(
    where: str, args: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """Prose names a command by its options alone ("`seal report --censored zero`"), so only
    an option or choice that does not exist fails here, not a value left out."""
    try:
        strict_parser().parse_args(first_choice(args))
    except SystemExit:
        err = capsys.readouterr().err
        assert not re.search(r"unrecognized arguments|invalid choice|ambiguous option", err), (
            f"{where}: {err.strip()}"
        )
