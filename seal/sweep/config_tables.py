"""The two tables `seal sweep` reads, `[resources]` and `[search]`, checked when a protocol loads.

A leaf module of `seal.sweep` (no Ray, nothing of the run), so that the protocol loader, and with
it `seal run`, `seal protocol explain` and every other reader of protocols, rejects a misspelled
key or a bad value in them before anything is written. Whether each searched `table.key` names a real config value is checked by the loader, which
builds the config with every value a distribution can take at its ends.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

from seal.errors import ConfigError, SealError

if TYPE_CHECKING:
    from ray.tune.search.sample import Domain

DISTRIBUTIONS: tuple[str, ...] = ("uniform", "loguniform", "choice", "int", "grid")
"""Distributions a [search] entry may name (`dist = ...`)."""

SEARCH_OPTIONS: tuple[str, ...] = (
    "num_samples",
    "seed",
    "scheduler",
    "grace_period",
    "reduction_factor",
    "max_concurrent",
)
"""Keys of [search] that configure the search itself; every other key names a config value."""

RESOURCE_KEYS: tuple[str, ...] = ("cpus", "gpus")
"""Keys of [resources]: CPUs and GPUs (a fraction shares one GPU) reserved per trial."""


# ---------------------------------------------------------------- [resources]


@dataclass(frozen=True)
class Resources:
    """What Ray reserves for one trial."""

    cpus: float = 1.0
    """CPUs per trial; rounded down (at least 1), the cores its protocol.threads is resolved on and capped at."""
    gpus: float = 0.0
    """GPUs per trial; a fraction (e.g. 0.25) lets several trials share one GPU."""

    @property
    def threads(self) -> int:
        """The cores a trial's updates may use: its whole CPUs, at least one (no oversubscription)."""
        return max(1, int(self.cpus))


def parse_resources(table: Mapping[str, Any], file: str) -> Resources:
    """A protocol's [resources] table, checked (default: 1 CPU, no GPU per trial)."""
    table = dict(table or {})
    unknown = sorted(set(table) - set(RESOURCE_KEYS))
    if unknown:
        raise ConfigError(
            f"{file}: resources.{unknown[0]} is not a valid key; valid keys: {', '.join(RESOURCE_KEYS)}"
        )
    values: dict[str, float] = {}
    for key, lowest, strict in (("cpus", 0.0, True), ("gpus", 0.0, False)):
        if key not in table:
            continue
        value = table[key]
        if (
            isinstance(value, bool)
            or not isinstance(value, int | float)
            or not math.isfinite(value)
            or value < lowest
            or (strict and value == lowest)
        ):
            span = "> 0" if strict else ">= 0"
            raise ConfigError(
                f"{file}: resources.{key} = {value!r} is not valid; expected a number {span}"
            )
        values[key] = float(value)
    return Resources(**values)


# ---------------------------------------------------------------- [search]


@dataclass(frozen=True)
class Distribution:
    """One searched config value: `dist` over [low, high] or over `values`."""

    key: str
    """The config key, "table.key" as for --set (e.g. "agent.actor_lr")."""
    dist: str
    """uniform, loguniform, choice, int (integers low..high inclusive) or grid (every value)."""
    low: float | None = None
    high: float | None = None
    values: tuple[Any, ...] = ()

    def ends(self) -> tuple[Any, ...]:
        """The values that bound what a draw can be: every choice or grid value, else low and
        high (integers for "int"). Each is checked alone against the protocol before a search."""
        if self.dist in ("choice", "grid"):
            return self.values
        if self.dist == "int":
            return (int(self.low or 0), int(self.high or 0))
        return (self.low, self.high)

    def tune_domain(self) -> Domain | dict[str, Iterable[object]]:
        """This distribution as a Ray Tune param_space entry (a `tune.uniform` ... domain; grid: `tune.grid_search`)."""
        from ray import tune

        if self.dist == "uniform":
            return tune.uniform(self.low, self.high)
        if self.dist == "loguniform":
            return tune.loguniform(self.low, self.high)
        if self.dist == "int":
            return tune.randint(
                int(self.low), int(self.high) + 1
            )  # Tune's upper bound is exclusive
        if self.dist == "choice":
            return tune.choice(list(self.values))
        return tune.grid_search(list(self.values))


@dataclass(frozen=True)
class SearchSpec:
    """A parsed [search] table."""

    params: tuple[Distribution, ...]
    num_samples: int = 10
    """Random draws; with `grid` entries, each draw is made for every grid point (Tune's semantics)."""
    seed: int = 0
    """Seed of the draws, so the same [search] table always tries the same configs."""
    scheduler: Literal["none", "asha"] = "none"
    """"asha": stop trials whose mean success lags at each rung (Li et al. 2020); "none": run all to the end."""
    grace_period: int = 1
    """ASHA: evaluations every trial gets before it can be stopped."""
    reduction_factor: float = 2.0
    """ASHA: keep the best 1/reduction_factor of trials at each rung."""
    max_concurrent: int | None = None
    """At most this many trials at once (default: as many as the cluster's resources allow)."""


