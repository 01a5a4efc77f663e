"""Scans for the viewer from dataset trees, with the evaluators' input checks.

Every problem is an :class:`~panoptic_bench.errors.InputError` naming the scan, token or file:
a scan or token not in the dataset, predictions or centres of another point count, unknown ids.
Without predictions the prediction side shows the ground truth (and says so).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from panoptic_bench.errors import InputError
from panoptic_bench.viewer.scene import ViewClasses, ViewScan, kitti_classes, nuscenes_classes

__all__ = ["load_nuscenes", "load_semantickitti", "parse_scan"]

_SCAN = re.compile(r"^(\d{1,2})/(\d{1,6})$")


def parse_scan(text: str) -> tuple[str, str]:
    """``"08/000123"`` (or ``"8/123"``) -> ``("08", "000123")``; InputError naming ``--scan``."""
    m = _SCAN.match(text.strip())
    if not m:
        raise InputError(f"--scan {text!r}: expected SEQUENCE/FRAME, e.g. 08/000000")
    return f"{int(m.group(1)):02d}", f"{int(m.group(2)):06d}"


def _centres(path: Path, xyz: np.ndarray, classes: ViewClasses) -> np.ndarray:
    """Regressed centres of the points the centre file calls things; NaN rows elsewhere."""
    from panoptic_bench.baselines.centers import read_centers

    cen = read_centers(path, n_points=len(xyz), num_classes=classes.num_classes)
    out = cen.centers(xyz).astype(np.float32)
    out[~np.isin(cen.sem, classes.things)] = np.nan
    return out


def load_semantickitti(
    dataset: str | Path,
    scan: str,
    *,
    predictions: str | Path | None = None,
    centers: str | Path | None = None,
) -> tuple[ViewScan, ViewClasses]:
    """One SemanticKITTI scan with ground truth, prediction and optional regressed centres.

    Parameters
    ----------
    dataset : path
        Root holding ``sequences/XX/{velodyne,labels}``.
    scan : str
        ``SEQUENCE/FRAME``, e.g. ``"08/000000"``.
    predictions : path, optional
        Root holding ``sequences/XX/predictions/NNNNNN.label`` (raw ids, uint32).
    centers : path, optional
        Root holding ``sequences/XX/centers/NNNNNN.npz`` (regressed-centre files).

    Returns
    -------
    (ViewScan, ViewClasses)
        Class ids are train ids; matching ids are the full uint32 labels, as in the evaluator.
    """
    from panoptic_bench.baselines.centers import centers_path_semantickitti
    from panoptic_bench.datasets import semantickitti as sk
    from panoptic_bench.evaluation.semantickitti import check_label_ids, scan_point_count

    seq, frame = parse_scan(scan)
    seq_dir = Path(dataset) / "sequences" / seq
    bin_path = seq_dir / "velodyne" / f"{frame}.bin"
    if not bin_path.is_file():
        where = "sequence not found" if not seq_dir.is_dir() else "no such scan"
        raise InputError(f"scan {seq}/{frame} is not in the dataset ({where})", bin_path)
    n = scan_point_count(bin_path)
    xyz = sk.read_scan(bin_path)[:, :3]
    label_path = seq_dir / "labels" / f"{frame}.label"
    if not label_path.is_file():
        raise InputError(f"scan {seq}/{frame} has no ground-truth labels", label_path)
    gt = sk.read_labels(label_path)
    check_label_ids(gt, n, label_path, "ground truth")
    if predictions is None:
        pred = gt
    else:
        ref = sk.ScanRef(seq, frame, bin_path, label_path)
        pred_path = sk.prediction_path(predictions, ref)
        if not pred_path.is_file():
            raise InputError(f"no prediction for scan {seq}/{frame}", pred_path)
        pred = sk.read_labels(pred_path)
        check_label_ids(pred, n, pred_path, "prediction")
    classes = kitti_classes()
    cen = None
    if centers is not None:
        path = centers_path_semantickitti(centers, seq, frame)
        cen = _centres(path, xyz, classes)
    view = ViewScan(
        name=f"{seq}/{frame}",
        xyz=xyz.astype(np.float32),
        pred_sem=sk.to_train(pred).astype(np.int64),
        pred_inst=pred.astype(np.int64),
        gt_sem=sk.to_train(gt).astype(np.int64),
        gt_inst=gt.astype(np.int64),
        centres=cen,
    )
    return view, classes


def _prediction_file(result_path: Path, token: str, eval_set: str | None) -> Path:
    if eval_set is not None:
        return result_path / "panoptic" / eval_set / f"{token}_panoptic.npz"
    found = sorted((result_path / "panoptic").glob(f"*/{token}_panoptic.npz"))
    if len(found) > 1:
        sets = ", ".join(p.parent.name for p in found)
        raise InputError(f"predictions for {token} in several eval sets ({sets}); pass --eval-set")
    if not found:
        return result_path / "panoptic" / "<eval_set>" / f"{token}_panoptic.npz"
    return found[0]


def load_nuscenes(
    dataroot: str | Path,
    version: str,
    token: str,
    *,
    result_path: str | Path | None = None,
    eval_set: str | None = None,
    centers: str | Path | None = None,
    min_points: int = 15,
) -> tuple[ViewScan, ViewClasses]:
    """One Panoptic nuScenes keyframe sweep with ground truth, prediction and optional centres.

    Parameters
    ----------
    dataroot, version : str
        nuScenes dataroot with panoptic ground truth, and its version (``v1.0-mini``).
    token : str
        LIDAR_TOP sample_data token.
    result_path : path, optional
        Holds ``panoptic/<eval_set>/<token>_panoptic.npz`` (challenge class x 1000 + instance).
    eval_set : str, optional
        The folder under ``panoptic/``; by default the one holding this token's file.
    centers : path, optional
        Holds ``centers/<token>.npz``.
    min_points : int
        The evaluator's ``--min-inst-points`` (devkit default 15).

    Returns
    -------
    (ViewScan, ViewClasses)
        Challenge class ids; matching ids are the full panoptic labels, as in the evaluator.
    """
    from panoptic_bench.baselines.centers import centers_path_nuscenes
    from panoptic_bench.datasets.nuscenes_reader import NuScenesLidar, load_panoptic_npz
    from panoptic_bench.evaluation.nuscenes import ChallengeClasses

    reader = NuScenesLidar(dataroot, version)
    try:
        record = reader.nusc.get("sample_data", token)
    except KeyError:
        raise InputError(
            f"sample_data token {token!r} is not in nuScenes {version}",
            reader.table_root / "sample_data.json",
        ) from None
    if record.get("channel", "LIDAR_TOP") != "LIDAR_TOP" or not record.get("is_key_frame", True):
        raise InputError(f"sample_data {token} is not a keyframe LIDAR_TOP sweep")
    points = reader.load_points(token)
    n = len(points)
    gt = reader.load_panoptic(token).astype(np.int64)
    cc = ChallengeClasses.from_nusc(reader.nusc)
    general = gt // 1000
    if general.max(initial=0) >= len(cc.lut) or (cc.lut[general] < 0).any():
        raise InputError("ground truth holds unknown general class ids", reader.label_path(token))
    gt_sem = cc.lut[general]
    if result_path is None:
        pred, pred_sem = gt, gt_sem
    else:
        path = _prediction_file(Path(result_path), token, eval_set)
        if not path.is_file():
            raise InputError(f"no prediction for sample_data {token}", path)
        pred = load_panoptic_npz(path).astype(np.int64)
        if len(pred) != n:
            raise InputError(
                f"prediction has {len(pred)} labels but the sweep of sample_data {token} has "
                f"{n} points",
                path,
            )
        pred_sem = pred // 1000
        bad = (pred < 0) | (pred_sem >= cc.num_classes)
        if bad.any():
            raise InputError(
                f"prediction class ids must be 0..{cc.num_classes - 1} (label // 1000); "
                f"found label {int(pred[bad][0])}",
                path,
            )
    classes = nuscenes_classes(reader.nusc, min_points)
    xyz = points[:, :3].astype(np.float32)
    cen = None
    if centers is not None:
        cen = _centres(centers_path_nuscenes(centers, token), xyz, classes)
    view = ViewScan(token, xyz, pred_sem, pred, gt_sem, gt, cen)
    return view, classes
