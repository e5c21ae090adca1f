"""The report a test engineer opens: one self-contained ``report.html`` of a validation run.

Everything is in the one file (figures as base64 PNG, styles inline, no script, no external asset), so it can
be mailed or archived beside the bus logs. Sections: the verdict, the prediction of the held-out drives, the
checks table (identified, truth or prediction, error, tolerance, why), the chain summary (bus loads, clock
offsets, flagged and clipped samples) and the figures (the paper's Figures 8-24 from the identification, and
the held-out drive predicted against its measurement).
"""

from __future__ import annotations

import base64
import html
import io
import math
from pathlib import Path
from typing import Any

import numpy as np

from benchtwin.config.specs import VehicleSpecs
from benchtwin.identification._fit import IdentificationResult
from benchtwin.validation.report import Check, ValidationReport

__all__ = ["figure_images", "render_html", "write_html"]

_CSS = """
body{font-family:sans-serif;margin:1.5em;max-width:1200px;color:#222}
h1{font-size:1.5em}h2{font-size:1.2em;border-bottom:1px solid #ccc;margin-top:1.6em}
table{border-collapse:collapse;font-size:0.85em;margin:0.5em 0}
td,th{border:1px solid #ddd;padding:2px 6px;vertical-align:top}th{background:#f3f3f3;text-align:left}
td.n{text-align:right;font-family:monospace;white-space:nowrap}
.pass{color:#176b1c;font-weight:bold}.fail{color:#b00020;font-weight:bold}
.verdict{font-size:1.4em;padding:0.4em 0.8em;display:inline-block;border-radius:4px}
.verdict.pass{background:#e3f4e4}.verdict.fail{background:#fbe3e6}
tr.grp td{background:#eef;font-weight:bold}td.why{font-size:0.9em;color:#555;max-width:520px}
figure{display:inline-block;margin:0.5em;vertical-align:top}figcaption{font-size:0.85em;color:#444}
img{max-width:560px;border:1px solid #eee}
"""


def _e(x: Any) -> str:
    return html.escape(str(x))


def _num(x: Any, fmt: str = ".6g") -> str:
    if isinstance(x, (int, float)) and math.isfinite(x):
        return format(x, fmt)
    return "-"


def _err_tol(c: Check) -> tuple[str, str]:
    if c.mode == "rel":
        return (f"{100 * c.error:+.3f} %" if math.isfinite(c.error) else "-", f"{100 * c.tolerance:.3g} %")
    if c.mode == "abs":
        return (_num(c.error, "+.4g"), f"{c.tolerance:.3g} {c.unit}".strip())
    return (_num(c.error, ".4f"), f">= {c.tolerance:.3f}")


def _checks_table(checks: list[Check]) -> str:
    rows = ["<table><tr><th>check</th><th>identified / predicted</th><th>truth / measured</th><th>error</th>"
            "<th>tolerance</th><th>result</th><th>why (tolerance, or reason of failure)</th></tr>"]
    group = None
    for c in checks:
        if c.group != group:
            group = c.group
            rows.append(f'<tr class="grp"><td colspan="7">{_e(group)}</td></tr>')
        err, tol = _err_tol(c)
        res = '<span class="pass">pass</span>' if c.passed else '<span class="fail">FAIL</span>'
        rows.append(f"<tr><td>{_e(c.name)}</td><td class=n>{_num(c.identified)}</td><td class=n>{_num(c.truth)}</td>"
                    f"<td class=n>{_e(err)}</td><td class=n>{_e(tol)}</td><td>{res}</td>"
                    f'<td class="why">{_e(c.note)}</td></tr>')
    rows.append("</table>")
    return "\n".join(rows)


def _kv_table(title: str, d: dict[str, Any], fmt: str = ".4g") -> str:
    if not d:
        return f"<p>{_e(title)}: none</p>"
    rows = "".join(f"<tr><td>{_e(k)}</td><td class=n>{_num(v, fmt) if isinstance(v, (int, float)) else _e(v)}</td></tr>"
                   for k, v in sorted(d.items()))
    return f"<table><tr><th colspan=2>{_e(title)}</th></tr>{rows}</table>"


