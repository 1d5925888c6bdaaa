"""A zoomable time-series plot as one self-contained HTML fragment (inline SVG + a small vanilla script: no network,
no JavaScript library), for reports that may be read offline.

:func:`timeseries_html` stacks one panel per channel (e.g. per joint) on a shared time axis. In the browser: the
mouse wheel zooms the time axis around the cursor, dragging pans, a double click resets, the checkboxes show or hide
a series, and hovering reads the values at the cursor. Each panel's y axis fits the visible data. The script draws
at most two points per pixel column (the min and max of the samples under it), so long series stay fast and no peak
is hidden at any zoom.

Data are embedded as JSON with 5 significant digits. A series longer than ``max_points`` samples is embedded as its
min/max envelope over ``max_points / 2`` equal-count buckets (each bucket's min and max, placed at its first and
last time), which still shows every excursion but not the finer detail inside a bucket.

Gaps: a step in ``t`` longer than ``GAP_FACTOR`` times the median step (samples a stage left out, e.g. a dropout of
the log) is drawn as a break in every line over a shaded band, never as a line bridging it; envelope buckets never
span a gap.
"""
from __future__ import annotations

import html
import json
import re
from typing import Mapping, Sequence

import numpy as np

__all__ = ["timeseries_html", "envelope", "SERIES_COLORS", "GAP_FACTOR"]

GAP_FACTOR = 3.0

