"""The sweep file: a base scenario, the axes to vary, the seeds and the figures to collect.

```toml
name = "telemetry_and_shunt_noise"
vehicle = "p2_phev_9at"       # shipped name or path, as in the other commands
setup = "paper"
campaign = "quick"
seeds = [7, 8]                # each seed is the campaign's (plant and sensor noise); default: the campaign's own
families = ["transmission"]   # optional: validate only these identification families (default: everything)

[axes]                        # dotted paths into the vehicle / setup / campaign models
setup.telemetry.k_tel = [250, 500, 1000]
setup.ivt.battery.current_errors.noise_std = {start = 0, stop = 3, num = 4}   # linspace, ends included
# a range may also give a step: {start = 0.1, stop = 0.5, step = 0.1}

[collect]                     # default: every check's error and pass/fail and every identified value
checks = true
parameters = true
only = ["transmission.*"]     # fnmatch patterns over the check and parameter names (default: all)
```

Paths are checked against the base models when the file loads (an unknown key is a one-line error naming
the key and the keys allowed there); values are applied per run, so a value the model refuses makes that
run fail with its message while the others go on.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, Field, ValidationError, field_validator, model_validator

from benchtwin.config import load_campaign, load_setup, load_vehicle, scenario_path
from benchtwin.config._base import StrictModel, validate_data
from benchtwin.config.campaign import CampaignConfig
from benchtwin.config.setup import SetupConfig
from benchtwin.config.vehicle import VehicleConfig
from benchtwin.errors import ConfigError
from benchtwin.validation.families import FAMILIES

__all__ = ["AXIS_ROOTS", "CollectConfig", "RangeSpec", "SweepConfig", "apply_axes", "load_sweep", "resolve_scenario"]

#: the models an axis may point into
AXIS_ROOTS: tuple[str, ...] = ("vehicle", "setup", "campaign")
_RANGE_KEYS = {"start", "stop", "num", "step"}


class RangeSpec(StrictModel):
    """A numeric range: ``num`` evenly spaced values from ``start`` to ``stop`` (both included), or
    ``start, start + step, ...`` up to ``stop`` (included when it falls on a step)."""

    start: float
    stop: float
    num: int | None = Field(default=None, ge=1, le=10_000)
    step: float | None = Field(default=None, gt=0)

    @model_validator(mode="after")
    def _one_of(self) -> RangeSpec:
        if (self.num is None) == (self.step is None):
            raise ValueError("a range takes exactly one of 'num' and 'step'")
        return self

    def values(self) -> list[float]:
        """The values of the range."""
        if self.num is not None:
            return [float(x) for x in np.linspace(self.start, self.stop, self.num)]
        n = int(np.floor((self.stop - self.start) / self.step + 1e-9)) + 1
        return [float(self.start + k * self.step) for k in range(max(n, 0))]


class CollectConfig(StrictModel):
    """Which figures each run's row keeps."""

    checks: bool = True
    parameters: bool = True
    only: list[str] = Field(default_factory=list)


class SweepConfig(StrictModel):
    """A sweep file (see the module docstring)."""

    name: str = "sweep"
    vehicle: str = "p2_phev_9at"
    setup: str = "paper"
    campaign: str = "paper"
    seeds: list[int] = Field(default_factory=list)
    families: list[str] | None = None
    profile: Literal["ideal", "realistic"] | None = None
    axes: dict[str, Any] = Field(default_factory=dict)
    collect: CollectConfig = Field(default_factory=CollectConfig)

    @field_validator("seeds")
    @classmethod
    def _seeds(cls, v: list[int]) -> list[int]:
        if any(s < 0 for s in v):
            raise ValueError("seeds must be >= 0")
        if len(set(v)) != len(v):
            raise ValueError("seeds must not repeat")
        return v

    @field_validator("families")
    @classmethod
    def _families(cls, v: list[str] | None) -> list[str] | None:
        if v is not None:
            bad = [f for f in v if f not in FAMILIES]
            if bad or not v:
                raise ValueError(f"unknown family {', '.join(map(repr, bad)) or '(empty list)'}; allowed: "
                                 f"{', '.join(FAMILIES)}")
        return v

    @field_validator("axes")
    @classmethod
    def _axes(cls, v: dict[str, Any]) -> dict[str, Any]:
        return {path: _parse_axis(path, values) for path, values in v.items()}

    def axis_values(self) -> dict[str, list[Any]]:
        """Axis path -> its values, in file order."""
        return {k: (v.values() if isinstance(v, RangeSpec) else list(v)) for k, v in self.axes.items()}


