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
vehicle = ["p2_phev_9at", "my_car.toml"]   # a whole model: a list of files (relative to this file) or shipped names

# or, instead of the list, a random family of physically plausible vehicles (benchtwin.studies.vehicle_family):
# [axes.vehicle]
# random = {count = 4, seed = 1, gears = [8, 9], fuels = ["diesel", "petrol"]}   # gears, fuels optional
# battery.alpha = [0.98, 1.02]    # dotted vehicle axes may sit beside it; they apply to each drawn vehicle

[collect]                     # default: every check's error and pass/fail and every identified value
checks = true
parameters = true
only = ["transmission.*"]     # fnmatch patterns over the check and parameter names (default: all)
```

Paths are checked against the base models when the file loads (an unknown key is a one-line error naming
the key and the keys allowed there); values are applied per run, so a value the model refuses makes that
run fail with its message while the others go on. An axis named by a model alone (``vehicle``, ``setup`` or
``campaign``) swaps that whole model: its files are loaded and checked when the sweep file loads (a bad one is
an error naming the axis and the file), and a run's dotted axes of that model then apply to the swapped one.

A random vehicle family ``[axes.vehicle] random = {count = N, seed = S}`` is a whole-model vehicle axis of the N
values ``"random-0"`` .. ``"random-<N-1>"``: vehicle i is
:func:`~benchtwin.studies.vehicle_family.random_vehicle` of the seed ``(S, i)`` on the base vehicle (so the same
seed gives the same vehicles, a larger count keeps the smaller one's), drawn when the sweep file loads. Each run
on a drawn vehicle moves the campaign's ramp-ups to that vehicle's gears
(:func:`~benchtwin.studies.vehicle_family.follow_gears`, as the property tests do: an 8-speed runs the 9-speed
base vehicle's ramp-ups in the corresponding gears, at the same motor speed). ``gears`` (default ``[8, 9]``)
and ``fuels`` (default ``["diesel", "petrol"]``) narrow the family. A key other than these four is an error
naming it.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, Field, PrivateAttr, ValidationError, field_validator, model_validator

from benchtwin.config import load_campaign, load_setup, load_vehicle, scenario_path
from benchtwin.config._base import StrictModel, validate_data
from benchtwin.config.campaign import CampaignConfig
from benchtwin.config.setup import SetupConfig
from benchtwin.config.vehicle import VehicleConfig
from benchtwin.errors import ConfigError
from benchtwin.studies.vehicle_family import FUELS, GEAR_COUNTS, random_family
from benchtwin.validation.families import FAMILIES

__all__ = ["AXIS_ROOTS", "CollectConfig", "RandomVehicles", "RangeSpec", "SweepConfig", "apply_axes", "load_sweep",
           "resolve_scenario"]

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


class RandomVehicles(StrictModel):
    """A random vehicle family: ``count`` vehicles drawn from ``seed`` (see the module docstring)."""

    count: int = Field(ge=1, le=10_000)
    seed: int = Field(ge=0)
    gears: list[int] = Field(default_factory=lambda: list(GEAR_COUNTS), min_length=1)
    fuels: list[str] = Field(default_factory=lambda: list(FUELS), min_length=1)

    @field_validator("gears")
    @classmethod
    def _gears(cls, v: list[int]) -> list[int]:
        if not set(v) <= set(GEAR_COUNTS):
            raise ValueError(f"gear counts {v}: allowed {', '.join(map(str, GEAR_COUNTS))}")
        return v

    @field_validator("fuels")
    @classmethod
    def _fuels(cls, v: list[str]) -> list[str]:
        if not set(v) <= set(FUELS):
            raise ValueError(f"fuels {v}: allowed {', '.join(FUELS)}")
        return v

    def values(self) -> list[str]:
        """The axis values: ``random-0`` .. ``random-<count-1>``."""
        return [f"random-{i}" for i in range(self.count)]


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
    #: whole-model axes: root -> axis value (as written) -> the model's JSON dump (filled by :func:`load_sweep`)
    _model_files: dict[str, dict[str, dict[str, Any]]] = PrivateAttr(default_factory=dict)
    #: vehicle axis values whose runs move the campaign's ramp-ups to the vehicle's gears (a random family's)
    _follow_gears: list[str] = PrivateAttr(default_factory=list)

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
        return {k: (v.values() if isinstance(v, (RangeSpec, RandomVehicles)) else list(v))
                for k, v in self.axes.items()}

    @property
    def model_files(self) -> dict[str, dict[str, dict[str, Any]]]:
        """Whole-model axes (``vehicle = [...]``): root -> value as written -> the loaded model's JSON dump."""
        return self._model_files

    @property
    def follow_gears(self) -> list[str]:
        """The vehicle axis values (a random family's) whose campaign follows the vehicle's gear count."""
        return self._follow_gears


def _parse_axis(path: str, values: Any) -> list[Any] | RangeSpec | RandomVehicles:
    """One axis: a non-empty list of values, a :class:`RangeSpec` or (``vehicle``) a :class:`RandomVehicles`
    (ValueError naming what is allowed)."""
    root = path.split(".", 1)[0]
    if path == "vehicle" and isinstance(values, (dict, RandomVehicles)):
        if isinstance(values, RandomVehicles):
            return values
        if set(values) != {"random"}:
            raise ValueError("a vehicle axis is a list of vehicle files or shipped names, or a table "
                             "{random = {count, seed, gears, fuels}}")
        try:
            return RandomVehicles.model_validate(values["random"])
        except ValidationError as exc:
            why = "; ".join(_why(e) for e in exc.errors())
            raise ValueError(f"random family: {why}") from None
    if path in AXIS_ROOTS:
        if not isinstance(values, list) or not values or not all(isinstance(v, str) and v for v in values):
            raise ValueError(f"a whole-model axis takes a non-empty list of {path} files or shipped names")
        if len(set(values)) != len(values):
            raise ValueError(f"the {path} files must not repeat")
        return values
    if root not in AXIS_ROOTS or "." not in path:
        raise ValueError(f"an axis must be one of {', '.join(AXIS_ROOTS)} (a list of files) or start with one "
                         "of them and name a key inside it (e.g. setup.telemetry.k_tel)")
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


def _why(e: Any) -> str:
    """One pydantic error as ``key: message`` (an unknown key named as such, with the keys allowed)."""
    loc = ".".join(map(str, e["loc"])) or "random"
    if e["type"] == "extra_forbidden":
        return f"unknown key {loc!r}; allowed: {', '.join(RandomVehicles.model_fields)}"
    if e["type"] == "missing":
        return f"key {loc!r} missing"
    return f"{loc}: {e['msg']}"


def _flatten_axes(node: Any, prefix: str, out: dict[str, Any]) -> None:
    """Nested TOML tables of dotted keys -> ``{"setup.telemetry.k_tel": [...]}``; a leaf is a list, a range
    table (``start``/``stop`` with ``num`` or ``step``) or a single value. ``vehicle.random`` (a random family)
    becomes the axis ``vehicle`` = ``{"random": ...}``."""
    if prefix == "vehicle" and isinstance(node, dict) and "random" in node:
        out["vehicle"] = {"random": node["random"]}
        node = {k: v for k, v in node.items() if k != "random"}
        if not node:
            return
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
    problems = []
    family = cfg.axes.get("vehicle")
    if isinstance(family, RandomVehicles):
        try:
            drawn = random_family(family.count, family.seed, gears=family.gears, fuels=family.fuels, base=vehicle)
        except (ValueError, ValidationError) as exc:
            problems.append(f"key 'axes.vehicle.random': the base vehicle {cfg.vehicle!r} cannot carry a drawn "
                            f"family ({str(exc).splitlines()[0]})")
            drawn = []
        cfg.model_files["vehicle"] = {f"random-{i}": v.model_dump(mode="json") for i, v in enumerate(drawn)}
        cfg.follow_gears.extend(family.values())
    for root in AXIS_ROOTS:
        if isinstance(cfg.axes.get(root), RandomVehicles):
            continue
        for value in cfg.axes.get(root, []):
            try:
                model = _LOADERS[root](resolve_scenario(f"{root}s", value, path.parent))
            except ConfigError as exc:
                problems.append(f"key 'axes.{root}' = {value!r}: {exc}")
                continue
            cfg.model_files.setdefault(root, {})[value] = model.model_dump(mode="json")
    problems += [p for axis in cfg.axes if axis not in AXIS_ROOTS and (p := _check_path(bases, axis))]
    if problems:
        raise ConfigError("\n".join(f"{path}: {p}" for p in problems))
    return cfg, vehicle, setup, campaign


_LOADERS = {"vehicle": load_vehicle, "setup": load_setup, "campaign": load_campaign}


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
    """The base models' JSON dumps with the axis values of one run set (a deep copy; nothing validated).

    A whole-model axis (``vehicle``: a file's name) takes its model from ``base["files"]`` (root -> value -> dump)
    before any dotted axis applies, whatever the order of the axes.
    """
    import copy

    out = copy.deepcopy(base)
    for root in AXIS_ROOTS:
        if root in params:
            out[root] = copy.deepcopy(base["files"][root][params[root]])
    for axis, value in params.items():
        if axis in AXIS_ROOTS:
            continue
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
