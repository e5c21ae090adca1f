"""The campaign file: the tests (Table 4 of the paper), the plant rate, the seed, the dyno and the driver.

Each ``[[tests]]`` entry has a ``kind`` and the settings of that kind. Tests run back to back; each
starts from the state the previous one left (speed, SOC, gear, temperatures).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, model_validator

from benchtwin.config._base import StrictModel, read_toml, scenario_path, validate_data
from benchtwin.errors import ConfigError

__all__ = [
    "AccelerationTest",
    "CampaignConfig",
    "CoastdownTest",
    "ConstantDriveTest",
    "CycleTest",
    "DecelerationTest",
    "DriverConfig",
    "DynoConfig",
    "NeutralBrakingTest",
    "RampDownTest",
    "RampUpTest",
    "TestConfig",
    "load_campaign",
]

#: the longest any one duration of a campaign may be (one day of plant time); the whole campaign is bounded
#: by the plant samples it needs (``benchtwin.emulator.MAX_PLANT_SAMPLES``)
MAX_DURATION_S = 86_400.0

#: a duration key: positive, finite, at most a day
Duration = Annotated[float, Field(gt=0, le=MAX_DURATION_S)]
#: a pedal position (accelerator or brake), percent of travel
Pedal = Annotated[float, Field(ge=0, le=100)]

HybridMode = Literal["hybrid", "electric", "e_save", "charge"]
Force = Literal["auto", "on", "off"]
Clutch = Literal["auto", "closed", "open"]

#: hybrid mode name -> the number in the Trace's ``hybrid_mode`` channel
HYBRID_MODES: dict[str, int] = {"hybrid": 0, "electric": 1, "e_save": 2, "charge": 3}


class DynoConfig(StrictModel):
    """The AWD chassis dyno: rollers, speed loop design, power limits."""

    roller_diameter_m: float = Field(default=1.2192, gt=0)
    roller_equivalent_mass_kg: float = Field(default=1150.0, gt=0)
    speed_loop_bandwidth_radps: float = Field(default=6.0, gt=0)
    speed_loop_damping: float = Field(default=1.0, gt=0)
    max_force_n: float = Field(default=12000.0, gt=0)
    max_power_w: float = Field(default=230000.0, gt=0)


class DriverConfig(StrictModel):
    """The robot driver's speed controller (PI on force, with feed-forward) and its preview."""

    bandwidth_radps: float = Field(default=1.5, gt=0)
    damping: float = Field(default=1.0, gt=0)
    preview_s: float = Field(default=0.4, ge=0, le=10)
    stop_decel_mps2: float = Field(default=1.5, gt=0, le=10)


class _TestBase(StrictModel):
    name: str | None = None
    mode: HybridMode = "hybrid"


class RampUpTest(_TestBase):
    """Dyno at constant speed, gear held, accelerator (and brake) pedal steps with holds."""

    kind: Literal["ramp_up"]
    gear: int = Field(ge=1)
    speed_kmh: float = Field(gt=0, le=200)
    pedal_steps_pct: list[Pedal] = Field(min_length=1)
    brake_steps_pct: list[Pedal] = Field(default_factory=list)
    step_hold_s: Duration = 8.0
    lead_in_s: Duration = 15.0
    engine: Force = "auto"
    k0: Clutch = "auto"
    lockup: Clutch = "closed"


class ConstantDriveTest(_TestBase):
    """Driver holds a constant speed (road-load mode) until a displayed SOC is reached or time runs out."""

    kind: Literal["constant_drive"]
    speed_kmh: float = Field(gt=0, le=200)
    gear: int = Field(default=0, ge=0, description="0: automatic")
    approach_s: Duration = 30.0
    max_duration_s: Duration
    end_displayed_soc_pct: float | None = Field(default=None, ge=0, le=100)


class AccelerationTest(_TestBase):
    """From standstill at a constant pedal until ``end_speed_kmh`` (or timeout), then the driver stops."""

    kind: Literal["acceleration"]
    pedal_pct: float = Field(gt=0, le=100)
    end_speed_kmh: float = Field(default=130.0, gt=0, le=250)
    max_duration_s: Duration = 150.0


class DecelerationTest(_TestBase):
    """Driver accelerates to a speed, then follows a constant-deceleration ramp to standstill (road-load mode)."""

    kind: Literal["deceleration"]
    start_speed_kmh: float = Field(gt=0, le=200)
    decel_mps2: float = Field(gt=0, le=6)
    approach_s: Duration = 40.0


class RampDownTest(_TestBase):
    """Dyno ramps the speed down slowly while the pedal is held constant (downshift lines)."""

    kind: Literal["ramp_down"]
    pedal_pct: float = Field(ge=0, le=100)
    start_speed_kmh: float = Field(default=130.0, gt=0, le=200)
    end_speed_kmh: float = Field(default=0.0, ge=0)
    rate_kmh_per_s: float = Field(default=1.0, gt=0)
    lead_in_s: Duration = 25.0

    @model_validator(mode="after")
    def _downwards(self) -> RampDownTest:
        if not self.end_speed_kmh < self.start_speed_kmh:
            raise ValueError(f"end_speed_kmh ({self.end_speed_kmh}) must be below start_speed_kmh "
                             f"({self.start_speed_kmh}): the dyno ramps down")
        return self


