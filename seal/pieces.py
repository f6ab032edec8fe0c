"""An env's pieces in a SEAL agent: what a mapped start can map, and what drift measures.

Every env of a SEAL agent has its own translator (the policy's input stack), action head, critic
(its online twin Q and their targets) and per-task temperatures; only the trunk is shared.
`[transfer] map_modules` names the pieces a mapped start maps (`seal.learner.transfer.map_env`,
the transfer testbed's ladder: docs/transfer_testbed.md), and `[logging] drift` logs how far each
piece has moved from its start (`seal.learner.drift`). Plain strings and no torch, so that the
protocol schema checks `map_modules` without loading the learner.
"""

from __future__ import annotations

from collections.abc import Sequence

from seal.errors import SealError

PIECES: tuple[str, ...] = ("translator", "head", "critic", "temperature")
"""An env's pieces, in the order they are listed everywhere."""
MAP_SPELLINGS: dict[str, tuple[str, ...]] = {"all": PIECES, "translator": ("translator",)}
"""`map_modules` strings: the two sets the oracle rungs were written with, kept as they meant."""
ON_TRANSLATOR = "translator"
"""The piece every mapped set holds: the head, critic and temperatures are mapped on top of the
perfect translator (the ladder's design); a mapped head on a fresh translator would read latents
the source never made, which no rung asks for, so such sets are refused."""


def map_pieces(value: str | Sequence[object]) -> tuple[str, ...]:
    """The pieces `transfer.map_modules = value` maps, in PIECES order: "all", "translator", or a
    list of distinct pieces holding "translator"; SealError naming the value and what is valid."""
    listed = ", ".join(f'"{p}"' for p in PIECES)
    valid = (
        f'valid: "all" (all four pieces), "translator" (the translator alone) or a list of '
        f'distinct pieces from {listed} that holds "{ON_TRANSLATOR}"'
    )
    if isinstance(value, str):
        if value in MAP_SPELLINGS:
            return MAP_SPELLINGS[value]
        raise SealError(f"map_modules = {value!r} is not valid; {valid}")
    items = list(value)
    unknown = [p for p in items if not isinstance(p, str) or p not in PIECES]
    repeated = sorted({p for p in items if isinstance(p, str) and items.count(p) > 1})
    why = (
        f"unknown piece {unknown[0]!r}"
        if unknown
        else f"{repeated[0]!r} repeats"
        if repeated
        else f'no "{ON_TRANSLATOR}": the other pieces are mapped on top of the perfect translator'
        if ON_TRANSLATOR not in items
        else None
    )
    if why is not None:
        raise SealError(f"map_modules = {items!r} is not valid ({why}); {valid}")
    return tuple(p for p in PIECES if p in items)
