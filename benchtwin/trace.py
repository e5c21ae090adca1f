"""The Trace: the emulator's truth on one time base, in SI units with the unit in each name.

Channel names end in their unit: ``_s``, ``_m``, ``_mps``, ``_mps2``, ``_radps``, ``_nm``, ``_n``,
``_w``, ``_a``, ``_v``, ``_pa``, ``_degc``, ``_kgps``, ``_frac`` (0..1), ``_pct`` (0..100) or a
dimensionless state (``gear_actual``, ``k0_closed``). See :data:`TRACE_CHANNELS` for the contract
that the sensors rely on.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from benchtwin.errors import DataError, MissingChannelError
from benchtwin.segments import Segment, segments_from_json, segments_to_json

__all__ = ["TRACE_CHANNELS", "SpooledTrace", "Trace", "TraceWriter"]

#: The channels every Trace from the emulator carries, with their meaning. Sign conventions:
#: torques positive when driving the wheels; battery and HV currents positive when discharging;
#: brake pressures gauge; forces positive in the direction of travel resisting the vehicle. A conventional car's
#: Trace is NaN in the channels it does not have (the motor's, the pack's, K0: ``meta["absent_channels"]``).
TRACE_CHANNELS: dict[str, str] = {
    "vehicle_speed_mps": "vehicle (wheel) speed",
    "vehicle_accel_mps2": "vehicle acceleration",
    "distance_m": "distance driven",
    "dyno_set_speed_mps": "speed set point of the dyno speed loop (NaN in road-load mode)",
    "dyno_speed_mps": "roller surface speed",
    "dyno_force_front_n": "tractive force measured on the front roller (positive: vehicle pushes)",
    "dyno_force_rear_n": "tractive force measured on the rear roller (positive: vehicle pushes)",
    "road_load_force_n": "F0 + F1 v + F2 v^2 that the dyno simulates",
    "pedal_pct": "accelerator pedal position",
    "brake_pedal_pct": "brake pedal demand",
    "hybrid_mode": "0 Hybrid, 1 Electric, 2 E-Save, 3 Charge",
    "engine_speed_radps": "crankshaft speed",
    "engine_torque_nm": "engine brake torque at the crankshaft",
    "engine_on": "1 when firing",
    "fuel_mass_flow_kgps": "fuel mass flow",
    "engine_coolant_in_degc": "engine coolant inlet temperature",
    "engine_coolant_out_degc": "engine coolant outlet temperature",
    "k0_closed": "1 when the K0 clutch is closed",
    "em_speed_radps": "motor speed (= torque converter pump speed)",
    "em_torque_nm": "motor shaft torque (positive motoring)",
    "em_elec_power_w": "motor DC electrical power at the HPCU (positive drawn from the HV bus)",
    "hpcu_hv_current_a": "HPCU high-voltage side current (positive into the HPCU)",
    "hpcu_hv_voltage_v": "HPCU high-voltage side voltage",
    "tc_pump_torque_nm": "torque converter pump torque",
    "tc_turbine_speed_radps": "turbine (gearbox input) speed",
    "tc_turbine_torque_nm": "turbine torque",
    "lockup_closed": "1 when the lock-up clutch is closed",
    "gear_target": "target gear requested by the shift schedule (0 neutral)",
    "gear_actual": "gear engaged (0 neutral)",
    "trans_input_torque_nm": "gearbox input torque",
    "shaft_torque_nm": "propeller shaft torque (gearbox output)",
    "shaft_speed_radps": "propeller shaft speed",
    "wheel_speed_radps": "rear wheel speed",
    "brake_pressure_fl_pa": "front-left caliper pressure",
    "brake_pressure_fr_pa": "front-right caliper pressure",
    "brake_pressure_rl_pa": "rear-left caliper pressure",
    "brake_pressure_rr_pa": "rear-right caliper pressure",
    "master_cylinder_pa": "master cylinder pressure",
    "brake_torque_front_nm": "hydraulic brake torque, front axle",
    "brake_torque_rear_nm": "hydraulic brake torque, rear axle",
    "battery_current_a": "HV battery current (positive discharge)",
    "battery_voltage_v": "HV battery terminal voltage",
    "battery_ocv_v": "HV battery open-circuit voltage",
    "battery_soc_frac": "true state of charge of the pack",
    "displayed_soc_pct": "state of charge displayed to the user (usable window)",
    "battery_temp_degc": "HV battery surface temperature",
    "battery_coolant_in_degc": "HV battery coolant inlet",
    "battery_coolant_out_degc": "HV battery coolant outlet",
    "hpcu_coolant_in_degc": "HPCU coolant inlet",
    "hpcu_coolant_out_degc": "HPCU coolant outlet",
    "motor_coolant_in_degc": "motor coolant inlet",
    "motor_coolant_out_degc": "motor coolant outlet",
    "gearbox_oil_degc": "gearbox oil (ATF) sump temperature",
    "dcdc_lv_current_a": "DC/DC converter low-voltage output current",
    "dcdc_lv_voltage_v": "DC/DC converter low-voltage output voltage",
    "lv_battery_current_a": "12 V battery current (positive discharge)",
    "lv_battery_voltage_v": "12 V battery voltage",
}


@dataclass
class Trace:
    """Named numpy arrays on one time base, plus the segment table.

    Attributes
    ----------
    time_s:
        Monotonic plant time, seconds.
    channels:
        Channel name -> array of the same length as ``time_s``.
    segments:
        The tests of the campaign, in time order.
    meta:
        Free metadata (vehicle name, campaign seed, plant rate), JSON-serialisable.
    """

    time_s: np.ndarray
    channels: dict[str, np.ndarray]
    segments: list[Segment] = field(default_factory=list)
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.time_s = np.asarray(self.time_s, dtype=np.float64)
        n = self.time_s.shape[0]
        for name, values in self.channels.items():
            arr = np.asarray(values)
            if arr.shape != (n,):
                raise DataError(f"trace channel {name!r} has shape {arr.shape}, expected ({n},)")
            self.channels[name] = arr

    def __getitem__(self, name: str) -> np.ndarray:
        if name == "time_s":
            return self.time_s
        try:
            return self.channels[name]
        except KeyError:
            raise MissingChannelError(f"trace has no channel {name!r}") from None

    def __contains__(self, name: object) -> bool:
        return name == "time_s" or name in self.channels

    def __iter__(self) -> Iterator[str]:
        return iter(self.channels)

    def __len__(self) -> int:
        return int(self.time_s.shape[0])

    def read(self, name: str, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Samples ``start:stop`` of channel ``name``."""
        return self[name][start:stop]

    def interp(self, name: str, t: np.ndarray) -> np.ndarray:
        """``np.interp(t, self.time_s, self[name])``, reading only the samples from the last at or before ``min(t)``
        to the first after ``max(t)`` (a spooled Trace reads that window of its file): the same numbers."""
        t = np.asarray(t, dtype=np.float64)
        tt = self.time_s
        n = len(tt)
        if not t.size:
            a, b = 0, min(n, 1)
        elif np.isfinite(t).all():
            a = max(int(np.searchsorted(tt, t.min(), side="right")) - 1, 0)
            b = min(int(np.searchsorted(tt, t.max(), side="right")) + 1, n)
        else:
            a, b = 0, n
        return np.interp(t, tt[a:b], self.read(name, a, b))

    @property
    def dt_s(self) -> float:
        """The plant step (median spacing of ``time_s``)."""
        if len(self) < 2:
            return float("nan")
        return float(np.median(np.diff(self.time_s)))

    @property
    def duration_s(self) -> float:
        """Time span covered by the trace."""
        return float(self.time_s[-1] - self.time_s[0]) if len(self) else 0.0

    def slice_time(self, start_s: float, end_s: float, *, lazy: bool = False) -> Trace:
        """Return the part of the trace with ``start_s <= t < end_s`` (segments clipped); ``lazy`` is for a
        :class:`SpooledTrace` (an in-memory Trace's part is cut at once)."""
        mask = (self.time_s >= start_s) & (self.time_s < end_s)
        segs = [s for s in self.segments if s.end_s > start_s and s.start_s < end_s]
        return Trace(self.time_s[mask], {k: v[mask] for k, v in self.channels.items()}, segs, dict(self.meta))

    def segment(self, name: str) -> Trace:
        """Return the part of the trace covered by the segment called ``name``."""
        for seg in self.segments:
            if seg.name == name:
                return self.slice_time(seg.start_s, seg.end_s)
        raise MissingChannelError(f"trace has no segment {name!r}")

    def save(self, directory: str | Path, *, compression: int | None = None) -> Path:
        """Save as ``trace.mf4`` (asammdf) plus ``segments.json`` and ``meta.json`` in ``directory``.

        ``compression`` is asammdf's (0 none, 1 deflate, 2 transposed deflate); None:
        :data:`benchtwin.recording.DEFAULT_COMPRESSION`.

        Returns
        -------
        Path
            The MF4 file written.
        """
        with TraceWriter(directory, compression=compression) as writer:
            writer.append(self)
        return writer.path

    @classmethod
    def load(cls, directory: str | Path) -> Trace:
        """Load a trace written by :meth:`save`."""
        from benchtwin.recording import open_mdf

        directory = Path(directory)
        path = directory / "trace.mf4"
        if not path.exists():
            raise DataError(f"{directory}: no trace.mf4 found")
        channels: dict[str, np.ndarray] = {}
        time_s = np.zeros(0)
        with open_mdf(path) as mdf:
            names = [n for n in mdf.channels_db if not (n.startswith("time") or n.startswith("$"))]
            # one select: each channel group's (compressed) data is read once for all its channels, not per channel
            for name, sig in zip(names, mdf.select([(n, *mdf.channels_db[n][0]) for n in names])):
                channels[name] = np.asarray(sig.samples, dtype=np.float64)
                time_s = np.asarray(sig.timestamps, dtype=np.float64)
        seg_path = directory / "segments.json"
        segments = segments_from_json(seg_path.read_text(encoding="utf-8"), str(seg_path)) if seg_path.exists() else []
        meta_path = directory / "meta.json"
        try:
            meta = json.loads(meta_path.read_text(encoding="utf-8")) if meta_path.exists() else {}
        except ValueError as exc:  # JSONDecodeError, UnicodeDecodeError
            raise DataError(f"{meta_path}: damaged, not the trace's meta data ({exc})") from None
        return cls(time_s, channels, segments, meta)


