"""The data a viewer page carries: per-point arrays of each scan in one compact binary payload.

Layout of the payload (decoded by ``viewer.js``): ``b"PBV1"``, a little-endian uint32 header
length, the UTF-8 JSON header ``{"meta": ..., "arrays": {name: [dtype, length, offset]}}``, then
the raw little-endian arrays, each starting at a multiple of 8 bytes from the payload start. The
page embeds it gzip-compressed and base64-encoded.

Per scan ``k`` the arrays are ``s{k}_xyz`` (int16, coordinates / ``scale``, flattened n x 3),
``s{k}_{side}_sem`` (uint8 class per point), ``s{k}_{side}_seg`` (int32 segment per point, -1 none)
and the segment tables ``s{k}_{side}_{inst,status,iou,colour}`` for ``side`` in ``pred`` / ``gt``,
plus ``s{k}_centres`` (int16, flattened) when the scan has regressed centres.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Sequence

import numpy as np

from panoptic_bench.viewer.matching import SegmentMatch
from panoptic_bench.viewer.scene import ViewClasses, ViewScan, scan_pq

__all__ = ["MAGIC", "decode_payload", "encode_payload", "scan_arrays", "subsample"]

MAGIC = b"PBV1"
_DTYPES = {"int8", "uint8", "int16", "uint16", "int32", "uint32", "float32", "float64"}
_INT16_MAX = 32000


def encode_payload(meta: dict, arrays: dict[str, np.ndarray]) -> bytes:
    """Pack ``meta`` (JSON-able) and 1-D numeric ``arrays`` into the payload described above."""
    header: dict = {"meta": meta, "arrays": {}}
    chunks, offset = [], 0
    for name, arr in arrays.items():
        arr = np.ascontiguousarray(arr).ravel()
        if arr.dtype.name not in _DTYPES:
            raise ValueError(f"array {name}: unsupported dtype {arr.dtype}")
        header["arrays"][name] = [arr.dtype.name, int(arr.size), offset]
        data = arr.astype(arr.dtype.newbyteorder("<"), copy=False).tobytes()
        data += b"\0" * (-len(data) % 8)
        chunks.append(data)
        offset += len(data)
    # offsets above are relative to the body; the body starts 8-aligned after the header
    head = json.dumps(header, separators=(",", ":")).encode("utf-8")
    start = len(MAGIC) + 4 + len(head)
    pad = -start % 8
    head += b" " * pad
    return MAGIC + struct.pack("<I", len(head)) + head + b"".join(chunks)


def decode_payload(data: bytes) -> tuple[dict, dict[str, np.ndarray]]:
    """Inverse of :func:`encode_payload` (used by the tests): ``(meta, arrays)``."""
    if data[:4] != MAGIC:
        raise ValueError("not a viewer payload")
    (n,) = struct.unpack("<I", data[4:8])
    header = json.loads(data[8 : 8 + n].decode("utf-8"))
    body = 8 + n
    arrays = {}
    for name, (dtype, size, offset) in header["arrays"].items():
        dt = np.dtype(dtype).newbyteorder("<")
        arrays[name] = np.frombuffer(data, dtype=dt, count=size, offset=body + offset)
    return header["meta"], arrays


def subsample(n_points: int, max_points: int | None, seed: int = 0) -> np.ndarray:
    """Sorted indices of at most ``max_points`` of ``n_points`` points (all if None), int64."""
    if max_points is None or n_points <= max_points:
        return np.arange(n_points)
    rng = np.random.default_rng(seed)
    return np.sort(rng.choice(n_points, size=max_points, replace=False))


def _instance_colours(match: SegmentMatch, classes: ViewClasses) -> tuple[np.ndarray, np.ndarray]:
    """Palette index per segment (-1: stuff); a matched prediction takes its partner's index."""
    things = np.isin(match.gt.cls, classes.things)
    g_col = np.full(len(match.gt), -1, dtype=np.int64)
    g_col[things] = np.arange(int(things.sum()))
    p_things = np.isin(match.pred.cls, classes.things)
    p_col = np.full(len(match.pred), -1, dtype=np.int64)
    matched = p_things & (match.pred.match >= 0)
    p_col[matched] = g_col[match.pred.match[matched]]
    free = p_things & ~matched
    p_col[free] = int(things.sum()) + np.arange(int(free.sum()))
    return p_col, g_col


