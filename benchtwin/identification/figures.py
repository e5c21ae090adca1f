"""PNG figures of an identification run, in the style of the paper's Figures 8-24 (model against data).

Each ``figure_*`` function takes an :class:`~benchtwin.identification._fit.IdentificationResult` and a
path, draws what the result holds (the arrays the fits keep in ``FitResult.data``) and returns the path
written, or ``None`` when the result has nothing for that figure. :func:`render_figures` draws them
all into a folder. Matplotlib is used through its object API on the Agg canvas, so no display and no
global backend switch are needed.

=========  ==============================================  ===============================
file       content (paper figure)                          fits used
=========  ==============================================  ===============================
fig08      transmission efficiency vs input torque (8)     ``transmission.gear<g>``
fig10      Willans line p_me vs p_ma, colour c_m (10)      ``motor.*``
fig11      motor efficiency contours + points (11)         ``motor.*`` with ``map_eta``
fig13      BSFC contours over speed x BMEP + points (13)   ``engine.bsfc``
fig16      battery voltage model vs measured, maps (16)    ``battery``, ``battery_map_free``
fig18      torque ratio vs speed ratio (18)                ``torque_converter.torque_ratio``
fig19      capacity factor vs speed ratio (19)             ``torque_converter.capacity_factor``
fig21      shift lines + event points (21)                 ``shifts.*``
fig22      caliper pressure vs brake torque lines (22)     ``brakes.*`` with pressure/torque
fig24      brake blending maps (24)                        ``brakes.*`` with blending maps
=========  ==============================================  ===============================
"""

from __future__ import annotations

import inspect
import io
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

import matplotlib
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from benchtwin.config.specs import VehicleSpecs
from benchtwin.identification._fit import FitResult, IdentificationResult

__all__ = ["FIGURES", "render_figures", "render_figures_png"]


def _new(nrows: int = 1, ncols: int = 1, size: tuple[float, float] = (7.0, 4.8)) -> tuple[Figure, np.ndarray]:
    # fixed margins: a layout engine costs more than the drawing for these simple grids
    fig = Figure(figsize=size, dpi=110)
    FigureCanvasAgg(fig)
    axes = np.atleast_1d(fig.subplots(nrows, ncols, squeeze=False)).ravel()
    fig.subplots_adjust(left=0.09 if ncols == 1 else 0.06, right=0.97, bottom=0.1 if nrows == 1 else 0.08,
                        top=0.92 if nrows == 1 else 0.94, wspace=0.3, hspace=0.38)
    return fig, axes


def _save(fig: Figure, path: Path | BinaryIO) -> Path | BinaryIO:
    """Write the figure as PNG to a file path, or into a binary stream (rendering into memory)."""
    if isinstance(path, Path):
        path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format="png")
    return path


def _fits(result: IdentificationResult, prefix: str) -> dict[str, FitResult]:
    return {k: f for k, f in result.fits.items() if k == prefix or k.startswith(prefix + ".")
            or (prefix.endswith(".") and k.startswith(prefix))}


def _has(fit: FitResult, *keys: str) -> bool:
    return all(k in fit.data and np.size(fit.data[k]) > 0 for k in keys)


def _status(fit: FitResult) -> str:
    return "" if fit.status == "ok" else " (flagged)"


