"""A run as one self-contained HTML page: the frames embedded as JSON, a canvas drawn by a few
lines of script (no library, no network), play/pause, a step slider, toggles for contacts and
impulses, an arrow-length control (x1/8 to x8 of the run's impulse scale, with a legend arrow), and
each step's numbers beside the canvas. `#frame=K` in the address opens frame K; `#arrows=Z` sets
the control to 2^Z.

The canvas sits at the page's top-left corner and has the window's aspect ratio, so a world
point maps to a pixel as in draw.Window.pixel (the tests check a screenshot there)."""
import numpy as np

from .. import __version__
from ..escape import fill, html_text, script_json
from .draw import ARROW_LONGEST, FILL, legend_impulse
from .frames import painter_for, read_frame


def _rounded(values, digits=4):
    return [round(float(v), digits) for v in np.asarray(values, np.float64).ravel()]


def viewer_html(clip, width=640, fps=30, impulse_scale=None, window=None):
    """The page for a clip: the window and the run's impulse scale as its pictures use them (or
    those given); a slider scales the arrows by 1/8 to 8 in the page."""
    painter = painter_for(clip, width, window=window, impulse_scale=impulse_scale)
    window, shapes = painter.window, painter.shapes
    frames = []
    for path in clip.files:
        header, bodies, contacts = read_frame(clip, path)
        solve = header.get("solve")
        frames.append({
            "step": int(header["index"]), "time": round(float(header["time"]), 6),
            "bodies": _rounded(np.column_stack([bodies["index"], bodies["position"], bodies["angle"],
                                                bodies["type"]])),
            "contacts": _rounded(np.column_stack([contacts["position"], contacts["normal"],
                                                  contacts["normal_impulse"], contacts["tangent_impulse"]])),
            "solve": None if not solve else {"iterations": int(solve["iterations"]),
                                             "residual": float(solve["residual"])},
        })
    data = {
        "scene": clip.scene, "seed": clip.seed, "run": str(clip.path), "steps": clip.total,
        "window": [window.x0, window.y0, window.x1, window.y1], "size": list(painter.size), "fps": fps,
        "scale": painter.impulse_scale, "legend": legend_impulse(painter.impulse_scale, window),
        "longest": (window.x1 - window.x0) * ARROW_LONGEST,
        "fill": {str(k): v for k, v in FILL.items()},
        "circles": _rounded(shapes.circles), "edges": _rounded(shapes.edges),
        "polygons": [[int(b), _rounded(v)] for b, v in shapes.polygons],
        "frames": frames,
    }
    w, h = painter.size
    return fill(PAGE, DATA=script_json(data), W=str(w), H=str(h), TITLE=html_text(f"{clip.scene} seed {clip.seed}"),
                VERSION=html_text(__version__))


