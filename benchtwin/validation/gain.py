"""Telemetry gain selection: every K_TEL position through the strain-gauge, telemetry and AD chain."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from benchtwin.config.setup import K_TEL_STEPS, SetupConfig
from benchtwin.config.vehicle import VehicleConfig
from benchtwin.errors import ConfigError, IdentificationError
from benchtwin.identification._fit import IdentificationResult
from benchtwin.identification.keys import FitKey
from benchtwin.identification.transmission import identify_transmission
from benchtwin.recording import Channel, Flag, Recording
from benchtwin.sensors.telemetry import decode_ad_frames, encode_telemetry, k_tot, torque_from_code, torque_step_nm
from benchtwin.trace import Trace

__all__ = ["GainOption", "select_gain"]


@dataclass
class GainOption:
    """One telemetry gain position and what it does to the measurement and to identification.

    Attributes
    ----------
    k_tel:
        Telemetry gain.
    k_tot_nm_per_v, resolution_nm, range_nm:
        Table 2 of the paper for this shaft.
    peak_torque_nm:
        Largest |shaft torque| of the campaign.
    clipped_frac:
        Fraction of AD-module samples at the converter's limit.
    clipped_segments:
        Tests in which clipping happened.
    transmission_eta_error:
        Worst relative error of eta_m over the gears identified with this gain (NaN if identification
        failed), and ``transmission_c0_error_nm`` the worst absolute C0 error.
    """

    k_tel: int
    k_tot_nm_per_v: float
    resolution_nm: float
    range_nm: float
    peak_torque_nm: float
    clipped_frac: float
    clipped_segments: list[str]
    transmission_eta_error: float = float("nan")
    transmission_c0_error_nm: float = float("nan")
    note: str = ""


def select_gain(trace: Trace, setup: SetupConfig, vehicle: VehicleConfig | None = None, *,
                seed: int = 0, base_recording: Recording | None = None,
                margin: float = 1.1) -> tuple[int, list[GainOption]]:
    """Choose the telemetry gain K_TEL for the propeller-shaft torque.

    Every switch position is simulated through the strain-gauge, telemetry and 12-bit AD chain of the
    setup on the campaign's own shaft torque. The recommended gain is the highest one whose range covers
    the campaign's peak torque times ``margin`` without clipping (best resolution, eq. 11); when a
    vehicle (truth) is given, the transmission identification is also rerun with each gain and its
    errors reported, so the choice can be judged on what it does to the parameters.

    Parameters
    ----------
    trace:
        The campaign's Trace.
    setup:
        The bench (its telemetry section is varied).
    vehicle:
        The truth, to score identification per gain (optional).
    seed:
        Seed of the sensor noise.
    base_recording:
        A Recording of the campaign to reuse for every other channel when scoring identification.
    margin:
        Headroom factor on the peak torque.

    Returns
    -------
    k_tel, options
        The recommended gain and one :class:`GainOption` per switch position.
    """
    if setup.telemetry is None:
        raise ConfigError(f"setup {setup.name!r} has no [telemetry] section: there is no gain to choose")
    shaft = trace["shaft_torque_nm"]
    peak = float(np.max(np.abs(shaft)))
    options: list[GainOption] = []
    for k in K_TEL_STEPS:
        tel = setup.telemetry.model_copy(update={"k_tel": int(k)})
        kt = k_tot(tel.shaft, k)
        frames = encode_telemetry(trace, tel, np.random.default_rng(seed))
        code, _counter, clip = decode_ad_frames(frames["data"].view("<u8")[:, 0], tel.can_id)
        t = frames["timestamp"]
        torque = torque_from_code(code, tel)
        clipped = clip.astype(bool)
        segs = sorted({s.name for s in trace.segments if np.any(clipped & s.contains(t))})
        opt = GainOption(int(k), kt, max(torque_step_nm(tel.shaft, k), tel.resolution_floor_nm),
                         kt * tel.vout_max_v, peak, float(np.mean(clipped)) if clipped.size else 0.0, segs)
        if vehicle is not None and base_recording is not None:
            opt.transmission_eta_error, opt.transmission_c0_error_nm, opt.note = _score_transmission(
                base_recording, t, torque, clipped, vehicle)
        options.append(opt)
    covering = [o for o in options if o.range_nm >= margin * peak and o.clipped_frac == 0.0]
    if not covering:
        best = min(options, key=lambda o: o.clipped_frac)
        return best.k_tel, options
    return max(covering, key=lambda o: o.k_tel).k_tel, options


def _score_transmission(base: Recording, t: np.ndarray, torque: np.ndarray, clipped: np.ndarray,
                        vehicle: VehicleConfig) -> tuple[float, float, str]:
    rec = Recording(dict(base.channels), list(base.segments), dict(base.meta))
    flags = np.where(clipped, int(Flag.SATURATED), 0).astype(np.uint16)
    rec.add(Channel("shaft_torque_nm", "Nm", t, torque, flags, "telemetry"))
    try:
        res = identify_transmission(rec, vehicle.specs)
    except IdentificationError as exc:
        return float("nan"), float("nan"), f"{type(exc).__name__}: {exc}"
    fits = res.fits if isinstance(res, IdentificationResult) else dict(res)
    eta_err, c0_err = [], []
    for name, fit in fits.items():
        key = FitKey.parse(name)
        if key.subsystem != "transmission" or key.direction != "drive" or fit.status != "ok":
            continue
        g = key.gear
        eta_err.append(abs(fit.value("eta_m") / vehicle.transmission.eta_m[g - 1] - 1.0))
        c0_err.append(abs(fit.value("C0") - vehicle.transmission.c0_nm[g - 1]))
    if not eta_err:
        return float("nan"), float("nan"), "no gear identified"
    return float(max(eta_err)), float(max(c0_err)), f"{len(eta_err)} gears identified"