class NeutralBrakingTest(_TestBase):
    """Gearbox in neutral, dyno at constant speed, brake pedal steps (brake gains)."""

    kind: Literal["neutral_braking"]
    speed_kmh: float = Field(gt=0, le=200)
    brake_steps_pct: list[Pedal] = Field(min_length=1)
    step_hold_s: Duration = 5.0
    lead_in_s: Duration = 15.0


class CycleTest(_TestBase):
    """A driving cycle in road-load mode; the driver follows the speed trace."""

    kind: Literal["cycle"]
    cycle: str = "wltc_class3b.csv"
    from_s: float = Field(default=0.0, ge=0, le=MAX_DURATION_S, description="run only part of the cycle: start time")
    to_s: float | None = Field(default=None, gt=0, le=MAX_DURATION_S,
                               description="end time (default: the end of the cycle)")

    @model_validator(mode="after")
    def _window(self) -> CycleTest:
        if self.to_s is not None and self.to_s <= self.from_s:
            raise ValueError("to_s must be after from_s")
        return self


class CoastdownTest(_TestBase):
    """Driver reaches ``start_speed_kmh``, then neutral, no pedals, road-load mode, until standstill."""

    kind: Literal["coastdown"]
    start_speed_kmh: float = Field(default=130.0, gt=0, le=200)
    approach_s: Duration = 60.0
    max_duration_s: Duration = 400.0


TestConfig = Annotated[
    RampUpTest | ConstantDriveTest | AccelerationTest | DecelerationTest | RampDownTest | NeutralBrakingTest
    | CycleTest | CoastdownTest,
    Field(discriminator="kind"),
]


class CampaignConfig(StrictModel):
    """A test campaign: tests in order, plant and output rate, seed, initial state, dyno and driver."""

    name: str
    seed: int = Field(ge=0)
    plant_rate_hz: float = Field(default=100.0, ge=10.0, le=2000.0)
    output_rate_hz: float | None = Field(default=None, gt=0)
    initial_displayed_soc_pct: float = Field(default=90.0, ge=0, le=100)
    ambient_degc: float = Field(default=23.0, ge=-40, le=60)
    dyno: DynoConfig = Field(default_factory=DynoConfig)
    driver: DriverConfig = Field(default_factory=DriverConfig)
    tests: list[TestConfig] = Field(min_length=1)
    #: run the test list this many times back to back (an endurance campaign); expanded on load: ``tests`` then
    #: holds every run, the first pass with the names as written, pass ``r`` (2, 3, ...) with ``_r<r>`` appended
    repeat: int = Field(default=1, ge=1, le=1000)

    @model_validator(mode="before")
    @classmethod
    def _repeat(cls, data: Any) -> Any:
        if not isinstance(data, dict) or not isinstance(data.get("repeat", 1), int) or data.get("repeat", 1) <= 1:
            return data
        tests = data.get("tests")
        if not isinstance(tests, list) or not all(isinstance(t, dict) for t in tests):
            return data  # the field validators say what is wrong
        if data["repeat"] > 1000:
            return data
        out = [dict(t) for t in tests]
        for r in range(2, data["repeat"] + 1):
            for k, t in enumerate(tests):
                name = t.get("name") or f"{t.get('kind')}_{k:02d}"
                out.append({**t, "name": f"{name}_r{r}"})
        return {**data, "tests": out, "repeat": 1}

    @model_validator(mode="after")
    def _rates(self) -> CampaignConfig:
        if self.output_rate_hz is not None:
            ratio = self.plant_rate_hz / self.output_rate_hz
            if ratio < 1 or abs(ratio - round(ratio)) > 1e-9:
                raise ValueError("output_rate_hz must divide plant_rate_hz (e.g. 100 and 1)")
        return self


def load_campaign(path: str | Path) -> CampaignConfig:
    """Load a campaign file; a bare name like ``quick.toml`` is looked up in the shipped campaigns.

    A file may take its tests from another campaign file with ``tests_from = "paper.toml"`` (a path relative
    to the file, or a shipped campaign's name) instead of listing them, e.g. to repeat them (``repeat``).

    Raises
    ------
    ConfigError
        The file is missing or invalid; the message names the file, the key and what is allowed.
    """
    p = Path(path)
    if not p.exists() and p.parent == Path("."):
        p = scenario_path("campaigns", p.name)
    data = read_toml(p)
    source = data.pop("tests_from", None)
    if source is not None:
        if "tests" in data:
            raise ConfigError(f"{p}: give either 'tests' or 'tests_from', not both")
        if not isinstance(source, str):
            raise ConfigError(f"{p}: key 'tests_from' must be a campaign file name, got {source!r}")
        src = p.parent / source
        if not src.exists() and Path(source).parent == Path("."):
            src = scenario_path("campaigns", source)
        if src.resolve() == p.resolve():
            raise ConfigError(f"{p}: key 'tests_from' names the file itself")
        if not src.exists():
            raise ConfigError(f"{p}: key 'tests_from': no campaign file {source!r} (next to it or shipped)")
        data["tests"] = load_campaign(src).model_dump(exclude_none=True)["tests"]
    return validate_data(CampaignConfig, data, str(p))
