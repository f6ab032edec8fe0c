"""The run directory writer: CSV append, crash-torn rows, truncation on resume, TOML writing."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from seal.errors import SealError
from seal.protocols.toml_io import dumps_toml
from seal.run.rundir import CsvLog, RunDir, new_group_id, parse_seed_dir


def test_csv_rows_count_and_truncate_drop_a_torn_last_line(tmp_path: Path) -> None:
    log = CsvLog(tmp_path / "m.csv", ("epoch", "value"))
    log.append([{"epoch": 1, "value": 0.5}, {"epoch": 2, "value": 0.25}])
    log.append([{"epoch": 3, "value": 1 / 3}])
    with open(tmp_path / "m.csv", "a") as fh:  # a kill in the middle of a write
        fh.write("4,0.12")
    assert log.num_rows() == 3  # the torn row has no newline and does not count
    log.truncate(2)
    assert (tmp_path / "m.csv").read_text() == "epoch,value\n1,0.5\n2,0.25\n"
    log.append([{"epoch": 3, "value": 1 / 3}])
    # Floats are written with repr, so they read back bit for bit.
    assert (tmp_path / "m.csv").read_text().splitlines()[-1] == f"3,{1 / 3!r}"


def test_create_refuses_existing_run_and_open_refuses_non_run(tmp_path: Path) -> None:
    RunDir.create(tmp_path / "seed-0", "x = 1\n", {"seed": 0})
    with pytest.raises(SealError, match="already exists"):
        RunDir.create(tmp_path / "seed-0", "x = 1\n", {"seed": 0})
    with pytest.raises(SealError, match="not a run directory"):
        RunDir.open(tmp_path)
    assert parse_seed_dir(tmp_path / "seed-12") == 12 and parse_seed_dir(tmp_path) is None


def test_group_id_is_timestamp_and_config_hash() -> None:
    import datetime as dt

    gid = new_group_id("a = 1\n", dt.datetime(2026, 11, 22, 4, 15, 3, tzinfo=dt.UTC))
    assert gid.startswith("20261122-041503-") and len(gid) == len("20261122-041503-") + 6
    assert gid != new_group_id("a = 2\n", dt.datetime(2026, 11, 22, 4, 15, 3, tzinfo=dt.UTC))


def test_dumps_toml_round_trips_protocol_values() -> None:
    data = {
        "protocol": {"name": "x", "seeds": 2, "lr": 3e-4, "on": True, "tasks": ["a-v3", "b"]},
        "envs": {"mw": {"adapter": "metaworld", "tasks": []}, "fk": {"episode_length": 280}},
        "scheduler": {
            "kind": "stepped",
            "start": {"mw": 0.9, "fk": 0.1},
            "phases": [{"epochs": 3, "tasks": ["a"]}],
        },
        "finetune": {"alignment": {}},
        "quoted": {'we"ird key': 'a "b" \\ c'},
    }
    assert tomllib.loads(dumps_toml(data)) == data


def test_row_types_name_the_csv_columns() -> None:
    from seal.run.rundir import METRICS_COLUMNS, TRAIN_COLUMNS, MetricsRow, TrainRow

    assert tuple(MetricsRow.__annotations__) == METRICS_COLUMNS
    assert tuple(TrainRow.__annotations__) == TRAIN_COLUMNS
