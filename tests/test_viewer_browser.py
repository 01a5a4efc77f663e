"""The viewer page in a real browser: headless Chromium with WebGL on SwiftShader.

Chromium is driven over the DevTools protocol (``tests/browser_cdp.py``): each test waits for the
page's own ready signal, not for a virtual-time budget (which, on a loaded machine, could run out
before the first WebGL frame and leave Chromium hung). One screenshot of a full real scan
(2 x 124,668 points) must show points in both views; an instrumented copy of a smaller page reports, from inside the browser, console errors, every
resource the page loaded, the colours the page computed (checked against the evaluator's
matching), the legend groups, the point-size control and the camera synchronisation.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from browser_cdp import Browser

from panoptic_bench.cli import main
from panoptic_bench.datasets import semantickitti as sk
from panoptic_bench.viewer.matching import match_segments
from panoptic_bench.viewer.payload import subsample

SMALL = 20_000

PROBE = """<script>
window.__log = [];
const __rec = (kind) => (...a) => window.__log.push(kind + ": " + a.map(String).join(" "));
console.error = __rec("error");
window.addEventListener("error", (e) => window.__log.push("uncaught: " + e.message));
window.addEventListener("unhandledrejection", (e) => window.__log.push("rejection: " + e.reason));
function __hist(codes) {
  const h = {};
  for (const c of codes) h[c] = (h[c] || 0) + 1;
  return h;
}
async function __probe() {
  const out = {log: window.__log};
  try {
    const v = window.pbViewer, gd = v.gd;
    out.traces = gd.data.map((t) => ({name: t.name, group: t.legendgroup, scene: t.scene,
      legend: t.showlegend, n: t.x.length, hover: t.hovertemplate || "",
      custom: t.customdata ? t.customdata[0] : null}));
    out.modes = {};
    for (const mode of ["errors", "semantic", "instance"]) {
      v.mode = mode;
      await v.recolour();
      out.modes[mode] = gd.data.filter((t) => t.customdata).map((t) => ({
        scene: t.scene, hist: __hist(t.marker.color)}));
    }
    const size = document.getElementById("pb-size");
    size.value = "4";
    size.dispatchEvent(new Event("input"));
    await new Promise((r) => setTimeout(r, 200));
    out.sizes = gd.data.map((t) => t.marker.size);
    await Plotly.relayout(gd, {"scene.camera": {eye: {x: 2.5, y: 0.1, z: 0.3}}});
    await new Promise((r) => setTimeout(r, 500));
    out.camera2 = gd.layout.scene2.camera.eye;
  } catch (e) { out.log.push("probe: " + e); }
  out.status = document.getElementById("pb-status").textContent;
  out.resources = performance.getEntriesByType("resource").map((r) => r.name);
  const pre = document.createElement("pre");
  pre.id = "pb-probe";
  pre.textContent = JSON.stringify(out);
  document.body.appendChild(pre);
}
(function wait() {
  const s = document.getElementById("pb-status");
  if (window.pbViewer || (s && s.className === "error")) __probe();
  else setTimeout(wait, 100);
})();
</script>"""


# resolves, two animation frames after the viewer is up (or has shown an error), to the status text
READY = """new Promise((done) => (function wait() {
  const s = document.getElementById("pb-status");
  if (window.pbViewer || (s && s.className === "error"))
    requestAnimationFrame(() => requestAnimationFrame(() => done(s.className + ": " + s.textContent)));
  else setTimeout(wait, 100);
})())"""
PROBED = """new Promise((done) => (function wait() {
  const p = document.getElementById("pb-probe");
  if (p) done(p.textContent); else setTimeout(wait, 100);
})())"""


@pytest.fixture(scope="module")
def chromium() -> str:
    path = shutil.which("chromium")
    assert path, "headless Chromium missing: apt-get install -y chromium (.ci/run installs it)"
    return path


@pytest.fixture(scope="module")
def pages(tmp_path_factory, kitti_root):
    """A full-size page and a small page of real scan 00/000002 with a damaged prediction."""
    root = tmp_path_factory.mktemp("browser")
    ref = sk.list_scans(kitti_root, sequences=["00"])[2]
    gt = sk.read_labels(ref.label)
    inst = gt >> 16
    pred = gt.copy()
    ids, sizes = np.unique(inst[inst > 0], return_counts=True)
    for k, i in enumerate(ids[sizes >= 300]):  # split big instances in thirds: 3 FP + 1 FN each
        where = np.flatnonzero(inst == i)
        pred[where] = (pred[where] & 0xFFFF) | ((1000 + 3 * k + np.arange(len(where)) % 3) << 16)
    pred[np.random.default_rng(1).random(len(gt)) < 0.05] = 40  # semantic errors
    sk.write_labels(sk.prediction_path(root / "pred", ref), pred)
    base = ["view", "semantickitti", "--dataset", str(kitti_root), "--scan", "00/000002"]
    base += ["--predictions", str(root / "pred")]
    full, small = root / "full.html", root / "small.html"
    assert main([*base, "--out", str(full)]) == 0
    assert main([*base, "--out", str(small), "--max-points", str(SMALL)]) == 0
    return {"full": full, "small": small, "gt": gt, "pred": pred}


def test_screenshot_shows_points_in_both_views(chromium, pages, tmp_path):
    from PIL import Image

    shot = tmp_path / "shot.png"
    with Browser(chromium) as browser:
        browser.open(pages["full"].as_uri())
        status = browser.evaluate(READY)
        shot.write_bytes(browser.screenshot())
        errors = [p for p in browser.problems() if not p.startswith("console.warning")]
    assert status == "ready: ready", status
    assert errors == [], errors
    img = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    h, w, _ = img.shape
    plot = img[int(0.2 * h) : int(0.85 * h)]
    # saturated pixels = drawn points (the page is white / grey elsewhere)
    saturated = (plot.max(axis=2) - plot.min(axis=2)) > 60
    left, right = saturated[:, : int(0.4 * w)], saturated[:, int(0.45 * w) : int(0.82 * w)]
    assert left.mean() > 0.05 and right.mean() > 0.05, (left.mean(), right.mean())


def test_page_in_browser_no_errors_no_network_and_evaluator_colours(chromium, pages, tmp_path):
    text = pages["small"].read_text()
    probe = tmp_path / "probe.html"
    probe.write_text(text.replace("<head>", "<head>\n" + PROBE, 1))
    with Browser(chromium) as browser:
        browser.open(probe.as_uri())
        out = json.loads(browser.evaluate(PROBED))
    assert out["log"] == [] and out["status"] == "ready", out["log"]
    # nothing loaded from outside the file (the page itself is the only file: URL)
    assert all(r.startswith(("file:", "data:", "blob:")) for r in out["resources"]), out
    # one legend entry per class; prediction and ground truth traces of a class share its group
    traces = [t for t in out["traces"] if t["group"] != "centres"]
    assert {t["scene"] for t in traces} == {"scene", "scene2"}
    names = [t["name"] for t in traces if t["legend"]]
    assert len(names) == len(set(names)) == len({t["name"] for t in traces})
    assert all(t["group"] == t["name"] for t in traces)
    assert sum(t["n"] for t in traces) == 2 * SMALL
    assert all("segment IoU" in t["hover"] and len(t["custom"]) == 3 for t in traces)
    # the colours computed in the browser are the evaluator's matching on the shown points
    gt, pred = pages["gt"], pages["pred"]
    idx = subsample(len(gt), SMALL, seed=0)
    sp, sg = sk.to_train(pred), sk.to_train(gt)
    mt = match_segments(sp, pred, sg, gt, num_classes=20, ignore=(0,), min_points=50)

    def codes(seg, status, miss):
        seg = seg[idx]
        c = np.full(len(seg), 4)
        st = status[seg[seg >= 0]]
        c[seg >= 0] = np.select([st == 0, st == 2], [0, 3], miss)
        return np.bincount(c, minlength=5)

    def browser(mode, scene):
        total = np.zeros(32, int)
        for t in out["modes"][mode]:
            if t["scene"] == scene:
                for k, v in t["hist"].items():
                    total[int(k)] += v
        return total if mode == "instance" else total[:5]

    want_pred = codes(mt.pred_segment, mt.pred.status, 1)
    want_gt = codes(mt.gt_segment, mt.gt.status, 2)
    assert want_pred[1] > 0 and want_gt[2] > 0  # the damage shows as FP and FN points
    np.testing.assert_array_equal(browser("errors", "scene"), want_pred)
    np.testing.assert_array_equal(browser("errors", "scene2"), want_gt)
    wrong = int(((sp != sg) & (sg != 0))[idx].sum())
    assert browser("semantic", "scene")[1] == browser("semantic", "scene2")[1] == wrong > 0
    assert browser("instance", "scene")[2:].sum() > 0  # thing instances get palette colours
    # point size control and synchronised cameras
    assert set(out["sizes"][: len(traces)]) == {4}
    assert out["camera2"]["x"] == pytest.approx(2.5)


def test_chromium_is_installed_by_ci():
    text = (Path(__file__).parents[1] / ".ci" / "run").read_text()
    assert "apt-get install -y chromium" in text
