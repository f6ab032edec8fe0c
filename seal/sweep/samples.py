"""A search's samples: the [search] table as Tune's param space, and how a drawn sample becomes a run.

`search_space` and the seeded `search_algorithm` are what Tune draws from; `count_trials`,
`trial_name` and `trial_index` number the draws; `sample_overrides` / `with_overrides` set a
sample's values on the base config; `evaluation_horizon` bounds the evaluations any sample can
make (ASHA's max_t).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

from seal.errors import ConfigError, SealError
from seal.protocols.config import ProtocolConfig
from seal.protocols.loader import config_from_dict, config_to_dict
from seal.protocols.toml_io import apply_overrides, toml_value
from seal.sweep import config_tables as sweep_tables
from seal.sweep.config_tables import SEARCH_OPTIONS, Distribution, SearchSpec

if TYPE_CHECKING:  # Ray is imported only where it is used (see the package docstring)
    from ray.tune.search.basic_variant import BasicVariantGenerator
    from ray.tune.search.sample import Domain


def parse_search(config: ProtocolConfig, num_samples: int | None = None) -> SearchSpec:
    """The protocol's [search] table as a SearchSpec; `num_samples` (from --samples) wins over the file's."""
    if not any(k not in SEARCH_OPTIONS for k in sweep_tables.flatten(config.search or {})):
        raise ConfigError(
            f"{config.path}: --search needs a [search] table naming at least one config value, e.g. "
            f'[search] "agent.actor_lr" = {{dist = "loguniform", low = 1e-5, high = 1e-3}}'
        )
    return sweep_tables.parse_search(config.search, config.path, num_samples)


def _plain(value: Any) -> Any:
    """numpy scalars -> Python numbers (so they print and serialise as TOML/JSON)."""
    item = getattr(value, "item", None)
    return item() if callable(item) and not isinstance(value, list | tuple | dict | str) else value


def sample_overrides(sample: Mapping[str, Any]) -> list[str]:
    """A sample as --set strings, e.g. {"agent.actor_lr": 1e-4} -> ["agent.actor_lr=0.0001"]."""
    return [f"{key}={toml_value(value)}" for key, value in sample.items()]


def with_overrides(
    config: ProtocolConfig, overrides: Sequence[str], where: str | None = None
) -> ProtocolConfig:
    """`config` with --set style overrides applied and everything validated again.

    The overrides are applied to the resolved config (after --scale), so a sampled
    `protocol.epochs` is used as given.
    """
    raw = apply_overrides(config_to_dict(config), overrides, where or config.path)
    return config_from_dict(raw, where or config.path)


def describe_sample(sample: Mapping[str, Any]) -> str:
    """A short one-line form of a sample, e.g. "agent.actor_lr=0.000123, agent.tau=0.01"."""
    parts = []
    for key, value in sample.items():
        shown = f"{value:.3g}" if isinstance(value, float) else toml_value(value)
        parts.append(f"{key}={shown}")
    return ", ".join(parts)


def search_space(spec: SearchSpec) -> dict[str, Domain | dict[str, Iterable[object]]]:
    """The [search] table as Tune's param_space: each "table.key" to its Tune distribution."""
    return {p.key: p.tune_domain() for p in spec.params}


def search_algorithm(spec: SearchSpec) -> BasicVariantGenerator:
    """Tune's random sampler seeded by [search].seed, so a search (and its resume) draws the same configs.

    It numbers its trials in the order it draws them, which is the sample index (`trial_index`).
    """
    from ray.tune.search.basic_variant import BasicVariantGenerator

    # Tune ignores TuneConfig.max_concurrent_trials when given a search algorithm: set it here.
    return BasicVariantGenerator(max_concurrent=spec.max_concurrent or 0, random_state=spec.seed)


def count_trials(spec: SearchSpec) -> int:
    """Trials of a search: `num_samples` draws for every point of the grid entries (Tune's semantics)."""
    return spec.num_samples * math.prod(len(p.values) for p in spec.params if p.dist == "grid")


def trial_name(index: int) -> str:
    """The name (and directory) of the sample drawn `index`-th, e.g. "sample-003"."""
    return f"sample-{index:03d}"


def trial_index(trial_id: str) -> int:
    """The sample index of a Tune trial id: BasicVariantGenerator ids end in the draw's number ("1a2b3_00003")."""
    return int(trial_id.rsplit("_", 1)[1])


def plain_sample(config: Mapping[str, Any]) -> dict[str, Any]:
    """A Tune trial's config (its sampled values) with plain Python numbers, in [search] order."""
    return {key: _plain(value) for key, value in config.items()}


def evaluations_per_run(config: ProtocolConfig) -> int:
    """How many evaluations a full run of `config` makes (every `interval` epochs and after the last)."""

    def count(epochs: int) -> int:
        interval = config.evaluation.interval
        return epochs // interval + (1 if epochs % interval else 0)

    if config.kind == "finetune" and config.finetune is not None:
        return count(config.finetune.pretrain_epochs) + count(config.finetune.finetune_epochs)
    return count(config.protocol.epochs)


def evaluation_horizon(base: ProtocolConfig, spec: SearchSpec) -> int:
    """The most evaluations any sample can make (ASHA's max_t; Tune draws the samples, so it is a bound).

    Evaluations grow with epochs and shrink with the interval, so the bound tries every combination
    of the ends (choice and grid: the values) of the searched values that change the count alone.
    """

    def ends(p: Distribution) -> tuple[Any, ...]:
        if p.dist in ("choice", "grid"):
            return p.values
        return (int(p.low), int(p.high)) if p.dist == "int" else (p.low, p.high)

    def count(sample: Mapping[str, Any]) -> int:
        try:
            return evaluations_per_run(with_overrides(base, sample_overrides(sample)))
        except SealError:
            return 0  # a value the schema refuses fails its trial before any evaluation

    plain = evaluations_per_run(base)
    varying = [p for p in spec.params if any(count({p.key: v}) != plain for v in ends(p))]
    keys = [p.key for p in varying]
    combos = itertools.product(*(ends(p) for p in varying))
    return max(plain, *(count(dict(zip(keys, c, strict=True))) for c in combos))
