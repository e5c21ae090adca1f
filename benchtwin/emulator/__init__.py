"""The plant: a P2 diesel PHEV on an AWD chassis dyno, driven by a test campaign.

Public API::

    from benchtwin.config import load_vehicle, load_campaign
    from benchtwin.emulator import simulate_campaign
    trace = simulate_campaign(load_vehicle(), load_campaign("wltc.toml"))

How it is built
---------------
- The stepping loop (:mod:`benchtwin.emulator.plant`) runs numba-compiled steps over preallocated arrays,
  each step a fixed order of pure sub-steps (``steps_*`` modules) over the model forms of
  :mod:`benchtwin.emulator.models`; tests run block by block (:mod:`benchtwin.emulator.protocols`
  precomputes per-step commands) and may end early on an in-loop condition (speed reached, displayed SOC reached).
- Controllers (driver PI on force with feed-forward, dyno speed PI) are designed for a pure mass and
  discretised with python-control's ``c2d`` (Tustin; :func:`benchtwin.lti.c2d`); their coefficients feed the loop
  (:mod:`benchtwin.emulator.params`).
- Thermal states (:mod:`benchtwin.emulator.thermal`) and the random 12 V load profile are computed outside
  the loop. Every random draw comes from the campaign seed, split per subsystem with
  :class:`numpy.random.SeedSequence`.

Model choices (the forms of docs/models.md are followed exactly)
----------------------------------------------------------------
- Engine, motor, torque converter, gearbox, battery and brakes use the paper's equations; see
  docs/models.md. Engine start: a fixed fuel mass; the engine runs up on its own with K0 open and the K0
  closes at synchronous speed (momentum kept, slip energy booked).
- Shifts: the target gear changes at once, the actual gear after the actuation delay. With the lock-up
  closed, the on-coming clutch exchanges momentum between the pump side and the vehicle; with it open,
  the turbine speed moves to the new ratio over the inertia phase (``shift_inertia_phase_s``).
- Lock-up: capacity ramps up while engaging and the clutch sticks once the torque needed to hold is within
  capacity. Traction / gearbox-input torque limiter on the driver's demand (``max_wheel_force_n``).
- Dyno: road-load mode simulates the test mass and applies target minus the vehicle's parasitic loss
  (so ``-m dv/dt`` on a coastdown is F0 + F1 v + F2 v^2); speed-controlled mode holds the roller speed
  with the rollers' own inertia. Roller forces are reported per axle.
- Energy: an explicit ledger (``trace.meta["energy_ledger_j"]``) integrates every input, loss, work and
  stored term at the step's mid-point speeds; :func:`energy_balance` sums it.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from benchtwin.config.campaign import CampaignConfig
from benchtwin.config.vehicle import LowVoltageConfig, VehicleConfig
from benchtwin.emulator.params import (
    C_ENG,
    C_HMODE,
    C_K0,
    C_LVLOAD,
    L_KE0,
    L_KE1,
    LEDGER_INPUTS,
    LEDGER_NAMES,
    NL,
    NO,
    O_A,
    O_BRAKE,
    O_DSET,
    O_DSOC,
    O_EON,
    O_FFRONT,
    O_FREAR,
    O_FRL,
    O_FUEL,
    O_GA,
    O_GT,
    O_HMODE,
    O_IB,
    O_ILV,
    O_ILVB,
    O_K0,
    O_LU,
    O_OCV,
    O_PEDAL,
    O_PEL,
    O_PF,
    O_PMC,
    O_PR,
    O_Q_BATT,
    O_Q_ENGINE,
    O_Q_MOTOR,
    O_SOC,
    O_T_BATT,
    O_T_COOLANT,
    O_T_OIL,
    O_TBF,
    O_TBR,
    O_TE,
    O_TIN,
    O_TM,
    O_TOUT,
    O_TP,
    O_TT,
    O_V,
    O_VB,
    O_VDYN,
    O_VLV,
    O_WE,
    O_WP,
    O_WS,
    O_WT,
    O_WW,
    O_X,
    P_MASS_KG,
    PlantTables,
    build_tables,
)
from benchtwin.emulator.plant import N_STATE, S_STEP, S_TIME_S, kinetic_energy, run_plant
from benchtwin.emulator.protocols import Protocol, build_protocol, lazy_protocol
from benchtwin.emulator.thermal import simulate_thermal, thermal_state
from benchtwin.errors import ConfigError, SimulationError
from benchtwin.segments import Segment
from benchtwin.trace import TRACE_CHANNELS, Trace

__all__ = ["ABSENT_CONVENTIONAL", "absent_channels", "check_campaign", "conventional_tests", "energy_balance",
           "iter_campaign", "lv_load_profile", "needs_motor", "simulate_campaign"]

#: Trace channel -> loop output column
_DIRECT: dict[str, int] = {
    "vehicle_speed_mps": O_V, "vehicle_accel_mps2": O_A, "distance_m": O_X, "dyno_set_speed_mps": O_DSET,
    "dyno_speed_mps": O_VDYN, "dyno_force_front_n": O_FFRONT, "dyno_force_rear_n": O_FREAR,
    "road_load_force_n": O_FRL, "pedal_pct": O_PEDAL, "brake_pedal_pct": O_BRAKE, "hybrid_mode": O_HMODE,
    "engine_speed_radps": O_WE, "engine_torque_nm": O_TE, "engine_on": O_EON, "fuel_mass_flow_kgps": O_FUEL,
    "k0_closed": O_K0, "em_speed_radps": O_WP, "em_torque_nm": O_TM, "em_elec_power_w": O_PEL,
    "hpcu_hv_current_a": O_IB, "hpcu_hv_voltage_v": O_VB, "tc_pump_torque_nm": O_TP,
    "tc_turbine_speed_radps": O_WT, "tc_turbine_torque_nm": O_TT, "lockup_closed": O_LU, "gear_target": O_GT,
    "gear_actual": O_GA, "trans_input_torque_nm": O_TIN, "shaft_torque_nm": O_TOUT, "shaft_speed_radps": O_WS,
    "wheel_speed_radps": O_WW, "brake_pressure_fl_pa": O_PF, "brake_pressure_fr_pa": O_PF,
    "brake_pressure_rl_pa": O_PR, "brake_pressure_rr_pa": O_PR, "master_cylinder_pa": O_PMC,
    "brake_torque_front_nm": O_TBF, "brake_torque_rear_nm": O_TBR, "battery_current_a": O_IB,
    "battery_voltage_v": O_VB, "battery_ocv_v": O_OCV, "battery_soc_frac": O_SOC, "displayed_soc_pct": O_DSOC,
    "dcdc_lv_current_a": O_ILV, "dcdc_lv_voltage_v": O_VLV, "lv_battery_current_a": O_ILVB,
    "lv_battery_voltage_v": O_VLV,
}

#: Trace channels a conventional car does not have (no motor, no HV pack, no HPCU, no K0: the engine is the
#: converter's pump, whose speed the engine speed is): NaN in its Trace, named in ``meta["absent_channels"]``
ABSENT_CONVENTIONAL: tuple[str, ...] = (
    "k0_closed", "em_speed_radps", "em_torque_nm", "em_elec_power_w", "hpcu_hv_current_a", "hpcu_hv_voltage_v",
    "battery_current_a", "battery_voltage_v", "battery_ocv_v", "battery_soc_frac", "displayed_soc_pct",
    "battery_temp_degc", "battery_coolant_in_degc", "battery_coolant_out_degc", "hpcu_coolant_in_degc",
    "hpcu_coolant_out_degc", "motor_coolant_in_degc", "motor_coolant_out_degc",
)


def absent_channels(vehicle: VehicleConfig) -> tuple[str, ...]:
    """The Trace channels the plant of ``vehicle`` has no signal for (NaN in its Trace; the setup drops them)."""
    return () if vehicle.has_motor else ABSENT_CONVENTIONAL

#: what a test asks that only the P2 motor and its pack can do: refused on a conventional car
_MOTOR_ONLY_MODES = {"electric": "drives on the motor alone", "e_save": "holds the pack's charge",
                     "charge": "charges the pack"}

#: settings keys ending in ``_s`` that are durations, not times on the test's clock
_DURATION_KEYS = frozenset({"step_hold_s", "lead_in_s", "approach_s", "max_duration_s"})

#: subsystems that draw random numbers, in the order of SeedSequence.spawn
RANDOM_SUBSYSTEMS: tuple[str, ...] = ("lv_loads",)


def lv_load_profile(cfg: LowVoltageConfig, n_steps: int, dt: float, rng: np.random.Generator) -> np.ndarray:
    """12 V load power per plant step: base load plus a fan and a pump switching on and off at random times.

    The fan runs at a random duty level (30-100 %) each time it switches on.

    Parameters
    ----------
    cfg:
        Low-voltage parameters (loads, mean switching interval).
    n_steps, dt:
        Number of plant steps and plant step, s.
    rng:
        Generator seeded from the campaign seed (the ``lv_loads`` child).

    Returns
    -------
    numpy.ndarray
        Load power, W.
    """
    return _LvLoad(cfg, n_steps, dt, rng).steps(0, n_steps)


class _LvLoad:
    """The 12 V load's switching times (drawn once for the whole campaign), evaluated over any range of steps."""

    def __init__(self, cfg: LowVoltageConfig, n_steps: int, dt: float, rng: np.random.Generator) -> None:
        duration = n_steps * dt
        self.base, self.dt = cfg.base_load_w, dt
        self.loads = []
        for power, duty in ((cfg.fan_load_w, True), (cfg.pump_load_w, False)):
            n_sw = int(duration / cfg.mean_switch_interval_s * 2) + 4
            times = np.cumsum(rng.exponential(cfg.mean_switch_interval_s, size=n_sw))
            levels = rng.uniform(0.3, 1.0, size=n_sw) if duty else np.ones(n_sw)
            on = (np.arange(n_sw) % 2 == 1).astype(float) * levels
            self.loads.append((power, times, on))

    def steps(self, k0: int, k1: int) -> np.ndarray:
        """Load power of plant steps ``k0 .. k1 - 1``, W."""
        load = np.full(k1 - k0, self.base)
        t = np.arange(k0, k1) * self.dt
        for power, times, on in self.loads:
            idx = np.minimum(np.searchsorted(times, t, side="right"), on.size - 1)
            load += power * on[idx]
        return load


