"""Fuzzed protocols: every mutation of a shipped protocol is accepted or refused in one line.

Hypothesis takes a shipped protocol (protocols/**/*.toml) and mutates it key by key: a value of
the wrong type, an out-of-range number, odd unicode, a deleted key, an unknown key, an emptied
table, deep nesting, and broken syntax (text cut, characters inserted, a line doubled). Each
result goes to the loader (`load_protocol`) and to `seal protocol explain`: it must load, or be
refused with SEAL's one-line error (SealError; exit 2 and one stderr line), never another
exception.

CI runs FUZZ_EXAMPLES = 200 examples, derandomized. The long profile (docs/faults.md):

    SEAL_FUZZ_EXAMPLES=10000 nice python -m pytest -p no:cacheprovider \\
        tests/protocols/test_fuzzed_protocols.py
"""

from __future__ import annotations

import contextlib
import datetime as dt
import io
import math
import os
import tomllib
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from seal.cli.main import main
from seal.errors import SealError
from seal.protocols import load_protocol
from seal.protocols.toml_io import dumps_toml

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = sorted(ROOT.glob("protocols/**/*.toml"))
FUZZ_EXAMPLES = int(os.environ.get("SEAL_FUZZ_EXAMPLES", "200"))
LONG = FUZZ_EXAMPLES > 200

ODD_TEXT = [
    "",
    " ",
    "\u202e",  # right-to-left override
    "\ufeff",  # byte order mark
    "e\u0301",  # combining accent
    "\u0000",
    "\x7f",
    "🤖",
    "ｅａｓｔ",  # fullwidth
    "east\n",
    "a.b",
    "../../etc/passwd",
    ":Y",
    ".x:Y",
    "seal.envs.point:",
    "\\",
    '"',
    "'''",
    "[x]",
    "1e400",
    "cuda",
    "cuda:3",
    "mps",
    "meta",
    "cpu:0",
]

scalars = st.one_of(
    st.booleans(),
    st.integers(),
    st.integers(min_value=-(2**63), max_value=2**63 - 1),
    st.sampled_from([0, -1, 1, 2**31, 2**63 - 1, -(2**63)]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 1e-300, 1e300, 0.5, 1.5, -1.0]),
    st.text(max_size=20),
    st.sampled_from(ODD_TEXT),
    st.datetimes(min_value=dt.datetime(1, 1, 1), max_value=dt.datetime(9999, 12, 31)),
    st.dates(),
)
keys = st.one_of(st.text(min_size=1, max_size=12), st.sampled_from(ODD_TEXT[1:]))
values = st.recursive(
    scalars,
    lambda inner: st.one_of(
        st.lists(inner, max_size=4),
        st.dictionaries(keys, inner, max_size=3),
    ),
    max_leaves=8,
)