def flatten(table: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """{"agent": {"actor_lr": {dist...}}} and {"agent.actor_lr": {dist...}} both become {"agent.actor_lr": {dist...}}."""
    out: dict[str, Any] = {}
    for key, value in table.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping) and "dist" not in value:
            out.update(flatten(value, f"{name}."))
        else:
            out[name] = value
    return out


def _number(value: object, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ConfigError(f"{where} = {value!r} is not valid; expected a finite number")
    return float(value)


def parse_distribution(key: str, spec: object, file: str) -> Distribution:
    """One `"table.key" = {dist = ..., ...}` entry of [search], checked."""
    where = f"{file}: search.{key}"
    if "." not in key:
        raise ConfigError(
            f'{where}: a searched key names a config value as table.key (e.g. "agent.actor_lr"); valid search options: {", ".join(SEARCH_OPTIONS)}'
        )
    if not isinstance(spec, Mapping) or "dist" not in spec:
        raise ConfigError(
            f'{where} = {spec!r} must be an inline table with dist = one of {", ".join(DISTRIBUTIONS)}, e.g. {{dist = "loguniform", low = 1e-5, high = 1e-3}}'
        )
    dist = spec["dist"]
    if dist not in DISTRIBUTIONS:
        raise ConfigError(
            f"{where}.dist = {dist!r} is not valid; valid: {', '.join(DISTRIBUTIONS)}"
        )
    needed = {
        "uniform": ("low", "high"),
        "loguniform": ("low", "high"),
        "int": ("low", "high"),
        "choice": ("values",),
        "grid": ("values",),
    }[dist]
    extra = sorted(set(spec) - {"dist", *needed})
    if extra:
        raise ConfigError(
            f"{where}.{extra[0]} is not valid for dist = {dist!r}; valid keys: dist, {', '.join(needed)}"
        )
    missing = [k for k in needed if k not in spec]
    if missing:
        raise ConfigError(
            f"{where}: dist = {dist!r} needs {' and '.join(needed)}; {missing[0]} is missing"
        )
    if dist in ("choice", "grid"):
        values = spec["values"]
        if not isinstance(values, list) or not values:
            raise ConfigError(
                f"{where}.values = {values!r} is not valid; expected a non-empty array, e.g. values = [1e-4, 3e-4]"
            )
        return Distribution(key, dist, values=tuple(values))
    low, high = _number(spec["low"], f"{where}.low"), _number(spec["high"], f"{where}.high")
    if dist == "int" and (low != int(low) or high != int(high)):
        raise ConfigError(
            f'{where}: dist = "int" needs integer low and high, got {spec["low"]!r}, {spec["high"]!r}'
        )
    if not low < high and not (dist == "int" and low == high):
        raise ConfigError(f"{where}: low = {spec['low']!r} must be below high = {spec['high']!r}")
    if dist == "loguniform" and low <= 0:
        raise ConfigError(
            f'{where}.low = {spec["low"]!r} is not valid for dist = "loguniform"; expected a number > 0'
        )
    return Distribution(key, dist, low=low, high=high)


def parse_search(table: Mapping[str, Any], file: str, num_samples: int | None = None) -> SearchSpec:
    """A protocol's [search] table, checked; `num_samples` (from --samples) wins over the file's."""
    table = flatten(table or {})
    options: dict[str, Any] = {}
    for key in SEARCH_OPTIONS:
        if key not in table:
            continue
        value, where = table[key], f"{file}: search.{key}"
        if key == "scheduler":
            if value not in ("none", "asha"):
                raise ConfigError(f"{where} = {value!r} is not valid; valid: 'none', 'asha'")
        elif key == "reduction_factor":
            if _number(value, where) <= 1:
                raise ConfigError(f"{where} = {value!r} is not valid; expected a number > 1")
            value = float(value)
        else:
            lowest = 0 if key == "seed" else 1
            if isinstance(value, bool) or not isinstance(value, int) or value < lowest:
                raise ConfigError(
                    f"{where} = {value!r} is not valid; expected an integer >= {lowest}"
                )
        options[key] = value
    if num_samples is not None:
        if num_samples < 1:
            raise SealError(f"--samples {num_samples}: expected an integer >= 1")
        options["num_samples"] = num_samples
    params = tuple(
        parse_distribution(k, v, file) for k, v in table.items() if k not in SEARCH_OPTIONS
    )
    return SearchSpec(params=params, **options)
