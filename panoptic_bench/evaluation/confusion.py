"""Where the points of each true class go: the largest confusions of a scored prediction set,
or how they changed between two (``panoptic-bench eval confusions``).

The matrix is the evaluator's own (summed from ``per_scan.npz``), with its convention: points whose
true class is ignored (unlabelled, outlier) are left out; a point predicted as an ignored class is
kept, as a miss of its true class (its predicted name is then e.g. ``unlabeled``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from panoptic_bench.evaluation.per_scan import PerScan

__all__ = ["confusion_matrix", "confusion_rows", "confusion_table", "csv_text"]


def confusion_matrix(per: PerScan) -> np.ndarray:
    """Point counts of one evaluation, true class by predicted class.

    Returns
    -------
    numpy.ndarray of shape (C, C), int64
        ``[t, p]`` = points of true class ``t`` predicted as ``p``, summed over the scans; rows
        of ignored true classes are 0.
    """
    conf = np.sum([s.confusion for s in per.stats], axis=0).astype(np.int64).T.copy()
    conf[list(per.stats[0].ignore)] = 0
    return conf


def confusion_rows(
    conf: np.ndarray,
    class_names: Sequence[str],
    top: int = 15,
    other: np.ndarray | None = None,
) -> list[dict[str, Any]]:
    """The largest off-diagonal cells of ``conf`` (or of its change to ``other``).

    Parameters
    ----------
    conf : array (C, C), int64
        True by predicted point counts (:func:`confusion_matrix`) of result A.
    class_names : sequence of str, length C
    top : int
        Number of cells returned.
    other : array (C, C), int64, optional
        The same matrix of result B on the same scans; the cells are then ranked by the size of
        their change ``B - A`` instead of by their size in A.

    Returns
    -------
    list of dict
        Per cell: ``true``, ``predicted`` (names), ``points`` (in A), ``of_true`` (fraction of
        the true class's points), ``of_predicted`` (fraction of the points predicted as that
        class); with ``other`` also ``points_b``, ``of_true_b`` and ``change`` (points B - A).
    """
    conf = np.asarray(conf, np.int64)
    b = None if other is None else np.asarray(other, np.int64)
    C = len(class_names)
    if conf.shape != (C, C) or (b is not None and b.shape != (C, C)):
        raise ValueError(f"confusion matrices must have shape ({C}, {C})")
    off = ~np.eye(C, dtype=bool)
    key = conf if b is None else np.abs(b - conf)
    order = np.argsort(-np.where(off, key, -1), axis=None, kind="stable")[: max(0, top)]
    rows = []
    for flat in order:
        t, p = divmod(int(flat), C)
        if key[t, p] <= 0:
            break
        row = {
            "true": class_names[t],
            "predicted": class_names[p],
            "points": int(conf[t, p]),
            "of_true": _share(conf[t, p], conf[t].sum()),
            "of_predicted": _share(conf[t, p], conf[:, p].sum()),
        }
        if b is not None:
            row |= {
                "points_b": int(b[t, p]),
                "of_true_b": _share(b[t, p], b[t].sum()),
                "change": int(b[t, p] - conf[t, p]),
            }
        rows.append(row)
    return rows


def _share(part: int, whole: int) -> float:
    return float(part / whole) if whole else float("nan")


def _pct(x: float) -> str:
    return "-" if np.isnan(x) else f"{100 * x:.1f}"


def confusion_table(rows: Sequence[dict[str, Any]]) -> str:
    """The rows of :func:`confusion_rows` as an aligned text table (shares in %)."""
    from panoptic_bench.evaluation.output import text_table

    pair = bool(rows) and "change" in rows[0]
    head = ["true class", "predicted as", "points", "% of true", "% of predicted"]
    if pair:
        head = ["true class", "predicted as", "A points", "A % of true", "B points", "B % of true",
                "B - A"]  # fmt: skip
    body = []
    for r in rows:
        if pair:
            body.append([r["true"], r["predicted"], str(r["points"]), _pct(r["of_true"]),
                         str(r["points_b"]), _pct(r["of_true_b"]), f"{r['change']:+d}"])  # fmt: skip
        else:
            body.append([r["true"], r["predicted"], str(r["points"]), _pct(r["of_true"]),
                         _pct(r["of_predicted"])])  # fmt: skip
    return text_table(head, body)


def csv_text(conf: np.ndarray, class_names: Sequence[str]) -> str:
    """The full matrix as CSV: a header ``true\\predicted,<names>``, one row per true class."""
    lines = ["true\\predicted," + ",".join(class_names)]
    for name, row in zip(class_names, np.asarray(conf, np.int64)):
        lines.append(name + "," + ",".join(str(int(v)) for v in row))
    return "\n".join(lines) + "\n"