def _initial_state(tables: PlantTables, vehicle: VehicleConfig, campaign: CampaignConfig) -> np.ndarray:
    from benchtwin.emulator import plant as pl

    st = np.zeros(N_STATE)
    b = vehicle.battery
    if b is not None:
        st[pl.S_SOC_FRAC] = (b.soc_min_frac
                             + campaign.initial_displayed_soc_pct / 100.0 * (b.soc_max_frac - b.soc_min_frac))
    else:  # conventional: the engine idles with the converter's pump (K0 "closed": one shaft), no pack
        st[pl.S_SOC_FRAC] = 0.5
        st[pl.S_ENGINE_ON] = st[pl.S_K0_CLOSED] = 1.0
        st[pl.S_PUMP_SPEED_RADPS] = st[pl.S_ENGINE_SPEED_RADPS] = vehicle.engine.idle_speed_rpm * np.pi / 30.0
    st[pl.S_LV_SOC_FRAC] = vehicle.low_voltage.battery_initial_soc_frac
    st[pl.S_GEAR] = 1
    st[pl.S_GEAR_TARGET] = 1
    st[pl.S_SEGMENT] = -1
    st[pl.S_EFF_MASS_KG] = tables.p[P_MASS_KG]
    st[pl.S_ESAVE_SOC_PCT] = campaign.initial_displayed_soc_pct
    hf = vehicle.high_fidelity
    if hf is not None:
        st[pl.S_BATTERY_DEGC] = hf.battery.initial_temp_degc
        st[pl.S_COOLANT_DEGC] = hf.engine.initial_coolant_degc
        st[pl.S_OIL_DEGC] = hf.transmission.initial_oil_degc
    return st


