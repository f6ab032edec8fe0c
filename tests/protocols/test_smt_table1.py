"""SMT Table 1 as one command (issue 57): every column's shipped protocol runs (tiny), and
`seal report` over their groups writes the paper's layout."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from seal.cli.main import main
from seal.protocols import load_protocol
from tests.protocols.test_shipped import EXTRA, PROTOCOLS, SHRINK

COLUMNS = {
    "sac_mt": "SAC-MT",
    "sac_mt_mh": "SAC-MT-MH",
    "soft_modular": "Soft Modular",
    "pcgrad": "PCGrad",
    "paco": "PaCo",
    "smt": "SMT",
}
TINY = {
    "soft_modular": ["agent.soft_width=8", "agent.soft_embedding=8"],
    "smt": EXTRA["mt10_smt"],
}


def test_the_columns_share_the_papers_settings_and_name_their_column() -> None:
    ref = load_protocol(PROTOCOLS / "smt_table1" / "sac_mt_mh.toml")
    assert ref.agent.hidden == (400, 400) and ref.training.batch_per_task == 256
    assert len(ref.envs["mw"].tasks) == 10 and ref.protocol.seeds == 5
    for name, column in COLUMNS.items():
        config = load_protocol(PROTOCOLS / "smt_table1" / f"{name}.toml")
        assert config.protocol.column == column
        assert config.envs == ref.envs and config.replay == ref.replay
        assert config.agent.actor_lr == config.agent.critic_lr == 3e-4
    # Only the learner differs from SAC-MT-MH (SMT also differs in its scheduler).
    assert load_protocol(PROTOCOLS / "smt_table1" / "paco.toml").agent.architecture == "paco"
    assert load_protocol(PROTOCOLS / "smt_table1" / "pcgrad.toml").agent.gradient == "pcgrad"
    sac_mt = load_protocol(PROTOCOLS / "smt_table1" / "sac_mt.toml").agent
    assert not sac_mt.multi_head_policy and not sac_mt.multi_head_critic


@pytest.mark.slow
def test_every_column_runs_and_the_report_has_smt_table1s_layout(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    groups = []
    for name in COLUMNS:
        args = ["run", str(PROTOCOLS / "smt_table1" / f"{name}.toml"), "--scale", "0.0001"]
        args += ["--out", str(tmp_path), "--quiet", "--json", "--no-report", "--seeds", "0"]
        for item in [*SHRINK, "envs.mw.episode_length=5", *TINY.get(name, [])]:
            args += ["--set", item]
        assert main(args) == 0, name
        run = Path(json.loads(capsys.readouterr().out.strip().splitlines()[-1])["run_dir"])
        groups.append(str(run.parent))
    assert main(["report", *groups, "--out", str(tmp_path / "table")]) == 0
    md = (tmp_path / "table" / "tables" / "success_by_task.md").read_text()
    rows = [line for line in md.splitlines() if line.startswith("|")]
    header = [c.strip() for c in rows[0].strip("|").split("|")]
    assert header == ["Algorithm", *(str(i) for i in range(10)), "Average"]
    assert [r.strip("|").split("|")[0].strip() for r in rows[2:]] == list(COLUMNS.values())
