"""The transfer testbed's arms (docs/transfer_testbed.md): what `seal bench --learn transfer` compares.

An arm is one protocol file run seed for seed (`Arm`), set against the target-alone arm with the
same per-step batch schedule, and perhaps started from another arm's last checkpoint. `Arm` is the
unit of every learning experiment (`kitchen`, `table1`, `quickstart` and `mtrl` give theirs their
own protocol directory); `ARMS` are the testbed's, under `protocols/testbed/`, and `arms` picks the
ones a run of the bench takes. `seal.experiments.launcher` runs arms; `seal.experiments.transfer`
holds the goals the testbed's are measured against.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from seal.errors import UnknownNameError

TESTBED = Path(__file__).resolve().parents[2] / "protocols" / "testbed"
"""The testbed's protocol files."""
TARGET_ENV = "target"
"""The [envs.<name>] of the target in every testbed protocol."""


@dataclass(frozen=True)
class Arm:
    """One run of the testbed: a protocol file, the target-alone arm it is set against, and what it starts from."""

    name: str
    label: str
    """Column heading of the table."""
    alone: str | None
    """The target-alone arm with the same per-step batch schedule; None for an alone arm itself."""
    full: bool = False
    """Only with --full."""
    directory: Path = TESTBED
    """Where the arm's protocol file lies."""
    pretrain: str | None = None
    """The arm whose last checkpoint starts this one (`--set transfer.checkpoint=...`), seed for seed."""
    has_target: bool = True
    """False for a source-only run (the pre-training): it is no column of the table."""
    ladder: bool = False
    """Only with --ladder (or named in --arms): a cell of the ladder's factorial that no other mode runs."""

    @property
    def protocol(self) -> Path:
        """The arm's protocol file."""
        return self.directory / f"{self.name}.toml"


def arms_in(directory: Path, named: Sequence[tuple[str, str]]) -> tuple[Arm, ...]:
    """Arms set against no alone arm, one a (name, label), their protocols in `directory`."""
    return tuple(Arm(name, label, None, directory=directory) for name, label in named)


def chosen(
    every: Sequence[Arm], only: Sequence[str] | None, what: str, also: Sequence[str] = ()
) -> list[Arm]:
    """`every` arm, or the ones `only` names and `also`'s, in `every`'s order; a name not among
    them is an `UnknownNameError` that calls it a `what`."""
    if not only:
        return list(every)
    by_name = {a.name: a for a in every}
    for name in only:
        if name not in by_name:
            raise UnknownNameError(what, name, list(by_name))
    return [a for a in every if a.name in {*only, *also}]


ARMS: tuple[Arm, ...] = (
    Arm("alone", "Single Env", None),
    Arm("high_source", "High Src", "alone"),
    Arm("no_correspondence", "No corr.", "alone"),
    Arm("pretrain_source", "Source pre-training", None, has_target=False),
    # The ladder of positive controls (docs/transfer_testbed.md, round 5), each from the seed's
    # pre-training: only the trunk pre-trained; the target's translator mapped too; its whole
    # policy, critic and temperatures mapped (transfer by construction).
    Arm("pretrained_trunk", "Pretrained trunk", "alone", pretrain="pretrain_source"),
    Arm("oracle_translator", "Oracle translator", "alone", pretrain="pretrain_source"),
    Arm("oracle_policy", "Oracle policy", "alone", pretrain="pretrain_source"),
    Arm("oracle_policy_clamp", "Oracle policy, clamp", "alone", pretrain="pretrain_source"),
    # The ladder (docs/transfer_testbed.md, "Ladder"): the other six cells of head x critic x
    # temperature mapped on top of oracle_translator's perfect translator (`--ladder`).
    *(
        Arm(f"ladder_{cell}", f"Ladder: {label}", "alone", pretrain="pretrain_source", ladder=True)
        for cell, label in (
            ("head", "head"),
            ("critic", "critic"),
            ("temperature", "temp."),
            ("head_critic", "head+critic"),
            ("head_temperature", "head+temp."),
            ("critic_temperature", "critic+temp."),
        )
    ),
    Arm("alone_sparse", "Single Env (sparse tgt)", None),
    Arm("positive_sparse_target", "Pos: sparse tgt", "alone_sparse", pretrain="pretrain_source"),
    Arm("high_source_per_env", "High Src per_env", "alone", full=True),
    Arm("alone_50_50", "Single Env (50/50 batch)", None, full=True),
    Arm("joint_50_50", "50/50", "alone_50_50", full=True),
    Arm("alone_high_target", "Single Env (High Tgt batch)", None, full=True),
    Arm("high_target", "High Tgt", "alone_high_target", full=True),
    # A diagnostic added after the first round-4 measurement, not a positive control: does the
    # target gain once its critic shares a pre-trained trunk too? (docs/transfer_testbed.md)
    Arm(
        "pretrain_source_shared_critic",
        "Source pre-training (shared critic)",
        None,
        full=True,
        has_target=False,
    ),
    Arm("alone_shared_critic", "Single Env (shared critic)", None, full=True),
    Arm(
        "diag_shared_critic",
        "Diag: shared critic",
        "alone_shared_critic",
        full=True,
        pretrain="pretrain_source_shared_critic",
    ),
)
"""The minimum set (docs/transfer_testbed.md, rounds 4 and 5), then the --full arms; the default-mode
high-source arm gives the round-3 headline, `seal.experiments.transfer.POSITIVE_CONTROLS` round 4's
positive controls."""

LADDER_ARMS: tuple[str, ...] = (
    "oracle_translator",
    *(a.name for a in ARMS if a.ladder),
    "oracle_policy",
)
"""The ladder's eight arms: the perfect translator with every subset of head, critic and
temperatures mapped too, from none (oracle_translator) to all (oracle_policy)."""

ARM_ALIASES: dict[str, str] = {"positive_pretrained": "pretrained_trunk"}
"""Old arm names `--arms` still takes (round 4's results keep theirs)."""


def arms(full: bool = False, only: Sequence[str] | None = None) -> list[Arm]:
    """The arms run by `seal bench --learn transfer` (with `--full`: all of them but the ladder's
    own; `only`: these and the arms they need)."""
    if not only:
        return [a for a in ARMS if (full or not a.full) and not a.ladder]
    by_name = {a.name: a for a in ARMS}
    only = [ARM_ALIASES.get(name, name) for name in only]
    for name in only:
        if name not in by_name:
            raise UnknownNameError("testbed arm", name, [*by_name, *ARM_ALIASES])
    needed = {by_name[n].alone for n in only} | {by_name[n].pretrain for n in only}
    wanted = set(only) | (needed - {None})
    return [a for a in ARMS if a.name in wanted]
