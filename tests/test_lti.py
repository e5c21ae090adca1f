"""benchtwin.lti.c2d against python-control's c2d (the oracle it replaces), bit for bit."""

from __future__ import annotations

import subprocess
import sys

import control
import numpy as np
import pytest

from benchtwin.lti import c2d


def _oracle(num: list[float], den: list[float], dt: float, method: str) -> tuple[np.ndarray, np.ndarray]:
    sysd = control.c2d(control.tf(num, den), dt, method=method)
    return np.asarray(sysd.num[0][0], dtype=float), np.asarray(sysd.den[0][0], dtype=float)


def _systems() -> list[tuple[list[float], list[float]]]:
    out = []
    for f_hz in (0.05, 0.7, 3.0, 25.0, 180.0):
        wc = 2 * np.pi * f_hz
        out.append(([wc], [1.0, wc]))  # a sensor's first order
        for zeta in (0.3, 0.707, 1.0):
            out.append(([wc * wc], [1.0, 2 * zeta * wc, wc * wc]))  # a sensor's second order
    for mass in (1800.0, 2400.0):
        for bw in (0.5, 2.0, 8.0):
            out.append(([2 * 0.9 * bw * mass, bw**2 * mass], [1.0, 0.0]))  # the PI of a pure mass
    out.append(([0.0, 0.0, 3.0], [0.0, 1.0, 4.0]))  # leading zeros given
    out.append(([0.0], [1.0, 2.0]))  # a zero numerator
    return out


@pytest.mark.filterwarnings("ignore::scipy.signal.BadCoefficients")  # the slowest filter at 1 ms, both sides
@pytest.mark.parametrize("method", ["zoh", "tustin"])
@pytest.mark.parametrize("dt", [1e-3, 2e-3, 0.01, 0.1])
def test_c2d_equals_python_control(method: str, dt: float) -> None:
    for num, den in _systems():
        got_n, got_d = c2d(num, den, dt, method=method)
        want_n, want_d = _oracle(num, den, dt, method)
        # the same scipy call on the same arrays: equal to the last bit, shapes included (leading zeros dropped)
        assert got_n.shape == want_n.shape and got_d.shape == want_d.shape, (num, den, got_n, want_n)
        assert np.array_equal(got_n, want_n) and np.array_equal(got_d, want_d), (num, den, got_n, want_n)


def test_the_emulator_and_sensor_coefficients_are_python_controls() -> None:
    from benchtwin.emulator.params import _pi_coefficients
    from benchtwin.sensors.imperfections import _discrete_filter

    for mass, bw, zeta, dt in ((2100.0, 2.0, 0.9, 1e-3), (1500.0, 0.8, 0.7, 0.01)):
        n, d = _oracle([2 * zeta * bw * mass, bw**2 * mass], [1.0, 0.0], dt, "tustin")
        n = n / d[0]
        assert _pi_coefficients(mass, bw, zeta, dt) == (float(n[0]), float(n[1]))
    for f_hz, order, dt in ((5.0, 1, 1e-3), (40.0, 2, 1e-3), (1.5, 2, 0.01)):
        wc = 2 * np.pi * f_hz
        den_c = [1.0, wc] if order == 1 else [1.0, 2 * 0.707 * wc, wc * wc]
        n, d = _oracle([wc if order == 1 else wc * wc], den_c, dt, "zoh")
        n = np.concatenate([np.zeros(d.size - n.size), n])
        b, a = _discrete_filter(f_hz, order, 0.707, dt)
        assert np.array_equal(b, n / d[0]) and np.array_equal(a, d / d[0])


@pytest.mark.parametrize("bad", [dict(dt=0.0), dict(dt=float("nan")), dict(method="matched"),
                                 dict(den=[0.0, 0.0]), dict(num=[float("inf")])])
def test_c2d_rejects_bad_input(bad: dict) -> None:
    args = dict(num=[1.0], den=[1.0, 1.0], dt=0.01, method="zoh") | bad
    with pytest.raises(ValueError, match="c2d"):
        c2d(**args)


def test_the_plant_and_sensors_do_not_import_python_control() -> None:
    # python-control imports matplotlib: 0.4 s at the start of every run, for two coefficient pairs
    code = ("import sys\n"
            "from benchtwin.config import load_campaign, load_vehicle, scenario_path\n"
            "from benchtwin.emulator.params import build_tables\n"
            "from benchtwin.sensors.imperfections import lti_filter\n"
            "import numpy as np\n"
            "build_tables(load_vehicle(), load_campaign(scenario_path('campaigns', 'paper.toml')))\n"
            "lti_filter(np.ones(10), 0.001, 5.0, order=2)\n"
            "print('control' in sys.modules, 'matplotlib' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"], out.stdout + out.stderr
