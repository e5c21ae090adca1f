"""The identification orchestrator: every method whose channels are present, in dependency order.

:func:`identify_all` runs the methods of the paper on one Recording and the public VehicleSpecs:

=================  ===========================================  =================================
method             needs (roles)                                fits
=================  ===========================================  =================================
transmission       vehicle speed, shaft torque, gear, lock-up,  ``transmission.gear<g>[_coast]``
                   K0; motor and engine torque (P2) or engine
                   speed and torque (conventional)
motor              motor speed/torque, HPCU V/I (or the pack's  ``motor.*``
                   V/I when the HPCU's are not logged)
engine             engine speed/torque, fuel flow               ``engine.*``
road_load          vehicle speed (coastdown)                    ``road_load.*``
brakes             four caliper pressures, dyno forces          ``brakes.*``
battery            battery V/I, displayed SOC (eq. 30)          ``battery``
battery_map_free   battery V/I (OCV/R without maps, R0 steps,   ``battery_map_free``, ``battery_r0``,
                   OCV at the end of long rests)                ``battery_ocv_rest``
torque_converter   speeds, torques, gear, lock-up (uses the     ``torque_converter.*``
                   transmission result of each gear)
shifts             target and actual gear, speed, pedal         ``shifts.up_1_2`` ..., ``shifts.actuation``
reduction_gear     motor speed/torque, speed, dyno forces (a    ``reduction_gear``
                   BEV's one fixed ratio; run by default for
                   the ``bev`` layout only)
=================  ===========================================  =================================

A method whose roles are missing, or whose spec keys the vehicle's layout does not have (a BEV has no engine
displacement or gear list, a conventional car no pack or rotor), is *skipped* (listed in ``meta['skipped']``
with the missing roles or keys);
a method that runs but cannot give trustworthy numbers records its error message in ``errors``
instead of stopping the run.
"""

from __future__ import annotations

import inspect
import logging
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, replace
from typing import Any

from threadpoolctl import threadpool_limits

from benchtwin.config.specs import VehicleSpecs
from benchtwin.errors import BenchtwinError, DataError, IdentificationError
from benchtwin.identification import battery_rc
from benchtwin.identification._fit import FitResult, IdentificationResult
from benchtwin.identification._reuse import shared_output, values_only
from benchtwin.identification._signals import STATE_ROLES
from benchtwin.identification.battery import identify_battery
from benchtwin.identification.battery_map_free import (
    identify_battery_map_free,
    identify_battery_ocv_rest,
    identify_battery_r0_steps,
)
from benchtwin.identification.brakes import identify_brakes
from benchtwin.identification.engine import identify_engine
from benchtwin.identification.engine_cold import COOLANT_ROLE
from benchtwin.identification.keys import FitKey
from benchtwin.identification.motor import identify_motor
from benchtwin.identification.reduction_gear import identify_reduction_gear
from benchtwin.identification.road_load import identify_road_load
from benchtwin.identification.shifts import identify_shift_thresholds, shift_fits
from benchtwin.identification.stuck import stuck_channels
from benchtwin.identification.torque_converter import identify_torque_converter
from benchtwin.identification.torque_converter_gearbox import converter_with_gearbox as _torque_converter
from benchtwin.identification.transmission import OIL_ROLE, identify_transmission
from benchtwin.identification.type_b_share import TypeBShare
from benchtwin.identification.uncertainty import propagate_type_b
from benchtwin.recording import Recording

