"""Sensor models against their references: Table 2, NIST type K, IVT-S frames and commands, imperfections."""

from __future__ import annotations

from pathlib import Path

import cantools
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from thermocouple_its90 import TypeK

from benchtwin.config import load_setup
from benchtwin.config.setup import ChannelErrors, IvtConfig, LinkErrors, SetupConfig, ShaftConfig, TelemetryConfig
from benchtwin.errors import ConfigError, FrameError
from benchtwin.sensors import encode
from benchtwin.sensors.imperfections import DeviceClock, device_rng, frame_faults, lti_filter, measure
from benchtwin.sensors.ivt import (
    MODE_CYCLIC,
    MODE_OFF,
    MODE_TRIGGERED,
    IvtDevice,
    result_codecs,
)
from benchtwin.sensors.synthetic import synthetic_trace
from benchtwin.sensors.telemetry import (
    bridge_voltage,
    encode_telemetry,
    k_tel_for,
    k_tot,
    table2,
    torque_from_code,
)
from benchtwin.sensors.thermocouple import emf_type_k, temperature_type_k
from benchtwin.trace import Trace
from benchtwin.wire.dbc import DBC_DIR

NIST = Path(__file__).resolve().parent / "data" / "type_k.tab"  # copy of reference/data/nist_its90/type_k.tab

# ---------------------------------------------------------------- Table 2

PAPER_TABLE2 = [  # K_TEL, resolution Nm, K_TOT Nm/V, range +-Nm (paper, Table 2)
    (250, "4.3", "874.9", 8749), (500, "2.1", "437.4", 4374), (1000, "1.1", "218.7", 2187),
    (2000, "0.5", "109.4", 1094), (4000, "0.3", "54.7", 547), (8000, "0.3", "27.3", 273),
]


def test_table2_reproduced_to_printed_digits() -> None:
    shaft = load_setup("paper").telemetry.shaft
    rows = table2(shaft)
    for row, (k, res, ktot, rng) in zip(rows, PAPER_TABLE2):
        assert row.k_tel == k
        assert f"{row.resolution_nm:.1f}" == res
        assert f"{row.k_tot_nm_per_v:.1f}" == ktot
        assert round(row.range_nm) == rng
        assert row.k_tot_nm_per_v * k == pytest.approx(218725, rel=1e-4)


def test_hollow_shaft_with_same_ip_over_re_gives_same_table() -> None:
    solid = ShaftConfig()
    ro = 0.025  # hollow shaft: choose R_i so that I_p / R_e equals the solid one's
    target = solid.polar_moment_m4 / solid.outer_radius_m
    ri = (ro**4 - 2 * target * ro / np.pi) ** 0.25
    hollow = ShaftConfig(outer_radius_m=ro, inner_radius_m=ri)
    assert k_tot(hollow, 1000) == pytest.approx(k_tot(solid, 1000), rel=1e-12)


def test_eq12_inverts_eq10() -> None:
    shaft = ShaftConfig()
    t = np.array([-1000.0, 1.0, 250.0])
    vout = 2000 * bridge_voltage(t, shaft)
    np.testing.assert_allclose(k_tot(shaft, 2000) * vout, t, rtol=1e-12)


def test_k_tel_selection_eq11() -> None:
    shaft = ShaftConfig()
    assert k_tel_for(shaft, 2000.0) == 1000
    assert k_tel_for(shaft, 3900.0) == 500
    assert k_tel_for(shaft, 200.0) == 8000
    with pytest.raises(ConfigError):
        k_tel_for(shaft, 20000.0)
    with pytest.raises(ConfigError):
        load_setup_with(telemetry={"k_tel": 300})


def load_setup_with(**kw: object) -> SetupConfig:
    from benchtwin.config import validate_data

    return validate_data(SetupConfig, kw, "<test>")


AD_DBC = cantools.database.load_file(str(DBC_DIR / "ad_module.dbc"))
IVT_DBC = cantools.database.load_file(str(DBC_DIR / "ivt_s.dbc"))


def _paper_vout(torque_nm: float, shaft: ShaftConfig, k_tel: int) -> float:
    """Eq. 4-10 of the paper written out here: torque -> shear stress -> strain -> bridge -> telemetry output."""
    i_p = np.pi * (shaft.outer_radius_m**4 - shaft.inner_radius_m**4) / 2.0
    tau = torque_nm * shaft.outer_radius_m / i_p
    eps = (1.0 + shaft.poisson) / shaft.youngs_modulus_pa * tau
    return k_tel * shaft.supply_v * shaft.gauge_factor * eps