def scan_arrays(
    k: int, scan: ViewScan, classes: ViewClasses, max_points: int | None = None
) -> tuple[dict, dict[str, np.ndarray]]:
    """Meta and payload arrays of scan number ``k`` (matched on all points, then subsampled).

    Returns
    -------
    (dict, dict of str to ndarray)
        ``{"name", "pq", "tp", "fp", "fn", "n_points", "n_shown", "scale"}`` and the arrays.
    """
    match = scan.match(classes)
    idx = subsample(len(scan), max_points, seed=k)
    xyz = np.asarray(scan.xyz, dtype=np.float64)[idx]
    span = float(np.abs(xyz).max()) if xyz.size else 1.0
    scale = max(0.01, span / _INT16_MAX)
    arrays: dict[str, np.ndarray] = {f"s{k}_xyz": np.rint(xyz / scale).astype(np.int16)}
    p_col, g_col = _instance_colours(match, classes)
    sides = (
        ("pred", scan.pred_sem, match.pred_segment, match.pred, p_col),
        ("gt", scan.gt_sem, match.gt_segment, match.gt, g_col),
    )
    for side, sem, seg, table, col in sides:
        arrays[f"s{k}_{side}_sem"] = np.asarray(sem)[idx].astype(np.uint8)
        arrays[f"s{k}_{side}_seg"] = seg[idx].astype(np.int32)
        arrays[f"s{k}_{side}_inst"] = classes.shown_instance(table.inst).astype(np.int32)
        arrays[f"s{k}_{side}_status"] = table.status.astype(np.uint8)
        arrays[f"s{k}_{side}_iou"] = table.iou.astype(np.float32)
        arrays[f"s{k}_{side}_colour"] = col.astype(np.int32)
    if scan.centres is not None:
        centres = np.asarray(scan.centres, dtype=np.float64)[idx]
        centres = centres[np.isfinite(centres).all(axis=1)]
        arrays[f"s{k}_centres"] = np.rint(np.clip(centres / scale, -_INT16_MAX, _INT16_MAX)).astype(
            np.int16
        )
    pq = scan_pq(scan, classes)
    meta = {
        "name": scan.name,
        "pq": None if np.isnan(pq) else pq,
        "tp": int((match.pred.status == 0).sum()),
        "fp": int((match.pred.status == 1).sum()),
        "fn": int((match.gt.status == 1).sum()),
        "n_points": len(scan),
        "n_shown": len(idx),
        "scale": scale,
        "centres": scan.centres is not None,
    }
    return meta, arrays


def build_payload(
    scans: Sequence[ViewScan],
    classes: ViewClasses,
    *,
    title: str,
    labels: Sequence[str] | None = None,
    anchors: Sequence[str] | None = None,
    max_points: int | None = None,
) -> bytes:
    """The payload of a page showing ``scans``.

    ``labels`` name the scans in the selector (e.g. ``"best scan by PQ"``), ``anchors`` are the
    URL fragments that open them (``page.html#worst``); defaults: the scan names, ``scan0``...
    """
    metas, arrays = [], {}
    for k, scan in enumerate(scans):
        meta, arr = scan_arrays(k, scan, classes, max_points)
        meta["label"] = labels[k] if labels else scan.name
        meta["anchor"] = anchors[k] if anchors else f"scan{k}"
        metas.append(meta)
        arrays.update(arr)
    meta = {"title": title, "classes": classes.to_dict(), "scans": metas}
    return encode_payload(meta, arrays)