PAGE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>__TITLE__ · deepcontact run viewer</title>
<style>
body { margin: 0; font: 13px/1.4 system-ui, sans-serif; color: #222; }
#view { position: absolute; left: 0; top: 0; width: __W__px; height: __H__px; }
#side { position: absolute; left: calc(__W__px + 12px); top: 8px; width: 300px; }
#side table { border-collapse: collapse; }
#side td { padding: 1px 8px 1px 0; }
#side td.v { text-align: right; font-variant-numeric: tabular-nums; }
#controls { margin: 8px 0; }
#slider { width: 250px; }
</style></head>
<body>
<canvas id="view" width="__W__" height="__H__"></canvas>
<div id="side">
  <div><b id="name"></b></div>
  <div id="controls">
    <button id="play" type="button">play</button>
    <label><input id="contacts" type="checkbox" checked> contacts</label>
    <label><input id="impulses" type="checkbox" checked> impulses</label><br>
    <input id="slider" type="range" min="0" value="0"><br>
    <label>arrows <input id="scale" type="range" min="-3" max="3" step="0.5" value="0"> <span id="scaled">x1</span></label>
  </div>
  <table id="numbers"></table>
  <p style="color:#777">deepcontact __VERSION__ · normal impulses red, friction blue</p>
</div>
<script id="data" type="application/json">__DATA__</script>
<script>
"use strict";
const D = JSON.parse(document.getElementById("data").textContent);
const canvas = document.getElementById("view"), g = canvas.getContext("2d");
const [X0, Y0, X1, Y1] = D.window, W = canvas.width, H = canvas.height;
const px = x => (x - X0) / (X1 - X0) * W, py = y => (Y1 - y) / (Y1 - Y0) * H, k = W / (X1 - X0);
const byBody = {};
function shapeOf(body) { return byBody[body] || (byBody[body] = {circles: [], polygons: [], edges: []}); }
for (let i = 0; i < D.circles.length; i += 4) shapeOf(D.circles[i]).circles.push(D.circles.slice(i + 1, i + 4));
for (let i = 0; i < D.edges.length; i += 5) shapeOf(D.edges[i]).edges.push(D.edges.slice(i + 1, i + 5));
for (const [b, v] of D.polygons) shapeOf(b).polygons.push(v);
const place = (x, y, a, lx, ly) => [x + Math.cos(a) * lx - Math.sin(a) * ly, y + Math.sin(a) * lx + Math.cos(a) * ly];
let frame = 0, timer = null;

function draw() {
  const f = D.frames[frame];
  g.fillStyle = "#ffffff"; g.fillRect(0, 0, W, H);
  g.lineWidth = 1;
  for (let i = 0; i < f.bodies.length; i += 5) {
    const [b, x, y, a, type] = f.bodies.slice(i, i + 5), s = byBody[b];
    if (!s) continue;
    g.fillStyle = D.fill[type] || D.fill["2"]; g.strokeStyle = "#3a3a3a";
    for (const [x1, y1, x2, y2] of s.edges) {
      const p = place(x, y, a, x1, y1), q = place(x, y, a, x2, y2);
      g.lineWidth = 1.5; g.beginPath(); g.moveTo(px(p[0]), py(p[1])); g.lineTo(px(q[0]), py(q[1])); g.stroke();
      g.lineWidth = 1;
    }
    for (const v of s.polygons) {
      g.beginPath();
      for (let j = 0; j < v.length; j += 2) { const p = place(x, y, a, v[j], v[j + 1]); g.lineTo(px(p[0]), py(p[1])); }
      g.closePath(); g.fill(); g.stroke();
    }
    for (const [r, lx, ly] of s.circles) {
      const c = place(x, y, a, lx, ly);
      g.beginPath(); g.arc(px(c[0]), py(c[1]), r * k, 0, 2 * Math.PI); g.fill(); g.stroke();
      g.beginPath(); g.moveTo(px(c[0] + 0.5 * r * Math.cos(a)), py(c[1] + 0.5 * r * Math.sin(a)));
      g.lineTo(px(c[0] + r * Math.cos(a)), py(c[1] + r * Math.sin(a))); g.stroke();
    }
  }
  const scale = D.scale * zoom();
  // an arrow no longer than the pictures' longest (its impulse is in the numbers, not the length)
  const len = v => Math.sign(v) * Math.min(Math.abs(v) * scale, D.longest);
  if (document.getElementById("contacts").checked) {
    const arrows = document.getElementById("impulses").checked;
    for (let i = 0; i < f.contacts.length; i += 6) {
      const [x, y, nx, ny, ln, lt] = f.contacts.slice(i, i + 6);
      if (arrows) {
        g.lineWidth = 1.5;
        g.strokeStyle = "#c92a2a"; g.beginPath(); g.moveTo(px(x), py(y));
        g.lineTo(px(x + nx * len(ln)), py(y + ny * len(ln))); g.stroke();
        g.strokeStyle = "#1c7ed6"; g.beginPath(); g.moveTo(px(x), py(y));
        g.lineTo(px(x + ny * len(lt)), py(y - nx * len(lt))); g.stroke();
        g.lineWidth = 1;
      }
      g.fillStyle = "#111111"; g.fillRect(px(x) - 1.5, py(y) - 1.5, 3, 3);
    }
    if (arrows && D.legend > 0) {   // the legend: the arrow of a round impulse, as the pictures draw it
      const l = Math.min(D.legend * scale, D.longest) * k, x1 = W - 0.02 * W, x0 = x1 - l, y0 = 0.03 * H + 6;
      g.fillStyle = "rgba(255,255,255,0.8)"; g.fillRect(x0 - 80, y0 - 10, l + 84, 20);
      g.strokeStyle = "#c92a2a"; g.lineWidth = 2; g.beginPath(); g.moveTo(x0, y0); g.lineTo(x1, y0); g.stroke();
      g.lineWidth = 1; g.fillStyle = "#222"; g.font = "11px system-ui, sans-serif"; g.textAlign = "right";
      g.fillText(`${+(D.legend * Math.min(1, D.longest / (D.legend * scale))).toPrecision(3)} N·s`, x0 - 6, y0 + 4);
      g.textAlign = "left";
    }
  }
  const rows = [["step", f.step + " (frame " + (frame + 1) + " of " + D.frames.length + ")"], ["time", f.time.toFixed(3) + " s"],
                ["bodies", f.bodies.length / 5], ["contact points", f.contacts.length / 6]];
  if (f.solve) rows.push(["solver sweeps", f.solve.iterations], ["residual", f.solve.residual.toExponential(2)]);
  document.getElementById("numbers").innerHTML = rows.map(([k, v]) => `<tr><td>${k}</td><td class="v">${v}</td></tr>`).join("");
  document.getElementById("slider").value = frame;
}

function zoom() { return Math.pow(2, +document.getElementById("scale").value); }
document.getElementById("scale").addEventListener("input", () => {
  const z = zoom();
  document.getElementById("scaled").textContent = "x" + (z >= 1 ? z.toFixed(z % 1 ? 1 : 0) : "1/" + (1 / z).toFixed((1 / z) % 1 ? 1 : 0));
  draw();
});

function show(k) { frame = Math.max(0, Math.min(D.frames.length - 1, k)); draw(); }
document.getElementById("name").textContent = `${D.scene} · seed ${D.seed} · ${D.steps} step files`;
const slider = document.getElementById("slider");
slider.max = D.frames.length - 1;
slider.addEventListener("input", () => show(+slider.value));
for (const id of ["contacts", "impulses"]) document.getElementById(id).addEventListener("change", draw);
document.getElementById("play").addEventListener("click", e => {
  if (timer) { clearInterval(timer); timer = null; e.target.textContent = "play"; return; }
  e.target.textContent = "pause";
  timer = setInterval(() => show(frame + 1 < D.frames.length ? frame + 1 : 0), 1000 / D.fps);
});
const m = /frame=(\\d+)/.exec(location.hash), a = /arrows=(-?[\\d.]+)/.exec(location.hash);
if (a) { document.getElementById("scale").value = a[1]; document.getElementById("scale").dispatchEvent(new Event("input")); }
show(m ? +m[1] : 0);
document.body.dataset.ready = "1";
</script>
</body></html>
"""
