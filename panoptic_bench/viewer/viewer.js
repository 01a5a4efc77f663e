// panoptic-bench viewer: builds plotly scatter3d traces from the embedded payload.
// Everything the page needs is inside the page: the plotly.js gl3d bundle and the payload are
// gzip-compressed base64 in <script type="application/octet-stream"> tags, unpacked with the
// browser's DecompressionStream. No network request is made.
(function () {
  "use strict";
  const STATUS = {
    pred: ["TP segment", "FP segment", "unmatched, below min points"],
    gt: ["TP segment", "FN segment", "unmatched, below min points"],
  };
  // segment-error codes: 0 TP, 1 FP, 2 FN, 3 small unmatched, 4 in no segment
  const SEG_COLOURS = ["#1a9850", "#d73027", "#4575b4", "#fdae61", "#d9d9d9"];
  // semantic codes: 0 correct, 1 wrong class, 2 ground truth ignored
  const SEM_COLOURS = ["#a6d96a", "#c51b7d", "#d9d9d9"];
  const PALETTE = [
    "#e6194b", "#3cb44b", "#4363d8", "#f58231", "#911eb4", "#42d4f4", "#f032e6", "#bfef45",
    "#fabed4", "#469990", "#dcbeff", "#9a6324", "#800000", "#aaffc3", "#808000", "#000075",
    "#ffd8b1", "#ffe119", "#a9a9a9", "#00a0a0",
  ];
  const STUFF_GREY = "#b4b4b4";
  const NONE_GREY = "#e6e6e6";

  function fail(err) {
    console.error("panoptic-bench viewer: " + (err && err.stack ? err.stack : err));
    const box = document.getElementById("pb-status");
    box.textContent = "The viewer could not start: " + err;
    box.className = "error";
  }

  function bytesOf(id) {
    const text = document.getElementById(id).textContent.replace(/\s+/g, "");
    const bin = atob(text);
    const out = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) out[i] = bin.charCodeAt(i);
    return out;
  }

  async function gunzip(bytes) {
    const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream("gzip"));
    return new Uint8Array(await new Response(stream).arrayBuffer());
  }

  const CTORS = {
    int8: Int8Array, uint8: Uint8Array, int16: Int16Array, uint16: Uint16Array,
    int32: Int32Array, uint32: Uint32Array, float32: Float32Array, float64: Float64Array,
  };

  function decode(bytes) {
    const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
    const magic = new TextDecoder().decode(bytes.subarray(0, 4));
    if (magic !== "PBV1") throw new Error("unknown payload format " + magic);
    const n = view.getUint32(4, true);
    const header = JSON.parse(new TextDecoder().decode(bytes.subarray(8, 8 + n)));
    const body = bytes.byteOffset + 8 + n;
    const arrays = {};
    for (const [name, [dtype, size, offset]] of Object.entries(header.arrays)) {
      arrays[name] = new CTORS[dtype](bytes.buffer, body + offset, size);
    }
    return { meta: header.meta, arrays: arrays };
  }

  function scaleOf(cs) {
    // a step colour scale for integer codes 0..k-1 with cmin 0, cmax k-1
    const k = cs.length;
    return cs.map((c, i) => [k > 1 ? i / (k - 1) : 0, c]);
  }

  function Viewer(gd, data, layout, config) {
    this.gd = gd;
    this.meta = data.meta;
    this.arrays = data.arrays;
    this.layout = layout;
    this.config = config;
    this.classes = data.meta.classes;
    this.mode = "class";
    this.size = 1.5;
    this.scan = 0;
  }

  Viewer.prototype.side = function (k, side) {
    const a = this.arrays;
    const p = "s" + k + "_" + side + "_";
    return {
      sem: a[p + "sem"], seg: a[p + "seg"], inst: a[p + "inst"], status: a[p + "status"],
      iou: a[p + "iou"], colour: a[p + "colour"],
    };
  };

  Viewer.prototype.codes = function (k, side, idx) {
    // per-point colour codes of the current mode, for the points idx of one class trace
    const s = this.side(k, side);
    const other = this.side(k, side === "pred" ? "gt" : "pred");
    const ignore = new Set(this.classes.ignore);
    const things = new Set(this.classes.things);
    const gtSem = side === "gt" ? s.sem : other.sem;
    const predSem = side === "pred" ? s.sem : other.sem;
    const out = new Array(idx.length);
    for (let j = 0; j < idx.length; j++) {
      const i = idx[j];
      const seg = s.seg[i];
      if (this.mode === "errors") {
        if (seg < 0) out[j] = 4;
        else {
          const st = s.status[seg];
          out[j] = st === 0 ? 0 : st === 2 ? 3 : side === "pred" ? 1 : 2;
        }
      } else if (this.mode === "semantic") {
        out[j] = ignore.has(gtSem[i]) ? 2 : predSem[i] === gtSem[i] ? 0 : 1;
      } else {
        // instance: palette index + 2; 0 stuff, 1 in no segment
        if (seg < 0) out[j] = 1;
        else if (!things.has(s.sem[i]) || s.colour[seg] < 0) out[j] = 0;
        else out[j] = 2 + (s.colour[seg] % PALETTE.length);
      }
    }
    return out;
  };

  Viewer.prototype.marker = function (k, side, cls, idx) {
    if (this.mode === "class") return { size: this.size, color: this.classes.colours[cls] };
    const cs = this.mode === "errors" ? SEG_COLOURS : this.mode === "semantic" ? SEM_COLOURS
      : [STUFF_GREY, NONE_GREY].concat(PALETTE);
    return {
      size: this.size, color: this.codes(k, side, idx), colorscale: scaleOf(cs),
      cmin: 0, cmax: cs.length - 1, showscale: false,
    };
  };

  Viewer.prototype.traces = function (k) {
    const m = this.meta.scans[k];
    const xyz = this.arrays["s" + k + "_xyz"];
    const names = this.classes.names;
    const traces = [];
    this.groups = [];
    const shown = new Set();
    for (const side of ["pred", "gt"]) {
      const s = this.side(k, side);
      const byClass = names.map(() => []);
      for (let i = 0; i < s.sem.length; i++) byClass[s.sem[i]].push(i);
      const info = Array.from(s.status, (st, g) => [
        s.inst[g], s.iou[g].toFixed(3), STATUS[side][st],
      ]);
      const none = ["-", "-", "in no segment (ground truth ignored or class ignored)"];
      byClass.forEach((idx, cls) => {
        if (!idx.length) return;
        const x = new Float32Array(idx.length), y = new Float32Array(idx.length);
        const z = new Float32Array(idx.length);
        const custom = new Array(idx.length);
        for (let j = 0; j < idx.length; j++) {
          const i = idx[j];
          x[j] = xyz[3 * i] * m.scale;
          y[j] = xyz[3 * i + 1] * m.scale;
          z[j] = xyz[3 * i + 2] * m.scale;
          custom[j] = s.seg[i] >= 0 ? info[s.seg[i]] : none;
        }
        traces.push({
          type: "scatter3d", mode: "markers", scene: side === "pred" ? "scene" : "scene2",
          name: names[cls], legendgroup: names[cls], showlegend: !shown.has(cls),
          x: x, y: y, z: z, customdata: custom, marker: this.marker(k, side, cls, idx),
          hovertemplate: "<b>%{fullData.name}</b><br>instance %{customdata[0]}<br>" +
            "segment IoU %{customdata[1]}<br>%{customdata[2]}<extra>" +
            (side === "pred" ? "prediction" : "ground truth") + "</extra>",
        });
        this.groups.push({ side: side, cls: cls, idx: idx });
        shown.add(cls);
      });
    }
    const c = this.arrays["s" + k + "_centres"];
    if (c) {
      const n = c.length / 3;
      const x = new Float32Array(n), y = new Float32Array(n), z = new Float32Array(n);
      for (let j = 0; j < n; j++) {
        x[j] = c[3 * j] * m.scale; y[j] = c[3 * j + 1] * m.scale; z[j] = c[3 * j + 2] * m.scale;
      }
      traces.push({
        type: "scatter3d", mode: "markers", scene: "scene", name: "regressed centres",
        legendgroup: "centres", x: x, y: y, z: z, hoverinfo: "skip",
        marker: { size: Math.max(1, this.size - 0.5), color: "#000000" },
      });
    }
    return traces;
  };

  Viewer.prototype.draw = function () {
    const m = this.meta.scans[this.scan];
    const pq = m.pq === null ? "n/a" : (100 * m.pq).toFixed(1) + " %";
    document.getElementById("pb-scan-info").textContent =
      m.label + ": scan " + m.name + ", PQ " + pq + " (classes present), " + m.tp + " TP, " +
      m.fp + " FP, " + m.fn + " FN segments; " + m.n_shown.toLocaleString() + " of " +
      m.n_points.toLocaleString() + " points shown";
    const layout = Object.assign({}, this.layout);
    if (this.gd.layout && this.gd.layout.scene) {
      layout.scene = Object.assign({}, layout.scene, { camera: this.gd.layout.scene.camera });
      layout.scene2 = Object.assign({}, layout.scene2, { camera: this.gd.layout.scene.camera });
    }
    return Plotly.react(this.gd, this.traces(this.scan), layout, this.config);
  };

  Viewer.prototype.recolour = function () {
    const idxs = [], colours = [], scales = [], cmin = [], cmax = [];
    this.groups.forEach((g, t) => {
      const mk = this.marker(this.scan, g.side, g.cls, g.idx);
      idxs.push(t); colours.push(mk.color); scales.push(mk.colorscale || null);
      cmin.push(mk.cmin === undefined ? null : mk.cmin);
      cmax.push(mk.cmax === undefined ? null : mk.cmax);
    });
    document.querySelectorAll(".pb-key").forEach((el) => {
      el.hidden = el.dataset.mode !== this.mode;
    });
    return Plotly.restyle(this.gd, {
      "marker.color": colours, "marker.colorscale": scales, "marker.cmin": cmin,
      "marker.cmax": cmax,
    }, idxs);
  };

  Viewer.prototype.syncCameras = function () {
    let busy = false;
    const sync = (ev) => {
      if (busy) return;
      let update = null;
      if (ev["scene.camera"]) update = { "scene2.camera": ev["scene.camera"] };
      else if (ev["scene2.camera"]) update = { "scene.camera": ev["scene2.camera"] };
      if (!update) return;
      busy = true;
      Plotly.relayout(this.gd, update).then(() => { busy = false; }, () => { busy = false; });
    };
    this.gd.on("plotly_relayout", sync);
    this.gd.on("plotly_relayouting", sync);
  };

  async function start() {
    const lib = await gunzip(bytesOf("pb-plotly"));
    const script = document.createElement("script");
    script.textContent = new TextDecoder().decode(lib);
    document.head.appendChild(script);
    if (typeof Plotly === "undefined") throw new Error("plotly.js did not load");
    const data = decode(await gunzip(bytesOf("pb-data")));
    const layout = JSON.parse(document.getElementById("pb-layout").textContent);
    const config = JSON.parse(document.getElementById("pb-config").textContent);
    const gd = document.getElementById("pb-plot");
    const v = new Viewer(gd, data, layout, config);
    const pick = document.getElementById("pb-scan");
    data.meta.scans.forEach((m, k) => {
      const opt = document.createElement("option");
      opt.value = String(k);
      opt.textContent = m.label + " (" + m.name + ")";
      pick.appendChild(opt);
    });
    pick.parentElement.hidden = data.meta.scans.length < 2;
    const fromHash = data.meta.scans.findIndex((m) => "#" + m.anchor === location.hash);
    v.scan = fromHash >= 0 ? fromHash : 0;
    pick.value = String(v.scan);
    await v.draw();
    v.syncCameras();
    pick.addEventListener("change", () => { v.scan = Number(pick.value); v.draw(); });
    document.getElementById("pb-mode").addEventListener("change", (ev) => {
      v.mode = ev.target.value; v.recolour();
    });
    document.getElementById("pb-size").addEventListener("input", (ev) => {
      v.size = Number(ev.target.value);
      Plotly.restyle(gd, { "marker.size": v.size }, v.groups.map((g, t) => t));
    });
    window.addEventListener("hashchange", () => {
      const k = data.meta.scans.findIndex((m) => "#" + m.anchor === location.hash);
      if (k >= 0 && k !== v.scan) { v.scan = k; pick.value = String(k); v.draw(); }
    });
    const status = document.getElementById("pb-status");
    status.textContent = "ready";
    status.className = "ready";
    window.pbViewer = v;
  }

  window.addEventListener("error", (ev) => fail(ev.message));
  start().catch(fail);
})();
