"""The self-contained zoomable time-series plot (proprio/timeseries_html.py): its embedded data, the envelope of long
series, input errors, and (where Node.js is installed) its script run against a minimal DOM: first draw, wheel zoom,
drag, reset and a series toggled off."""
from __future__ import annotations

import json
import re
import shutil
import subprocess

import numpy as np
import pytest

from proprio.timeseries_html import envelope, timeseries_html


def embedded(fragment: str, element_id: str = "ts") -> dict:
    m = re.search(rf"<script type='application/json' id='{element_id}-data'>(.*?)</script>", fragment, re.S)
    return json.loads(m.group(1))


def test_data_are_embedded_and_nothing_is_fetched():
    t = np.linspace(0.0, 2.0, 401)
    y = np.column_stack([np.sin(5 * t), 100 * np.cos(3 * t)])
    frag = timeseries_html(t, {"before": y, "after": 0.1 * y}, ["j1", "j2"], title="gap </script> test",
                           y_label="N·m")
    data = embedded(frag)
    assert not data["envelope"] and data["samples"] == 401
    np.testing.assert_allclose(data["t"], t, rtol=1e-5)
    np.testing.assert_allclose(data["panels"][1]["y"][0], y[:, 1], rtol=1e-4, atol=1e-9)
    np.testing.assert_allclose(data["panels"][0]["y"][1], 0.1 * y[:, 0], rtol=1e-4, atol=1e-9)
    assert [s["label"] for s in data["series"]] == ["before", "after"]
    assert "gap &lt;/script&gt; test" in frag                     # the title is escaped
    assert not re.search(r"(src|href)\s*=", frag) and "import " not in frag   # no external resources


def test_long_series_keep_every_excursion_in_the_envelope():
    rng = np.random.default_rng(1)
    t = np.arange(100_000) * 1e-3
    y = rng.normal(size=(t.size, 1))
    y[54_321, 0] = 25.0                                            # a single-sample spike
    t_env, y_env = envelope(t, y, 2_000)
    assert t_env.size == 2_000 and np.all(np.diff(t_env) >= 0)
    assert y_env.max() == 25.0 and y_env.min() == y.min()
    data = embedded(timeseries_html(t, {"e": y}, ["j1"], max_points=2_000))
    assert data["envelope"] and len(data["t"]) == 2_000 and max(data["panels"][0]["y"][0]) == 25.0


@pytest.mark.parametrize("kwargs, match", [
    ({"t": np.array([0.0, 1.0, 0.5])}, "non-decreasing"),
    ({"series": {"e": np.zeros((3, 3))}}, "shape"),
    ({"series": {"e": np.full((3, 2), np.nan)}}, "finite"),
    ({"element_id": "a b"}, "element_id"),
])
def test_bad_input_names_the_field(kwargs, match):
    args = {"t": np.array([0.0, 1.0, 2.0]), "series": {"e": np.zeros((3, 2))}, "panel_names": ["a", "b"]}
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        timeseries_html(**args)


DOM = r"""
class Node {
  constructor(tag) { this.tag = tag; this.children = []; this.attrs = {}; this.listeners = {}; this.style = {};
                     this.textContent = ""; this.checked = false; }
  appendChild(c) { this.children.push(c); return c; }
  removeChild(c) { this.children.splice(this.children.indexOf(c), 1); }
  get firstChild() { return this.children[0] || null; }
  setAttribute(k, v) { this.attrs[k] = String(v); }
  addEventListener(type, f) { (this.listeners[type] = this.listeners[type] || []).push(f); }
  fire(type, ev) { (this.listeners[type] || []).forEach(f => f(ev)); }
  getBoundingClientRect() { return {left: 0, top: 0, width: 900, height: 120}; }
  get clientWidth() { return 900; }
}
const fs = require("fs");
const root = new Node("div"); root.id = "ts";
const dataNode = {textContent: fs.readFileSync(process.argv[2], "utf8")};
const win = new Node("window");
global.window = win;
global.document = {
  getElementById: id => id === "ts" ? root : id === "ts-data" ? dataNode : null,
  createElement: tag => new Node(tag), createElementNS: (ns, tag) => new Node(tag),
  createTextNode: s => { const n = new Node("#text"); n.textContent = s; return n; },
};
eval(fs.readFileSync(process.argv[3], "utf8"));
const svgs = root.children.filter(c => c.tag === "svg");
const lines = () => svgs.map(s => s.children.filter(c => c.tag === "polyline").map(p => p.attrs.points.split(" ").length));
const view = () => svgs[svgs.length - 1].attrs["data-view"].split(",").map(Number);
const out = {panels: svgs.length, first: lines(), view0: view()};
svgs[0].fire("wheel", {clientX: 64 + 413, deltaY: -800, preventDefault() {}});
out.zoomed = view();
svgs[0].fire("mousedown", {clientX: 500});
win.fire("mousemove", {clientX: 400}); win.fire("mouseup", {});
out.panned = view();
svgs[1].fire("mousemove", {clientX: 300});
out.readout = root.children[root.children.length - 1].textContent;
svgs[0].fire("dblclick", {});
out.reset = view();
const box = root.children[0].children[1].children[0];          // legend → 2nd label → checkbox
box.checked = false; box.fire("change", {});
out.toggled = lines();
console.log(JSON.stringify(out));
"""


@pytest.mark.skipif(shutil.which("node") is None, reason="Node.js not installed")
def test_script_draws_zooms_pans_and_toggles(tmp_path):
    t = np.linspace(0.0, 10.0, 20_001)
    y = np.column_stack([np.sin(t), np.cos(7 * t), t])
    frag = timeseries_html(t, {"before": y, "after": y / 2}, ["a", "b", "c"], y_label="N·m")
    (tmp_path / "data.json").write_text(json.dumps(embedded(frag)))
    script = re.search(r"<script>(.*?)</script>", frag, re.S).group(1)
    (tmp_path / "plot.js").write_text(script)
    (tmp_path / "dom.js").write_text(DOM)
    run = subprocess.run(["node", str(tmp_path / "dom.js"), str(tmp_path / "data.json"), str(tmp_path / "plot.js")],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    assert out["panels"] == 3
    pw = 900 - 64 - 10
    for panel in out["first"]:                 # two series, each at most min+max per pixel column of 20 001 samples
        assert len(panel) == 2 and all(100 < k <= 2 * (pw + 2) for k in panel)
    assert out["view0"] == [0.0, 10.0]
    a, b = out["zoomed"]
    assert 0 < a < 5 < b < 10 and b - a < 5                      # zoomed in around the cursor (t ≈ 5 s)
    pa, pb = out["panned"]
    assert pb - pa == pytest.approx(b - a) and pa > a             # dragged left: later times, same span
    assert out["readout"].startswith("t = ") and " / " in out["readout"]
    assert out["reset"] == [0.0, 10.0]
    assert [len(p) for p in out["toggled"]] == [1, 1, 1]          # "after" hidden in every panel
