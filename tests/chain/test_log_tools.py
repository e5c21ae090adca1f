"""Raw logs as the tools expect them: absolute time in every format, folders that decode on their own.

- BLF and MF4 bus logs of a run read with unmodified ``can.BLFReader`` / ``can.MF4Reader`` keep each bus's
  offset and start at the Recording's start time;
- the per-bus DBC written beside the logs decodes every frame of the logs with plain cantools (the
  shipped generic DBCs do not: they cover factory identifiers only), the shaft torque in Nm;
- the Recording MF4 carries value-to-text tables for states and a bit-field text table for the flags.
"""

from __future__ import annotations

import can  # before asammdf (facts: can.MF4Reader may not find asammdf otherwise)
import cantools
import numpy as np
import pytest

from benchtwin.chain.batch import deliver, run_batch
from benchtwin.config.setup import load_setup
from benchtwin.sensors import encode
from benchtwin.sensors.synthetic import synthetic_trace
from benchtwin.sensors.telemetry import k_tot
from benchtwin.wire.dbc import DBC_DIR, build_vehicle


@pytest.fixture(scope="module")
def paper_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper_logs")
    setup = load_setup("paper")
    trace = synthetic_trace(3.0)
    rec = run_batch(trace, setup, 0, out, blf=True)
    received = deliver(encode(trace, setup, 0), setup, seed=0)
    return setup, out, rec, received


def _first_times(reader) -> float:
    for msg in reader:
        return float(msg.timestamp)
    raise AssertionError("empty log")


def test_blf_and_mf4_logs_read_by_python_can_align_the_buses_and_start_at_the_recordings_start(paper_run):
    from asammdf import MDF

    setup, out, _, received = paper_run
    with MDF(out / "recording.mf4") as mdf:
        rec_start = mdf.header.start_time.timestamp()
    true_first = {b: float(t.frames["timestamp"][0]) for b, t in received.can.items()}
    # the paper setup's dyno logger starts 123.5 ms into the run: the offset the readers must keep
    assert true_first["dyno"] - true_first["instrument"] > 0.1
    for bus in setup.buses:
        with can.BLFReader(str(out / f"{bus}.blf")) as r:
            blf_first = _first_times(r)
        with can.MF4Reader(str(out / f"{bus}.mf4")) as r:
            mf4_first = _first_times(r)
        assert abs(blf_first - mf4_first) < 1e-3, bus
        assert abs((blf_first - rec_start) - true_first[bus]) < 1e-3, bus
        assert abs((mf4_first - rec_start) - true_first[bus]) < 1e-3, bus
    # between buses: the offsets are the true ones, in both formats
    with can.BLFReader(str(out / "dyno.blf")) as r1, can.BLFReader(str(out / "instrument.blf")) as r2:
        d = _first_times(r1) - _first_times(r2)
    assert abs(d - (true_first["dyno"] - true_first["instrument"])) < 1e-3


def test_the_batch_round_trip_through_blf_keeps_run_times(paper_run, tmp_path):
    from benchtwin.chain.buslog import read_blf, read_mf4

    _, out, _, received = paper_run
    for bus, table in received.can.items():
        blf = read_blf(out / f"{bus}.blf", bus)
        mf4 = read_mf4(out / f"{bus}.mf4", bus)
        np.testing.assert_allclose(blf.frames["timestamp"], table.frames["timestamp"], atol=1e-6)
        np.testing.assert_allclose(mf4.frames["timestamp"], table.frames["timestamp"], atol=1e-6)


def _unknown(frames_by_bus, dbs) -> tuple[int, int]:
    unknown = total = 0
    for bus, frames in frames_by_bus.items():
        db = dbs[bus]
        for msg in frames:
            total += 1
            try:
                db.decode_message(msg.arbitration_id, bytes(msg.data))
            except KeyError:
                unknown += 1
    return unknown, total


