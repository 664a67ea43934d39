"""The debug view's page: the nearest obstacle, badges, the sent scan, 60 s of history, heads."""

from __future__ import annotations

import html
from collections.abc import Sequence
from string import Template
from urllib.parse import quote

_PAGE = Template("""<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>avoidd debug view</title>
<style>
 body { background: #181818; color: #e8e8e8; font: 16px sans-serif; margin: 10px; }
 header { display: flex; align-items: center; gap: 18px; margin-bottom: 8px; }
 h1 { font-size: 20px; margin: 0; }
 h2 { font-size: 16px; margin: 8px 0 4px 0; }
 #nearest { font-size: 40px; font-weight: bold; font-variant-numeric: tabular-nums; }
 #nearest small { font-size: 18px; font-weight: normal; color: #bbb; }
 .badge { padding: 4px 10px; border-radius: 4px; font-weight: bold; font-size: 18px; }
 .badge.ok { background: #1e6b2e; }
 .badge.warn { background: #b07a00; color: #111; }
 .badge.bad { background: #b3261e; }
 main { display: grid; grid-template-columns: 400px 1fr; gap: 12px; align-items: start; }
 #heads { display: grid; grid-template-columns: repeat(auto-fit, minmax(420px, 1fr)); gap: 10px; }
 #polar { width: 400px; height: auto; }
 img { display: block; max-width: 100%; background: #000; }
 img.head { width: 100%; max-height: 38vh; object-fit: contain; }
 #history { width: 400px; height: 210px; background: #202020; display: block; }
 #status { font-family: monospace; font-size: 13px; white-space: pre-wrap; background: #262626;
           padding: 6px; min-height: 2.6em; margin-top: 8px; }
 a { color: #8cf; }
</style>
</head>
<body>
<header>
 <h1>avoidd: $heads_label</h1>
 <div id="nearest">-</div>
 <div id="badges"></div>
</header>
<main>
 <section>
  <h2>OBSTACLE_DISTANCE as sent</h2>
  <img id="polar" alt="polar plot of the sent scan" src="/stream/polar.mjpg$query">
  <h2>last 60 s</h2>
  <canvas id="history" width="400" height="210"></canvas>
 </section>
 <section id="heads">
$head_sections
 </section>
</main>
<div id="status">waiting for /api/stats ...</div>
<p><a href="/api/stats$query">/api/stats</a> &middot; <a href="/metrics$query">/metrics</a></p>
<script>
const query = "$query";
const history = [];  // one sample a second: nearest m, fps, latency ms
function yn(value) { return value ? "yes" : "no"; }
function badge(text, kind) {
  const b = document.createElement("span");
  b.className = "badge " + kind;
  b.textContent = text;
  return b;
}
function chart(ctx, top, height, label, unit, values, colour) {
  const width = ctx.canvas.width, left = 4;
  const finite = values.filter(v => v !== null && isFinite(v));
  const high = Math.max(1, ...finite) * 1.1;
  ctx.fillStyle = "#aaa";
  ctx.font = "12px sans-serif";
  const last = values.length ? values[values.length - 1] : null;
  ctx.fillText(label + ": " + (last === null ? "-" : last.toFixed(1) + " " + unit) +
               "  (max " + (finite.length ? Math.max(...finite).toFixed(1) : "-") + ")",
               left, top + 12);
  ctx.strokeStyle = colour;
  ctx.lineWidth = 2;
  ctx.beginPath();
  let drawing = false;
  values.forEach((v, i) => {
    if (v === null || !isFinite(v)) { drawing = false; return; }
    const x = left + (width - 2 * left) * i / 59;
    const y = top + height - (height - 18) * v / high;
    if (drawing) { ctx.lineTo(x, y); } else { ctx.moveTo(x, y); drawing = true; }
  });
  ctx.stroke();
}
function drawHistory() {
  const ctx = document.getElementById("history").getContext("2d");
  ctx.clearRect(0, 0, ctx.canvas.width, ctx.canvas.height);
  chart(ctx, 0, 70, "nearest", "m", history.map(h => h.nearest), "#f66");
  chart(ctx, 70, 70, "fps", "", history.map(h => h.fps), "#6cf");
  chart(ctx, 140, 70, "latency", "ms", history.map(h => h.latency), "#fc6");
}
function show(s) {
  const heads = s.heads.map(h =>
    h.name + ": " + h.processed_fps.toFixed(1) + " fps (captured " +
    h.captured_fps.toFixed(1) + ", skipped " + h.skipped_fps.toFixed(1) + "), latency " +
    h.mean_latency_ms.toFixed(0) + " ms" + (h.stale ? ", STALE" : "")).join("; ");
  const l = s.link;
  const link = l.up ? ("link up: " + l.autopilot + " sys " + l.system_id + ", mode " +
    l.mode + ", armed " + yn(l.armed)) : "no autopilot heard";
  const health = s.healthy ? "healthy" : (s.fresh_data ? "degraded" : "NO FRESH DATA");
  document.getElementById("status").textContent =
    heads + "\\n" + link + "; " + health + (s.planner ? "; " + s.planner : "");
  const near = document.getElementById("nearest");
  if (s.nearest) {
    near.innerHTML = s.nearest.distance_m.toFixed(2) + " m <small>at " +
      s.nearest.bearing_deg.toFixed(0) + "&deg;</small>";
  } else {
    near.innerHTML = "<small>" + (s.fresh_data ? "nothing near" : "no fresh data") +
      "</small>";
  }
  const badges = document.getElementById("badges");
  badges.replaceChildren();
  s.heads.filter(h => h.stale).forEach(h => badges.append(badge("STALE " + h.name, "bad")));
  if (!l.up) { badges.append(badge("NO LINK", "warn")); }
  if (s.healthy && l.up) { badges.append(badge("OK", "ok")); }
  const fps = s.heads.reduce((sum, h) => sum + h.processed_fps, 0);
  const latency = Math.max(0, ...s.heads.map(h => h.mean_latency_ms));
  history.push({nearest: s.nearest ? s.nearest.distance_m : null, fps: fps,
                latency: latency});
  while (history.length > 60) { history.shift(); }
  drawHistory();
}
async function refresh() {
  try {
    const response = await fetch("/api/stats" + query, {cache: "no-store"});
    show(await response.json());
  } catch (error) {
    document.getElementById("status").textContent = "stats unavailable: " + error;
  }
}
refresh();
const timer = setInterval(refresh, 1000);
</script>
</body>
</html>
""")

_HEAD = Template("""<div><h2>head $name</h2>
<img class="head" id="head-$name" alt="head $name: left view and depth"
 src="/stream/head/$path.mjpg$query"></div>
""")


def page_html(heads: Sequence[str], token: str | None) -> str:
    """The page; with a token, every URL on it carries it (an ``img`` sends no headers).

    Args:
        heads: Head names, in configuration order.
        token: The token the page was asked with, or None.

    Returns:
        The HTML.
    """
    query = f"?token={quote(token, safe='')}" if token else ""
    query_html = html.escape(query)
    sections = "".join(
        _HEAD.substitute(name=html.escape(name), path=quote(name, safe=""), query=query_html)
        for name in heads
    )
    return _PAGE.substitute(
        heads_label=html.escape(", ".join(heads)), head_sections=sections, query=query_html
    )
