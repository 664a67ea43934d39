"""The debug view's HTML page: one per rig, a stream per head, the sent scan, a status line."""

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
 body { background: #181818; color: #e8e8e8; font: 14px sans-serif; margin: 12px; }
 h1 { font-size: 18px; margin: 0 0 6px 0; }
 h2 { font-size: 15px; margin: 14px 0 4px 0; }
 #status { font-family: monospace; white-space: pre-wrap; background: #262626;
           padding: 6px; min-height: 2.6em; }
 img { display: block; max-width: 100%; background: #000; }
 a { color: #8cf; }
</style>
</head>
<body>
<h1>avoidd: $heads_label</h1>
<div id="status">waiting for /api/stats ...</div>
<h2>OBSTACLE_DISTANCE as sent</h2>
<img id="polar" alt="polar plot of the sent scan" src="/stream/polar.mjpg$query">
$head_sections
<p><a href="/api/stats$query">/api/stats</a> &middot; <a href="/metrics$query">/metrics</a></p>
<script>
const query = "$query";
function yn(value) { return value ? "yes" : "no"; }
async function refresh() {
  try {
    const response = await fetch("/api/stats" + query, {cache: "no-store"});
    const s = await response.json();
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
  } catch (error) {
    document.getElementById("status").textContent = "stats unavailable: " + error;
  }
}
refresh();
setInterval(refresh, 1000);
</script>
</body>
</html>
""")

_HEAD = Template("""<h2>head $name</h2>
<img class="head" id="head-$name" alt="head $name: left view and depth"
 src="/stream/head/$path.mjpg$query">
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
