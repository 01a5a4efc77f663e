"""Where one true class's points go, bin by bin of a per-point quantity, over a SemanticKITTI tree
(``panoptic-bench eval breakdown``).

Both label files are mapped to train ids exactly as the evaluator maps them
(:func:`~panoptic_bench.evaluation.semantickitti.checked_train_ids`), so the counts summed over
all bins of a quantity that every point has are the true class's row of the evaluator's
confusion matrix. Files are checked as ``eval semantickitti`` checks them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from panoptic_bench.datasets import semantickitti as sk
from panoptic_bench.errors import InputError
from panoptic_bench.evaluation import workers as workers_module
from panoptic_bench.evaluation.semantickitti import checked_train_ids, require_predictions
from panoptic_bench.metrics.breakdown import BinnedCounts, check_edges
from panoptic_bench.metrics.by_range import point_range
from panoptic_bench.metrics.point_features import DEFAULT_EDGES, FEATURES, point_feature

__all__ = ["Breakdown", "breakdown_semantickitti", "breakdown_table", "write_breakdown"]


@dataclass(frozen=True)
class Breakdown:
    """The summed counts of one breakdown and what it was taken over."""

    counts: BinnedCounts
    true_class: str
    feature: str
    n_scans: int
    class_names: tuple[str, ...]
    within: tuple[float, float] | None = None

    def columns(self, top: int) -> list[int]:
        """The true class, then the ``top - 1`` most predicted other classes (indices)."""
        total = self.counts.counts.sum(axis=0)
        t = self.class_names.index(self.true_class)
        order = [int(c) for c in np.argsort(-total, kind="stable") if c != t and total[c] > 0]
        return [t, *order[: max(0, top - 1)]]


def _class_index(name: str) -> int:
    names = sk.LABELS.class_names
    if name not in names:
        raise InputError(f"--class: unknown class {name!r}; choose one of {list(names[1:])}")
    idx = names.index(name)
    if idx in sk.LABELS.ignore_ids:
        raise InputError(f"--class: {name!r} is ignored by the evaluator; choose a scored class")
    return idx


def breakdown_semantickitti(
    dataset: str | Path,
    predictions: str | Path,
    *,
    true_class: str,
    feature: str,
    edges: Sequence[float] | None = None,
    split: str | None = "valid",
    sequences: Sequence[str] | None = None,
    within: tuple[float, float] | None = None,
    progress: bool | None = None,
) -> Breakdown:
    """Count the predicted classes of ``true_class``'s points per bin of ``feature``.

    Parameters
    ----------
    dataset, predictions : path
        Roots as for ``eval semantickitti``.
    true_class : str
        Class name (``"terrain"``).
    feature : {"range", "height", "roughness", "remission"}
        See :mod:`panoptic_bench.metrics.point_features`; ``height`` is above the plane of the
        scan's *true* road points.
    edges : sequence of float, optional
        Bin edges; default :data:`~panoptic_bench.metrics.point_features.DEFAULT_EDGES`.
    within : (float, float), optional
        Only points whose range (m) lies in ``[lo, hi)``.

    Raises
    ------
    InputError
        Unknown class or feature, bad edges, missing or malformed files (naming the file).
    """
    if feature not in FEATURES:
        raise InputError(f"--by: unknown quantity {feature!r}; choose one of {list(FEATURES)}")
    try:
        edges = check_edges(DEFAULT_EDGES[feature] if edges is None else edges)
    except ValueError as exc:
        raise InputError(f"--edges: {exc}") from None
    if within is not None and not (0 <= within[0] < within[1]):
        raise InputError(f"--within: expected 0 <= MIN < MAX metres, got {within}")
    t = _class_index(true_class)
    road = sk.LABELS.class_names.index("road")
    C = sk.LABELS.num_classes
    refs = sk.list_scans(dataset, split=split, sequences=sequences)
    require_predictions(refs, predictions)
    total = BinnedCounts(edges, np.zeros((len(edges) - 1, C), np.int64))
    bar = workers_module.progress_bar(len(refs), "breakdown", "scan", progress)
    try:
        for ref in refs:
            points = sk.read_scan(ref.scan)
            n = len(points)
            gt = checked_train_ids(sk.read_labels(ref.label), n, ref.label, "ground truth")
            pred_path = sk.prediction_path(predictions, ref)
            pred = checked_train_ids(sk.read_labels(pred_path), n, pred_path, "prediction")
            keep = gt == t
            r = point_range(points) if within is not None or feature == "range" else None
            if within is not None:
                keep &= (r >= within[0]) & (r < within[1])
            values = r if feature == "range" else point_feature(feature, points, gt == road)
            total = total + BinnedCounts.of_scan(values[keep], pred[keep], edges, C)
            bar.update()
    finally:
        bar.close()
    return Breakdown(total, true_class, feature, len(refs), sk.LABELS.class_names, within)


def _bin_label(lo: float, hi: float) -> str:
    return f"[{lo:g}, {hi:g})"


def breakdown_table(b: Breakdown, top: int = 6) -> str:
    """Fixed-width text: one row per bin, points and % predicted as the top classes and the rest."""
    cols = b.columns(top)
    shares = 100 * b.counts.shares()
    names = [b.class_names[c] for c in cols]
    head = f"{'bin':>16} {'points':>9} " + " ".join(f"{n[:13]:>13}" for n in names) + "  others"
    lines = [head]
    for i, (lo, hi) in enumerate(zip(b.counts.edges, b.counts.edges[1:])):
        n = int(b.counts.points()[i])
        cells = [f"{shares[i, c]:13.1f}" if n else f"{'-':>13}" for c in cols]
        rest = f"{100 - np.sum(shares[i, cols]):6.1f}" if n else f"{'-':>6}"
        lines.append(f"{_bin_label(lo, hi):>16} {n:9d} " + " ".join(cells) + f"  {rest}")
    where = "" if b.within is None else f", range [{b.within[0]:g}, {b.within[1]:g}) m"
    intro = (
        f"true {b.true_class} by {b.feature}{where}, {b.n_scans} scans: % of each bin's points "
        f"predicted as ({b.counts.unbinned} points without a value or outside the bins)\n"
    )
    return intro + "\n".join(lines) + "\n"


def _csv(b: Breakdown) -> str:
    rows = ["bin_lo,bin_hi,points," + ",".join(b.class_names)]
    for i, (lo, hi) in enumerate(zip(b.counts.edges, b.counts.edges[1:])):
        c = b.counts.counts[i]
        rows.append(f"{lo:g},{hi:g},{int(c.sum())}," + ",".join(str(int(v)) for v in c))
    return "\n".join(rows) + "\n"


def plot_breakdown(b: Breakdown, path: str | Path, top: int = 6) -> Path:
    """Stacked bars: each bin's points by predicted class (the top classes, then the rest)."""
    from panoptic_bench.reports.style import colour, figure

    cols = b.columns(top)
    shares = 100 * np.nan_to_num(b.counts.shares())
    labels = [_bin_label(lo, hi) for lo, hi in zip(b.counts.edges, b.counts.edges[1:])]
    y = np.arange(len(labels))
    with figure(path, size=(6.4, 0.32 * len(labels) + 1.6)) as (_, axes):
        ax = axes[0, 0]
        left = np.zeros(len(labels))
        for k, c in enumerate(cols):
            ax.barh(y, shares[:, c], left=left, color=colour(k), label=b.class_names[c])
            left += shares[:, c]
        ax.barh(y, np.where(b.counts.points() > 0, 100 - left, 0), left=left, color="0.8",
                label="others")  # fmt: skip
        ax.set_yticks(y, [f"{s} ({n})" for s, n in zip(labels, b.counts.points())], fontsize=7)
        ax.set_xlim(0, 100)
        ax.set_xlabel(f"% of the true {b.true_class} points in the bin")
        ax.set_ylabel(b.feature)
        ax.set_title(f"true {b.true_class}: predicted as, by {b.feature}")
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    return Path(path)


def write_breakdown(tmp: Path, b: Breakdown, top: int = 6) -> str:
    """Write ``breakdown.csv`` (counts of every class), ``breakdown.txt`` and ``breakdown.png``
    into the directory ``tmp``; returns the table text."""
    from panoptic_bench.io import write_text

    text = breakdown_table(b, top)
    write_text(tmp / "breakdown.csv", _csv(b))
    write_text(tmp / "breakdown.txt", text)
    plot_breakdown(b, tmp / "breakdown.png", top)
    return text