_UNIT_SUFFIXES: Mapping[str, str] = {
    "_mps2": "m/s^2", "_mps": "m/s", "_radps": "rad/s", "_nm": "Nm", "_n": "N", "_w": "W", "_a": "A",
    "_v": "V", "_pa": "Pa", "_degc": "degC", "_kgps": "kg/s", "_frac": "1", "_pct": "%", "_s": "s", "_m": "m",
}


def _unit_of(name: str) -> str:
    for suffix, unit in _UNIT_SUFFIXES.items():
        if name.endswith(suffix):
            return unit
    return ""


class TraceWriter:
    """Writes a Trace piece by piece (e.g. :func:`benchtwin.emulator.iter_campaign`'s tests) as :meth:`Trace.save`
    writes it whole: the same ``trace.mf4``, ``segments.json`` and ``meta.json``.

    asammdf keeps what is appended in its temporary file until the compressed file is saved on :meth:`close`, so
    only one piece is in memory at a time. The pieces must follow one another in time, with the same channels;
    the meta data written is the last piece's (the ledger to the campaign's end).

    Parameters
    ----------
    directory:
        Output folder (created).
    compression:
        As :meth:`Trace.save`.
    """

    def __init__(self, directory: str | Path, *, compression: int | None = None) -> None:
        from asammdf import MDF

        from benchtwin.mdf import DEFAULT_COMPRESSION, check_compression

        self.compression = check_compression(DEFAULT_COMPRESSION if compression is None else compression)
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.path = self.directory / "trace.mf4"
        self._mdf: Any = MDF(version="4.10")
        self._names: list[str] | None = None
        self._end = -np.inf
        self._start = np.nan
        self.segments: list[Segment] = []
        self.meta: dict[str, Any] = {}
        self.samples = 0

    def append(self, piece: Trace) -> None:
        """Append the next piece of the Trace.

        Raises
        ------
        DataError
            The piece's channels differ from the first piece's, or it does not start after the last one ended.
        """
        from asammdf import Signal

        names = list(piece.channels)
        if self._names is not None and names != self._names:
            raise DataError(f"trace piece has channels {sorted(set(names) ^ set(self._names))} unlike the first piece")
        if len(piece) and not piece.time_s[0] > self._end:
            raise DataError(f"trace piece starts at {piece.time_s[0]:.6g} s, not after the last one "
                            f"({self._end:.6g} s)")
        if len(piece):
            if self._names is None:
                self._mdf.append([Signal(samples=np.asarray(v, dtype=np.float64), timestamps=piece.time_s, name=k,
                                         unit=_unit_of(k), comment=TRACE_CHANNELS.get(k, ""))
                                  for k, v in piece.channels.items()], comment="benchtwin trace (truth)")
            else:
                self._mdf.extend(0, [(piece.time_s, None)]
                                 + [(np.asarray(piece.channels[k], dtype=np.float64), None) for k in names])
            if self._names is None:
                self._start = float(piece.time_s[0])
            self._names = names
            self._end = float(piece.time_s[-1])
            self.samples += len(piece)
        self.segments.extend(piece.segments)
        self.meta = dict(piece.meta)

    @property
    def span_s(self) -> tuple[float, float]:
        """First and last sample time written so far (0, 0 before any sample)."""
        return (self._start, self._end) if self.samples else (0.0, 0.0)

    def close(self) -> Path:
        """Save the compressed ``trace.mf4`` with ``segments.json`` and ``meta.json``; return the MF4 path."""
        if self._mdf is None:
            return self.path
        try:
            self._mdf.save(self.path, overwrite=True, compression=self.compression)
        finally:
            self._mdf.close()
            self._mdf = None
        (self.directory / "segments.json").write_text(segments_to_json(self.segments), encoding="utf-8")
        (self.directory / "meta.json").write_text(json.dumps(self.meta, indent=1, default=str), encoding="utf-8")
        return self.path

    def __enter__(self) -> TraceWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _SpooledChannels(Mapping[str, np.ndarray]):
    """The channels of a :class:`SpooledTrace`: each read whole from its file when asked for (never kept)."""

    def __init__(self, owner: SpooledTrace) -> None:
        self._owner = owner

    def __getitem__(self, name: str) -> np.ndarray:
        return self._owner.read(name)

    def __contains__(self, name: object) -> bool:
        return name in self._owner._dtypes

    def __iter__(self) -> Iterator[str]:
        return iter(self._owner._dtypes)

    def __len__(self) -> int:
        return len(self._owner._dtypes)