def test_the_dbc_beside_the_logs_decodes_every_frame_and_the_shaft_torque_in_nm(paper_run):
    setup, out, rec, _ = paper_run
    frames = {}
    for bus in setup.buses:
        with can.MF4Reader(str(out / f"{bus}.mf4")) as r:
            frames[bus] = list(r)
    beside = {bus: cantools.database.load_file(str(out / f"{bus}.dbc")) for bus in setup.buses}
    unknown, total = _unknown(frames, beside)
    assert total > 5000 and unknown == 0
    # the shipped generic files cover the factory ids only: most instrument frames are unknown to them
    shipped = cantools.database.Database()
    for stem in ("vehicle", "dyno", "ivt_s", "ad_module"):
        shipped.add_dbc_file(str(DBC_DIR / f"{stem}.dbc"))
    unknown_shipped, _ = _unknown({"instrument": frames["instrument"]}, {"instrument": shipped})
    assert unknown_shipped > 0.3 * len(frames["instrument"])
    # the AD module's frame decodes to Nm with the setup's K_TOT, equal to the Recording's channel
    ad = [m for m in frames["instrument"] if m.arbitration_id == setup.telemetry.can_id]
    msg = beside["instrument"].get_message_by_frame_id(setup.telemetry.can_id)
    sig = msg.get_signal_by_name("AD_Torque_ShaftTorque")
    assert sig.unit == "Nm"
    assert sig.scale == pytest.approx(k_tot(setup.telemetry.shaft, setup.telemetry.k_tel) * 20.0 / 4096)
    nm = np.array([beside["instrument"].decode_message(m.arbitration_id, bytes(m.data))["AD_Torque_ShaftTorque"]
                   for m in ad])
    np.testing.assert_allclose(nm, rec["shaft_torque_nm"].values[:len(nm)], atol=1e-9)
    generic = cantools.database.load_file(str(DBC_DIR / "ad_module.dbc"))
    assert generic.get_message_by_frame_id(0x310).get_signal_by_name("AD_Torque_Vout").unit == "V"


def test_the_recording_mf4_shows_words_for_states_and_flags(paper_run):
    from asammdf import MDF

    _, out, rec, _ = paper_run
    choices = build_vehicle().get_message_by_name("HYB_Status").get_signal_by_name("HybridMode").choices
    with MDF(out / "recording.mf4") as mdf:
        sig = mdf.get("hybrid_mode")
        raw = mdf.get("hybrid_mode", raw=True)
        assert raw.conversion is not None and raw.conversion.conversion_type == 7  # value to text
        for value, text in zip(raw.samples, sig.samples):
            assert text.decode() == str(choices[int(value)])
        conv = raw.conversion
        table = {int(conv[f"val_{k}"]): conv.referenced_blocks[f"text_{k}"].decode()
                 for k in range(conv.ref_param_nr - 1)}
        assert table[1] == "Electric" == str(choices[1])
        gear = mdf.get("gear_actual", raw=True)
        assert gear.conversion is not None and gear.conversion.conversion_type == 7
        flags = mdf.get("shaft_torque_nm.flags", raw=True)
        assert flags.conversion is not None and flags.conversion.conversion_type == 11  # bit-field text table
        assert mdf.header.start_time == rec.start_time
    with MDF(out / "vehicle.mf4") as mdf:
        assert mdf.header.start_time == rec.start_time


def test_a_record_folder_decodes_on_its_own(paper_run, tmp_path):
    """What record/serve --record leave beside the Recording: logs, DBCs, EDS, setup.json; acquire reads it."""
    from asammdf import MDF

    from benchtwin.chain.live.bench import save_capture
    from benchtwin.chain.live.recorder import LiveCapture
    from benchtwin.cli import main
    from benchtwin.recording import Recording

    setup, _, _, received = paper_run
    cap = LiveCapture(can=dict(received.can), polls=dict(received.polls), start_wall=1_790_000_000.25, speedup=1.0)
    rec = save_capture(cap, setup, tmp_path / "live.mf4")
    raw = tmp_path / "live_raw"
    for name in ("setup.json", "thermo_module.eds", *(f"{b}.dbc" for b in setup.buses),
                 *(f"{b}.mf4" for b in setup.buses)):
        assert (raw / name).exists(), name
    assert main(["acquire", str(raw), "--out", str(tmp_path / "again.mf4")]) == 0
    again = Recording.load(tmp_path / "again.mf4")
    assert set(again.channels) == set(rec.channels)
    np.testing.assert_allclose(again["shaft_torque_nm"].values, rec["shaft_torque_nm"].values)
    np.testing.assert_allclose(again["vehicle_speed_kmh"].timestamps, rec["vehicle_speed_kmh"].timestamps)
    # the logs and both Recordings start at the acquisition start
    starts = []
    for path in (raw / "vehicle.mf4", tmp_path / "live.mf4", tmp_path / "again.mf4"):
        with MDF(path) as mdf:
            starts.append(mdf.header.start_time.timestamp())
    assert starts == pytest.approx([1_790_000_000.25] * 3, abs=1e-6)
