"""Identification families: one subsystem validated on its own tests only.

A sweep over sensors, noise or gains that looks at one subsystem need not push the whole campaign
through the chain: :func:`~benchtwin.validation.run.validate` with ``families=[...]`` runs the chain
only over the campaign's tests of the kinds a family needs, runs only that family's identification
methods, and keeps only its checks (its parameters, its R^2 against the paper's, and the chain checks
of the roles its methods read).

=================  =========================================================  ===================================
family             tests (segment kinds)                                      identification methods
=================  =========================================================  ===================================
transmission       ramp_up                                                    transmission
torque_converter   ramp_up, acceleration, deceleration, coastdown, ramp_down  transmission, torque_converter
engine             ramp_up                                                    engine
motor              ramp_up                                                    motor
road_load          coastdown                                                  road_load
brakes             neutral_braking, deceleration                              brakes
battery            constant_drive                                             battery
shifts             acceleration, deceleration, ramp_down                      shifts
=================  =========================================================  ===================================

The bench of a family run carries only the devices whose channels the family reads (:func:`family_setup`):
each device draws from its own random stream, so what the kept devices deliver is unchanged, and the chain
costs a fraction of the whole bench's (the report's bus load is that of the kept devices); a kept thermo module
converts only the inputs the family reads (``not_recorded``: the others still take their noise draws, so the read
ones are the same), and a kept vehicle CAN decodes only the roles the family reads and sends only the messages that
carry one of them (``[vehicle_can] not_recorded``; the messages left out still take their draws). A setup with faults
injected on a whole bus keeps every device, since those faults draw over all the bus's frames.

The paper campaign's ramp-downs are tests of kind ``deceleration``. The identified values differ
slightly from a whole-campaign run where a method also reads other tests by default (transmission,
engine and motor also use the constant drives), and the sensor noise of each contiguous run of tests
has its own seed derived from the campaign's.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from benchtwin.config.setup import SetupConfig
from benchtwin.errors import ConfigError
from benchtwin.identification.run import METHODS
from benchtwin.recording import Channel, Recording
from benchtwin.segments import Segment
from benchtwin.trace import SpooledTrace, Trace
from benchtwin.validation.report import Check

__all__ = ["FAMILIES", "FAMILY_CHUNK_S", "Family", "family_checks", "family_setup", "family_spans", "merge_recordings",
           "resolve_families", "span_seed", "span_view", "stitch_traces"]

#: plant seconds per chunk through the chain in a family run (the Recording is the same for any cut): a family's few
#: thousand seconds of tests go in a few chunks, not one per test (paper vehicle, converter family, 1,700 s of tests
#: in 25 tests: validate 0.52 -> 0.45 s of wall, 0.70 -> 0.56 s of CPU); a chunk holds the frames of a 600-s test
FAMILY_CHUNK_S = 600.0


@dataclass(frozen=True)
class Family:
    """One identification family.

    Attributes
    ----------
    name:
        Family name (also the group of its checks).
    kinds:
        Segment kinds of the tests it needs.
    methods:
        Identification methods to run, in the orchestrator's order.
    optional:
        Roles its methods also read when the Recording has them (beside the roles they require); the
        bench of a family run keeps their devices too (:func:`family_setup`).
    """

    name: str
    kinds: tuple[str, ...]
    methods: tuple[str, ...]
    optional: tuple[str, ...] = ()

    def roles(self) -> set[str]:
        """Recording roles its methods require (for the chain checks)."""
        out: set[str] = set()
        for m in METHODS:
            if m.name in self.methods:
                # a method with alternative inputs (e.g. the motor's HPCU or pack DC side) may read any of them
                out |= set(m.roles) | set(m.any_roles) | {r for alt in m.alternatives for r in alt}
        return out

    def reads(self) -> set[str]:
        """Every role its methods read: the required ones and the optional ones (the family's and the methods')."""
        methods = {r for m in METHODS if m.name in self.methods for r in m.optional_roles}
        return self.roles() | set(self.optional) | methods


FAMILIES: dict[str, Family] = {f.name: f for f in (
    # the ``optional`` vehicle-CAN states below are read by the methods (to pick and split their points) though their
    # declarations do not name them: found by recording every channel a family's identification reads (paper setup,
    # both shipped vehicles); a family run's vehicle CAN sends only the messages of the roles the family reads
    Family("transmission", ("ramp_up",), ("transmission",), ("gear_target", "k0_closed", "lockup_closed")),
    # converter mode (lock-up open) is seen mostly in the accelerations and decelerations: with ramp-ups
    # only, too few converter points reach the curves (paper campaign: 6 of 13 checks fail, all pass with them)
    # coupling mode (speed ratio above the coupling point, lock-up open) is reached in the coastdown's run-up
    # to 130 km/h: without it 79 coupling points and the coupling curve 14 % off on the ideal chain, with it
    # 96 points and 1.2 %
    # near stall (SR below 0.3) the converter's quasi-steady points come from the ramp-downs (the vehicle
    # slowing to a stop in 1st gear with the pedal held): without them the family's points start at SR 0.32
    # and the stall torque ratio and capacity are extrapolated (paper vehicle, ideal chain: torque-ratio
    # curve 2.7 % off, with them 0.03 %)
    Family("torque_converter", ("ramp_up", "acceleration", "deceleration", "coastdown", "ramp_down"),
           ("transmission", "torque_converter"), ("engine_on", "gear_target", "k0_closed", "lockup_closed")),
    Family("engine", ("ramp_up",), ("engine",), ("engine_on", "gear_actual", "k0_closed")),
    # the DC/DC efficiency comes from the LV side of the DC/DC when it is recorded
    Family("motor", ("ramp_up",), ("motor",), ("dcdc_lv_current_a", "dcdc_lv_voltage_v", "gear_actual", "hybrid_mode",
                                               "k0_closed", "lockup_closed")),
    Family("road_load", ("coastdown",), ("road_load",), ("brake_pedal_pct", "gear_actual", "pedal_pct")),
    # the axle torques come from the dyno's roller forces; speeds pick the braking points
    Family("brakes", ("neutral_braking", "deceleration"), ("brakes",),
           ("dyno_force_front_n", "dyno_force_rear_n", "dyno_speed_kmh", "vehicle_speed_kmh", "gear_actual")),
    Family("battery", ("constant_drive",), ("battery",)),
    Family("shifts", ("acceleration", "deceleration", "ramp_down"), ("shifts",), ("gear_actual",)),
)}


def resolve_families(names: Iterable[str] | None) -> list[Family] | None:
    """The families named (None: every family, i.e. the whole validation).

    Raises
    ------
    ConfigError
        An unknown family name (the message lists the allowed ones), or an empty list.
    """
    if names is None:
        return None
    if isinstance(names, str):
        names = [names]
    names = list(names)
    bad = [n for n in names if n not in FAMILIES]
    if bad:
        raise ConfigError(f"families: unknown {', '.join(map(repr, bad))}; allowed: {', '.join(FAMILIES)}")
    if not names:
        raise ConfigError(f"families: empty list; allowed: {', '.join(FAMILIES)}")
    return [FAMILIES[n] for n in dict.fromkeys(names)]


def family_setup(setup: SetupConfig, roles: Iterable[str]) -> SetupConfig:
    """The setup with only the devices that deliver one of ``roles`` (and their own faults).

    Each device draws from its own random stream (split by its name from the campaign seed), so the kept
    devices deliver exactly what they deliver on the whole bench. The clock alignment pairs sources that
    measure one quantity (vehicle CAN against the dyno, against the HPCU or battery shunt); a pair with one
    side dropped only loses a shift that no kept channel needed. Faults injected on a whole bus draw over
    every frame of the bus: such a setup is returned whole.
    """
    from benchtwin.sensors import devices

    if any(f.bus is not None for f in setup.faults):
        return setup
    roles = set(roles)
    devs = devices(setup)
    keep = {d.name for d in devs if set(d.truth_channels()) & roles}
    if not keep or len(keep) == len(devs):
        return setup
    sections = {d.section for d in devs if d.name in keep}
    update: dict[str, object] = {
        "ivt": {place: cfg for place, cfg in setup.ivt.items()
                if any(d.name in keep and d.cfg is cfg for d in devs if d.section == "ivt")},
        "faults": [f for f in setup.faults if f.device in keep],
    }
    for sec in ("pressure", "telemetry", "thermo", "vehicle_can", "dyno"):
        if sec not in sections:
            update[sec] = None
    vcan = [d for d in devs if d.name in keep and d.section == "vehicle_can"]
    if vcan and setup.vehicle_can is not None:
        # the vehicle CAN's roles no kept role reads are not decoded, and a message of such roles alone is not sent
        # (its draws still taken: the read messages are the same, draw for draw)
        unread = set(vcan[0].truth_channels()) - roles
        update["vehicle_can"] = setup.vehicle_can.model_copy(
            update={"not_recorded": sorted(set(setup.vehicle_can.not_recorded) | unread)})
    if "thermo" in sections and setup.thermo is not None:
        # the module's inputs no kept role reads are left open (the read ones draw as on the whole bench)
        unread = [p for p in setup.thermo.places if p not in roles]
        update["thermo"] = setup.thermo.model_copy(update={"not_recorded": sorted(set(setup.thermo.not_recorded)
                                                                                   | set(unread))})
    return setup.model_copy(update=update)


def family_spans(segments: Sequence[Segment], kinds: Iterable[str]) -> list[tuple[float, float]]:
    """Contiguous time spans covering the segments of ``kinds`` (neighbouring tests joined)."""
    kinds = set(kinds)
    spans: list[list[float]] = []
    prev_used = False
    for s in sorted(segments, key=lambda s: s.start_s):
        used = s.kind in kinds
        if used:
            if prev_used and spans:
                spans[-1][1] = s.end_s
            else:
                spans.append([s.start_s, s.end_s])
        prev_used = used
    return [(a, b) for a, b in spans]


def span_view(trace: Trace, start_s: float, end_s: float) -> Trace:
    """``trace.slice_time(start_s, end_s)`` as views on the Trace's arrays (its samples with ``start_s <= t <
    end_s``, the segments it overlaps), for an in-memory Trace; a spooled one is sliced as usual (from its files).

    A family run's spans are most of its Trace (the converter example: one span, the whole Trace): the boolean mask
    of :meth:`~benchtwin.trace.Trace.slice_time` copied its 57 channels (0.015-0.02 s of a 0.6 s example) for a
    chain that only reads them (it cuts its own pieces as views, :func:`~benchtwin.chain.stream.trace_pieces`).
    """
    if isinstance(trace, SpooledTrace):
        return trace.slice_time(start_s, end_s)
    t = trace.time_s
    a, b = (int(k) for k in np.searchsorted(t, [start_s, end_s], side="left"))
    segs = [s for s in trace.segments if s.end_s > start_s and s.start_s < end_s]
    return Trace(t[a:b], {k: v[a:b] for k, v in trace.channels.items()}, segs, dict(trace.meta))


def span_seed(seed: int, k: int) -> int:
    """Chain seed of the k-th span: the campaign seed for the first, a derived one for the others."""
    if k == 0:
        return int(seed)
    return int(np.random.SeedSequence([int(seed), int(k)]).generate_state(1)[0])


def merge_recordings(recs: Sequence[Recording]) -> Recording:
    """One Recording of several disjoint time spans (channels concatenated in time order)."""
    if len(recs) == 1:
        return recs[0]
    out = Recording(segments=[s for r in recs for s in r.segments], meta=dict(recs[0].meta))
    names = list(dict.fromkeys(n for r in recs for n in r.channels))
    for name in names:
        parts = [r.channels[name] for r in recs if name in r.channels]
        first = parts[0]
        t = np.concatenate([c.timestamps for c in parts])
        order = np.argsort(t, kind="stable")
        out.add(Channel(name, first.unit, t[order], np.concatenate([c.values for c in parts])[order],
                        np.concatenate([c.flags for c in parts])[order], first.source))
    return out


def stitch_traces(traces: Sequence[Trace]) -> Trace:
    """The slices of one Trace side by side on their own (gapped) clock, for comparing a merged Recording."""
    if len(traces) == 1:
        return traces[0]
    return Trace(np.concatenate([t.time_s for t in traces]),
                 {k: np.concatenate([t.channels[k] for t in traces]) for k in traces[0].channels},
                 [s for t in traces for s in t.segments], dict(traces[0].meta))


def family_checks(checks: Iterable[Check], families: Sequence[Family]) -> list[Check]:
    """The parameter checks and R^2 checks that belong to the families."""
    groups = {f.name for f in families}
    out = []
    for c in checks:
        if c.group == "r2":
            if c.name.split(".", 1)[0] in groups:
                out.append(c)
        elif c.group in groups:
            out.append(c)
    return out