@settings(max_examples=120, deadline=None)
@given(st.floats(-5000, 5000), st.sampled_from([250, 500, 1000, 2000, 4000, 8000]))
def test_telemetry_chain_round_trip(torque: float, k_tel: int) -> None:
    """The frames the production encoder sends, decoded by cantools from the shipped DBC, carry the code the
    paper's chain gives (computed here); the acquisition's conversion brings the torque back within half a step."""
    cfg = TelemetryConfig(k_tel=k_tel)
    t = np.arange(0.0, 0.1, 0.01)
    trace = Trace(t, {"shaft_torque_nm": np.full(t.shape, torque)})
    frames = encode_telemetry(trace, cfg, np.random.default_rng(0))
    assert len(frames) > 0 and np.all(frames["arbitration_id"] == 0x310)
    vout = _paper_vout(torque, cfg.shaft, k_tel)
    code = int(np.clip(np.rint(np.clip(vout, -10.0, 10.0) / (20.0 / 4096)), -2048, 2047))
    for k, fr in enumerate(frames):
        msg = AD_DBC.decode_message(0x310, bytes(fr["data"][:fr["dlc"]]), decode_choices=False)
        assert msg["AD_Torque_Vout"] == pytest.approx(code * 20.0 / 4096, abs=1e-12)
        assert msg["AD_Torque_Counter"] == k % 16
        assert msg["AD_Torque_Clip"] == int(abs(vout) >= 10.0 or not -2048 <= np.rint(vout / (20.0 / 4096)) <= 2047)
    # eq. 12 by hand: K_TOT = E I_p / (K_TEL V_s K_SG (1 + nu) R_e)
    sh = cfg.shaft
    kt = (sh.youngs_modulus_pa * np.pi * (sh.outer_radius_m**4 - sh.inner_radius_m**4) / 2.0
          / (k_tel * sh.supply_v * sh.gauge_factor * (1.0 + sh.poisson) * sh.outer_radius_m))
    t_back = torque_from_code(np.array([code]), cfg)[0]
    assert t_back == pytest.approx(kt * code * 20.0 / 4096, rel=1e-12)
    if abs(torque) < kt * 10 * (2047 / 2048):
        assert abs(t_back - torque) <= kt * 20 / 4096 / 2 + 1e-9


# ---------------------------------------------------------------- thermocouples


def _nist_points() -> list[tuple[float, float]]:
    """(degC, mV) of every tabulated point; the column direction (+1 or -1 per column) comes from
    each section's header line (``0 1 2 ...`` or ``0 -1 -2 ...``)."""
    pts = []
    step = 1
    for line in NIST.read_text(encoding="latin-1").splitlines():
        if line.startswith("*"):
            break  # the coefficient section follows the tables
        parts = line.split()
        if len(parts) < 2:
            continue
        try:
            base = float(parts[0])
        except ValueError:
            if parts[1] == "0" and len(parts) > 2:  # header: degree sign, then the column offsets
                step = 1 if float(parts[2]) > 0 else -1
            continue
        vals = [float(p) for p in parts[1:]]
        for k, v in enumerate(vals):
            pts.append((base + step * k, v))
    return pts


def test_type_k_every_nist_point_within_rounding() -> None:
    pts = _nist_points()
    assert len(pts) > 1600
    t = np.array([p[0] for p in pts])
    mv = np.array([p[1] for p in pts])
    err = np.abs(emf_type_k(t) - mv)
    assert err.max() <= 0.0005 + 1e-9, f"worst at {t[np.argmax(err)]} degC"
    # the inverse (module side) returns the temperature to well under the 0.1 degC output step
    sel = (t >= -200) & (t <= 1372)
    back = temperature_type_k(emf_type_k(t[sel]))
    assert np.abs(back - t[sel]).max() < 2e-3


def test_type_k_agrees_with_thermocouple_its90() -> None:
    for t in (-150.0, 0.0, 25.0, 100.0, 300.0, 1000.0):
        assert emf_type_k(np.array([t]))[0] == pytest.approx(TypeK.emf(t), abs=1e-9)
    assert temperature_type_k(np.array([4.096 + TypeK.emf(25.0)]))[0] == pytest.approx(
        TypeK.temperature(4.096, reference=25.0), abs=2e-3)


# ---------------------------------------------------------------- IVT-S


