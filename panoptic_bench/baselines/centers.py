"""Regressed-centre exchange format: one ``.npz`` per scan, written by any network.

Keys
----
``sem``
    uint8, shape (N,): semantic prediction as train ids (SemanticKITTI 0..19, nuScenes 0..16).
``offset``
    float32, shape (N, 3): vector from each point to its predicted instance centre (metres, LiDAR
    frame). Regressed centres are ``points[:, :3] + offset``; only things points are used.
``features`` (optional)
    any numeric array of shape (N, ...): per-point embeddings for other clusterers.
``score`` (optional)
    float array of shape (N,) or (N, C): semantic confidence or class scores.
``source`` (optional)
    0-d string: where the file comes from, e.g. ``"simulated regression"`` (see
    :mod:`panoptic_bench.baselines.regression`).

N must equal the number of points of the scan, in the scan's point order.

Layout: SemanticKITTI ``DIR/sequences/XX/centers/NNNNNN.npz`` (next to ``predictions/`` when a
network writes both into one prediction root); nuScenes ``DIR/centers/<lidar sample_data token>.npz``.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from panoptic_bench.errors import InputError
from panoptic_bench.io import write_npz

__all__ = [
    "Centers",
    "centers_path_nuscenes",
    "centers_path_semantickitti",
    "read_centers",
    "write_centers",
]


@dataclass(frozen=True, eq=False)
class Centers:
    """The content of one regressed-centre file (see module docstring for shapes and dtypes)."""

    sem: np.ndarray
    offset: np.ndarray
    features: np.ndarray | None = None
    score: np.ndarray | None = None
    source: str | None = None

    def __len__(self) -> int:
        return len(self.sem)

    def centers(self, points: np.ndarray) -> np.ndarray:
        """Regressed centres ``points[:, :3] + offset``: array of shape (N, 3), float64."""
        return np.asarray(points, dtype=np.float64)[:, :3] + self.offset


def centers_path_semantickitti(root: str | Path, sequence: str, frame: str) -> Path:
    """``root/sequences/<sequence>/centers/<frame>.npz``."""
    return Path(root) / "sequences" / sequence / "centers" / f"{frame}.npz"


def centers_path_nuscenes(root: str | Path, lidar_token: str) -> Path:
    """``root/centers/<lidar_token>.npz``."""
    return Path(root) / "centers" / f"{lidar_token}.npz"


def _problems(
    sem: np.ndarray,
    offset: np.ndarray,
    features: np.ndarray | None,
    score: np.ndarray | None,
    n_points: int | None,
    num_classes: int | None,
) -> list[str]:
    out = []
    if sem.ndim != 1:
        out.append(f"'sem' must have shape (N,), got {sem.shape}")
    elif not np.issubdtype(sem.dtype, np.integer):
        out.append(f"'sem' must hold integer train ids, got dtype {sem.dtype}")
    if offset.ndim != 2 or offset.shape[1:] != (3,):
        out.append(f"'offset' must have shape (N, 3), got {offset.shape}")
    elif not np.issubdtype(offset.dtype, np.floating):
        out.append(f"'offset' must be float, got dtype {offset.dtype}")
    if out:
        return out
    n = len(sem)
    if len(offset) != n:
        out.append(f"'sem' has {n} points but 'offset' has {len(offset)}")
    if n_points is not None and n != n_points:
        out.append(
            f"holds {n} points but the scan has {n_points}; was it written for another scan?"
        )
    bad = ~np.isfinite(offset).all(axis=1)
    if bad.any():
        out.append(
            f"'offset' has {int(bad.sum())} rows with NaN or inf (first at point {int(np.argmax(bad))})"
        )
    if n and (sem.min() < 0 or (num_classes is not None and sem.max() >= num_classes)):
        out.append(f"'sem' ids must lie in [0, {num_classes}), got {sem.min()}..{sem.max()}")
    for name, arr in (("features", features), ("score", score)):
        if arr is not None and (arr.ndim == 0 or len(arr) != n):
            out.append(f"'{name}' must have N={n} rows, got shape {arr.shape}")
    return out


def write_centers(
    path: str | Path,
    sem: np.ndarray,
    offset: np.ndarray,
    *,
    features: np.ndarray | None = None,
    score: np.ndarray | None = None,
    source: str | None = None,
) -> None:
    """Atomically write one regressed-centre file.

    Parameters
    ----------
    path : path
        Destination ``.npz``.
    sem : array of shape (N,), integer in [0, 256)
        Semantic train ids (stored as uint8).
    offset : array of shape (N, 3), float
        Point → centre vectors (stored as float32).
    features, score : array with N rows, optional
    source : str, optional
        Provenance label, e.g. ``"simulated regression"``.
    """
    sem = np.asarray(sem)
    offset = np.asarray(offset)
    problems = _problems(sem, offset, features, score, None, 256)
    if problems:
        raise ValueError("; ".join(problems))
    arrays = {"sem": sem.astype(np.uint8), "offset": offset.astype(np.float32)}
    if features is not None:
        arrays["features"] = np.asarray(features)
    if score is not None:
        arrays["score"] = np.asarray(score)
    if source is not None:
        arrays["source"] = np.array(source)
    write_npz(path, **arrays)


def read_centers(
    path: str | Path, *, n_points: int | None = None, num_classes: int | None = None
) -> Centers:
    """Read and validate one regressed-centre file.

    Parameters
    ----------
    path : path
        The ``.npz`` file.
    n_points : int, optional
        Number of points of the matching scan; a different N is an :class:`InputError`.
    num_classes : int, optional
        Semantic ids must be below it.

    Returns
    -------
    Centers
        ``sem`` uint8 (N,), ``offset`` float64 (N, 3), optional ``features``/``score``/``source``.

    Raises
    ------
    InputError
        Missing or unreadable file, missing keys, wrong shapes, N mismatch, NaN/inf offsets.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(
            "regressed-centre file not found; write one .npz per scan (keys sem, offset)", path
        )
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        raise InputError(f"cannot read regressed-centre file ({exc})", path) from None
    missing = [k for k in ("sem", "offset") if k not in arrays]
    if missing:
        raise InputError(
            f"regressed-centre file lacks key(s) {missing}; it needs 'sem' (N,) and 'offset' (N, 3)",
            path,
        )
    sem, offset = arrays["sem"], arrays["offset"]
    features, score = arrays.get("features"), arrays.get("score")
    problems = _problems(sem, offset, features, score, n_points, num_classes)
    if problems:
        raise InputError("; ".join(problems), path)
    source = arrays.get("source")
    return Centers(
        sem=sem.astype(np.uint8),
        offset=offset.astype(np.float64),
        features=features,
        score=score,
        source=None if source is None else str(source),
    )