def figure_transmission(result: IdentificationResult, path: Path) -> Path | None:
    """Figure 8: transmission efficiency vs input torque, data and eq. 14 per gear."""
    fits = {k: f for k, f in _fits(result, "transmission").items() if _has(f, "c", "eta")}
    if not fits:
        return None
    fig, (ax,) = _new()
    cmap = matplotlib.colormaps["viridis"]
    for j, (key, f) in enumerate(sorted(fits.items())):
        col = cmap(j / max(len(fits) - 1, 1))
        label = key.removeprefix("transmission.")
        ax.plot(f.data["c"], f.data["eta"], "o", ms=3, color=col, alpha=0.6)
        if _has(f, "c_curve", "eta_curve"):
            ax.plot(f.data["c_curve"], f.data["eta_curve"], "-", color=col,
                    label=f"{label}: eta_m {f.value('eta_m'):.3f}, C0 {f.value('C0'):.1f} Nm, "
                          f"R2 {f.r2:.3f}{_status(f)}")
    ax.set_xlabel("input torque C (Nm)")
    ax.set_ylabel("efficiency (-)")
    ax.set_title("Transmission efficiency: data (dots) and eq. 14 (lines)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=6)
    return _save(fig, path)


def figure_motor_willans(result: IdentificationResult, path: Path) -> Path | None:
    """Figure 10: normalised Willans line p_me vs p_ma, coloured by mean rotor speed c_m."""
    fits = {k: f for k, f in _fits(result, "motor").items() if _has(f, "p_me", "p_ma")}
    if not fits:
        return None
    fig, (ax,) = _new()
    sc = None
    for key, f in sorted(fits.items()):
        sc = ax.scatter(f.data["p_ma"] / 1e5, f.data["p_me"] / 1e5, c=f.data.get("c_m"), s=8, cmap="plasma")
        model = f.data.get("p_me_fit")
        if model is not None:
            order = np.argsort(f.data["p_ma"])
            ax.plot(f.data["p_ma"][order] / 1e5, model[order] / 1e5, "k.", ms=2,
                    label=f"{key}: model, R2 {f.r2:.3f}{_status(f)}")
        elif "p_ma_fit" in f.data:
            order = np.argsort(f.data["p_me"])
            ax.plot(f.data["p_ma_fit"][order] / 1e5, f.data["p_me"][order] / 1e5, "k.", ms=2,
                    label=f"{key}: model, R2 {f.r2:.3f}{_status(f)}")
    if sc is not None and "c_m" in next(iter(fits.values())).data:
        fig.colorbar(sc, ax=ax, label="c_m (m/s)")
    ax.set_xlabel("p_ma (bar)")
    ax.set_ylabel("p_me (bar)")
    ax.set_title("Motor Willans line: data (colour) and model (black)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    return _save(fig, path)


def _full_load(specs: VehicleSpecs | None, n_max: float) -> tuple[np.ndarray, np.ndarray] | None:
    """The motor's full-load curve ``T = min(T_max, P_max / omega)`` from the public rating, or None."""
    if specs is None or specs.em_max_torque_nm is None:
        return None
    n = np.linspace(0.0, specs.em_max_speed_rpm or n_max, 200)
    t = np.full_like(n, specs.em_max_torque_nm)
    if specs.em_max_power_w is not None:
        w = n * np.pi / 30.0
        t = np.minimum(t, np.divide(specs.em_max_power_w, w, out=np.full_like(w, np.inf), where=w > 0))
    return n, t


def figure_motor_efficiency(result: IdentificationResult, path: Path, specs: VehicleSpecs | None = None
                            ) -> Path | None:
    """Figure 11: motor efficiency contours over speed x torque with the measured points.

    The contours are the identified Willans line's efficiency ``e T w / (T w + W_loss)`` up to the motor's
    full-load curve (from the public rating in ``specs``, when given); the region the campaign visited is
    the convex hull of the measured points.
    """
    fits = [f for _, f in sorted(_fits(result, "motor").items())
            if _has(f, "map_speed_rpm", "map_torque_nm", "map_eta")]
    if not fits:
        return None
    f = fits[0]
    fig, (ax,) = _new()
    pts_n = np.asarray(f.data.get("speed_rpm", []), dtype=float)
    pts_t = np.asarray(f.data.get("torque_nm", []), dtype=float)
    full = _full_load(specs, float(np.max(f.data["map_speed_rpm"])))
    if full is not None and "e" in f.params and "W_loss" in f.params:
        sg = np.linspace(max(full[0][1], 1.0), full[0][-1], 80)
        tg = np.linspace(0.0, float(np.max(full[1])), 81)[1:]
        N, T = np.meshgrid(sg, tg)
        P = T * N * np.pi / 30.0
        eta = f.value("e") * P / (P + f.value("W_loss"))
        eta[np.interp(sg, *full)[None, :] * (1 + 1e-9) < T] = np.nan
        x, y = sg, tg
    else:
        eta = np.asarray(f.data["map_eta"], dtype=float)
        x, y = f.data["map_speed_rpm"], f.data["map_torque_nm"]
    levels = [lv for lv in (0.70, 0.80, 0.85, 0.88, 0.90, 0.92, 0.93, 0.94, 0.95, 0.96)
              if np.nanmin(eta) < lv < np.nanmax(eta)] if np.isfinite(eta).any() else []
    cs = ax.contour(x, y, eta, levels=levels or 8, cmap="viridis")
    ax.clabel(cs, fontsize=7, fmt="%.2f")
    if pts_n.size:
        ax.plot(pts_n, pts_t, "r.", ms=3, label="measured points")
    ok = np.isfinite(pts_n) & np.isfinite(pts_t)
    if ok.sum() >= 3:
        from scipy.spatial import ConvexHull, QhullError

        xy = np.column_stack([pts_n[ok], pts_t[ok]])
        try:
            hull = ConvexHull(xy)
        except QhullError:
            hull = None
        if hull is not None:
            ring = np.append(hull.vertices, hull.vertices[0])
            ax.plot(xy[ring, 0], xy[ring, 1], "k--", lw=1, label="region visited (convex hull)")
    if full is not None:
        ax.plot(full[0], full[1], "b-", lw=1.5,
                label=f"full load (rating: {specs.em_max_torque_nm:.0f} Nm"  # type: ignore[union-attr]
                      + (f", {specs.em_max_power_w / 1e3:.0f} kW)" if specs.em_max_power_w else ")"))  # type: ignore[union-attr]
    ax.set_xlabel("motor speed (rpm)")
    ax.set_ylabel("motor torque (Nm)")
    ax.set_title("Motor efficiency map from the Willans line")
    ax.legend(fontsize=7)
    return _save(fig, path)


def figure_bsfc(result: IdentificationResult, path: Path) -> Path | None:
    """Figure 13: BSFC contours over engine speed x BMEP with the data points."""
    f = result.fits.get("engine.bsfc")
    if f is None or not _has(f, "map_speed_rpm", "map_bmep_bar", "map_bsfc"):
        return None
    fig, (ax,) = _new()
    z = np.asarray(f.data["map_bsfc"], dtype=float)
    x, y = np.asarray(f.data["map_speed_rpm"]), np.asarray(f.data["map_bmep_bar"])
    if z.shape != (y.size, x.size) and z.shape == (x.size, y.size):
        z = z.T
    zmin = np.nanmin(z)
    levels = np.unique(np.round(zmin + np.array([2, 8, 15, 25, 40, 60, 90, 130, 200, 300]), 0))
    cs = ax.contour(x, y, z, levels=levels, cmap="viridis_r")
    ax.clabel(cs, fontsize=7, fmt="%.0f")
    if "map_extrapolated" in f.data:
        ext = np.asarray(f.data["map_extrapolated"], dtype=float)
        if ext.shape == z.shape and ext.any():
            ax.contourf(x, y, ext, levels=[0.5, 1.5], colors="none", hatches=["///"])
    if _has(f, "speed_rpm", "bmep_bar"):
        ax.scatter(f.data["speed_rpm"], f.data["bmep_bar"], c="r", s=10, label="steady points")
    ax.set_xlabel("engine speed (rpm)")
    ax.set_ylabel("BMEP (bar)")
    ax.set_title("BSFC map (g/kWh); hatched: extrapolated")
    ax.legend(fontsize=7)
    return _save(fig, path)


def figure_battery(result: IdentificationResult, path: Path) -> Path | None:
    """Figure 16: battery voltage (literature model, corrected model, measured) and corrected maps."""
    f = result.fits.get("battery")
    mf = result.fits.get("battery_map_free")
    if f is not None and _has(f, "t", "v_meas", "v_model"):
        fig, axes = _new(2, 3, size=(12.0, 6.5))
        t = f.data["t"]
        step = max(1, t.size // 2000)
        ax = axes[0]
        ax.plot(t[::step], f.data["v_meas"][::step], "k-", lw=0.8, label="measured")
        if "v_lit" in f.data:
            ax.plot(t[::step], f.data["v_lit"][::step], "b-", lw=0.8, label="literature maps")
        ax.set_title("(b) raw: measured vs literature model")
        ax2 = axes[1]
        ax2.plot(t[::step], f.data["v_meas"][::step], "k-", lw=0.8, label="measured")
        ax2.plot(t[::step], f.data["v_model"][::step], "b-", lw=0.8,
                 label=f"eq. 30, adj. R2 {f.adj_r2:.4f}{_status(f)}")
        ax2.set_title("(f) optimised model")
        for a in axes[:2]:
            a.set_xlabel("time (s)")
            a.set_ylabel("pack voltage (V)")
            a.legend(fontsize=7)
        soc = f.data["map_soc"]
        for a, lit, cor, title, unit in (
            (axes[3], "lit_r_dch", "map_r_dch", "(c) discharge resistance", "mOhm"),
            (axes[4], "lit_r_ch", "map_r_ch", "(d) charge resistance", "mOhm"),
            (axes[5], "lit_ocv", "map_ocv", "(e) OCV", "V"),
        ):
            k = 1e3 if unit == "mOhm" else 1.0
            a.plot(soc, f.data[lit] * k, "b--", label="literature")
            a.plot(soc, f.data[cor] * k, "r-", label="corrected")
            a.set_title(title + " per cell")
            a.set_xlabel("displayed SOC (%)")
            a.set_ylabel(unit)
            a.legend(fontsize=7)
        axes[2].plot(f.data["current"][::step], (f.data["v_meas"] - f.data["v_model"])[::step], ".", ms=2)
        axes[2].set_xlabel("current (A)")
        axes[2].set_ylabel("residual (V)")
        axes[2].set_title(f"residuals, RMSE {f.rmse:.3f} V")
        return _save(fig, path)
    if mf is not None and _has(mf, "t", "v_meas", "v_model"):
        fig, axes = _new(1, 3, size=(12.0, 4.0))
        t = mf.data["t"]
        step = max(1, t.size // 2000)
        axes[0].plot(t[::step], mf.data["v_meas"][::step], "k.", ms=1, label="measured")
        axes[0].plot(t[::step], mf.data["v_model"][::step], "b.", ms=1, label=f"OCV - I R, R2 {mf.r2:.3f}")
        axes[0].set_xlabel("time (s)")
        axes[0].set_ylabel("voltage (V)")
        axes[0].legend(fontsize=7)
        nodes = mf.data["soc_nodes"]
        style = "o-" if nodes.size > 1 else "o"
        axes[1].plot(nodes, mf.data["ocv_nodes"], style, label="OCV - I R fit")
        rest = result.fits.get("battery_ocv_rest")
        if rest is not None and _has(rest, "soc", "ocv"):
            axes[1].plot(rest.data["soc"], rest.data["ocv"], "rx", label="end of long rests")
        axes[1].legend(fontsize=7)
        axes[1].set_title("OCV(SOC)")
        axes[1].set_xlabel("SOC (%)")
        axes[2].plot(nodes, mf.data["r_dch_nodes"] * 1e3, style, label="discharge (fit)")
        axes[2].plot(nodes, mf.data["r_ch_nodes"] * 1e3, style, label="charge (fit)")
        r0 = result.fits.get("battery_r0")
        if r0 is not None and _has(r0, "soc_nodes", "r0_nodes"):
            axes[2].plot(r0.data["soc_nodes"], r0.data["r0_nodes"] * 1e3, "k^", label="R0 (current steps)")
        axes[2].set_title("R(SOC) (mOhm)")
        axes[2].set_xlabel("SOC (%)")
        axes[2].legend(fontsize=7)
        return _save(fig, path)
    return None


def _tc_curve(result: IdentificationResult, name: str) -> FitResult | None:
    f = result.fits.get(f"torque_converter.{name}")
    return f if f is not None and _has(f, "sr") else None


def figure_torque_ratio(result: IdentificationResult, path: Path) -> Path | None:
    """Figure 18: torque ratio vs speed ratio, model and data."""
    f = _tc_curve(result, "torque_ratio")
    if f is None:
        return None
    d = f.data
    fig, (ax,) = _new()
    inl = np.asarray(d.get("inlier", np.ones(np.size(d["sr"]))), dtype=bool)
    if inl.shape == np.shape(d["sr"]) and not inl.all():
        ax.plot(d["sr"][~inl], d["tr"][~inl], ".", color="0.7", ms=3, label="left out (transients)")
        ax.plot(d["sr"][inl], d["tr"][inl], ".", color="tab:red", ms=3, label="data")
    else:
        ax.plot(d["sr"], d["tr"], ".", color="tab:red", ms=3, label="data")
    order = np.argsort(d["sr"])
    ax.plot(d["sr"][order], d["tr_model"][order], "-", color="tab:blue", label=f"model, R2 {f.r2:.3f}")
    g = float(d["gamma"][0])
    ax.axvline(g, color="k", ls=":", label=f"coupling point {g:.3f}")
    ax.set_xlabel("speed ratio SR (-)")
    ax.set_ylabel("torque ratio TR (-)")
    ax.set_title("Torque converter: torque ratio")
    ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3)
    return _save(fig, path)


def figure_capacity_factor(result: IdentificationResult, path: Path) -> Path | None:
    """Figure 19: capacity factor n_p / sqrt(T_p) vs speed ratio, model and data."""
    f = _tc_curve(result, "capacity_factor")
    if f is None:
        return None
    d = f.data
    fc = result.fits.get("torque_converter.capacity_factor_coupling")
    fig, (ax,) = _new()
    inl = np.asarray(d.get("inlier", np.ones(np.size(d["sr"]))), dtype=bool)
    if inl.shape == np.shape(d["sr"]) and not inl.all():
        ax.plot(d["sr"][~inl], d["cf"][~inl], ".", color="0.7", ms=3, label="left out (transients)")
        ax.plot(d["sr"][inl], d["cf"][inl], ".", color="tab:red", ms=3, label="data")
    else:
        ax.plot(d["sr"], d["cf"], ".", color="tab:red", ms=3, label="data")
    order = np.argsort(d["sr"])
    lab = f"model, R2 {f.r2:.3f} converter" + (f", {fc.r2:.3f} coupling" if fc is not None else "")
    ax.plot(d["sr"][order], d["cf_model"][order], "-", color="tab:blue", label=lab)
    finite = d["cf"][np.isfinite(d["cf"])]
    if finite.size:
        ax.set_ylim(0, float(np.percentile(finite, 99)) * 1.3)
    ax.set_xlabel("speed ratio SR (-)")
    ax.set_ylabel("capacity factor (rpm / sqrt(Nm))")
    ax.set_title("Torque converter: capacity factor")
    ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3)
    return _save(fig, path)


def figure_shifts(result: IdentificationResult, path: Path) -> Path | None:
    """Figure 21: shift lines (speed vs pedal) with the target-gear change events."""
    fits = {k.removeprefix("shifts."): f for k, f in _fits(result, "shifts").items() if _has(f, "pedal", "speed")}
    if not fits:
        return None
    cmap = matplotlib.colormaps["tab10"]
    fig, (ax,) = _new(size=(8.0, 5.5))
    pmax = max(float(np.max(f.data["pedal"])) for f in fits.values())
    pp = np.linspace(0.0, max(pmax, 1.0), 50)
    for name, f in sorted(fits.items(), key=lambda kv: (int(kv[0].split("_")[1]), kv[0])):
        direction, a, b = name.split("_")
        col = cmap((min(int(a), int(b)) - 1) % 10)
        ls, mk = ("-", "o") if direction == "up" else ("--", "s")
        ax.plot(f.data["pedal"], f.data["speed"], mk, color=col, ms=4, mfc="none" if direction == "down" else col)
        c0, c1 = f.value("c0_kmh"), f.value("c1_kmh_per_pct")
        if np.isfinite(c0) and np.isfinite(c1):
            ax.plot(pp, c0 + c1 * pp, ls, color=col, lw=1, label=f"{a}->{b}" + _status(f))
    ax.set_xlabel("accelerator pedal (%)")
    ax.set_ylabel("vehicle speed (km/h)")
    ax.set_title("Shift thresholds: up (solid, dots) and down (dashed, squares)")
    ax.legend(fontsize=6, ncol=2)
    ax.grid(True, alpha=0.3)
    return _save(fig, path)


def figure_brake_gains(result: IdentificationResult, path: Path) -> Path | None:
    """Figure 22: axle brake torque vs caliper pressure with the fitted gain lines."""
    def xy(f: FitResult) -> tuple[np.ndarray, np.ndarray] | None:
        for pk in ("p_bar", "pressure_bar"):
            if _has(f, pk, "torque_nm"):
                return np.asarray(f.data[pk]), np.asarray(f.data["torque_nm"])
        a = f.data.get("A")
        if a is not None and np.ndim(a) == 2 and np.shape(a)[1] == 1 and _has(f, "y"):  # torque = gain * pressure
            return np.asarray(a)[:, 0], np.asarray(f.data["y"])
        return None

    fits = {k: f for k, f in _fits(result, "brakes").items() if xy(f) is not None}
    if not fits:
        return None
    fig, (ax,) = _new()
    for key, f in sorted(fits.items()):
        x, y = xy(f)  # type: ignore[misc]
        yf = f.data.get("torque_fit_nm", f.data.get("y_fit"))
        ax.plot(x, y, ".", ms=3, label=f"{key.removeprefix('brakes.')} data")
        if _has(f, "p_curve_bar", "torque_curve_nm"):
            gain = next((p for n, p in f.params.items() if n.startswith("m_")), None)
            lab = f"fit{'' if gain is None else f' {gain.value:.1f} Nm/bar'}, R2 {f.r2:.3f}{_status(f)}"
            ax.plot(f.data["p_curve_bar"], f.data["torque_curve_nm"], "-", label=lab)
        elif yf is not None and np.size(yf) == np.size(x):
            order = np.argsort(x)
            ax.plot(np.asarray(x)[order], np.asarray(yf)[order], "-", label=f"fit, R2 {f.r2:.3f}{_status(f)}")
    ax.set_xlabel("caliper pressure (bar)")
    ax.set_ylabel("brake torque (Nm)")
    ax.set_title("Brake pressure-to-torque gains")
    ax.legend(fontsize=7)
    ax.grid(True, alpha=0.3)
    return _save(fig, path)


def figure_blending(result: IdentificationResult, path: Path) -> Path | None:
    """Figure 24: brake blending maps (shares over speed x deceleration)."""
    maps = []
    for key, f in sorted(_fits(result, "brakes").items()):
        for name, z in f.data.items():
            if not name.endswith("_share"):
                continue
            z = np.asarray(z, dtype=float)
            if z.ndim == 2:
                maps.append((f"{key.removeprefix('brakes.')}: {name.removeprefix('map_')}", f, z))
    if not maps:
        return None
    n = len(maps)
    fig, axes = _new(1, n, size=(4.2 * n, 4.0))
    for ax, (title, f, z) in zip(axes, maps):
        x = f.data.get("map_speed_edges_kmh", f.data.get("map_speed_kmh"))
        y = f.data.get("map_decel_edges_mps2", f.data.get("map_decel_mps2"))
        if x is not None and y is not None and (z.shape == (np.size(y), np.size(x))
                                                or z.shape == (np.size(y) - 1, np.size(x) - 1)):
            im = ax.pcolormesh(x, y, z, shading="auto", cmap="viridis", vmin=0, vmax=1)
            ax.set_xlabel("speed (km/h)")
            ax.set_ylabel("deceleration (m/s2)")
        else:
            im = ax.imshow(z, origin="lower", aspect="auto", cmap="viridis", vmin=0, vmax=1)
        fig.colorbar(im, ax=ax)
        ax.set_title(title, fontsize=8)
    return _save(fig, path)


#: file stem -> figure function, in the paper's order
FIGURES: dict[str, Callable[[IdentificationResult, Path], Path | None]] = {
    "fig08_transmission_efficiency": figure_transmission,
    "fig10_motor_willans": figure_motor_willans,
    "fig11_motor_efficiency_map": figure_motor_efficiency,
    "fig13_bsfc_map": figure_bsfc,
    "fig16_battery": figure_battery,
    "fig18_tc_torque_ratio": figure_torque_ratio,
    "fig19_tc_capacity_factor": figure_capacity_factor,
    "fig21_shift_thresholds": figure_shifts,
    "fig22_brake_gains": figure_brake_gains,
    "fig24_brake_blending": figure_blending,
}


def _draw(result: IdentificationResult, target_of: Callable[[str], Path | BinaryIO], specs: VehicleSpecs | None,
          errors: dict[str, str] | None) -> dict[str, Path | BinaryIO]:
    written: dict[str, Path | BinaryIO] = {}
    for stem, func in FIGURES.items():
        kwargs = {"specs": specs} if "specs" in inspect.signature(func).parameters else {}
        try:
            p = func(result, target_of(stem), **kwargs)
        except (ValueError, TypeError, KeyError, IndexError) as exc:
            if errors is None:
                raise
            errors[stem] = f"{type(exc).__name__}: {exc}"
            continue
        if p is not None:
            written[stem] = p
    return written


def render_figures(result: IdentificationResult, out_dir: str | Path,
                   errors: dict[str, str] | None = None, specs: VehicleSpecs | None = None) -> dict[str, Path]:
    """Draw every figure the result has data for into ``out_dir``.

    Parameters
    ----------
    result:
        The identification result.
    out_dir:
        Folder for the PNG files (created).
    errors:
        When given, a figure that cannot be drawn (unexpected arrays) is skipped and its error
        message stored here under its file stem, so one bad figure does not stop the others.
    specs:
        Public specs, for what a figure draws from the catalogue (the motor's full-load curve).

    Returns
    -------
    dict
        File stem -> path written (figures without data are left out).
    """
    out_dir = Path(out_dir)
    return _draw(result, lambda stem: out_dir / f"{stem}.png", specs, errors)  # type: ignore[return-value]


def render_figures_png(result: IdentificationResult, errors: dict[str, str] | None = None,
                       specs: VehicleSpecs | None = None) -> dict[str, bytes]:
    """Draw every figure into memory: file stem -> PNG bytes (for a self-contained HTML report).

    Parameters
    ----------
    result:
        The identification result whose fits are drawn.
    errors:
        Fit name -> error message of the methods that could not fit (shown instead of their figure).
    specs:
        Public specs (the motor's full-load curve on the efficiency map, when they give its rating).
    """
    buffers: dict[str, io.BytesIO] = {}

    def target(stem: str) -> io.BytesIO:
        buffers[stem] = io.BytesIO()
        return buffers[stem]

    written = _draw(result, target, specs, errors)
    return {stem: buffers[stem].getvalue() for stem in written}