def _interval_section(report: ValidationReport) -> str:
    """Each scalar parameter's statistical and total 95 % interval against the truth (GUM type A and B)."""
    rows = report.coverage
    if not rows:
        return ""
    tb = (report.identification.meta.get("type_b", {}) if report.identification is not None else {})
    note = ("The statistical interval carries the fit's scatter only (type A); the total one adds the systematic "
            "errors the setup declares (gain, offset, resolution: type B), propagated through each fit.")
    if not tb.get("declared"):
        note += " " + str(tb.get("note", "No systematic uncertainties were declared: total = statistical."))
    n = len(rows)
    k_s, k_t = sum(r["inside_stat"] for r in rows), sum(r["inside_total"] for r in rows)
    out = [f"<h2>95 % intervals against the truth</h2><p>{_e(note)} Truth inside: statistical {k_s}/{n}, "
           f"total {k_t}/{n}.</p>",
           "<table><tr><th>parameter</th><th>identified</th><th>truth</th><th>u stat</th><th>u total</th>"
           "<th>95 % statistical</th><th>95 % total</th><th>truth inside (stat / total)</th></tr>"]
    for r in rows:
        def ci(c: Any) -> str:
            return f"[{_num(c[0])}, {_num(c[1])}]" if c is not None else "-"
        inside = f"{'yes' if r['inside_stat'] else 'no'} / {'yes' if r['inside_total'] else 'no'}"
        out.append(f"<tr><td>{_e(r['key'])}</td><td class=n>{_num(r['value'])}</td><td class=n>{_num(r['truth'])}</td>"
                   f"<td class=n>{_num(r['u_stat'], '.3g')}</td><td class=n>{_num(r['u_total'], '.3g')}</td>"
                   f"<td class=n>{_e(ci(r.get('ci95')))}</td><td class=n>{_e(ci(r.get('ci95_total')))}</td>"
                   f"<td>{_e(inside)}</td></tr>")
    out.append("</table>")
    return "\n".join(out)


def _prediction_section(pred: dict[str, Any]) -> str:
    out = ["<h2>Prediction of held-out drives (map-based model)</h2>"]
    drives = pred.get("drives", [])
    if pred.get("held_out"):
        out.append(f"<p>Identification ran without the segment <b>{_e(pred['held_out'])}</b>; the map-based model "
                   "(road load, eq. 14 per gear, converter curves, Willans lines, eq. 30, BSFC map; only the "
                   "identification result and the public specs) predicts it and further drives it never saw (the WLTC "
                   "from a low SOC, the NEDC from a few points above the sustain threshold). "
                   "Goal: fuel and electric energy within 2 %, final SOC within 1 point.</p>")
    if drives:
        out.append("<table><tr><th>drive</th><th>gears</th><th>quantity</th><th>predicted</th><th>measured</th>"
                   "<th>error</th></tr>")
        for d in drives:
            p, m, e = d["predicted"], d["measured"], d["errors"]
            firing = m.get("fuel_firing_g")
            rows = [("fuel (g)", p["fuel_g"], m["fuel_g"], f"{100 * e['fuel']:+.2f} %")]
            if firing is not None:
                pf = p.get("fuel_firing_g", p["fuel_g"])
                rows.append((f"fuel without {m.get('engine_starts', 0):.0f} engine starts (g)", pf, firing,
                             f"{100 * (pf / firing - 1) if firing > 0 else float('nan'):+.2f} %"))
            dist = max(m.get("distance_km", 0.0), 1e-9)
            rows += [("CO2 (g/km)", p["co2_g"] / dist, m["co2_g"] / dist, f"{100 * e['co2']:+.2f} %"),
                     ("battery electric energy (Wh)", p["electric_wh"], m["electric_wh"],
                      f"{100 * e['electric']:+.2f} %" + (
                          f" of the net; {100 * e['electric_of_fuel_energy']:+.2f} % of the fuel energy "
                          "(charge-sustaining)" if e.get("charge_sustaining") else "")),
                     ("initial SOC (%)", p["initial_soc_pct"], m["initial_soc_pct"],
                      f"{p['initial_soc_pct'] - m['initial_soc_pct']:+.2f} pt"),
                     ("final SOC (%)", p["final_soc_pct"], m["final_soc_pct"], f"{e['soc_points']:+.2f} pt")]
            for k, (q, pv, mv, ev) in enumerate(rows):
                head = (f'<td rowspan="{len(rows)}">{_e(d["name"])}</td><td rowspan="{len(rows)}">'
                        f'{_e(d["gear_source"])}</td>') if k == 0 else ""
                out.append(f"<tr>{head}<td>{_e(q)}</td><td class=n>{_num(pv, '.5g')}</td>"
                           f"<td class=n>{_num(mv, '.5g')}</td><td class=n>{_e(ev)}</td></tr>")
        out.append("</table>")
    notes = list(pred.get("notes", []))
    for d in drives[:1]:
        notes += [n for n in d.get("notes", []) if n not in notes]
    if notes:
        out.append("<ul>" + "".join(f"<li>{_e(n)}</li>" for n in notes) + "</ul>")
    return "\n".join(out)


def _png(fig: Any) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()


def _prediction_figure(pred: dict[str, Any]) -> bytes | None:
    s, m = pred.get("series"), pred.get("series_measured")
    if not s or not m:
        return None
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.0, 6.0), dpi=100)
    FigureCanvasAgg(fig)
    axes = fig.subplots(3, 1, sharex=True)
    fig.subplots_adjust(left=0.11, right=0.97, bottom=0.08, top=0.93, hspace=0.25)
    t0 = float(np.asarray(s["t_s"])[0])
    for ax, key, label in zip(axes, ("soc_pct", "battery_voltage_v", "fuel_g"),
                              ("displayed SOC (%)", "battery voltage (V)", "fuel burnt (g)"), strict=True):
        ax.plot(np.asarray(m["t_s"]) - t0, m[key], "k-", lw=0.8, label="measured (emulated)")
        ax.plot(np.asarray(s["t_s"]) - t0, s[key], "r-", lw=0.8, alpha=0.8, label="predicted (maps)")
        ax.set_ylabel(label, fontsize=8)
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=7)
    axes[0].set_title(f"Held-out drive {pred.get('held_out', '')}: model vs measurement", fontsize=9)
    axes[-1].set_xlabel("time in the drive (s)")
    return _png(fig)