def _paths(node: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every key path (tables' keys and arrays' indices) below `node`."""
    found = []
    items = node.items() if isinstance(node, dict) else enumerate(node)
    for key, value in items:
        found.append((*prefix, key))
        if isinstance(value, (dict, list)):
            found.extend(_paths(value, (*prefix, key)))
    return found


def _parent(raw: dict[str, Any], path: tuple[Any, ...]) -> Any:
    node: Any = raw
    for key in path[:-1]:
        node = node[key]
    return node


def _nested(depth: int, table: bool) -> str:
    return "{a = " * depth + "1" + "}" * depth if table else "[" * depth + "1" + "]" * depth


def _near(old: object) -> st.SearchStrategy[object]:
    """Out-of-range numbers: near the old value or a bound, huge, negative, not finite."""
    around = (
        st.integers(-3, 3).map(lambda d: old + d)
        if isinstance(old, int) and not isinstance(old, bool)
        else st.floats(-2.0, 2.0)
    )
    extremes = [0, -1, 1, 2**62, -(2**62), 0.0, -1e-9, 1.0000001, math.inf, -math.inf, math.nan]
    return st.sampled_from(extremes) | around


def _odd(old: object) -> st.SearchStrategy[object]:
    """A value of the old one's type that is odd for its key: unicode, empty, repeated, flipped."""
    if isinstance(old, bool):
        return st.just(not old)
    if isinstance(old, str):
        return st.sampled_from(ODD_TEXT) | st.text(max_size=8) | st.just(old * 3)
    if isinstance(old, list):
        options: list[object] = [[], old * 2, old[::-1], old[:1] * 3]
        return st.sampled_from(options)
    if isinstance(old, dict):
        return st.sampled_from([{}, {k: v for k, v in list(old.items())[:1]}])
    return _near(old)


def _retyped(old: object) -> list[object]:
    """The old value as another type: a number as a string, a string as a number, a list unwrapped."""
    out: list[object] = [str(old), [old], {"value": old}]
    if isinstance(old, (int, float)) and not isinstance(old, bool):
        out += (
            [float(old), bool(old)]
            if isinstance(old, int)
            else [int(old) if math.isfinite(old) else 0, str(old)]
        )
    if isinstance(old, list) and old:
        out += [old[0], old * 2, old[:-1]]
    return out


@st.composite
def mutated_protocols(draw: st.DrawFn) -> bytes:
    """A shipped protocol with one to three mutations, as the bytes of a file."""
    source = draw(st.sampled_from(SHIPPED))
    raw = tomllib.loads(source.read_text())
    pick = draw(st.randoms(use_true_random=False))  # uniform over paths, however many there are
    for _ in range(draw(st.sampled_from([1, 1, 1, 2, 3]))):
        paths = _paths(raw)
        if not paths:
            break
        path = pick.choice(paths)
        parent, key = _parent(raw, path), path[-1]
        old = parent[key]
        action = draw(
            st.sampled_from(
                ["set", "number", "odd", "odd", "retype", "delete", "unknown", "empty", "nest"]
            )
        )
        if action == "set":
            parent[key] = draw(values)
        elif action == "number":
            parent[key] = draw(_near(old))
        elif action == "odd":
            parent[key] = draw(_odd(old))
        elif action == "retype":
            parent[key] = draw(st.sampled_from(_retyped(old)))
        elif action == "delete":
            del parent[key]
        elif action == "unknown":
            target = old if isinstance(old, dict) else parent if isinstance(parent, dict) else raw
            target[draw(keys)] = draw(values)
        elif action == "empty":
            parent[key] = (
                {} if isinstance(old, dict) else draw(st.sampled_from([[], [{}], [[]], ""]))
            )
        else:  # nest: the old value wrapped in arrays or tables, a few levels or many
            depth = draw(st.integers(1, 6) | st.integers(20, 60))
            for _level in range(depth):
                old = [old] if draw(st.booleans()) else {"a": old}
            parent[key] = old
    text = dumps_toml(raw)
    lines = text.splitlines(keepends=True)
    edit = draw(
        st.sampled_from(["none"] * 6 + ["deep", "cut", "insert", "double", "bytes", "unicode"])
    )
    if edit == "deep":  # nesting that recurses past any limit, after a random line
        depth = draw(st.integers(2, 40) | st.integers(300, 3000))
        lines.insert(
            draw(st.integers(0, len(lines))), f"deep = {_nested(depth, draw(st.booleans()))}\n"
        )
    elif edit == "cut" and text:
        start = draw(st.integers(0, len(text) - 1))
        lines = [text[:start] + text[start + draw(st.integers(1, 20)) :]]
    elif edit == "insert":
        at = draw(st.integers(0, len(text)))
        lines = [text[:at] + draw(st.text(min_size=1, max_size=5)) + text[at:]]
    elif edit == "unicode":  # odd unicode in a key or a string, quoted or bare
        at = draw(st.integers(0, len(text)))
        lines = [text[:at] + draw(st.sampled_from(ODD_TEXT[1:])) + text[at:]]
    elif edit == "double" and lines:
        at = draw(st.integers(0, len(lines) - 1))
        lines.insert(at, lines[at])
    data = "".join(lines).encode("utf-8", errors="surrogatepass")
    if edit == "bytes":  # not UTF-8, a lone surrogate, or a NUL byte
        at = draw(st.integers(0, len(data)))
        data = (
            data[:at]
            + draw(st.sampled_from([b"\xff", b"\xc3", b"\x00", b"\xed\xa0\x80"]))
            + data[at:]
        )
    return data


def _one_line(message: str) -> bool:
    return bool(message.strip()) and "\n" not in message.strip() and "Traceback" not in message


@pytest.fixture(scope="module")
def protocol_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz") / "fuzzed.toml"


def test_the_shipped_protocols_are_there() -> None:
    assert len(SHIPPED) >= 30


@settings(
    max_examples=FUZZ_EXAMPLES,
    deadline=None,
    derandomize=not LONG,
    database=None,
    print_blob=True,
    suppress_health_check=[
        HealthCheck.too_slow,
        HealthCheck.data_too_large,
        HealthCheck.large_base_example,
        HealthCheck.function_scoped_fixture,
    ],
)
@given(data=mutated_protocols())
def test_a_mutated_protocol_is_accepted_or_refused_in_one_line(
    data: bytes, protocol_file: Path
) -> None:
    protocol_file.write_bytes(data)
    try:
        load_protocol(protocol_file)
        loaded = True
    except SealError as exc:
        assert _one_line(str(exc)), repr(str(exc))
        loaded = False
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["protocol", "explain", str(protocol_file)])
    if code == 0:
        assert loaded, "explain accepted what the loader refused"
        assert out.getvalue().startswith(f"# {protocol_file}")
    else:
        assert code == 2, err.getvalue()
        assert _one_line(err.getvalue()), err.getvalue()
        assert err.getvalue().startswith("seal protocol: error: ")
