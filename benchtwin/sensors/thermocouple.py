"""Type K thermocouples on a CANopen thermo module with cold-junction compensation.

Per input: the probe's junction temperature ``T`` (with the probe's errors and time constant)
gives the thermoelectric voltage ``E(T) - E(T_cj)`` at the module terminals (ITS-90 type K reference
function, NIST Monograph 175, coefficients of the ``thermocouple-its90`` package evaluated with
numpy); the module quantises it (``emf_resolution_uv``), adds ``E(T_cj_measured)`` from its own
cold-junction sensor, inverts the reference function (NIST inverse polynomial refined by Newton
steps) and publishes ``T`` in 0.1 degC in object 0x9130 (INTEGER16; 0x7FFF above range,
-0x8000 below range or open). The cold-junction temperature goes to 0x2100.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from thermocouple_its90._data import TYPES as _ITS90

from benchtwin.config.setup import ChannelErrors, FaultSpec, LinkErrors, ThermoConfig
from benchtwin.sensors.base import CanopenEndpoint, Delivered, Device, FrameDecoder, TruthChannel
from benchtwin.sensors.blocks import Block
from benchtwin.sensors.imperfections import (
    DeviceClock,
    draw_as_measured,
    frame_faults,
    in_spans,
    measure,
    silent_ticks,
    span_frame_faults,
    with_stuck,
)
from benchtwin.trace import Trace
from benchtwin.wire.canopen_pdo import AI_OVERLOAD_NEG, AI_OVERLOAD_POS, EDS_PATH, TpdoLayout, pdo_layout
from benchtwin.wire.dbc import build_thermo_pdos
from benchtwin.wire.frames import ProcessImage
from benchtwin.wire.quality import FLAG, DecodeSink, FrameStream, mark_after, split_bad, timing_flags

if TYPE_CHECKING:
    from cantools.database.can import Database

__all__ = ["ThermoModule", "emf_type_k", "encode_thermo", "seebeck_type_k", "temperature_type_k"]

_K = _ITS90["K"]
_T_MIN, _T_MAX = -270.0, 1372.0


def _forward(t: np.ndarray, derivative: bool = False) -> np.ndarray:
    out = np.full(t.shape, np.nan)
    for seg in _K["forward"]:
        lo, hi = seg["t_min_c"], seg["t_max_c"]
        m = (t >= lo) & (t <= hi) if lo < 0 else (t > lo) & (t <= hi)
        if not m.any():
            continue
        c = np.asarray(seg["coeffs"], dtype=np.float64)
        x = t[m]
        if derivative:
            v = np.polyval((c[1:] * np.arange(1, c.size))[::-1], x)
        else:
            v = np.polyval(c[::-1], x)
        ex = seg.get("exponential")
        if ex:
            g = ex["a0"] * np.exp(ex["a1"] * (x - ex["a2"]) ** 2)
            v = v + (g * 2.0 * ex["a1"] * (x - ex["a2"]) if derivative else g)
        out[m] = v
    return out


def emf_type_k(t_degc: np.ndarray) -> np.ndarray:
    """Type K thermoelectric voltage (mV, reference junction at 0 degC), -270..1372 degC; NaN outside."""
    return _forward(np.asarray(t_degc, dtype=np.float64))


def seebeck_type_k(t_degc: np.ndarray) -> np.ndarray:
    """dE/dT of the type K reference function, mV/degC."""
    return _forward(np.asarray(t_degc, dtype=np.float64), derivative=True)


def temperature_type_k(emf_mv: np.ndarray, newton_steps: int = 3) -> np.ndarray:
    """Invert the type K reference function: mV -> degC (inverse polynomial + Newton refinement)."""
    e = np.asarray(emf_mv, dtype=np.float64)
    t = np.full(e.shape, np.nan)
    for seg in _K["inverse"]:
        m = (e >= seg["mv_min"]) & (e <= seg["mv_max"])
        if m.any():
            t[m] = np.polyval(np.asarray(seg["coeffs"], dtype=np.float64)[::-1], e[m])
    # outside the inverse polynomials' span (below -200 degC): start from a linear guess
    rest = ~np.isfinite(t) & np.isfinite(e)
    t[rest] = np.clip(e[rest] / 0.0395, _T_MIN, _T_MAX)
    for _ in range(newton_steps):
        t = np.clip(t - (emf_type_k(t) - e) / seebeck_type_k(t), _T_MIN, _T_MAX)
    return t


def encode_thermo(trace: Trace, cfg: ThermoConfig, rng: np.random.Generator,
                  faults: Sequence[FaultSpec] = (), blk: Block | None = None) -> ProcessImage:
    """The thermo module's object-dictionary values at each TPDO event (its own clock).

    Columns follow the EDS TPDO mapping (0x9130 sub 1..10, then 0x2100); inputs without a
    thermocouple read -0x8000 (open circuit), as does an input with an injected ``open_circuit`` over
    its span. A ``silent`` node sends no TPDO over its span. ``blk``: the block of plant time to encode
    (``trace`` and ``rng`` are then unused); None: the whole ``trace``.
    """
    blk = Block.whole(trace, rng) if blk is None else blk
    trace, rng = blk.trace, blk.rng
    layout = pdo_layout(cfg.node_id)
    clock = DeviceClock.of(cfg.link)
    t_dev = clock.ticks(blk.start_s, blk.end_s, cfg.pdo_period_ms / 1000.0)
    t_dev = silent_ticks(t_dev, clock, faults)
    t = clock.to_plant(t_dev)
    n = t.shape[0]
    entries = layout.entries
    values = np.full((n, len(entries)), AI_OVERLOAD_NEG, dtype=np.int64)
    t_cj = cfg.cold_junction_degc
    e_cj_true = float(emf_type_k(np.array([t_cj]))[0])
    e_cj_meas = float(emf_type_k(np.array([t_cj + cfg.cold_junction_error_degc]))[0])
    # every input's reading first (each draws from the block's generator in input order), then the type K
    # conversions of all inputs at once: elementwise, the same numbers as input by input, a tenth of the calls
    # an input not recorded (``not_recorded``) is left open; its noise is still drawn, so the other inputs'
    # readings are the same draw for draw
    read = [(k, place) for k, place in enumerate(cfg.places) if place not in cfg.not_recorded]
    temps = np.empty((len(read), n))
    j = 0
    for place in cfg.places:
        if place in cfg.not_recorded:
            draw_as_measured(cfg.errors, rng, n)
            continue
        temps[j] = measure(trace.time_s, trace[place], t, with_stuck(cfg.errors, faults, place), rng,
                           latency_s=cfg.link.latency_s, blk=blk, key=place)
        j += 1
    v_term = emf_type_k(np.clip(temps, _T_MIN, _T_MAX)) - e_cj_true
    if cfg.emf_resolution_uv > 0:
        step = cfg.emf_resolution_uv * 1e-3
        v_term = np.rint(v_term / step) * step
    t_all = temperature_type_k(v_term + e_cj_meas)
    for j, (k, place) in enumerate(read):
        t_meas = t_all[j]
        col = entries.index((0x9130, k + 1))
        dec = 10.0 ** layout.decimals.get(k + 1, 1)
        raw = np.rint(t_meas * dec)
        raw = np.where(t_meas > cfg.range_max_degc, AI_OVERLOAD_POS, raw)
        raw = np.where((t_meas < cfg.range_min_degc) | ~np.isfinite(t_meas), AI_OVERLOAD_NEG, raw)
        values[:, col] = np.clip(raw, AI_OVERLOAD_NEG, AI_OVERLOAD_POS)
        values[in_spans(t, [f for f in faults if f.channel == place], "open_circuit"), col] = AI_OVERLOAD_NEG
    if (0x2100, 0) in entries:
        values[:, entries.index((0x2100, 0))] = round((t_cj + cfg.cold_junction_error_degc) * 10.0)
    return ProcessImage("thermo", cfg.node_id, t_dev, entries, values)


class ThermoModule(Device):
    """Type K thermocouples on the CANopen thermo module (setup section ``[thermo]``, ``thermo_module.eds``)."""

    section = "thermo"
    wire = "canopen"

    def encode(self, blk: Block) -> ProcessImage:
        """The object-dictionary values at each TPDO event of one block."""
        return encode_thermo(blk.trace, self.cfg, blk.rng, self.setup.faults_of(self.name), blk)

    def deliver(self, output: ProcessImage, rng: np.random.Generator, span_s: tuple[float, float],
                state: dict) -> Delivered:
        """The TPDO frames of ``output`` (the updates of one block) on the module's bus, with its link's frame
        faults (stream ``thermo_pdo``)."""
        pdo = pdo_layout(self.cfg.node_id).pack(output)
        frames = frame_faults(pdo, pdo["arbitration_id"].astype(np.int64), self.cfg.link, rng)
        return Delivered(frames=span_frame_faults(frames, frames["arbitration_id"].astype(np.int64),
                                                  self.setup.faults_of(self.name), rng, DeviceClock.of(self.cfg.link)))

    def database(self) -> Database:
        """The TPDOs as DBC messages derived from the EDS mapping."""
        return build_thermo_pdos(self.cfg.node_id, self.cfg.places)

    def frame_decoders(self) -> dict[int, FrameDecoder]:
        """One decoder per TPDO of the EDS mapping."""
        layout = pdo_layout(self.cfg.node_id)
        out = {tp.cob_id: FrameDecoder(tp.length, self._decoder(tp)) for tp in layout.tpdos}
        out[0x700 + self.cfg.node_id] = FrameDecoder(1, self._nmt)  # boot-up and heartbeat of the live node
        return out

    def _nmt(self, s: FrameStream, sink: DecodeSink) -> None:
        """Boot-up messages and heartbeats: counted in ``meta["canopen_nmt"]``, no channel."""
        sink.count("canopen_nmt", self.name, len(s.t))

    def _decoder(self, tp: TpdoLayout):
        layout = pdo_layout(self.cfg.node_id)
        period = tp.event_ms / 1000.0
        th = self.cfg

        def decode(s: FrameStream, sink: DecodeSink) -> None:
            good, proto, nbad = split_bad(s.dlc, tp.length)
            sink.protocol_error(s.where, nbad)
            t = s.t[good]
            base = proto | timing_flags(t, period, s.words[good])
            mark_after(base, t, s.drops, FLAG["TRANSPORT_DROP"] | FLAG["LOST_FRAME"])
            vals = layout.unpack_words(tp, s.words[good])
            for (index, sub), raw in vals.items():
                if index == 0x9130:
                    if sub > len(th.places) or th.places[sub - 1] in th.not_recorded:
                        continue
                    name = th.places[sub - 1]
                elif index == 0x2100:
                    name = "thermo_cold_junction_degc"
                else:
                    continue
                v = raw * layout.scale((index, sub))
                flags = base.copy()
                hi, lo = raw == AI_OVERLOAD_POS, raw == AI_OVERLOAD_NEG
                if lo.any():  # below range or open: a coolant probe is never below -40 degC, so open
                    sink.fault("open_circuit", self.name, t[lo], channel=name)
                flags[hi | lo] |= FLAG["OUT_OF_RANGE"] | FLAG["SATURATED"]
                v = np.where(hi, th.range_max_degc, np.where(lo, th.range_min_degc, v))
                sink.add(name, "degC", t, v, flags, self.name)

        return decode

    def truth_channels(self) -> dict[str, TruthChannel]:
        """Every place, to the 0.1 degC step of object 0x9130."""
        return {place: TruthChannel(place, 1.0, False, 0.1) for place in self._recorded()}

    def _recorded(self) -> list[str]:
        return [p for p in self.cfg.places if p not in self.cfg.not_recorded]

    def error_budget(self) -> dict[str, tuple[ChannelErrors | None, LinkErrors, float]]:
        """The probes' errors plus the cold-junction sensor's error."""
        return {place: (self.cfg.errors, self.cfg.link, abs(self.cfg.cold_junction_error_degc))
                for place in self._recorded()}

    def saturation(self) -> dict[str, ChannelErrors]:
        """Every place."""
        return {place: self.cfg.errors for place in self._recorded()}

    def canopen_endpoint(self) -> CanopenEndpoint:
        """The module as a CANopen node on its bus."""
        return CanopenEndpoint(self.name, self.cfg.node_id, EDS_PATH, self.cfg.bus)