def _parse_axis(path: str, values: Any) -> list[Any] | RangeSpec:
    """One axis: a non-empty list of values or a :class:`RangeSpec` (ValueError naming what is allowed)."""
    root = path.split(".", 1)[0]
    if root not in AXIS_ROOTS or "." not in path:
        raise ValueError(f"an axis must start with one of {', '.join(AXIS_ROOTS)} and name a key inside it "
                         "(e.g. setup.telemetry.k_tel)")
    if isinstance(values, list):
        if not values:
            raise ValueError("empty list of values")
        return values
    try:
        return RangeSpec.model_validate(values)
    except ValidationError as exc:
        why = "; ".join(f"{'.'.join(map(str, e['loc'])) or 'range'}: {e['msg']}" for e in exc.errors())
        raise ValueError(f"allowed: a list of values or a range {{start, stop, num}} or {{start, stop, step}} "
                         f"({why})") from None


def _flatten_axes(node: Any, prefix: str, out: dict[str, Any]) -> None:
    """Nested TOML tables of dotted keys -> ``{"setup.telemetry.k_tel": [...]}``; a leaf is a list, a range
    table (``start``/``stop`` with ``num`` or ``step``) or a single value."""
    if isinstance(node, dict) and not (node and set(node) <= _RANGE_KEYS and "start" in node):
        for k, v in node.items():
            _flatten_axes(v, f"{prefix}.{k}" if prefix else str(k), out)
        return
    out[prefix] = node if isinstance(node, (list, dict)) else [node]


def resolve_scenario(kind: str, value: str, base: Path | None = None) -> Path:
    """A scenario file by path (relative to the sweep file's folder when not found as given) or shipped name."""
    p = Path(value)
    if p.exists():
        return p
    if base is not None and (base / p).exists():
        return base / p
    if p.parent != Path("."):
        return p
    return scenario_path(kind, value if value.endswith(".toml") else f"{value}.toml")


def load_sweep(path: str | Path) -> tuple[SweepConfig, VehicleConfig, SetupConfig, CampaignConfig]:
    """Read and check a sweep file and load its base scenario.

    Raises
    ------
    ConfigError
        One line per problem, naming the file, the key and what is allowed.
    """
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None
    if isinstance(data.get("axes"), dict):
        flat: dict[str, Any] = {}
        _flatten_axes(data["axes"], "", flat)
        data["axes"] = flat
        bad = []
        for axis, values in flat.items():
            try:
                _parse_axis(axis, values)
            except ValueError as exc:
                bad.append(f"{path}: key 'axes.{axis}' = {values!r}: {exc}")
        if bad:
            data["axes"] = {}
            try:
                validate_data(SweepConfig, data, str(path))
            except ConfigError as exc:
                bad.insert(0, str(exc))
            raise ConfigError("\n".join(bad))
    cfg = validate_data(SweepConfig, data, str(path))
    vehicle = load_vehicle(resolve_scenario("vehicles", cfg.vehicle, path.parent))
    setup = load_setup(resolve_scenario("setups", cfg.setup, path.parent))
    campaign = load_campaign(resolve_scenario("campaigns", cfg.campaign, path.parent))
    bases = {"vehicle": vehicle, "setup": setup, "campaign": campaign}
    problems = [p for axis in cfg.axes if (p := _check_path(bases, axis))]
    if problems:
        raise ConfigError("\n".join(f"{path}: {p}" for p in problems))
    return cfg, vehicle, setup, campaign


def _check_path(bases: dict[str, BaseModel], axis: str) -> str:
    """'' when ``axis`` names an existing key of its base model, else the one-line problem."""
    root, *parts = axis.split(".")
    cur: Any = bases[root].model_dump(mode="json")
    walked = root
    for part in parts:
        if isinstance(cur, list):
            if not part.isdigit() or int(part) >= len(cur):
                return (f"key 'axes.{axis}': {walked} is a list of {len(cur)}; the next part must be an index "
                        f"0..{len(cur) - 1}, not {part!r}")
            cur = cur[int(part)]
        elif isinstance(cur, dict):
            if part not in cur:
                allowed = ", ".join(map(str, cur)) or "(none)"
                return f"key 'axes.{axis}': {walked} has no key {part!r}; allowed keys here: {allowed}"
            cur = cur[part]
        else:
            return f"key 'axes.{axis}': {walked} is a value, it has no key {part!r}"
        walked += f".{part}"
    return ""


def apply_axes(base: dict[str, dict[str, Any]], params: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The base models' JSON dumps with the axis values of one run set (a deep copy; nothing validated)."""
    import copy

    out = copy.deepcopy(base)
    for axis, value in params.items():
        root, *parts = axis.split(".")
        cur: Any = out[root]
        for part in parts[:-1]:
            cur = cur[int(part)] if isinstance(cur, list) else cur[part]
        last = parts[-1]
        if isinstance(cur, list):
            cur[int(last)] = value
        else:
            cur[last] = value
    return out


def validate_models(doc: dict[str, dict[str, Any]], source: str) -> tuple[VehicleConfig, SetupConfig, CampaignConfig]:
    """The three models of one run from their (modified) dumps; ConfigError naming the key on a bad value."""
    return (validate_data(VehicleConfig, doc["vehicle"], f"{source} vehicle"),
            validate_data(SetupConfig, doc["setup"], f"{source} setup"),
            validate_data(CampaignConfig, doc["campaign"], f"{source} campaign"))