def figure_images(prediction: dict[str, Any] | None, identification: IdentificationResult | None,
                  specs: VehicleSpecs | None = None) -> tuple[list[tuple[str, bytes]], dict[str, str]]:
    """The report's figures: the held-out drive's (from ``prediction``) and the identification's.

    Parameters
    ----------
    prediction:
        The report's prediction (``ValidationReport.prediction``).
    identification:
        The identification result whose fits are drawn (the figures read the fits, not their type B intervals).
    specs:
        Public specs (the motor's full-load curve).

    Returns
    -------
    tuple
        (caption, PNG bytes) in the report's order, and figure stem -> why it could not be drawn.
    """
    imgs: list[tuple[str, bytes]] = []
    errors: dict[str, str] = {}
    if prediction:
        p = _prediction_figure(prediction)
        if p is not None:
            imgs.append(("held-out drive: model vs measurement", p))
    if identification is not None:
        from benchtwin.identification.figures import render_figures_png

        imgs += list(render_figures_png(identification, errors=errors, specs=specs).items())
    return imgs, errors


def render_html(report: ValidationReport, specs: VehicleSpecs | None = None, *, figures: bool = True,
                images: tuple[list[tuple[str, bytes]], dict[str, str]] | None = None) -> str:
    """The report as one self-contained HTML document.

    Parameters
    ----------
    report:
        The validation report.
    specs:
        Public specs (for the figures).
    figures:
        Draw the figures section.
    images:
        The figures already drawn (:func:`figure_images`, e.g. beside the type B re-runs); None: drawn here.
    """
    meta = report.meta
    n_fail = len(report.failures())
    verdict = "PASS" if report.passed else "FAIL"
    cls = "pass" if report.passed else "fail"
    parts = ["<!DOCTYPE html><html lang=en><head><meta charset=utf-8>",
             f"<title>benchtwin validation: {verdict}</title><style>{_CSS}</style></head><body>",
             "<h1>benchtwin validation report</h1>",
             f'<p id="verdict" class="verdict {cls}">Verdict: {verdict} &mdash; {len(report.checks)} checks, '
             f"{len(report.checks) - n_fail} passed, {n_fail} failed</p>",
             "<p>" + ", ".join(f"{_e(k)} <b>{_e(v)}</b>" for k, v in meta.items()) + "</p>",
             "<p>wall time: " + ", ".join(f"{_e(k)} {v:.1f} s" for k, v in report.timings_s.items()) + "</p>",
             "<p>How to read: every check compares an identified (or predicted) number with the truth of the "
             "emulated vehicle (or the emulated measurement); <i>error</i> is in the terms of the tolerance "
             "(relative, or absolute in the unit, or a minimum such as R&sup2;), and <i>why</i> says where the "
             "tolerance comes from or why the check failed. Failed checks are listed first below.</p>"]
    if report.failures():
        parts.append("<h2>Failed checks</h2>" + _checks_table(report.failures()))
    if report.prediction:
        parts.append(_prediction_section(report.prediction))
    parts.append("<h2>All checks</h2>" + _checks_table(report.checks))
    parts.append(_interval_section(report))
    ch = report.chain
    parts.append("<h2>Acquisition chain</h2>")
    parts.append(f"<p>plant time {_num(ch.get('plant_seconds'), '.1f')} s</p>")
    parts.append(_kv_table("bus load", ch.get("bus_load", {}), ".3g"))
    parts.append(_kv_table("clock offsets detected (s)", ch.get("clock_offsets_s", {}), ".4g"))
    parts.append(_kv_table("flagged samples per channel", ch.get("flagged_samples", {}), "d"))
    parts.append(_kv_table("clipped (saturated) samples per channel", ch.get("clipped_samples", {}), "d"))
    if figures:
        imgs, errors = images if images is not None else figure_images(report.prediction, report.identification,
                                                                         specs)
        if errors:
            parts.append("<p>figures not drawn: " + _e("; ".join(f"{k}: {v}" for k, v in errors.items())) + "</p>")
        parts.append("<h2>Figures</h2>")
        for cap, data in imgs:
            b64 = base64.b64encode(data).decode("ascii")
            parts.append(f'<figure><img alt="{_e(cap)}" src="data:image/png;base64,{b64}">'
                         f"<figcaption>{_e(cap)}</figcaption></figure>")
    parts.append("</body></html>")
    return "\n".join(parts)


def write_html(report: ValidationReport, path: str | Path, specs: VehicleSpecs | None = None, *,
               images: tuple[list[tuple[str, bytes]], dict[str, str]] | None = None) -> Path:
    """Write :func:`render_html` to ``path`` (``images``: the figures already drawn, see :func:`render_html`)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(render_html(report, specs, images=images), encoding="utf-8")
    return path
