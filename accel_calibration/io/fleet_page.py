"""One page a fleet operator opens: vehicles x IMUs with their status, per IMU its flights' evidence over
time with its bounds, and per flight what was seen. One self-contained HTML file: its data and its one
script are inside it (no network when viewed, no CDN); the script draws each IMU's chart as inline SVG."""
from __future__ import annotations

import dataclasses
import datetime as _dt
import html
import json
from typing import Any

from ..core.evidence_trend import Trend
from ..core.units import MG
from .flight_history import ImuSeries

STATUS_CLASS = {"moved": "moved", "holds": "holds", "cannot tell": "cannot-tell"}

_STYLE = """
body { font-family: sans-serif; margin: 1.5em; color: #222; }
table { border-collapse: collapse; margin: 0.5em 0 1.5em; }
th, td { border: 1px solid #ccc; padding: 0.3em 0.6em; text-align: left; font-size: 0.9em; }
td.status { font-weight: bold; }
.moved { background: #f8c4c0; } .holds { background: #c8ebc8; } .cannot-tell { background: #f3e3a8; }
section.imu { margin-bottom: 2em; } svg.chart { border: 1px solid #ddd; background: #fff; }
"""

# Draws each IMU's charts (the ground's z in mg, then each kind of in-flight evidence) per flight with its
# 1-sigma (its own and the scatter between flights), the mean before the change and its +-k sigma band, the
# change marked. Plain DOM and SVG: no library.
_SCRIPT = """
(function () {
  var data = JSON.parse(document.getElementById('fleet-data').textContent);
  var NS = 'http://www.w3.org/2000/svg', W = 720, H = 220, PAD = 40;
  function el(name, attrs, parent) {
    var node = document.createElementNS(NS, name);
    for (var key in attrs) { node.setAttribute(key, attrs[key]); }
    parent.appendChild(node); return node;
  }
  var drawn = 0;
  function draw(chart, holder) {
    var svg = el('svg', {width: W, height: H, class: 'chart', role: 'img', 'data-kind': chart.kind}, holder);
    var low = Math.min.apply(null, chart.z.map(function (v, i) { return v - 3 * chart.sigma[i]; })
      .concat([chart.band[0]]));
    var high = Math.max.apply(null, chart.z.map(function (v, i) { return v + 3 * chart.sigma[i]; })
      .concat([chart.band[1]]));
    if (high - low < 1e-6) { high = low + 1; }
    var n = chart.z.length;
    function x(i) { return PAD + (W - 2 * PAD) * (n > 1 ? i / (n - 1) : 0.5); }
    function y(v) { return H - PAD - (H - 2 * PAD) * (v - low) / (high - low); }
    el('rect', {x: PAD, y: y(chart.band[1]), width: W - 2 * PAD,
                height: Math.max(y(chart.band[0]) - y(chart.band[1]), 1), fill: '#dde8f6', class: 'bounds'}, svg);
    el('line', {x1: PAD, x2: W - PAD, y1: y(chart.mean), y2: y(chart.mean), stroke: '#4a78b0'}, svg);
    if (chart.since !== null) {
      el('line', {x1: x(chart.since) - 3, x2: x(chart.since) - 3, y1: PAD / 2, y2: H - PAD, stroke: '#c0392b',
                  'stroke-dasharray': '4 3', class: 'change'}, svg);
    }
    chart.z.forEach(function (v, i) {
      el('line', {x1: x(i), x2: x(i), y1: y(v - chart.sigma[i]), y2: y(v + chart.sigma[i]), stroke: '#555'}, svg);
      var dot = el('circle', {cx: x(i), cy: y(v), r: 3, fill: i >= (chart.since === null ? n : chart.since) ? '#c0392b'
                               : '#222', class: 'flight'}, svg);
      el('title', {}, dot).textContent = chart.flights[i] + ': ' + v.toPrecision(3) + ' ' + chart.unit;
    });
    el('text', {x: 4, y: 14, 'font-size': 11}, svg).textContent = chart.label + ' (' + chart.unit + '), ' + n +
      ' flights; band: the mean before the split +- k sigma of the step';
    el('text', {x: 4, y: H - 8, 'font-size': 10}, svg).textContent =
      low.toPrecision(3) + ' .. ' + high.toPrecision(3) + ' ' + chart.unit;
    drawn += 1;
  }
  data.imus.forEach(function (imu, index) {
    imu.charts.forEach(function (chart, j) {
      var holder = document.getElementById('chart-' + index + '-' + j);
      if (holder && chart.z.length > 0) { draw(chart, holder); }
    });
  });
  document.body.setAttribute('data-charts', String(drawn));
})();
"""


def _chart(kind: str, label: str, unit: str, values: list[float], sigmas: list[float], flights: list[str],
           t: Trend, k_sigma: float) -> dict[str, Any]:
    """One chart's data in its unit: the values with their sigma and the scatter between flights, the band."""
    sigma = [(s**2 + t.scatter**2) ** 0.5 for s in sigmas]
    before = values[: t.since] if t.since else values
    mean = sum(before) / len(before) if before else 0.0
    spread = k_sigma * (t.sigma if t.sigma is not None else (max(sigma) if sigma else 0.0))
    return {"kind": kind, "label": label, "unit": unit, "z": values, "sigma": sigma, "flights": flights,
            "mean": mean, "band": [mean - spread, mean + spread], "since": t.since if t.status == "moved" else None}


def _scaled(t: Trend, per_unit: float) -> Trend:
    return dataclasses.replace(t, scatter=t.scatter / per_unit, sigma=None if t.sigma is None else t.sigma / per_unit)


