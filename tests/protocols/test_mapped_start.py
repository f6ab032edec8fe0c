"""[transfer] map through the runner: the testbed's oracle rungs start the target as the map says.

A tiny pre-training of `protocols/testbed/pretrain_source.toml`, then one epoch of each oracle
rung whose warm-up outlasts the epoch, so that no gradient step runs and the rung's checkpoint
holds the agent exactly as the transfer and the map left it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from seal.envs.testbed import paired_states, point_action
from seal.errors import ConfigError
from seal.experiments.arms import TESTBED
from seal.experiments.records import last_checkpoint
from seal.learner.checkpoint import read_checkpoint
from seal.learner.probes import agent_from_state
from seal.protocols import load_protocol
from seal.run.runner import run_seed
from tests.testbed_tiny import SMALL as TINY


@pytest.fixture(scope="module")
def pretrained(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The last checkpoint of a 2-epoch pre-training of the testbed's source."""
    out = tmp_path_factory.mktemp("pretrain")
    config = load_protocol(TESTBED / "pretrain_source.toml", [*TINY, "protocol.epochs=2"])
    return last_checkpoint(run_seed(config, 0, out / "g").run_dir)


def _start(rung: str, checkpoint: Path, out: Path, extra: tuple[str, ...] = ()) -> Path:
    """Run one epoch of `rung` without a gradient step; its checkpoint."""
    overrides = [*TINY, "protocol.epochs=1", "training.warmup_steps=10000", *extra]
    config = load_protocol(
        TESTBED / f"{rung}.toml", [*overrides, f"transfer.checkpoint={checkpoint}"]
    )
    return last_checkpoint(run_seed(config, 0, out / rung).run_dir)


def test_oracle_policy_starts_the_target_as_the_pretrained_source(
    pretrained: Path, tmp_path: Path
) -> None:
    source = agent_from_state(read_checkpoint(pretrained)["agent"])
    joint = agent_from_state(
        read_checkpoint(_start("oracle_policy", pretrained, tmp_path))["agent"]
    )
    point_obs, view_obs = paired_states(128, seed=0)
    ids = np.arange(128) % 4
    # t0..t3 = north, east, south, west; point's tasks run east, north, west, south.
    source_ids = np.array([1, 0, 3, 2])[ids]
    acted = joint.act("target", view_obs, ids, deterministic=True)
    expected = source.act("source", point_obs, source_ids, deterministic=True)
    np.testing.assert_allclose(point_action(acted), expected, rtol=1e-5, atol=1e-5)
    assert np.abs(expected).max() > 1e-3  # the pre-trained head moves the point
    torch.testing.assert_close(
        joint.log_alpha_of("target").detach(), source.log_alpha_of("source").detach()[[1, 0, 3, 2]]
    )


def test_the_distractors_log_std_is_the_protocols(pretrained: Path, tmp_path: Path) -> None:
    for value in (-20.0, -1.354):
        checkpoint = _start(
            "oracle_policy",
            pretrained,
            tmp_path / str(value),
            (f"transfer.map_unmapped_log_std={value}",),
        )
        joint = agent_from_state(read_checkpoint(checkpoint)["agent"])
        _, view_obs = paired_states(8, seed=2)
        x = torch.cat((torch.tensor(view_obs).float(), torch.eye(4)[torch.arange(8) % 4]), -1)
        with torch.no_grad():
            _, log_std = joint.policy("target", torch.arange(8) % 4)(x).chunk(2, -1)
        assert torch.allclose(log_std[:, [0, 2, 4]], torch.tensor(value)), value


def test_oracle_translator_maps_the_translator_only(pretrained: Path, tmp_path: Path) -> None:
    source = agent_from_state(read_checkpoint(pretrained)["agent"])
    joint = agent_from_state(
        read_checkpoint(_start("oracle_translator", pretrained, tmp_path))["agent"]
    )
    point_obs, view_obs = paired_states(64, seed=1)
    ids = torch.arange(64) % 4
    one_hot = torch.eye(4)
    with torch.no_grad():
        latent = joint.actor.translators["target"](
            torch.cat((torch.tensor(view_obs).float(), one_hot[ids]), -1)
        )
        expected = source.actor.translators["source"](
            torch.cat(
                (torch.tensor(point_obs).float(), one_hot[torch.tensor([1, 0, 3, 2])[ids]]), -1
            )
        )
    torch.testing.assert_close(latent, expected, rtol=1e-5, atol=1e-5)
    # The target's temperatures are fresh (log init_alpha = 0), not the source's.
    assert torch.equal(joint.log_alpha_of("target").detach(), torch.zeros(4))


def test_a_map_that_does_not_fit_the_protocol_fails_before_any_run_dir(
    pretrained: Path, tmp_path: Path
) -> None:
    with pytest.raises(ConfigError, match="unknown env map 'nope'; valid: testbed_oracle"):
        load_protocol(TESTBED / "oracle_policy.toml", ["transfer.map=nope"])
    # No point_view env to map into: the control's diagonal source instead of the target.
    config = load_protocol(
        TESTBED / "oracle_policy.toml",
        [*TINY, "envs.target.adapter=point_diagonal", f"transfer.checkpoint={pretrained}"],
    )
    with pytest.raises(
        ConfigError, match=r"needs exactly one \[envs.<name>\] with adapter 'point_view'"
    ):
        run_seed(config, 0, tmp_path / "g")
    assert not (tmp_path / "g").exists()


@pytest.mark.parametrize(
    ("rung", "pieces"),
    [
        ("oracle_policy", '["translator", "head", "critic", "temperature"]'),
        ("oracle_translator", '["translator"]'),
    ],
)
def test_a_rung_spelt_as_its_list_of_pieces_learns_the_same(
    pretrained: Path, tmp_path: Path, rung: str, pieces: str
) -> None:
    """A few epochs with gradient steps: the list spelling gives the string's run, row for row."""
    runs = {}
    for name, modules in (("string", None), ("list", pieces)):
        extra = [] if modules is None else [f"transfer.map_modules={modules}"]
        config = load_protocol(
            TESTBED / f"{rung}.toml",
            [*TINY, "protocol.epochs=3", f"transfer.checkpoint={pretrained}", *extra],
        )
        runs[name] = run_seed(config, 0, tmp_path / name).run_dir
    for table in ("metrics.csv", "train.csv"):
        left, right = (pd.read_csv(runs[n] / table) for n in ("string", "list"))
        if "wall_s" in left:
            left, right = left.drop(columns="wall_s"), right.drop(columns="wall_s")
        assert len(left) > 0
        pd.testing.assert_frame_equal(left, right)
    assert (pd.read_csv(runs["list"] / "metrics.csv")["grad_steps"] > 0).any()