def check_campaign(vehicle: VehicleConfig, campaign: CampaignConfig) -> None:
    """Check that the campaign's tests fit the vehicle (gears that exist, machine speeds within limits).

    Raises
    ------
    ConfigError
        One line per problem, naming the test, the key and what is allowed.
    """
    problems = []
    n = vehicle.n_gears
    motor_rpm = vehicle.motor.max_speed_rpm if vehicle.motor is not None else vehicle.engine.max_speed_rpm
    max_rpm_any = min(motor_rpm, vehicle.engine.max_speed_rpm)
    for k, test in enumerate(campaign.tests):
        # with K0 held open and the engine held off only the motor spins with the gearbox input
        electric = getattr(test, "k0", "auto") == "open" and getattr(test, "engine", "auto") == "off"
        max_rpm = motor_rpm if electric else max_rpm_any
        gear = getattr(test, "gear", 0)
        label = f"campaign {campaign.name!r}: tests[{k}] ({test.name or test.kind})"
        if not vehicle.has_motor:
            why = needs_motor(test)
            if why:
                problems.append(f"{label}: {why}, and vehicle {vehicle.name!r} (layout 'conventional') has no motor "
                                f"or HV pack; drop the test, or use conventional_tests() / campaigns/conventional.toml")
                continue
        if gear > n:
            problems.append(f"{label}: key 'gear' = {gear}: the vehicle has {n} gears (1..{n})")
            continue
        speed = getattr(test, "speed_kmh", None)
        if gear > 0 and speed is not None:
            rpm = (speed / 3.6 / vehicle.specs.wheel_radius_m * vehicle.specs.final_drive_ratio
                   * vehicle.specs.gear_ratios[gear - 1] * 30.0 / np.pi)
            if rpm > max_rpm:
                problems.append(f"{label}: key 'speed_kmh' = {speed}: {rpm:.0f} rpm in gear {gear} exceeds "
                                f"{max_rpm:.0f} rpm; use a lower speed or a higher gear")
    if problems:
        raise ConfigError("\n".join(problems))