__all__ = ["METHODS", "Method", "identify_all", "method_option_defaults", "method_options", "transmission_table"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Method:
    """One identification method of the orchestrator.

    Attributes
    ----------
    name:
        Method name (also the prefix of its fits).
    roles:
        Roles that must all be present.
    any_roles:
        Of these, at least one must be present (empty: no such condition).
    needs_specs:
        Whether the method needs the VehicleSpecs.
    spec_keys:
        VehicleSpecs keys the method needs (a layout without them, e.g. a BEV's gear ratios, skips it).
    alternatives:
        Sets of roles of which at least one whole set must be present (the same quantity measured where
        the layout has it, e.g. the motor's DC input at the HPCU or at the pack); empty: no such condition.
    optional_roles:
        Roles the method also reads when the Recording has them (e.g. the gearbox oil temperature for the
        transmission's temperature-dependent drag); their declared errors enter the type B budget.
    run:
        ``run(rec, specs, result_so_far, options) -> FitResult | dict[str, FitResult] | IdentificationResult``.
    """

    name: str
    roles: tuple[str, ...]
    run: Callable[[Recording, VehicleSpecs | None, IdentificationResult, Mapping[str, Any]], Any]
    needs_specs: bool = True
    any_roles: tuple[str, ...] = ()
    spec_keys: tuple[str, ...] = ()
    alternatives: tuple[tuple[str, ...], ...] = ()
    optional_roles: tuple[str, ...] = ()


def transmission_table(result: IdentificationResult) -> dict[int, tuple[float, float]]:
    """Gear -> ``(eta_m, C0)`` from the drive fits ``transmission.gear<g>`` that are not flagged.

    Parameters
    ----------
    result:
        An identification result holding the transmission fits.
    """
    out: dict[int, tuple[float, float]] = {}
    for name, fit in result.fits.items():
        key = FitKey.parse(name)
        if key.subsystem != "transmission" or key.direction != "drive" or fit.status != "ok":
            continue
        try:
            out[key.gear] = (fit.value("eta_m"), fit.value("C0"))
        except KeyError:
            continue
    return out


def _direct(fn: Callable[..., Any]) -> Callable[..., Any]:
    """A method that takes ``(rec, specs, **options)``."""
    def run(rec: Recording, specs: VehicleSpecs | None, _res: IdentificationResult, opts: Mapping[str, Any]) -> Any:
        return fn(rec, specs, **dict(opts))

    return run


def _battery(rec: Recording, specs: VehicleSpecs | None, _res: IdentificationResult, opts: Mapping[str, Any]) -> Any:
    """Eq. 30 on the constant drives (``battery``) and, on every usable sample, with RC branches (``battery.rc``)."""
    out = IdentificationResult(fits={"battery": identify_battery(rec, specs, **opts)})
    try:
        out.fits["battery.rc"] = battery_rc.identify_battery_rc(rec, specs, n_cells=opts.get("n_cells"),
                                                                maps=opts.get("maps"))
    except (IdentificationError, DataError) as exc:
        out.errors["battery.rc"] = f"{type(exc).__name__}: {exc}"
    return out


def _battery_map_free(rec: Recording, specs: VehicleSpecs | None, _res: IdentificationResult,
                      opts: Mapping[str, Any]) -> Any:
    o = dict(opts)
    n_cells = int(o.pop("n_cells", 1))
    cap = o.pop("capacity_ah", None)
    nodes = o.pop("soc_nodes_pct", None)
    min_rest_s = float(o.pop("min_rest_s", 600.0))
    start = o.pop("start_soc_pct", None)
    if "displayed_soc_pct" not in rec and cap is None:
        nodes = None
    out = IdentificationResult()
    out.fits["battery_map_free"] = identify_battery_map_free(rec, n_cells=n_cells, capacity_ah=cap,
                                                             soc_nodes_pct=nodes, start_soc_pct=start, **o)
    try:
        out.fits["battery_r0"] = identify_battery_r0_steps(rec, n_cells=n_cells, capacity_ah=cap,
                                                           soc_nodes_pct=nodes, start_soc_pct=start)
    except IdentificationError as exc:
        out.errors["battery_r0"] = f"{type(exc).__name__}: {exc}"
    if "displayed_soc_pct" in rec or cap is not None:
        try:
            out.fits["battery_ocv_rest"] = identify_battery_ocv_rest(rec, n_cells=n_cells, capacity_ah=cap,
                                                                     min_rest_s=min_rest_s, start_soc_pct=start)
        except IdentificationError as exc:
            out.errors["battery_ocv_rest"] = f"{type(exc).__name__}: {exc}"
    ref = out.fits["battery_map_free"].data.get("soc_reference")
    if ref is not None:
        out.meta["soc_reference"] = ref
    return out


def _shifts(rec: Recording, specs: VehicleSpecs | None, _res: IdentificationResult, opts: Mapping[str, Any]) -> Any:
    o = dict(opts)
    if specs is not None and specs.gear_ratios is not None:
        o.setdefault("n_gears", len(specs.gear_ratios))
    return shift_fits(rec, **o)


_TX = ("vehicle_speed_kmh", "shaft_torque_nm", "gear_actual")
#: the gearbox input: motor and engine (P2 hybrid), or the engine alone (conventional)
_TX_INPUT = (("em_speed_rpm", "em_torque_nm", "engine_torque_nm"), ("engine_speed_rpm", "engine_torque_nm"))
_RATIOS = ("gear_ratios", "final_drive_ratio", "wheel_radius_m")
#: the converter's pump: the motor (P2 hybrid, K0 open), or the engine alone (conventional)
_TC_PUMP = (("em_speed_rpm", "em_torque_nm"), ("engine_speed_rpm", "engine_torque_nm"))

#: every method in run order (transmission before the torque converter, which uses it)
METHODS: tuple[Method, ...] = (
    Method("transmission", _TX, _direct(identify_transmission), spec_keys=_RATIOS, alternatives=_TX_INPUT,
           optional_roles=(OIL_ROLE,)),
    Method("motor", ("em_speed_rpm", "em_torque_nm"), _direct(identify_motor),
           spec_keys=("em_rotor_radius_m", "em_rotor_volume_m3"),
           alternatives=(("hpcu_current_a", "hpcu_voltage_v"), ("battery_current_a", "battery_voltage_v"))),
    Method("engine", ("engine_speed_rpm", "engine_torque_nm", "fuel_mass_flow_gps"),
           _direct(identify_engine), spec_keys=("engine_displacement_m3",), optional_roles=(COOLANT_ROLE,)),
    Method("road_load", ("vehicle_speed_kmh",), _direct(identify_road_load),
           any_roles=("dyno_speed_kmh", "dyno_force_front_n"), spec_keys=("test_mass_kg",)),
    Method("brakes", ("brake_pressure_fl_bar", "brake_pressure_fr_bar", "brake_pressure_rl_bar",
                      "brake_pressure_rr_bar"), _direct(identify_brakes), spec_keys=("wheel_radius_m",)),
    Method("battery", ("battery_voltage_v", "battery_current_a", "displayed_soc_pct"), _battery,
           spec_keys=("n_cells_series",), optional_roles=(battery_rc.TEMP_ROLE,)),
    Method("battery_map_free", ("battery_voltage_v", "battery_current_a"), _battery_map_free, needs_specs=False),
    Method("torque_converter", ("vehicle_speed_kmh", "shaft_torque_nm", "gear_actual"), _torque_converter,
           spec_keys=_RATIOS, alternatives=_TC_PUMP,
           optional_roles=("dyno_force_front_n", "dyno_force_rear_n", "dyno_speed_kmh")),
    Method("shifts", ("gear_target", "vehicle_speed_kmh", "pedal_pct"), _shifts, needs_specs=False),
    Method("reduction_gear", ("em_speed_rpm", "em_torque_nm", "vehicle_speed_kmh", "dyno_force_front_n",
                              "dyno_force_rear_n"), _direct(identify_reduction_gear),
           spec_keys=("final_drive_ratio", "wheel_radius_m")),
)

#: methods run by default; battery_map_free is for logs whose chemistry the literature maps do not fit
DEFAULT_METHODS: tuple[str, ...] = ("transmission", "motor", "engine", "road_load", "brakes", "battery",
                                    "torque_converter", "shifts")


#: the function that takes each method's keyword options
_TARGETS: dict[str, Callable[..., Any]] = {
    "transmission": identify_transmission,
    "motor": identify_motor,
    "engine": identify_engine,
    "road_load": identify_road_load,
    "brakes": identify_brakes,
    "battery": identify_battery,
    "battery_map_free": identify_battery_map_free,
    "torque_converter": identify_torque_converter,
    "shifts": identify_shift_thresholds,
    "reduction_gear": identify_reduction_gear,
}


def method_options(name: str) -> set[str] | None:
    """Keyword options a method accepts (``None``: any, the function takes ``**kwargs``).

    Parameters
    ----------
    name:
        Method name (see :data:`METHODS`).

    Raises
    ------
    DataError
        Unknown method, or its module is not installed.
    """
    if name not in _TARGETS:
        raise DataError(f"unknown identification method {name!r}; known: {', '.join(_TARGETS)}")
    params = inspect.signature(_TARGETS[name]).parameters
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return None
    names = {n for n, p in params.items() if p.kind is inspect.Parameter.KEYWORD_ONLY}
    if name == "battery_map_free":
        names |= {"min_rest_s"}  # also passed to identify_battery_ocv_rest by the orchestrator
    if name == "torque_converter":
        names -= {"transmission", "drag"}  # filled from the transmission result (code only)
    return names


def method_option_defaults(name: str) -> dict[str, Any]:
    """Default of each keyword option of a method (what a value given on the command line must match).

    Parameters
    ----------
    name:
        Method name (see :data:`METHODS`).

    Raises
    ------
    DataError
        Unknown method.
    """
    allowed = method_options(name)
    params = inspect.signature(_TARGETS[name]).parameters
    return {n: p.default for n, p in params.items()
            if (allowed is None or n in allowed) and p.kind is inspect.Parameter.KEYWORD_ONLY}


def _merge(result: IdentificationResult, name: str, out: Any) -> None:
    if isinstance(out, IdentificationResult):
        result.fits.update(out.fits)
        result.errors.update(out.errors)
        if out.meta:
            result.meta.setdefault("methods_meta", {})[name] = out.meta
            if "soc_reference" in out.meta:
                result.meta["soc_reference"] = out.meta["soc_reference"]
    elif isinstance(out, FitResult):
        result.fits[name] = out
    elif isinstance(out, Mapping):
        for key, fit in out.items():
            full = key if key == name or key.startswith(name + ".") else f"{name}.{key}"
            if isinstance(fit, FitResult):
                result.fits[full] = fit
            elif isinstance(fit, IdentificationResult):
                _merge(result, full, fit)
            elif isinstance(fit, BaseException):
                result.errors[full] = f"{type(fit).__name__}: {fit}"
    else:
        raise TypeError(f"method {name} returned {type(out).__name__}")


def identify_all(
    recording: Recording,
    specs: VehicleSpecs | None,
    *,
    methods: Iterable[str] | None = None,
    options: Mapping[str, Mapping[str, Any]] | None = None,
    type_b: bool = True,
    type_b_share: TypeBShare | None = None,
    on_nominal: Callable[[IdentificationResult], None] | None = None,
) -> IdentificationResult:
    """Run every identification method whose roles are present.

    Parameters
    ----------
    recording:
        The Recording (emulated chain or an imported real log).
    specs:
        Public vehicle specs; methods that need them are skipped when ``None``.
    methods:
        Names of the methods to run (default :data:`DEFAULT_METHODS`; ``battery_map_free`` must be
        asked for, or runs instead of ``battery`` when the Recording has no ``displayed_soc_pct``).
    options:
        Per-method keyword arguments, e.g. ``{"battery_map_free": {"capacity_ah": 6.0}}``.
    type_b:
        Propagate the systematic uncertainties the Recording declares into every parameter
        (:mod:`benchtwin.identification.uncertainty`): each method runs again once per declared component
        of the roles it reads. False: the total intervals equal the statistical ones (but the converter's, which keep
        its own calibrations' components: :mod:`~benchtwin.identification.torque_converter_calibration`).
    type_b_share:
        Another worker that runs a share of the type B re-runs (:mod:`~benchtwin.identification.type_b_share`).
    on_nominal:
        Called with the result once every method has run, before the type B re-runs (which then add to it in
        place): for a caller that draws the fits meanwhile.

    Returns
    -------
    IdentificationResult
        ``fits`` of every method that ran, ``errors`` (fit name -> message) of those that could not
        give trustworthy numbers, and ``meta``: ``ran``, ``skipped`` (name -> reason), ``seconds``
        (per method), ``type_b`` (what was propagated, or why nothing was).

    Raises
    ------
    DataError
        An unknown method name.
    """
    known = {m.name: m for m in METHODS}
    wanted = list(methods) if methods is not None else list(DEFAULT_METHODS)
    unknown = [w for w in wanted if w not in known]
    if unknown:
        raise DataError(f"unknown identification method(s) {', '.join(unknown)}; known: {', '.join(known)}")
    if methods is None and "displayed_soc_pct" not in recording and "battery_voltage_v" in recording:
        wanted.append("battery_map_free")
    if methods is None and specs is not None and specs.layout == "bev":
        wanted.append("reduction_gear")  # the one fixed ratio's efficiency (a gearbox's is the transmission's)
    options = options or {}
    result = IdentificationResult(meta={"ran": [], "skipped": {}, "seconds": {}})
    stuck = stuck_channels(recording)
    if stuck:
        result.meta["stuck_channels"] = stuck
        log.warning("channels that never change (not used): %s", ", ".join(f"{k} = {v:g}" for k, v in stuck.items()))
    # the fits solve many small systems: BLAS threads only wait for a free core on a loaded machine
    # (measured: single runs of 3 s instead of 0.6 s at load 4 on 2 cores), so one thread is faster
    produced: dict[str, set[str]] = {}
    with threadpool_limits(limits=1, user_api="blas"):
        for m in METHODS:
            if m.name in wanted:
                before = set(result.fits)
                kept = recording.loaded()
                _run_method(m, recording, specs, result, options)
                produced[m.name] = set(result.fits) - before
                # a lazy Recording (Recording.open): what this method read goes, so only one family's channels are
                # in memory at a time; channels the caller had loaded stay
                recording.drop(recording.loaded() - kept)
        if on_nominal is not None:
            on_nominal(result)
        if type_b:
            t0 = time.perf_counter()
            plan = [(fits, _reads(m.name), _rerun(m.name, specs, options)) for m in METHODS
                    if (fits := produced.get(m.name))]
            result.meta["type_b"] = propagate_type_b(result, recording, plan, share=type_b_share)
            result.meta["seconds"]["type_b"] = round(time.perf_counter() - t0, 4)
        else:
            result.meta["type_b"] = {"declared": False, "note": "type B propagation not asked for: the total "
                                                                "interval equals the statistical one"}
    return result


#: methods that read another method's result (run again with it on a perturbed Recording)
_DEPENDS: dict[str, tuple[str, ...]] = {"torque_converter": ("transmission",)}


def _reads(name: str) -> list[str]:
    """Continuous roles a method reads, with those of the methods it depends on (states carry no type B)."""
    known = {m.name: m for m in METHODS}
    roles: list[str] = []
    for n in (*_DEPENDS.get(name, ()), name):
        alternative = [r for alt in known[n].alternatives for r in alt]
        roles += [r for r in (*known[n].roles, *known[n].any_roles, *alternative, *known[n].optional_roles)
                  if r not in STATE_ROLES and r not in roles]
    return roles


def _rerun(name: str, specs: VehicleSpecs | None,
           options: Mapping[str, Mapping[str, Any]]) -> Callable[[Recording], IdentificationResult]:
    """A function that runs method ``name`` (after the methods it depends on) on another Recording."""
    known = {m.name: m for m in METHODS}

    def run(rec: Recording) -> IdentificationResult:
        out = IdentificationResult(meta={"ran": [], "skipped": {}, "seconds": {}})
        with values_only():  # propagate_type_b reads the changes of the values only
            for n in (*_DEPENDS.get(name, ()), name):
                _run_method(_shared(known[n], specs, options), rec, specs, out, options)
        return out

    return run


#: methods another method runs first in its re-runs, and that read no other result: their output on one moved
#: Recording is shared by the re-runs of the methods of one type B propagation (``_reuse.shared_output``)
_SHARED = frozenset(d for deps in _DEPENDS.values() for d in deps if d not in _DEPENDS)


def _shared(m: Method, specs: VehicleSpecs | None, options: Mapping[str, Mapping[str, Any]]) -> Method:
    """``m`` whose output goes through :func:`~benchtwin.identification._reuse.shared_output` when another method
    runs it first (keyed by the specs and options objects: one ``identify_all`` call's)."""
    if m.name not in _SHARED:
        return m
    inner = m.run

    def run(rec: Recording, sp: VehicleSpecs | None, res: IdentificationResult, opts: Mapping[str, Any]) -> Any:
        return shared_output(m.name, (id(specs), id(options)), (specs, options), lambda: inner(rec, sp, res, opts))

    return replace(m, run=run)


def _run_method(m: Method, recording: Recording, specs: VehicleSpecs | None, result: IdentificationResult,
                options: Mapping[str, Mapping[str, Any]]) -> None:
    """Run one method into ``result``: skipped, fitted, or its error recorded (never raised)."""
    used = list(m.roles) + [r for alt in m.alternatives for r in alt if r not in m.roles and r in recording]
    stuck = [r for r in dict.fromkeys(used) if r in result.meta.get("stuck_channels", {})]
    if stuck:
        result.meta["skipped"][m.name] = "; ".join(
            f"channel {r} holds {result.meta['stuck_channels'][r]:g} over the whole recording (a stuck sensor or a "
            "wrong signal mapping)" for r in stuck)
        return
    missing = [r for r in m.roles if r not in recording]
    if m.any_roles and not any(r in recording for r in m.any_roles):
        missing.append(" or ".join(m.any_roles))
    if m.alternatives and not any(all(r in recording for r in alt) for alt in m.alternatives):
        missing.append(" or ".join("(" + ", ".join(alt) + ")" for alt in m.alternatives))
    if missing:
        result.meta["skipped"][m.name] = f"missing channel(s): {', '.join(missing)}"
        return
    if m.needs_specs and specs is None:
        result.meta["skipped"][m.name] = "needs the vehicle specs (--specs or a [specs] table)"
        return
    absent = [k for k in m.spec_keys if specs is not None and getattr(specs, k) is None]
    if absent:
        result.meta["skipped"][m.name] = (f"needs spec key(s) {', '.join(absent)}, which the {specs.layout} "  # type: ignore[union-attr]
                                          "layout's specs do not give")
        return
    t0 = time.perf_counter()
    try:
        out = m.run(recording, specs, result, options.get(m.name, {}))
        _merge(result, m.name, out)
        result.meta["ran"].append(m.name)
    except BenchtwinError as exc:
        result.errors[m.name] = f"{type(exc).__name__}: {exc}"
        result.meta["ran"].append(m.name)
    except (ValueError, TypeError, ArithmeticError, IndexError, KeyError) as exc:
        # a method that breaks on unexpected data must not stop the others; record it
        log.exception("identification method %s failed", m.name)
        result.errors[m.name] = f"unexpected {type(exc).__name__}: {exc}"
        result.meta["ran"].append(m.name)
    result.meta["seconds"][m.name] = round(time.perf_counter() - t0, 4)