def _charts(imu: ImuSeries, k_sigma: float) -> list[dict[str, Any]]:
    z = [float(r.z_mps2 or 0.0) / MG for r in imu.judged]
    sigmas = [float(r.z_sigma_mps2 or 0.0) / MG for r in imu.judged]
    charts = [_chart("ground", "still on the ground: bias z or scale z at 1 g", "mg", z, sigmas,
                     [r.flight for r in imu.judged], _scaled(imu.trend, MG), k_sigma)] if z else []
    for k in imu.in_flight:
        label = (f"in flight, the filter's {k.quantity}" if k.kind == "estimator"
                 else f"in flight, {k.quantity} against {'its siblings' if k.siblings > 1 else k.against}")
        charts.append(_chart(k.kind, label, k.unit, [v / k.per_unit for v in k.values],
                             [v / k.per_unit for v in k.sigmas], k.flights, _scaled(k.trend, k.per_unit), k_sigma))
    return charts


def _cell(imu: ImuSeries | None) -> str:
    if imu is None:
        return "<td>-</td>"
    status = imu.status
    return (f'<td class="status {STATUS_CLASS[status]}" data-status="{html.escape(status)}" '
            f'title="{html.escape(chr(10).join([imu.said(), *imu.said_in_flight()]))}">{html.escape(status)}</td>')


def _in_flight_text(text: str | None) -> str:
    """A flight's in-flight evidence as read: accel in mg, gyro in deg/s, each with its 1 sigma; or why none."""
    import math

    try:
        said = json.loads(text) if text else {}
    except ValueError:
        return "-"
    if not isinstance(said, dict) or not said:
        return "-"
    if said.get("reason"):
        return f"none: {said['reason']}"
    parts = []
    for part, per_unit, unit in (("accel", MG, "mg"), ("gyro", math.radians(1.0), "deg/s")):
        values, sigmas = said.get(part), said.get(f"{part}_sigma")
        if isinstance(values, list) and isinstance(sigmas, list):
            shown = " ".join("-" if v is None else f"{v / per_unit:+.3g}" for v in values)
            spread = " ".join("-" if v is None else f"{v / per_unit:.2g}" for v in sigmas)
            parts.append(f"{part} {shown} {unit} (1 sigma {spread})")
    against = f" against {said['against']}" if said.get("against") else ""
    return "; ".join(parts) + against if parts else "-"


def _flights_table(imu: ImuSeries) -> str:
    rows = []
    for r in imu.flights:
        z = "-" if r.z_mps2 is None else f"{r.z_mps2 / MG:+.2f} ± {(r.z_sigma_mps2 or 0.0) / MG:.3f}"
        rows.append(f"<tr><td>{html.escape(r.flight)}</td><td>{html.escape(r.status)}</td><td>{r.poses or 0}</td>"
                    f"<td>{html.escape(z)}</td><td>{html.escape(r.verdict or '-')}</td>"
                    f"<td>{html.escape(r.reason or '')}</td><td class=\"estimator\">"
                    f"{html.escape(_in_flight_text(r.estimator))}</td><td class=\"agreement\">"
                    f"{html.escape(_in_flight_text(r.agreement))}</td></tr>")
    return ("<details><summary>per flight: what was seen</summary><table><tr><th>flight</th><th>row</th>"
            "<th>poses</th><th>bias z or scale z (mg at 1 g ± 1 sigma)</th><th>this flight alone</th>"
            "<th>why none</th><th>in flight: the filter's bias x y z</th><th>in flight: this IMU minus its "
            "sibling x y z</th></tr>" + "".join(rows) + "</table></details>")


def fleet_page(series: list[ImuSeries], source: str, k_sigma: float) -> str:
    """The page's HTML text."""
    vehicles = sorted({imu.vehicle for imu in series})
    slots = sorted({imu.flights[-1].imu for imu in series}, key=lambda n: (n is None, n or 0))
    by_place = {(imu.vehicle, imu.flights[-1].imu): imu for imu in series}
    charts = [_charts(imu, k_sigma) for imu in series]
    header = "".join(f"<th>{'IMU' if n is None else f'IMU {n + 1}'}</th>" for n in slots)
    grid = "".join(f"<tr><th>{html.escape(v)}</th>{''.join(_cell(by_place.get((v, n))) for n in slots)}</tr>"
                   for v in vehicles)
    sections = "".join(
        f'<section class="imu" data-status="{html.escape(imu.status)}"><h3>{html.escape(imu.vehicle)} '
        f'{html.escape(imu.who)}</h3>'
        + "".join(f'<p class="said">{html.escape(line)}</p>' for line in [imu.said(), *imu.said_in_flight()])
        + "".join(f'<div id="chart-{i}-{j}" class="chart-holder"></div>' for j in range(len(charts[i])))
        + f'{_flights_table(imu)}</section>'
        for i, imu in enumerate(series))
    data = json.dumps({"imus": [{"charts": c} for c in charts]}).replace("</", "<\\/")
    written = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    return (f"<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>Fleet IMU calibration"
            f"</title><style>{_STYLE}</style></head><body><h1>Does each IMU's calibration still hold?</h1>"
            f"<p>{html.escape(source)}, {written}: still moments on the ground before arming and after landing, "
            "against the calibration in force read from each log; level ground sees the z bias and z scale "
            "together. In flight: the autopilot filter's own bias estimates, and each IMU against its siblings."
            f"</p><table class=\"fleet\"><tr><th>vehicle</th>{header}</tr>{grid}</table>{sections}"
            f"<script type=\"application/json\" id=\"fleet-data\">{data}</script><script>{_SCRIPT}</script>"
            "</body></html>")
