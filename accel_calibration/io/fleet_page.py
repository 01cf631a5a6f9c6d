"""One page a fleet operator opens: vehicles x IMUs with their status, per IMU its flights' evidence over
time with its bounds, and per flight what was seen. One self-contained HTML file: its data and its one
script are inside it (no network when viewed, no CDN); the script draws each IMU's chart as inline SVG."""
from __future__ import annotations

import datetime as _dt
import html
import json
from typing import Any

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

# Draws each IMU's chart: z (mg) per flight with its 1-sigma (its own and the scatter between flights), the
# mean before the change and its +-k sigma band, the change marked. Plain DOM and SVG: no library.
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
  data.imus.forEach(function (imu, index) {
    var holder = document.getElementById('chart-' + index);
    if (!holder || imu.z.length === 0) { return; }
    var svg = el('svg', {width: W, height: H, class: 'chart', role: 'img'}, holder);
    var low = Math.min.apply(null, imu.z.map(function (v, i) { return v - 3 * imu.sigma[i]; }).concat([imu.band[0]]));
    var high = Math.max.apply(null, imu.z.map(function (v, i) { return v + 3 * imu.sigma[i]; }).concat([imu.band[1]]));
    if (high - low < 1e-6) { high = low + 1; }
    var n = imu.z.length;
    function x(i) { return PAD + (W - 2 * PAD) * (n > 1 ? i / (n - 1) : 0.5); }
    function y(v) { return H - PAD - (H - 2 * PAD) * (v - low) / (high - low); }
    el('rect', {x: PAD, y: y(imu.band[1]), width: W - 2 * PAD, height: Math.max(y(imu.band[0]) - y(imu.band[1]), 1),
                fill: '#dde8f6', class: 'bounds'}, svg);
    el('line', {x1: PAD, x2: W - PAD, y1: y(imu.mean), y2: y(imu.mean), stroke: '#4a78b0'}, svg);
    if (imu.since !== null) {
      el('line', {x1: x(imu.since) - 3, x2: x(imu.since) - 3, y1: PAD / 2, y2: H - PAD, stroke: '#c0392b',
                  'stroke-dasharray': '4 3', class: 'change'}, svg);
    }
    imu.z.forEach(function (v, i) {
      el('line', {x1: x(i), x2: x(i), y1: y(v - imu.sigma[i]), y2: y(v + imu.sigma[i]), stroke: '#555'}, svg);
      var dot = el('circle', {cx: x(i), cy: y(v), r: 3, fill: i >= (imu.since === null ? n : imu.since) ? '#c0392b'
                               : '#222', class: 'flight'}, svg);
      el('title', {}, dot).textContent = imu.flights[i] + ': ' + v.toFixed(2) + ' mg';
    });
    var axis = el('text', {x: 4, y: 14, 'font-size': 11}, svg);
    axis.textContent = 'bias z or scale z at 1 g (mg), ' + n +
      ' flights; band: the mean before the split +- k sigma of the step';
    el('text', {x: 4, y: H - 8, 'font-size': 10}, svg).textContent = low.toFixed(1) + ' .. ' + high.toFixed(1) + ' mg';
    drawn += 1;
  });
  document.body.setAttribute('data-charts', String(drawn));
})();
"""


def _imu_data(imu: ImuSeries, k_sigma: float) -> dict[str, Any]:
    t = imu.trend
    z = [float(r.z_mps2 or 0.0) / MG for r in imu.judged]
    sigma = [((float(r.z_sigma_mps2 or 0.0) ** 2 + t.scatter**2) ** 0.5) / MG for r in imu.judged]
    before = z[: t.since] if t.since else z
    mean = sum(before) / len(before) if before else 0.0
    spread = k_sigma * (t.sigma / MG if t.sigma is not None else (max(sigma) if sigma else 0.0))
    return {"z": z, "sigma": sigma, "flights": [r.flight for r in imu.judged], "mean": mean,
            "band": [mean - spread, mean + spread], "since": t.since if t.status == "moved" else None}


def _cell(imu: ImuSeries | None) -> str:
    if imu is None:
        return "<td>-</td>"
    status = imu.trend.status
    return (f'<td class="status {STATUS_CLASS[status]}" data-status="{html.escape(status)}" '
            f'title="{html.escape(imu.said())}">{html.escape(status)}</td>')


def _flights_table(imu: ImuSeries) -> str:
    rows = []
    for r in imu.flights:
        z = "-" if r.z_mps2 is None else f"{r.z_mps2 / MG:+.2f} ± {(r.z_sigma_mps2 or 0.0) / MG:.3f}"
        rows.append(f"<tr><td>{html.escape(r.flight)}</td><td>{html.escape(r.status)}</td><td>{r.poses or 0}</td>"
                    f"<td>{html.escape(z)}</td><td>{html.escape(r.verdict or '-')}</td>"
                    f"<td>{html.escape(r.reason or '')}</td></tr>")
    return ("<details><summary>per flight: what was seen</summary><table><tr><th>flight</th><th>row</th>"
            "<th>poses</th><th>bias z or scale z (mg at 1 g ± 1 sigma)</th><th>this flight alone</th>"
            "<th>why none</th></tr>" + "".join(rows) + "</table></details>")


def fleet_page(series: list[ImuSeries], source: str, k_sigma: float) -> str:
    """The page's HTML text."""
    vehicles = sorted({imu.vehicle for imu in series})
    slots = sorted({imu.flights[-1].imu for imu in series}, key=lambda n: (n is None, n or 0))
    by_place = {(imu.vehicle, imu.flights[-1].imu): imu for imu in series}
    header = "".join(f"<th>{'IMU' if n is None else f'IMU {n + 1}'}</th>" for n in slots)
    grid = "".join(f"<tr><th>{html.escape(v)}</th>{''.join(_cell(by_place.get((v, n))) for n in slots)}</tr>"
                   for v in vehicles)
    sections = "".join(
        f'<section class="imu" data-status="{html.escape(imu.trend.status)}"><h3>{html.escape(imu.vehicle)} '
        f'{html.escape(imu.who)}</h3><p class="said">{html.escape(imu.said())}</p>'
        f'<div id="chart-{i}" class="chart-holder"></div>{_flights_table(imu)}</section>'
        for i, imu in enumerate(series))
    data = json.dumps({"imus": [_imu_data(imu, k_sigma) for imu in series]}).replace("</", "<\\/")
    written = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    return (f"<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>Fleet IMU calibration"
            f"</title><style>{_STYLE}</style></head><body><h1>Does each IMU's calibration still hold?</h1>"
            f"<p>{html.escape(source)}, {written}: still moments on the ground before arming and after landing, "
            "against the calibration in force read from each log; level ground sees the z bias and z scale "
            f"together.</p><table class=\"fleet\"><tr><th>vehicle</th>{header}</tr>{grid}</table>{sections}"
            f"<script type=\"application/json\" id=\"fleet-data\">{data}</script><script>{_SCRIPT}</script>"
            "</body></html>")