def needs_motor(test: object) -> str:
    """Why a campaign test needs the P2 motor or its HV pack ("" if a conventional car can drive it).

    The rule: a test that holds the engine off or K0 open, runs in a mode that drives on the motor, holds or
    charges the pack (electric, e-save, charge), or ends on a displayed SOC needs them; a coastdown and
    neutral braking (gearbox in neutral, no traction) never do, whatever their mode says.
    """
    kind = getattr(test, "kind", "")
    if getattr(test, "engine", "auto") == "off":
        return "it holds the engine off (engine = \"off\")"
    if getattr(test, "k0", "auto") == "open":
        return "it holds K0 open (k0 = \"open\"): only the motor drives"
    if getattr(test, "end_displayed_soc_pct", None) is not None:
        return "it ends on the pack's displayed SOC (end_displayed_soc_pct)"
    mode = getattr(test, "mode", "hybrid")
    if kind not in ("coastdown", "neutral_braking") and mode in _MOTOR_ONLY_MODES:
        return f"its mode {mode!r} {_MOTOR_ONLY_MODES[mode]}"
    return ""


def conventional_tests(campaign: CampaignConfig) -> tuple[CampaignConfig, dict[str, str]]:
    """The campaign's tests a conventional car can drive (:func:`needs_motor`'s rule), and those dropped with why.

    Parameters
    ----------
    campaign:
        A campaign written for the P2 PHEV (e.g. the paper's).

    Returns
    -------
    tuple
        The campaign with the kept tests (same seed, rates, dyno and driver; its name suffixed ``:conventional``
        when a test was dropped) and ``{test name: reason}`` of the dropped ones.

    Raises
    ------
    ConfigError
        If no test is left.
    """
    dropped = {t.name or t.kind: why for t in campaign.tests if (why := needs_motor(t))}
    kept = [t for t in campaign.tests if not needs_motor(t)]
    if not kept:
        raise ConfigError(f"campaign {campaign.name!r}: no test a conventional car can drive (each needs the motor "
                          f"or the pack)")
    if not dropped:
        return campaign, dropped
    return campaign.model_copy(update={"tests": kept, "name": f"{campaign.name}:conventional"}), dropped


@dataclass
class _Run:
    """A campaign being simulated: its tables, per-step commands and the plant's state (carried across tests)."""

    tables: PlantTables
    dt: float
    decim: int
    proto: Protocol
    lv_load: _LvLoad
    st: np.ndarray
    led: np.ndarray
    thermal: np.ndarray
    conventional: bool = False

    @property
    def n_steps(self) -> int:
        return self.proto.n_steps

    @property
    def n_tests(self) -> int:
        return len(self.proto.segments)

    def run_block(self, k: int, out: np.ndarray, row0: int) -> tuple[int, Segment]:
        """Run test ``k`` writing its output rows from ``row0``; return the rows written and its segment."""
        block, seg = self.proto.block(k), self.proto.segments[k]
        k0 = int(self.st[S_STEP])
        block[C_LVLOAD] = self.lv_load.steps(k0, k0 + block.shape[1])
        if self.conventional:  # one shaft from the engine to the pump, the engine always running
            block[C_ENG], block[C_K0], block[C_HMODE] = 1.0, 1.0, 0.0
        t_start = self.st[S_TIME_S]
        written, steps = run_plant(self.tables, block, self.decim, self.st, out, row0, self.led)
        settings = {key: (float(v + t_start) if key.endswith("_s") and key not in _DURATION_KEYS else v)
                    for key, v in seg.settings.items()}
        return written, Segment(float(t_start), float(t_start + steps * self.dt), seg.kind, seg.name, settings)


