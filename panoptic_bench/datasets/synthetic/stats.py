"""Realism statistics: compare synthetic SemanticKITTI scans with real ones.

Per scan: number of points, class frequencies (19 train classes), number of thing instances,
points per car instance versus its mean range, and the range histogram. The key realism figure is
the log-log slope of points per car instance against range over 10-50 m: about -4 on real
HDL-64E scans (1/r^2 from the beam geometry, the rest from occlusion in rows of parked cars).

:func:`scan_stats` is a pure array function; :func:`dataset_stats` reads a tree;
:func:`compare` writes the table (markdown + CSV) and the figure.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from panoptic_bench.datasets.synthetic.realism import MEASURES, aggregate, scan_measures
from panoptic_bench.errors import InputError
from panoptic_bench.io import (
    check_output_location,
    ensure_output_dir,
    write_json,
    write_text,
)

__all__ = [
    "DatasetStats",
    "ScanStats",
    "car_slope",
    "compare",
    "dataset_stats",
    "scan_stats",
    "simulated_stats",
]

RANGE_BINS = np.arange(0.0, 82.0, 2.0)
CAR_TRAIN_ID = 1


@dataclass(frozen=True)
class ScanStats:
    """Statistics of one scan.

    Attributes
    ----------
    n_points : int
    class_counts : ndarray of shape (20,), int64
        Points per train id (0 = unlabeled / ignored).
    n_instances : int
        Thing instances (distinct (class, instance) pairs of thing classes with instance > 0).
    car_points, car_range : ndarray of shape (n_cars,)
        Points of each car instance and the mean horizontal range of those points, metres.
    range_hist : ndarray of shape (len(RANGE_BINS) - 1,), int64
        Histogram of horizontal point ranges over :data:`RANGE_BINS`.
    """

    n_points: int
    class_counts: np.ndarray
    n_instances: int
    car_points: np.ndarray
    car_range: np.ndarray
    range_hist: np.ndarray


def scan_stats(points: np.ndarray, labels: np.ndarray) -> ScanStats:
    """Statistics of one scan.

    Parameters
    ----------
    points : ndarray of shape (N, 4), float32
        ``x, y, z, remission`` in the sensor frame.
    labels : ndarray of shape (N,), uint32
        SemanticKITTI labels (raw id in the low 16 bits, instance in the high 16 bits).
    """
    from panoptic_bench.datasets.semantickitti import LABELS, split_label, to_train

    sem_raw, inst = split_label(labels)
    train = to_train(sem_raw).astype(np.int64)
    r = np.hypot(points[:, 0], points[:, 1])
    counts = np.bincount(train, minlength=len(LABELS.class_names))
    thing = np.isin(train, LABELS.thing_ids) & (inst > 0)
    n_inst = np.unique(train[thing] * 65536 + inst[thing]).size
    car = (train == CAR_TRAIN_ID) & (inst > 0)
    ids, idx, npts = np.unique(inst[car], return_inverse=True, return_counts=True)
    mean_r = np.bincount(idx, weights=r[car], minlength=ids.size) / np.maximum(npts, 1)
    return ScanStats(
        int(points.shape[0]),
        counts,
        int(n_inst),
        npts.astype(np.int64),
        mean_r,
        np.histogram(r, RANGE_BINS)[0].astype(np.int64),
    )


def car_slope(
    car_range: np.ndarray, car_points: np.ndarray, lo: float = 10.0, hi: float = 50.0
) -> float:
    """Least-squares slope of ``log(points)`` against ``log(range)`` for cars in ``[lo, hi]`` m.

    Returns ``nan`` when fewer than 3 cars fall in the window.
    """
    sel = (car_range >= lo) & (car_range <= hi) & (car_points > 0)
    if sel.sum() < 3:
        return float("nan")
    return float(np.polyfit(np.log(car_range[sel]), np.log(car_points[sel]), 1)[0])


@dataclass(frozen=True)
class DatasetStats:
    """Statistics of a set of scans (see :class:`ScanStats`); ``slope`` is :func:`car_slope`.

    ``measures`` and ``hists`` are the sensor/world realism measures of
    :func:`~panoptic_bench.datasets.synthetic.realism.aggregate` (empty when not measured).
    """

    n_scans: int
    points_per_scan: np.ndarray
    instances_per_scan: np.ndarray
    class_freq: np.ndarray
    car_points: np.ndarray
    car_range: np.ndarray
    range_hist: np.ndarray
    slope: float
    measures: dict = field(default_factory=dict)
    hists: dict = field(default_factory=dict)

    @classmethod
    def from_scans(cls, scans: list[ScanStats], realism: list | None = None) -> DatasetStats:
        """Aggregate per-scan statistics (and per-scan realism measures, when given)."""
        counts = np.sum([s.class_counts for s in scans], axis=0)
        hist = np.sum([s.range_hist for s in scans], axis=0)
        cp = np.concatenate([s.car_points for s in scans])
        cr = np.concatenate([s.car_range for s in scans])
        return cls(
            len(scans),
            np.array([s.n_points for s in scans]),
            np.array([s.n_instances for s in scans]),
            counts / max(counts.sum(), 1),
            cp,
            cr,
            hist / max(hist.sum(), 1),
            car_slope(cr, cp),
            *(aggregate(realism) if realism else ({}, {})),
        )


def dataset_stats(
    root: str | Path, max_scans: int | None = None, progress: bool = True
) -> DatasetStats:
    """Statistics of the labelled scans of a SemanticKITTI tree (at most ``max_scans``, evenly)."""
    from tqdm import tqdm

    from panoptic_bench.datasets.semantickitti import list_scans, read_labels, read_scan

    refs = list_scans(root)
    if max_scans is not None and len(refs) > max_scans:
        refs = [refs[i] for i in np.linspace(0, len(refs) - 1, max_scans).round().astype(int)]
    scans, realism = [], []
    for ref in tqdm(
        refs, desc=f"stats {Path(root).name}", unit="scan", disable=None if progress else True
    ):
        points, labels = read_scan(ref.scan), read_labels(ref.label)
        if labels.shape[0] != points.shape[0]:
            raise InputError(f"{labels.shape[0]} labels for {points.shape[0]} points", ref.label)
        scans.append(scan_stats(points, labels))
        realism.append(scan_measures(points, labels))
    return DatasetStats.from_scans(scans, realism)


def simulated_stats(
    n_scans: int = 12, seed: int = 0, profile=None, progress: bool = True
) -> DatasetStats:
    """Statistics of ``n_scans`` synthetic HDL-64E scans simulated in memory.

    Scan ``k`` is frame 0 of sequence ``k`` of ``seed`` (one street per scan), so the scans
    sample different streets and sensor poses.

    Parameters
    ----------
    n_scans : int
        Number of scans, 1-1000.
    seed : int
        Global seed.
    profile : WorldProfile, optional
        World/sensor profile (``classic`` by default).
    progress : bool
        Show a progress bar.
    """
    from tqdm import tqdm

    from panoptic_bench.datasets.semantickitti import make_label
    from panoptic_bench.datasets.synthetic.sequence import Sequence

    if not 1 <= int(n_scans) <= 1000:
        raise InputError(f"--synthetic-scans {n_scans} is out of range; use 1-1000")
    scans, realism = [], []
    for key in tqdm(
        range(n_scans), desc="simulate", unit="scan", disable=None if progress else True
    ):
        sw = Sequence(seed, key, 1, profile=profile).frame(0).sweep
        points = np.column_stack([sw.xyz, sw.remission])
        labels = make_label(sw.label, sw.instance)
        scans.append(scan_stats(points, labels))
        realism.append(scan_measures(points, labels))
    return DatasetStats.from_scans(scans, realism)


def _rows(real: DatasetStats, synth: DatasetStats) -> list[tuple[str, float, float]]:
    from panoptic_bench.datasets.semantickitti import LABELS

    rows = [
        ("scans", real.n_scans, synth.n_scans),
        ("points per scan (mean)", real.points_per_scan.mean(), synth.points_per_scan.mean()),
        ("thing instances per scan (mean)", real.instances_per_scan.mean(), synth.instances_per_scan.mean()),
        ("car instances with 10-50 m mean range", ((real.car_range >= 10) & (real.car_range <= 50)).sum(),
         ((synth.car_range >= 10) & (synth.car_range <= 50)).sum()),
        ("log-log slope points per car vs range (10-50 m)", real.slope, synth.slope),
        ("median range of points (m)", _median_range(real), _median_range(synth)),
    ]  # fmt: skip
    for k, name in enumerate(LABELS.class_names):
        rows.append(
            (f"class frequency % {name}", 100 * real.class_freq[k], 100 * synth.class_freq[k])
        )
    for key, (label, _) in MEASURES.items():
        if key in real.measures and key in synth.measures:
            rows.append((label, real.measures[key], synth.measures[key]))
    return rows


def _median_range(s: DatasetStats) -> float:
    c = np.cumsum(s.range_hist)
    return float(RANGE_BINS[1:][np.searchsorted(c, 0.5)])


def compare(
    real_root: str | Path,
    synth_root: str | Path | None,
    out: str | Path,
    *,
    max_scans: int | None = 200,
    figure: str | Path | None = None,
    overwrite: bool = False,
    progress: bool = True,
    synthetic_scans: int = 12,
    seed: int = 0,
    profile=None,
) -> tuple[DatasetStats, DatasetStats]:
    """Compare real and synthetic scans side by side.

    Writes ``realism.md`` (table), ``realism.csv``, ``realism.json`` (every value and the
    histograms), ``realism.png`` (counts, classes, cars vs range) and ``realism_sensor.png``
    (remission, ground heights, rings, ego hole), all atomically and only once every input has
    been read.

    Parameters
    ----------
    real_root : str or Path
        Real SemanticKITTI tree (labelled scans).
    synth_root : str or Path or None
        Synthetic SemanticKITTI tree; None simulates ``synthetic_scans`` scans of ``profile``
        in memory (:func:`simulated_stats`).
    out : str or Path
        Output directory.
    max_scans : int or None
        At most this many scans per tree, evenly spread (None: all).
    figure : str or Path, optional
        Also write the figures here (e.g. ``docs/synthetic_realism.png`` and, next to it,
        ``docs/synthetic_realism_sensor.png``).
    overwrite : bool
        Allow a non-empty ``out``.
    synthetic_scans, seed, profile
        The simulated scans when ``synth_root`` is None.

    Returns
    -------
    (DatasetStats, DatasetStats)
        Real and synthetic statistics.
    """
    from panoptic_bench.datasets.synthetic.realism_figure import overview_figure, sensor_figure

    if max_scans is not None and max_scans < 1:
        raise InputError(f"--max-scans {max_scans} is out of range; use at least 1")
    inputs = (real_root,) if synth_root is None else (real_root, synth_root)
    check_output_location(out, inputs)
    outp = Path(out)
    if outp.is_dir() and not overwrite and any(outp.iterdir()):
        raise InputError("output directory is not empty; pass --overwrite to replace it", out)
    real = dataset_stats(real_root, max_scans, progress)
    if synth_root is None:
        synth = simulated_stats(synthetic_scans, seed, profile, progress)
    else:
        synth = dataset_stats(synth_root, max_scans, progress)
    out = ensure_output_dir(out, overwrite=overwrite, inputs=inputs)
    rows = _rows(real, synth)
    md = ["| statistic | real | synthetic |", "|---|---:|---:|"]
    md += [f"| {n} | {a:.4g} | {b:.4g} |" for n, a, b in rows]
    write_text(out / "realism.md", "\n".join(md) + "\n")
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(["statistic", "real", "synthetic"])
    writer.writerows([n, f"{a:.6g}", f"{b:.6g}"] for n, a, b in rows)
    write_text(out / "realism.csv", buf.getvalue())

    def _json(s: DatasetStats) -> dict:
        return {
            "scans": s.n_scans,
            "measures": {k: _finite(v) for k, v in s.measures.items()},
            "hists": {k: [_finite(x) for x in np.asarray(v).tolist()] for k, v in s.hists.items()},
        }

    write_json(
        out / "realism.json",
        {"rows": [[n, _finite(a), _finite(b)] for n, a, b in rows], "real": _json(real),
         "synthetic": _json(synth)},
    )  # fmt: skip
    overview_figure(real, synth, rows, out / "realism.png")
    sensor_figure(real.hists, synth.hists, out / "realism_sensor.png")
    if figure is not None:
        figure = Path(figure)
        overview_figure(real, synth, rows, figure)
        sensor_figure(real.hists, synth.hists, figure.with_name(figure.stem + "_sensor.png"))
    return real, synth


def _finite(v) -> float | None:
    v = float(v)
    return v if np.isfinite(v) else None
