"""One self-contained HTML page: prediction and ground truth of one or more scans, side by side.

Rendering is plotly.js (WebGL ``scatter3d``), chosen over hand-written WebGL or a vendored
three.js because it already brings what the page needs and is well kept: two 3-D scenes,
a legend whose entries toggle classes (double-click isolates one), hover read-outs, camera events
to synchronise the two scenes, and it draws 2 x 125k points interactively. The page embeds the
plotly.js *gl3d partial bundle* (same plotly.js version as the ``plotly`` Python package, MIT
licence, ``panoptic_bench/viewer/vendor``) instead of the full bundle: 1.75 MB instead of 4.8 MB
(0.56 MB gzip-compressed), which keeps committed report pages small. The figure layout is
built and validated with the ``plotly`` Python package; ``viewer.js`` builds the traces from
the binary payload of :mod:`panoptic_bench.viewer.payload`.

Library and payload are gzip-compressed base64 inside the page and unpacked with the browser's
``DecompressionStream`` (Chrome/Edge >= 80, Firefox >= 113, Safari >= 16.4). The page makes no
network request.
"""

from __future__ import annotations

import base64
import gzip
import html
import json
from collections.abc import Sequence
from functools import cache
from importlib import resources
from pathlib import Path

from panoptic_bench.io import write_text
from panoptic_bench.viewer.payload import build_payload
from panoptic_bench.viewer.scene import ViewClasses, ViewScan

__all__ = ["PLOTLY_BUNDLE", "plotly_bundle_gz", "render_page", "write_page"]

PLOTLY_BUNDLE = "plotly-gl3d.min.js.gz"
ERROR_KEYS = {
    "errors": [
        ("#1a9850", "TP segment (matched, IoU > 0.5)"),
        ("#d73027", "FP segment (prediction unmatched)"),
        ("#4575b4", "FN segment (ground truth unmatched)"),
        ("#fdae61", "unmatched, below min points (not counted)"),
        ("#d9d9d9", "in no segment (ground truth ignored)"),
    ],
    "semantic": [
        ("#a6d96a", "class correct"),
        ("#c51b7d", "class wrong"),
        ("#d9d9d9", "ground truth ignored"),
    ],
    "instance": [
        ("#b4b4b4", "stuff; matched instances share a colour on both sides"),
    ],
}


@cache
def plotly_bundle_gz() -> bytes:
    """The gzip-compressed plotly.js gl3d bundle shipped in ``panoptic_bench/viewer/vendor``."""
    return (resources.files("panoptic_bench.viewer") / "vendor" / PLOTLY_BUNDLE).read_bytes()


@cache
def _viewer_js() -> str:
    return (resources.files("panoptic_bench.viewer") / "viewer.js").read_text("utf-8")


def _layout(classes: ViewClasses) -> dict:
    import plotly.graph_objects as go

    axis = {"visible": False}
    scene = {
        "aspectmode": "data",
        "xaxis": axis,
        "yaxis": axis,
        "zaxis": axis,
        "camera": {"eye": {"x": -0.9, "y": -0.9, "z": 0.75}, "up": {"x": 0, "y": 0, "z": 1}},
    }
    note = {"xref": "paper", "yref": "paper", "y": 1.0, "showarrow": False, "font": {"size": 16}}
    layout = go.Layout(
        scene={**scene, "domain": {"x": [0.0, 0.495], "y": [0.0, 1.0]}},
        scene2={**scene, "domain": {"x": [0.505, 1.0], "y": [0.0, 1.0]}},
        annotations=[
            {**note, "x": 0.2475, "text": "prediction"},
            {**note, "x": 0.7525, "text": "ground truth"},
        ],
        margin={"l": 0, "r": 0, "t": 30, "b": 0},
        legend={"title": {"text": "classes (click: hide / show)"}, "itemsizing": "constant"},
        paper_bgcolor="#ffffff",
        uirevision="keep",
    )
    return layout.to_plotly_json()


CONFIG = {"displaylogo": False, "showLink": False, "showSendToCloud": False, "responsive": True}