def _start(vehicle: VehicleConfig, campaign: CampaignConfig, *, lazy: bool = False) -> _Run:
    check_campaign(vehicle, campaign)
    tables = build_tables(vehicle, campaign)
    dt = 1.0 / campaign.plant_rate_hz
    proto = lazy_protocol(campaign) if lazy else build_protocol(campaign)
    children = np.random.SeedSequence(campaign.seed).spawn(len(RANDOM_SUBSYSTEMS))
    rngs = {name: np.random.default_rng(child) for name, child in zip(RANDOM_SUBSYSTEMS, children, strict=True)}
    lv_load = _LvLoad(vehicle.low_voltage, proto.n_steps, dt, rngs["lv_loads"])
    decim = 1 if campaign.output_rate_hz is None else round(campaign.plant_rate_hz / campaign.output_rate_hz)
    st = _initial_state(tables, vehicle, campaign)
    led = np.zeros(NL)
    led[L_KE0] = kinetic_energy(tables.p, st)
    return _Run(tables, dt, decim, proto, lv_load, st, led,
                thermal_state(vehicle.thermal, campaign.ambient_degc), conventional=not vehicle.has_motor)


def _trace_of(run: _Run, vehicle: VehicleConfig, campaign: CampaignConfig, out: np.ndarray, row0: int,
              segments: list[Segment]) -> Trace:
    """The Trace of output rows ``out`` (the campaign's rows from ``row0``); advances the thermal state."""
    if not np.all(np.isfinite(out[[O_V, O_WP, O_IB, O_SOC] if vehicle.has_motor else [O_V, O_WP]])):
        raise SimulationError(f"campaign {campaign.name!r}: the plant left its physical domain (non-finite states)")
    dt_out = run.dt * run.decim
    time_s = (row0 + np.arange(out.shape[1])) * dt_out
    channels: dict[str, np.ndarray] = {}
    used: set[int] = set()
    for name, col in _DIRECT.items():  # views on the output rows; a row shared by two channels is copied once
        channels[name] = out[col] if col not in used else out[col].copy()
        used.add(col)
    q_trans = out[O_TIN] * out[O_WT] - out[O_TOUT] * out[O_WS]  # gearbox input minus output power
    channels.update(simulate_thermal(vehicle.thermal, dt_out, out[O_Q_ENGINE], out[O_Q_MOTOR],
                                     out[O_Q_BATT], campaign.ambient_degc, run.thermal, q_trans))
    if vehicle.high_fidelity is not None:
        # the high-fidelity plant carries the cell and coolant temperatures it feeds back: the thermocouples
        # read those states (the coolant inlet keeps the post-processed radiator drop)
        drop = channels["engine_coolant_out_degc"] - channels["engine_coolant_in_degc"]
        channels["battery_temp_degc"] = out[O_T_BATT].copy()
        channels["engine_coolant_out_degc"] = out[O_T_COOLANT].copy()
        channels["engine_coolant_in_degc"] = out[O_T_COOLANT] - drop
        channels["gearbox_oil_degc"] = out[O_T_OIL].copy()
    missing = set(TRACE_CHANNELS) - set(channels)
    if missing:  # pragma: no cover - guarded by the tests
        raise SimulationError(f"emulator does not produce {sorted(missing)}")
    absent = absent_channels(vehicle)
    for name in absent:  # the plant has no such signal: NaN, not a placeholder value a sensor could pass on
        channels[name] = np.full(out.shape[1], np.nan)
    ordered = {name: channels[name] for name in TRACE_CHANNELS}
    led = run.led.copy()
    led[L_KE1] = kinetic_energy(run.tables.p, run.st)
    meta = {
        "vehicle": vehicle.name,
        "campaign": campaign.name,
        "seed": campaign.seed,
        "plant_rate_hz": campaign.plant_rate_hz,
        "output_rate_hz": campaign.plant_rate_hz / run.decim,
        "energy_ledger_j": {name: float(led[k]) for k, name in enumerate(LEDGER_NAMES)},
    }
    if absent:
        meta["layout"] = vehicle.layout
        meta["absent_channels"] = list(absent)
    return Trace(time_s, ordered, segments, meta)


