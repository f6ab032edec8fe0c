"""scripts/update_profile.py: the line it prints, by hand, and a profile of a real update."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.faults.point_protocol import point_protocol
from tests.script_module import load_script


def test_the_line_sums_the_matmuls_and_names_the_next_ops_by_share() -> None:
    script = load_script("update_profile")
    profiled = {
        "ms": 12.34,
        "shares": {
            "aten::mm": 0.3,
            "aten::bmm": 0.2,
            "aten::add": 0.1,
            "aten::mul": 0.25,
            "aten::baddbmm": 0.05,
            "aten::tanh": 0.1,
        },
    }
    line = script.format_profile("x", profiled, top=2)
    # matmuls 0.3 + 0.2 + 0.05 = 55%; then mul 25%, and add and tanh tie at 10% (the first kept)
    assert line == "x: 12.3 ms an update in ops, matmuls 55.0%; next: mul 25.0%, add 10.0%"


def test_a_profile_of_a_point_update_has_its_matmuls_and_shares_that_sum_to_one(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    script = load_script("update_profile")
    path = tmp_path / "pt.toml"
    path.write_text(point_protocol("pt", 1))
    profiled = script.profile_update(path, updates=2)
    assert profiled["ms"] > 0
    assert sum(profiled["shares"].values()) == pytest.approx(1.0)
    assert "aten::addmm" in profiled["shares"]  # the actor's and critics' dense layers
    assert script.main([str(path), "--updates", "1"]) == 0
    assert capsys.readouterr().out.startswith("pt: ")
    assert script.main([str(tmp_path / "none.toml")]) == 2
    assert "none.toml" in capsys.readouterr().err
