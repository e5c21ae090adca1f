"""The pump side's free run-down at standstill (the map-based model's standstill term).

When the car stands in gear with the lock-up clutch open, the engine off and the pedal released, a P2 motor
gives no torque and the pump side (motor rotor and converter pump) runs down against the converter at stall
(speed ratio 0, turbine held by the brakes): ``J dw/dt = -c w^2`` with ``c`` the converter's capacity at
SR 0 (``a0`` of eq. 35, or the identified table's capacity at SR 0) and ``J`` the identified pump-side
inertia. Its solution from the speed ``w0`` at the stop is ``w(t) = w0 / (1 + w0 t c / J)``: it falls below
1 rad/s (where the motor's draw stops) after ``(J/c)(1 - 1/w0)``, for any ``w0`` well above 1 rad/s about
``J/c`` whatever ``w0`` was. While it turns, the motor draws its zero-torque loss: what the model would
otherwise leave out over a drive with many stops (the NEDC's 13).
"""

from __future__ import annotations

import numpy as np


def stop_runs(stand: np.ndarray) -> list[tuple[int, int]]:
    """Index ranges ``[i0, i1)`` of the runs of ``True`` in ``stand``."""
    s = np.asarray(stand, bool).astype(np.int8)
    d = np.diff(np.concatenate(([0], s, [0])))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=True))


def rundown_speed(stand: np.ndarray, dt_s: float, j_over_c_s: float, w_cap_radps: float) -> np.ndarray:
    """Pump speed (rad/s) over each standstill run, the free run-down from a pump well above 1 rad/s.

    Parameters
    ----------
    stand:
        Per sample, ``True`` where the pump side runs down freely (standing in gear, lock-up open, engine off).
    dt_s:
        Sample spacing, s.
    j_over_c_s:
        ``J / c`` (kg m^2 over Nm s^2, i.e. seconds times rad/s): the run-down's time scale at 1 rad/s.
    w_cap_radps:
        The speed at the stop (the run-down starts there; ``inf``: the limit ``w = (J/c) / t``).

    Returns
    -------
    numpy.ndarray
        The pump speed at the standstill samples (time from the stop counted at the sample's middle), 0 elsewhere.
    """
    w = np.zeros(np.asarray(stand).shape, dtype=float)
    if not (np.isfinite(j_over_c_s) and j_over_c_s > 0 and dt_s > 0):
        return w
    for i0, i1 in stop_runs(stand):
        t = (np.arange(i1 - i0) + 0.5) * dt_s
        w[i0:i1] = 1.0 / (1.0 / w_cap_radps + t / j_over_c_s)
    return w