def simulate_campaign(vehicle: VehicleConfig, campaign: CampaignConfig, *, progress: bool = False) -> Trace:
    """Run every test of ``campaign`` on ``vehicle`` and return the truth as a Trace.

    Parameters
    ----------
    vehicle:
        True parameters of the plant.
    campaign:
        Tests, plant and output rate, seed, dyno and driver settings.
    progress:
        Show a tqdm progress bar over simulated time.

    Returns
    -------
    Trace
        Every channel of :data:`~benchtwin.trace.TRACE_CHANNELS` at the output rate, the segment table
        (one Segment per test) and meta data (vehicle, seed, rates, energy ledger in J).

    Raises
    ------
    SimulationError
        If the plant leaves its physical domain (non-finite states).
    """
    run = _start(vehicle, campaign)
    n_max = run.n_steps
    out = np.empty((NO, (n_max + run.decim - 1) // run.decim + 1))  # one contiguous row per channel
    bar = None
    if progress:
        from tqdm import tqdm

        # a fixed total: the plant seconds of every test's full block; a test that ends early (its end
        # condition reached) still advances the bar by its whole block, so the total never moves
        bar = tqdm(total=round(n_max * run.dt), unit="s sim", desc=campaign.name, leave=False)
    done = 0
    rows = 0
    segments: list[Segment] = []
    try:
        for k in range(run.n_tests):
            written, seg = run.run_block(k, out, rows)
            rows += written
            segments.append(seg)
            done += run.proto.steps[k]
            if bar is not None:
                bar.update(round(done * run.dt) - bar.n)
    finally:
        if bar is not None:
            bar.close()
    out = out[:, :rows] if rows > 0.8 * out.shape[1] else out[:, :rows].copy()  # release an unused tail
    return _trace_of(run, vehicle, campaign, out, 0, segments)


def iter_campaign(vehicle: VehicleConfig, campaign: CampaignConfig) -> Iterator[Trace]:
    """The campaign's truth test by test: one Trace per test, on the campaign's clock.

    The plant's state (and the thermal lumps', and the 12 V load profile's draws) runs on from one test to the
    next, so the chunks put end to end are :func:`simulate_campaign`'s Trace bit for bit; only one test's
    output rows are held at a time. Each chunk's ``meta["energy_ledger_j"]`` is the ledger from the campaign
    start to the chunk's end. Each test's commands are built when it starts, so a campaign may be longer than one
    Trace may hold (:data:`~benchtwin.emulator.protocols.MAX_PLANT_SAMPLES` bounds each test, not their sum).

    Raises
    ------
    ConfigError
        A test needs more plant steps than :data:`~benchtwin.emulator.protocols.MAX_PLANT_SAMPLES`.
    SimulationError
        If the plant leaves its physical domain (non-finite states).
    """
    run = _start(vehicle, campaign, lazy=True)
    rows = 0
    for k in range(run.n_tests):
        out = np.empty((NO, (run.proto.steps[k] + run.decim - 1) // run.decim + 1))
        written, seg = run.run_block(k, out, 0)
        yield _trace_of(run, vehicle, campaign, out[:, :written], rows, [seg])
        rows += written


def energy_balance(ledger: dict[str, float]) -> dict[str, float]:
    """Sum the energy ledger of a Trace's meta: inputs, outputs (losses + work + stored) and the residual.

    Parameters
    ----------
    ledger:
        ``trace.meta["energy_ledger_j"]``.

    Returns
    -------
    dict
        ``inputs_j``, ``outputs_j``, ``residual_j`` and ``residual_frac`` (residual over inputs).
    """
    inputs = sum(ledger[k] for k in LEDGER_INPUTS)
    losses = sum(v for k, v in ledger.items() if k not in LEDGER_INPUTS and not k.startswith("kinetic_"))
    stored = ledger["kinetic_end"] - ledger["kinetic_start"]
    outputs = losses + stored
    residual = inputs - outputs
    scale = max(abs(ledger["fuel_chemical"]) + abs(ledger["hv_battery_chemical"]), 1.0)
    return {"inputs_j": inputs, "outputs_j": outputs, "residual_j": residual, "residual_frac": residual / scale}