class _WindowChannels(_SpooledChannels):
    """The channels of samples ``a:b`` of a :class:`SpooledTrace` (``slice_time(..., lazy=True)``): each read from its
    file when first asked for, then kept."""

    def __init__(self, owner: SpooledTrace, a: int, b: int) -> None:
        super().__init__(owner)
        self._a, self._b = a, b
        self._got: dict[str, np.ndarray] = {}

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in self._got:
            self._got[name] = self._owner.read(name, self._a, self._b)
        return self._got[name]


class SpooledTrace(Trace):
    """A Trace appended piece by piece to raw files on disk, each channel read when used (whole or a time window).

    Memory holds the segment table and the meta data; a channel (``trace[name]``) is read from its file on every
    use and a time window (:meth:`slice_time`) reads only its samples, so the truth of a long campaign is never in
    memory at once. The time base is spooled too: each use of :attr:`time_s` maps its file read-only (a search in it
    touches a few pages; the pages go with the map), so it is not held between uses (8.4 MB a paper campaign,
    held through every later stage of a run when it was an array). The files are removed by :meth:`close` (or the
    ``with`` block's end); the length and the first and last times stay known.

    Parameters
    ----------
    directory:
        Where the folder of files is made (default: the system's temporary folder).
    """

    def __init__(self, directory: str | Path | None = None) -> None:  # no dataclass __init__: nothing is in memory
        import tempfile

        self._dir: Path | None = Path(tempfile.mkdtemp(prefix=".trace-", suffix=".spool", dir=directory))
        self._dtypes: dict[str, np.dtype[Any]] = {}
        self._n = 0
        self._first = self._last = float("nan")
        self.channels = _SpooledChannels(self)  # type: ignore[assignment]
        self.segments = []
        self.meta = {}

    @property  # type: ignore[override]
    def time_s(self) -> np.ndarray:
        """The time base, mapped read-only from its file (a new map each use; empty before the first piece)."""
        if self._n == 0:
            return np.zeros(0)
        if self._dir is None:
            raise DataError("the spooled Trace is closed: its files are gone")
        return np.memmap(self._dir / "time_s.raw", dtype=np.float64, mode="r", shape=(self._n,)).view(np.ndarray)

    def __len__(self) -> int:
        return self._n

    @property
    def duration_s(self) -> float:
        """Time span covered by the trace (known after :meth:`close` too)."""
        return self._last - self._first if self._n else 0.0

    def _path(self, name: str) -> Path:
        if self._dir is None:
            raise DataError("the spooled Trace is closed: its files are gone")
        return self._dir / f"{list(self._dtypes).index(name)}.raw"

    def append(self, piece: Trace) -> None:
        """Append the next piece (same channels, after the last one in time); its segments and meta data."""
        self._check(piece)
        for name in piece.channels:
            v = np.asarray(piece.channels[name])
            self._dtypes.setdefault(name, v.dtype)
            with self._path(name).open("ab") as fh:
                np.ascontiguousarray(v, dtype=self._dtypes[name]).tofile(fh)
        if self._dir is None:
            raise DataError("the spooled Trace is closed: its files are gone")
        with (self._dir / "time_s.raw").open("ab") as fh:
            np.ascontiguousarray(piece.time_s, dtype=np.float64).tofile(fh)
        self._note(piece)

    def adopt(self, piece: Trace) -> None:
        """Count the next piece as appended where its samples are in the files already: appended by the copy of this
        spool a forked process holds (its files are this one's) before the piece was handed over. The same checks
        and bookkeeping as :meth:`append`, nothing written."""
        self._check(piece)
        for name in piece.channels:
            self._dtypes.setdefault(name, np.asarray(piece.channels[name]).dtype)
        self._note(piece)

    def counted(self) -> dict[str, Any]:
        """What this spool has counted of the pieces appended (for :meth:`take_counted` of the copy of it in the
        process that forked this one: its files are this one's)."""
        return {"dtypes": dict(self._dtypes), "n": self._n, "first": self._first, "last": self._last,
                "segments": list(self.segments), "meta": dict(self.meta)}

    def take_counted(self, counted: dict[str, Any]) -> None:
        """Count what a forked copy of this spool appended into the files (its :meth:`counted`): nothing is written;
        the count may only grow (a copy of another spool, or an older count, is refused)."""
        if counted["n"] < self._n or list(counted["dtypes"])[:len(self._dtypes)] != list(self._dtypes):
            raise DataError("a spool's count that does not extend this one's")
        self._dtypes = dict(counted["dtypes"])
        self._n, self._first, self._last = counted["n"], counted["first"], counted["last"]
        self.segments = list(counted["segments"])
        self.meta = dict(counted["meta"])

    def appended(self, pieces: Iterable[Trace]) -> Iterator[Trace]:
        """Yield ``pieces``, each appended (:meth:`append`) before it is yielded."""
        for piece in pieces:
            self.append(piece)
            yield piece

    def _check(self, piece: Trace) -> None:
        names = list(piece.channels)
        if self._dtypes and names != list(self._dtypes):
            raise DataError(f"trace piece has channels {sorted(set(names) ^ set(self._dtypes))} unlike the first piece")
        end = self._last if self._n else -np.inf
        if len(piece) and not piece.time_s[0] > end:
            raise DataError(f"trace piece starts at {piece.time_s[0]:.6g} s, not after the last one ({end:.6g} s)")

    def _note(self, piece: Trace) -> None:
        if len(piece):
            self._first = float(piece.time_s[0]) if not self._n else self._first
            self._last = float(piece.time_s[-1])
            self._n += len(piece)
        self.segments.extend(piece.segments)
        self.meta = dict(piece.meta)

    def read(self, name: str, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Samples ``start:stop`` of channel ``name``, read from its file."""
        if name not in self._dtypes:
            raise MissingChannelError(f"trace has no channel {name!r}")
        n = self._n
        stop = n if stop is None else min(stop, n)
        dt = self._dtypes[name]
        with self._path(name).open("rb") as fh:
            fh.seek(start * dt.itemsize)
            return np.fromfile(fh, dtype=dt, count=max(stop - start, 0))

    def slice_time(self, start_s: float, end_s: float, *, lazy: bool = False) -> Trace:
        """The part with ``start_s <= t < end_s`` (an in-memory Trace): only that window is read; with ``lazy``
        only the window of each channel asked for, when first asked for (kept; the files must stay until then)."""
        t = self.time_s
        a, b = int(np.searchsorted(t, start_s, side="left")), int(np.searchsorted(t, end_s, side="left"))
        segs = [s for s in self.segments if s.end_s > start_s and s.start_s < end_s]
        if lazy:  # not Trace(...): its check of the channels' shapes would read them all
            out = Trace.__new__(Trace)
            out.time_s, out.segments, out.meta = np.asarray(t[a:b], dtype=np.float64), segs, dict(self.meta)
            out.channels = _WindowChannels(self, a, b)  # type: ignore[assignment]
            return out
        return Trace(t[a:b], {k: self.read(k, a, b) for k in self._dtypes}, segs, dict(self.meta))

    def close(self) -> None:
        """Remove the files (the channels can no longer be read)."""
        import shutil

        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)
            self._dir = None

    def __enter__(self) -> SpooledTrace:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
