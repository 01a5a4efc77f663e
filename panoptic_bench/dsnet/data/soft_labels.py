"""Per-point class probabilities of a teacher: the targets of distillation.

``panoptic-bench infer --save-probs`` writes, beside each scan's prediction, the class
probabilities its checkpoint (or ensemble, with its test-time views) gave every point:
``sequences/<seq>/probs/<frame>.npy`` under the prediction root of a SemanticKITTI-format root,
``probs/<token>.npy`` for nuScenes, float16 of shape (n, C), each row summing to 1 with 0 on the
ignored classes. A training run with ``loss.distill`` > 0 reads them from ``loss.distill_probs``
(:class:`~panoptic_bench.dsnet.data.training_set.TrainingSet`) and carries them with the points
through thinning and pasting (a pasted instance's points get its class with probability 1).

Example
-------
>>> path = soft_label_path("preds/teacher", ("00", "000000"))
>>> str(path)
'preds/teacher/sequences/00/probs/000000.npy'
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from panoptic_bench.errors import InputError
from panoptic_bench.io import write_bytes

__all__ = [
    "ROW_SUM_TOLERANCE",
    "one_hot",
    "read_soft_labels",
    "soft_label_path",
    "write_soft_labels",
]

#: Largest accepted distance of a row sum from 1 (float16 rounding of 20 probabilities).
ROW_SUM_TOLERANCE = 0.02


def soft_label_path(root: str | Path, key: tuple[str, ...]) -> Path:
    """The probability file of the scan ``key`` (``(sequence, frame)`` or ``(token,)``)."""
    root = Path(root)
    if len(key) == 2:
        return root / "sequences" / key[0] / "probs" / f"{key[1]}.npy"
    return root / "probs" / f"{key[0]}.npy"


def write_soft_labels(path: str | Path, probs: np.ndarray) -> None:
    """Atomically write ``probs`` (n, C) as float16 ``.npy``."""
    buffer = io.BytesIO()
    np.save(buffer, np.asarray(probs, dtype=np.float16))
    write_bytes(path, buffer.getvalue())


def read_soft_labels(path: str | Path, n_points: int, num_classes: int) -> np.ndarray:
    """The probabilities of one scan, checked against the scan they belong to.

    Parameters
    ----------
    path : path
        A file written by :func:`write_soft_labels`.
    n_points : int
        Points of the scan (rows expected).
    num_classes : int
        Classes of the training config (columns expected).

    Returns
    -------
    ndarray of shape (n_points, num_classes), float16

    Raises
    ------
    InputError
        Missing or unreadable file, wrong shape, values outside [0, 1] or not finite, or rows
        whose sum is not 1; the message names the file.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(
            "no teacher probabilities for this scan: write them with "
            "`panoptic-bench infer --save-probs` on the training root",
            path,
        )
    try:
        probs = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise InputError(f"unreadable teacher probabilities ({exc})", path) from None
    if probs.shape != (n_points, num_classes):
        raise InputError(
            f"teacher probabilities of shape {probs.shape}, expected ({n_points}, "
            f"{num_classes}) for this scan (points, classes): written for another root?",
            path,
        )
    values = probs.astype(np.float32)
    if not np.isfinite(values).all() or values.min(initial=0) < 0 or values.max(initial=0) > 1:
        raise InputError("teacher probabilities must be finite and within [0, 1]", path)
    sums = values.sum(1)
    if len(sums) and np.abs(sums - 1).max() > ROW_SUM_TOLERANCE:
        raise InputError(
            f"teacher probabilities: a row sums to {sums[np.abs(sums - 1).argmax()]:.3f}, not 1",
            path,
        )
    return probs.astype(np.float16, copy=False)


def one_hot(sem: np.ndarray, num_classes: int) -> np.ndarray:
    """Probability rows of certain labels: (n, C) float16 with 1 at ``sem``."""
    out = np.zeros((len(sem), num_classes), dtype=np.float16)
    out[np.arange(len(sem)), sem] = 1
    return out