def test_ivt_example_frame() -> None:
    """The data sheet's example (facts.md): I = -12345 mA with counter 5 is 00 05 FF FF CF C7."""
    dev = IvtDevice(IvtConfig())
    dev.counters[0] = 5
    cid, data = dev.result_frame(0, -12345)
    assert cid == 0x521 and data.hex() == "0005ffffcfc7"
    assert dev.unpack_result(0, data) == (0, -12345)


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 7), st.integers(0, 15), st.integers(0, 15), st.integers(-(2**31), 2**31 - 1))
def test_ivt_codec_round_trip(mux: int, counter: int, status: int, value: int) -> None:
    """Live result frames against the layout of facts.md (byte 0 mux, byte 1 status|counter nibbles, int32 BE)
    and against cantools decoding the shipped ivt_s.dbc."""
    dev = IvtDevice(IvtConfig())
    dev.counters[mux] = counter
    cid, data = dev.result_frame(mux, value, status)
    assert cid == 0x521 + mux and len(data) == 6
    assert data[0] == mux and data[1] == (status << 4) | counter
    assert int.from_bytes(data[2:6], "big", signed=True) == value
    name = IVT_DBC.get_message_by_frame_id(cid).name.removeprefix("IVT_Result_")
    msg = IVT_DBC.decode_message(cid, data, decode_choices=False, scaling=False)
    assert (msg[f"IVT_{name}_MuxID"], msg[f"IVT_{name}_Counter"], msg[f"IVT_{name}_Status"]) == (mux, counter, status)
    assert msg[f"IVT_{name}"] == value
    assert dev.unpack_result(mux, data) == (status, value)


def test_ivt_command_answers() -> None:
    dev = IvtDevice(IvtConfig())
    assert dev.modes == [MODE_CYCLIC] * 8
    ans = dev.handle_command(bytes.fromhex("20010014"))  # current: triggered, 20 ms
    assert ans.data[0] == 0xA0 and dev.modes[0] == MODE_TRIGGERED and dev.cycles_ms[0] == 20
    ans = dev.handle_command(bytes.fromhex("2102000A"))  # U1 cyclic every 10 ms
    assert ans.data[0] == 0xA1 and dev.modes[1] == MODE_CYCLIC and dev.cycles_ms[1] == 10
    ans = dev.handle_command(bytes([0x31, 0x00, 0x03]))  # trigger I and U1: only I is triggered
    assert ans.data[0] == 0xB1 and ans.triggered == [0]
    assert dev.handle_command(bytes([0x34, 0x00])).data[0] == 0xB4 and not dev.running
    assert dev.handle_command(bytes([0x31, 0x00, 0x01])).triggered == []
    assert dev.cyclic_due(0.0, 100.0) == []
    dev.handle_command(bytes([0x34, 0x01]))
    assert dev.cyclic_due(9.0, 10.0) == [1]
    assert dev.cyclic_due(19.0, 20.0) == [1, 2, 3, 4, 5, 6, 7]
    dev.latched_status = 0x4
    assert dev.handle_command(bytes([0x30])).data[0] == 0xB0 and dev.latched_status == 0
    assert dev.handle_command(bytes([0x22, 0x00])).data[0] == 0xA2 and dev.modes[2] == MODE_OFF
    unknown = dev.handle_command(bytes([0x55, 1, 2]))
    assert unknown.data[0] == 0xFF and unknown.data[1] == 0x55
    with pytest.raises(FrameError):
        dev.handle_command(b"")
    cid, data = dev.result_frame(0, -12345)
    assert cid == 0x521 and data.hex() == "0000ffffcfc7"
    assert dev.result_frame(0, -12345)[1].hex() == "0001ffffcfc7"


def test_ivt_out_of_range_status_and_triggered_mode() -> None:
    trace = synthetic_trace(10.0, 100.0, seed=1, excursion=True)
    setup = load_setup_with(ivt={"battery": {"mode": "triggered", "trigger_period_ms": 50}},
                            buses={"instrument": {"bitrate": 1000000}})
    frames = encode(trace, setup, 0).can["instrument"].frames
    cmd = frames[frames["arbitration_id"] == 0x411]
    assert len(cmd) == pytest.approx(10.0 / 0.05, abs=2)
    assert np.all(cmd["data"][:, 0] == 0x31)
    assert np.all(frames[frames["arbitration_id"] == 0x511]["data"][:, 0] == 0xB1)
    cur = frames[frames["arbitration_id"] == 0x521]
    assert len(cur) == len(cmd)
    raw = result_codecs()[0].unpack(cur["data"])
    status, value = raw["IVT_I_Status"], raw["IVT_I"]
    over = (status & 0x2) != 0
    assert over.any() and np.all(np.abs(value[over]) == 1_000_000)
    assert np.all(np.abs(value[~over]) <= 1_000_000)


# ---------------------------------------------------------------- imperfections


def test_measure_errors_statistics() -> None:
    t = np.arange(0, 100, 0.01)
    x = np.full(t.shape, 10.0)
    rng = device_rng(5, "x")
    y = measure(t, x, t, ChannelErrors(noise_std=0.2, offset=0.5, gain_error_frac=0.01), rng)
    assert y.mean() == pytest.approx(10.0 * 1.01 + 0.5, abs=0.01)
    assert y.std() == pytest.approx(0.2, rel=0.05)
    q = measure(t, np.sin(t), t, ChannelErrors(quantisation_step=0.25), rng)
    np.testing.assert_allclose(q / 0.25, np.rint(q / 0.25), atol=1e-12)