SERIES_COLORS = ("#d62728", "#1f77b4", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b")

_SCRIPT = r"""
(function () {
  const root = document.getElementById(%(id)s);
  const data = JSON.parse(document.getElementById(%(data_id)s).textContent);
  const NS = "http://www.w3.org/2000/svg";
  const t = data.t, n = t.length, H = data.panel_height, M = {l: 64, r: 10, t: 6, b: 22};
  const shown = data.series.map(() => true), gaps = data.gaps || [];
  let view = [t[0], t[n - 1]];
  function el(name, attrs, parent) {
    const e = document.createElementNS(NS, name);
    for (const k in attrs) e.setAttribute(k, attrs[k]);
    if (parent) parent.appendChild(e);
    return e;
  }
  function lower(x) {            // first index with t[i] >= x
    let lo = 0, hi = n;
    while (lo < hi) { const mid = (lo + hi) >> 1; if (t[mid] < x) lo = mid + 1; else hi = mid; }
    return lo;
  }
  function ticks(a, b, count) {  // "nice" tick values in [a, b]
    const span = b - a || Math.abs(a) || 1, raw = span / count, p = Math.pow(10, Math.floor(Math.log10(raw)));
    const step = [1, 2, 5, 10].map(m => m * p).find(s => s >= raw);
    const out = [];
    for (let v = Math.ceil(a / step) * step; v <= b + 1e-9 * span; v += step) out.push(+v.toPrecision(10));
    return out;
  }
  function fmt(v) { return Math.abs(v) >= 1e4 || (Math.abs(v) < 1e-3 && v !== 0) ? v.toExponential(2) : +v.toPrecision(4); }
  const legend = document.createElement("div");
  legend.style.cssText = "font:12px sans-serif;margin:4px 0 4px " + M.l + "px";
  data.series.forEach((s, k) => {
    const lab = document.createElement("label");
    lab.style.marginRight = "14px";
    const box = document.createElement("input");
    box.type = "checkbox"; box.checked = true;
    box.addEventListener("change", () => { shown[k] = box.checked; draw(); });
    const sw = document.createElement("span");
    sw.style.cssText = "display:inline-block;width:18px;height:3px;vertical-align:middle;margin:0 4px;background:" + s.color;
    lab.appendChild(box); lab.appendChild(sw); lab.appendChild(document.createTextNode(s.label));
    legend.appendChild(lab);
  });
  const help = document.createElement("span");
  help.style.color = "#666";
  help.textContent = "wheel: zoom · drag: pan · double click: reset";
  legend.appendChild(help);
  root.appendChild(legend);
  const readout = document.createElement("div");
  readout.style.cssText = "font:11px monospace;min-height:14px;margin-left:" + M.l + "px;color:#333";
  const panels = data.panels.map((p, j) => {
    const svg = el("svg", {width: "100%%", height: H, style: "display:block;cursor:crosshair"}, null);
    root.appendChild(svg);
    return {svg: svg, name: p.name, y: p.y};
  });
  root.appendChild(readout);
  function width() { return Math.max(200, panels[0].svg.getBoundingClientRect().width || root.clientWidth || 800); }
  function draw() {
    const W = width(), pw = W - M.l - M.r, ph = H - M.t - M.b;
    const i0 = Math.max(0, lower(view[0]) - 1), i1 = Math.min(n, lower(view[1]) + 1);
    const sx = pw / (view[1] - view[0] || 1);
    panels.forEach((p, j) => {
      while (p.svg.firstChild) p.svg.removeChild(p.svg.firstChild);
      const clip = el("clipPath", {id: root.id + "-clip-" + j}, el("defs", {}, p.svg));
      el("rect", {x: M.l, y: M.t, width: pw, height: ph}, clip);
      let lo = Infinity, hi = -Infinity;
      p.y.forEach((y, k) => { if (shown[k]) for (let i = i0; i < i1; i++) { if (y[i] < lo) lo = y[i]; if (y[i] > hi) hi = y[i]; } });
      if (!(hi >= lo)) { lo = -1; hi = 1; }
      if (hi - lo < 1e-12) { lo -= 1; hi += 1; }
      const pad = 0.05 * (hi - lo); lo -= pad; hi += pad;
      const sy = ph / (hi - lo), X = v => M.l + (v - view[0]) * sx, Y = v => M.t + (hi - v) * sy;
      el("rect", {x: M.l, y: M.t, width: pw, height: ph, fill: "none", stroke: "#bbb"}, p.svg);
      ticks(lo, hi, 3).forEach(v => {
        el("line", {x1: M.l, x2: M.l + pw, y1: Y(v), y2: Y(v), stroke: "#eee"}, p.svg);
        el("text", {x: M.l - 4, y: Y(v) + 3, "text-anchor": "end", "font-size": 10}, p.svg).textContent = fmt(v);
      });
      ticks(view[0], view[1], 8).forEach(v => {
        el("line", {x1: X(v), x2: X(v), y1: M.t, y2: M.t + ph, stroke: "#eee"}, p.svg);
        el("text", {x: X(v), y: H - 8, "text-anchor": "middle", "font-size": 10}, p.svg).textContent = fmt(v);
      });
      el("text", {x: 4, y: M.t + 11, "font-size": 11, "font-weight": "bold"}, p.svg).textContent = p.name;
      el("text", {x: 4, y: M.t + 24, "font-size": 10, fill: "#666"}, p.svg).textContent = data.y_label;
      gaps.forEach(g => {                // no data there: a shaded band, and every line breaks
        if (g[1] > view[0] && g[0] < view[1])
          el("rect", {x: X(Math.max(g[0], view[0])), y: M.t, height: ph, fill: "#eee",
                      width: X(Math.min(g[1], view[1])) - X(Math.max(g[0], view[0]))}, p.svg);
      });
      p.y.forEach((y, k) => {
        if (!shown[k]) return;
        const segs = [];
        let pts = [], last = -Infinity;  // at most the min and max of each pixel column
        let col = -1, cmin = 0, cmax = 0, imin = 0, imax = 0;
        const flush = () => {
          if (col < 0) return;
          const a = [[imin, cmin], [imax, cmax]].sort((u, v) => u[0] - v[0]);
          a.forEach(q => {
            const tq = t[q[0]];
            if (pts.length && gaps.some(g => last <= g[0] && tq >= g[1])) { segs.push(pts); pts = []; }
            pts.push(X(tq).toFixed(1) + "," + Y(q[1]).toFixed(1));
            last = tq;
          });
        };
        for (let i = i0; i < i1; i++) {
          const c = Math.floor((t[i] - view[0]) * sx);
          if (c !== col) { flush(); col = c; cmin = cmax = y[i]; imin = imax = i; }
          else { if (y[i] < cmin) { cmin = y[i]; imin = i; } if (y[i] > cmax) { cmax = y[i]; imax = i; } }
        }
        flush();
        segs.push(pts);
        segs.forEach(s => el("polyline", {points: s.join(" "), fill: "none", stroke: data.series[k].color,
                                          "stroke-width": 1, "clip-path": "url(#" + root.id + "-clip-" + j + ")"},
                             p.svg));
      });
    });
    if (panels.length) panels[panels.length - 1].svg.setAttribute("data-view", view.join(","));
  }
  function timeAt(svg, clientX) {
    const r = svg.getBoundingClientRect(), pw = r.width - M.l - M.r;
    return view[0] + (clientX - r.left - M.l) / pw * (view[1] - view[0]);
  }
  let drag = null;
  panels.forEach(p => {
    p.svg.addEventListener("wheel", ev => {
      ev.preventDefault();
      const c = timeAt(p.svg, ev.clientX), f = Math.exp(0.0015 * ev.deltaY), full = t[n - 1] - t[0];
      let a = c - (c - view[0]) * f, b = c + (view[1] - c) * f;
      const minSpan = 5 * (full / Math.max(n - 1, 1));
      if (b - a < minSpan) { a = c - minSpan / 2; b = c + minSpan / 2; }
      view = [Math.max(t[0], a), Math.min(t[n - 1], b)];
      draw();
    }, {passive: false});
    p.svg.addEventListener("mousedown", ev => { drag = {x: ev.clientX, v: view.slice(), svg: p.svg}; });
    p.svg.addEventListener("dblclick", () => { view = [t[0], t[n - 1]]; draw(); });
    p.svg.addEventListener("mousemove", ev => {
      const x = timeAt(p.svg, ev.clientX), i = Math.min(n - 1, lower(x));
      readout.textContent = "t = " + fmt(t[i]) + " s   " + panels.map(q => q.name + ": " +
        q.y.map((y, k) => shown[k] ? fmt(y[i]) : "").filter(s => s !== "").join(" / ")).join("   ");
    });
  });
  window.addEventListener("mousemove", ev => {
    if (!drag) return;
    const r = drag.svg.getBoundingClientRect(), pw = r.width - M.l - M.r;
    const span = drag.v[1] - drag.v[0], dt = -(ev.clientX - drag.x) / pw * span;
    const a = Math.min(Math.max(t[0], drag.v[0] + dt), t[n - 1] - span);
    view = [a, a + span];
    draw();
  });
  window.addEventListener("mouseup", () => { drag = null; });
  window.addEventListener("resize", draw);
  draw();
})();
"""


def envelope(t: np.ndarray, y: np.ndarray, max_points: int) -> tuple[np.ndarray, np.ndarray]:
    """``(t, y)`` itself when ``N ≤ max_points``, else the min/max envelope of ``y [N, ...]`` over
    ``max_points // 2`` equal-count buckets along axis 0: per bucket (its first time, min) and (its last time, max)."""
    n = t.shape[0]
    if n <= max_points:
        return t, y
    edges = np.linspace(0, n, max_points // 2 + 1).astype(int)
    lo = np.minimum.reduceat(y, edges[:-1], axis=0)
    hi = np.maximum.reduceat(y, edges[:-1], axis=0)
    t_env = np.column_stack([t[edges[:-1]], t[edges[1:] - 1]]).ravel()
    y_env = np.stack([lo, hi], axis=1).reshape((-1,) + y.shape[1:])
    return t_env, y_env


def _round(a: np.ndarray) -> list:
    return [float(f"{v:.5g}") for v in np.asarray(a, dtype=float).ravel()]


def timeseries_html(t: np.ndarray, series: Mapping[str, np.ndarray], panel_names: Sequence[str], title: str = "",
                    y_label: str = "", panel_height: int = 120, max_points: int = 40_000,
                    colors: Sequence[str] = SERIES_COLORS, element_id: str = "ts") -> str:
    """A self-contained zoomable plot (module docstring) as an HTML fragment.

    Args:
        t: sample times ``[N]`` (increasing) [s].
        series: label → values ``[N, P]``, one column per panel (e.g. per joint), all in the same unit.
        panel_names: the P panel titles. y_label: the unit shown in each panel (e.g. ``"N·m"``).
        max_points: larger series are embedded as their min/max envelope (module docstring).
        element_id: the HTML id of the plot (unique within a page; letters, digits, ``-``, ``_``).
    """
    t = np.asarray(t, dtype=float)
    if t.ndim != 1 or t.size < 2 or np.any(np.diff(t) < 0) or not np.all(np.isfinite(t)):
        raise ValueError("timeseries_html: t must be a finite, non-decreasing [N] array with N >= 2")
    if not series:
        raise ValueError("timeseries_html: no series given")
    if not re.fullmatch(r"[A-Za-z][\w-]*", element_id):
        raise ValueError(f"timeseries_html: element_id {element_id!r} must be letters, digits, '-' or '_'")
    names = list(panel_names)
    arrays = {}
    for label, y in series.items():
        y = np.asarray(y, dtype=float)
        if y.shape != (t.size, len(names)) or not np.all(np.isfinite(y)):
            raise ValueError(f"timeseries_html: series {label!r} must be finite with shape [{t.size}, {len(names)}], "
                             f"got {list(y.shape)}")
        arrays[label] = y
    stacked = np.stack(list(arrays.values()), axis=2)                     # [N, P, S]
    steps = np.diff(t)
    med = float(np.median(steps))
    cut = np.flatnonzero(steps > GAP_FACTOR * med) if med > 0 else np.zeros(0, dtype=int)   # a gap after cut[k]
    bounds = np.r_[0, cut + 1, t.size]
    pieces = [envelope(t[a:b], stacked[a:b], max(2, int(max_points * (b - a) / t.size)))   # no bucket spans a gap
              for a, b in zip(bounds[:-1], bounds[1:])]
    t_emb = np.concatenate([p[0] for p in pieces])
    y_emb = np.concatenate([p[1] for p in pieces])
    data = {"t": _round(t_emb), "y_label": y_label, "panel_height": int(panel_height),
            "series": [{"label": lb, "color": colors[k % len(colors)]} for k, lb in enumerate(arrays)],
            "panels": [{"name": nm, "y": [_round(y_emb[:, p, s]) for s in range(len(arrays))]}
                       for p, nm in enumerate(names)],
            "envelope": bool(t_emb.size != t.size), "samples": int(t.size),
            "gaps": [[a, b] for a, b in zip(_round(t[cut]), _round(t[cut + 1]))]}
    data_id = f"{element_id}-data"
    script = _SCRIPT % {"id": json.dumps(element_id), "data_id": json.dumps(data_id)}
    note = (f" (min/max envelope of {t.size} samples)" if data["envelope"] else "")
    head = f"<div style='font:bold 13px sans-serif'>{html.escape(title)}{html.escape(note)}</div>" if title or note \
        else ""
    return (f"<div class='proprio-timeseries' id='{element_id}'>{head}</div>\n"
            f"<script type='application/json' id='{data_id}'>"
            + json.dumps(data, separators=(",", ":")).replace("</", "<\\/") + "</script>\n"
            f"<script>{script}</script>\n")