_CSS = """
body{font-family:system-ui,sans-serif;margin:0.6em 1em;color:#222}
h1{font-size:1.25em;margin:0.2em 0}
#pb-controls{display:flex;gap:1.5em;align-items:center;flex-wrap:wrap;margin:0.4em 0}
#pb-plot{width:100%;height:78vh;border:1px solid #ddd}
.pb-key span.sw{display:inline-block;width:0.9em;height:0.9em;margin:0 0.3em 0 0.9em;
vertical-align:middle}
#pb-status.error{color:#b00;font-weight:bold}
#pb-status.ready{color:#666}
.small{color:#555;font-size:0.9em}
"""


def _keys() -> str:
    parts = []
    for mode, entries in ERROR_KEYS.items():
        items = "".join(
            f'<span class="sw" style="background:{c}"></span>{html.escape(t)}' for c, t in entries
        )
        parts.append(f'<div class="pb-key small" data-mode="{mode}" hidden>{items}</div>')
    return "\n".join(parts)


def _b64(data: bytes) -> str:
    text = base64.b64encode(data).decode("ascii")
    return "\n".join(text[i : i + 4096] for i in range(0, len(text), 4096))


def render_page(
    scans: Sequence[ViewScan],
    classes: ViewClasses,
    *,
    title: str,
    labels: Sequence[str] | None = None,
    anchors: Sequence[str] | None = None,
    max_points: int | None = None,
    note: str = "",
) -> str:
    """The HTML text of a viewer page.

    Parameters
    ----------
    scans : sequence of ViewScan
        Scans to show (a selector switches between them when there are several).
    classes : ViewClasses
        Class names, colours and the evaluator's rules.
    title : str
        Page title.
    labels, anchors : sequence of str, optional
        Per scan: the selector label (e.g. ``"worst scan by PQ"``) and the URL fragment that
        opens it (``page.html#worst``).
    max_points : int, optional
        Show at most this many points per scan (a fixed random subset; the matching and the
        numbers always use every point).
    note : str
        A sentence shown under the title (e.g. where the data comes from).
    """
    if not scans:
        raise ValueError("no scans to show")
    payload = build_payload(
        scans, classes, title=title, labels=labels, anchors=anchors, max_points=max_points
    )
    data_gz = gzip.compress(payload, compresslevel=9, mtime=0)
    layout = json.dumps(_layout(classes), separators=(",", ":"))
    esc = html.escape
    return f"""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>{esc(title)}</title>
<style>{_CSS}</style>
</head>
<body>
<h1>{esc(title)}</h1>
<div class="small">{esc(note)} Left: prediction; right: ground truth (cameras move together).
Segments matched as by the evaluator ({esc(classes.dataset)}: IoU &gt; 0.5, unmatched segments
under {classes.min_points} points not counted).</div>
<div id="pb-controls">
<label>scan <select id="pb-scan"></select></label>
<label>colour by <select id="pb-mode">
<option value="class">semantic class</option>
<option value="instance">instance</option>
<option value="errors">segment errors (TP / FP / FN)</option>
<option value="semantic">semantic errors</option>
</select></label>
<label>point size <input id="pb-size" type="range" min="0.5" max="6" step="0.5" value="1.5"></label>
<span id="pb-status">loading...</span>
</div>
<div id="pb-scan-info" class="small"></div>
{_keys()}
<div id="pb-plot"></div>
<div class="small">Hover a point for its class, instance id, the IoU of its segment and whether
the segment is TP, FP or FN. Made with plotly.js (MIT licence), embedded in this file.</div>
<script id="pb-layout" type="application/json">{layout}</script>
<script id="pb-config" type="application/json">{json.dumps(CONFIG)}</script>
<script id="pb-plotly" type="application/octet-stream">
{_b64(plotly_bundle_gz())}
</script>
<script id="pb-data" type="application/octet-stream">
{_b64(data_gz)}
</script>
<script>
{_viewer_js()}
</script>
</body>
</html>
"""


def write_page(path: str | Path, scans: Sequence[ViewScan], classes: ViewClasses, **kw) -> Path:
    """Render with :func:`render_page` and write atomically to ``path``; returns the path."""
    text = render_page(scans, classes, **kw)
    write_text(path, text)
    return Path(path)