def test_bandwidth_filter_is_the_lti_model() -> None:
    dt, fc = 0.001, 5.0
    t = np.arange(0, 1, dt)
    step = (t >= 0.1).astype(float)
    y = lti_filter(step, dt, fc, 1)
    tau = 1 / (2 * np.pi * fc)
    k = np.searchsorted(t, 0.1 + tau)
    assert y[k] == pytest.approx(1 - np.exp(-1), abs=0.01)  # first order: 63 % after one time constant
    # a sine at the cut-off frequency comes out at -3 dB (second order, zeta 0.707)
    tt = np.arange(0, 4, dt)
    s = lti_filter(np.sin(2 * np.pi * fc * tt), dt, fc, 2, 0.707)
    assert np.abs(s[len(tt) // 2:]).max() == pytest.approx(1 / np.sqrt(2), rel=0.03)
    assert lti_filter(step, dt, 0.0) is step or np.array_equal(lti_filter(step, dt, 0.0), step)


def test_latency_stuck_and_clock() -> None:
    t = np.arange(0, 10, 0.01)
    x = t.copy()
    rng = device_rng(1, "x")
    y = measure(t, x, t[100:200], ChannelErrors(), rng, latency_s=0.25)
    np.testing.assert_allclose(y, t[100:200] - 0.25, atol=1e-12)
    st_err = ChannelErrors(stuck=[{"start_s": 2.0, "end_s": 3.0}], noise_std=0.01)
    y = measure(t, x, t, st_err, rng)
    inside = (t >= 2.0) & (t < 3.0)
    assert np.all(y[inside] == y[inside][0]) and y[inside][0] == pytest.approx(2.0, abs=0.05)
    assert np.abs(y[~inside] - t[~inside]).max() < 0.06 and np.std(np.diff(y[~inside][:150])) > 0
    clk = DeviceClock(0.5, 100.0)
    np.testing.assert_allclose(clk.to_plant(clk.to_device(t)), t, atol=1e-12)
    ticks = clk.ticks(0.0, 10.0, 0.02)
    assert np.all(np.diff(ticks) == pytest.approx(0.02))
    assert clk.to_plant(ticks[0]) >= 0.0 and clk.to_plant(ticks[-1]) < 10.0


def test_frame_faults_counts() -> None:
    from benchtwin.wire.frames import FRAME_DTYPE

    n = 20000
    fr = np.zeros(n, dtype=FRAME_DTYPE)
    fr["timestamp"] = np.arange(n) * 0.001
    fr["data"][:, 0] = np.arange(n) % 256
    link = LinkErrors(drop_prob=0.01, duplicate_prob=0.02, reorder_prob=0.01)
    out = frame_faults(fr, np.zeros(n, np.int64), link, device_rng(2, "f"))
    assert len(out) == pytest.approx(n * (1 - 0.01 + 0.02 * 0.99), rel=0.05)
    assert np.all(np.diff(out["timestamp"]) >= 0)
    swapped = np.sum(np.diff(out["data"][:, 0].astype(int)) % 256 == 255)
    assert swapped > 0.5 * 0.01 * n


def test_encode_is_reproducible_and_seeded() -> None:
    trace = synthetic_trace(5.0, 100.0, seed=2)
    setup = load_setup("paper")
    a = encode(trace, setup, 42)
    b = encode(trace, setup, 42)
    c = encode(trace, setup, 43)
    for bus in a.can:
        assert np.array_equal(a.can[bus].frames, b.can[bus].frames)
    assert not np.array_equal(a.can["instrument"].frames["data"], c.can["instrument"].frames["data"])
    ideal = encode(trace, load_setup("ideal"), 1)
    ideal2 = encode(trace, load_setup("ideal"), 99)
    assert np.array_equal(ideal.can["instrument"].frames, ideal2.can["instrument"].frames)


def test_setup_errors_are_one_line_config_errors(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('[ivt.battery]\nresult_base_id = 0x521\nnoise = 1\n[ivt.hpcu]\nresult_base_id = 0x521\n')
    with pytest.raises(ConfigError) as exc:
        load_setup(bad)
    assert "noise" in str(exc.value)
    bad.write_text('[ivt.battery]\n[ivt.hpcu]\n')  # both on the factory ids
    with pytest.raises(ConfigError, match="0x521"):
        load_setup(bad)
    bad.write_text('[thermo]\nbus = "nowhere"\n')
    with pytest.raises(ConfigError, match="nowhere"):
        load_setup(bad)
