"""What the viewer shows: one scan's points with prediction and ground truth, and the class facts.

:class:`ViewClasses` holds the class names, official colours and thing / ignored ids of a dataset;
:class:`ViewScan` one scan's arrays. The loaders of :mod:`panoptic_bench.viewer.load` build them
from dataset trees; reports build them from a run directory's ``viewer_scans.npz``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from panoptic_bench.metrics.panoptic import panoptic_stats
from panoptic_bench.viewer.matching import SegmentMatch, match_segments

__all__ = ["ViewClasses", "ViewScan", "kitti_classes", "nuscenes_classes", "scan_pq"]


@dataclass(frozen=True)
class ViewClasses:
    """Class facts of a dataset for the viewer.

    Attributes
    ----------
    dataset : str
        ``"semantickitti"`` or ``"nuscenes"``.
    names : tuple of str
        Class name per class id (train ids / challenge ids).
    colours : tuple of str
        ``#rrggbb`` per class id, from the official colour map.
    things : tuple of int
        Thing class ids.
    ignore : tuple of int
        Ignored class ids.
    min_points : int
        The evaluator's minimum size of an unmatched segment (50 SemanticKITTI, 15 nuScenes).
    instance_shift : int
        Shown instance id = matching id >> 16 (SemanticKITTI labels) when 16, else
        matching id % 1000 (nuScenes panoptic labels) when 0.
    """

    dataset: str
    names: tuple[str, ...]
    colours: tuple[str, ...]
    things: tuple[int, ...]
    ignore: tuple[int, ...]
    min_points: int
    instance_shift: int = 16

    @property
    def num_classes(self) -> int:
        return len(self.names)

    @property
    def stuff(self) -> tuple[int, ...]:
        return tuple(c for c in range(self.num_classes) if c not in self.things + self.ignore)

    def shown_instance(self, ids: np.ndarray) -> np.ndarray:
        """Instance ids as people know them (label >> 16, or panoptic label % 1000), int64."""
        ids = np.asarray(ids, dtype=np.int64)
        return ids >> 16 if self.instance_shift else ids % 1000

    def to_dict(self) -> dict:
        return {
            "dataset": self.dataset,
            "names": list(self.names),
            "colours": list(self.colours),
            "things": list(self.things),
            "ignore": list(self.ignore),
            "min_points": self.min_points,
            "instance_shift": self.instance_shift,
        }

    @classmethod
    def from_dict(cls, data: dict) -> ViewClasses:
        """Inverse of :meth:`to_dict`; unknown or missing keys are rejected."""
        keys = {"dataset", "names", "colours", "things", "ignore", "min_points", "instance_shift"}
        if set(data) != keys:
            raise ValueError(f"ViewClasses keys must be {sorted(keys)}, got {sorted(data)}")
        return cls(
            str(data["dataset"]),
            tuple(map(str, data["names"])),
            tuple(map(str, data["colours"])),
            tuple(map(int, data["things"])),
            tuple(map(int, data["ignore"])),
            int(data["min_points"]),
            int(data["instance_shift"]),
        )


def _hex(rgb: Sequence[int]) -> str:
    return "#" + "".join(f"{int(c):02x}" for c in rgb)


def kitti_classes() -> ViewClasses:
    """SemanticKITTI train ids with the official ``color_map`` (BGR in the file, made RGB)."""
    from panoptic_bench.datasets.semantickitti import LABELS
    from panoptic_bench.evaluation.semantickitti import OFFICIAL_MIN_POINTS

    colours = []
    for train_id in range(LABELS.num_classes):
        b, g, r = LABELS.color_map[LABELS.learning_map_inv[train_id]]
        colours.append(_hex((r, g, b)))
    return ViewClasses(
        "semantickitti",
        LABELS.class_names,
        tuple(colours),
        LABELS.thing_ids,
        LABELS.ignore_ids,
        OFFICIAL_MIN_POINTS,
        16,
    )


def nuscenes_classes(nusc, min_points: int = 15) -> ViewClasses:
    """Panoptic nuScenes challenge classes with the devkit's coarse colour map."""
    from nuscenes.eval.panoptic.utils import PanopticClassMapper

    from panoptic_bench.evaluation.nuscenes import IGNORE, ChallengeClasses

    classes = ChallengeClasses.from_nusc(nusc)
    cmap = PanopticClassMapper(nusc).coarse_colormap
    colours = tuple(_hex(cmap.get(name, (0, 0, 0))[:3]) for name in classes.names)
    return ViewClasses("nuscenes", classes.names, colours, classes.things, (IGNORE,), min_points, 0)


@dataclass(frozen=True, eq=False)
class ViewScan:
    """One scan to show.

    Attributes
    ----------
    name : str
        E.g. ``"08/000123"`` or a nuScenes sample_data token.
    xyz : ndarray of shape (n_points, 3), float32
        Point coordinates (m, sensor frame).
    pred_sem, gt_sem : ndarray of shape (n_points,), int64
        Predicted and ground-truth class ids.
    pred_inst, gt_inst : ndarray of shape (n_points,), int64
        Instance ids used for matching (as the evaluator uses them).
    centres : ndarray of shape (n_points, 3), float32, optional
        Regressed centre of each point (NaN rows for points without one).
    """

    name: str
    xyz: np.ndarray
    pred_sem: np.ndarray
    pred_inst: np.ndarray
    gt_sem: np.ndarray
    gt_inst: np.ndarray
    centres: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.xyz)
        if np.shape(self.xyz) != (n, 3):
            raise ValueError(f"xyz must have shape (n, 3), got {np.shape(self.xyz)}")
        for key in ("pred_sem", "pred_inst", "gt_sem", "gt_inst"):
            if np.shape(getattr(self, key)) != (n,):
                raise ValueError(
                    f"{key} must have shape ({n},), got {np.shape(getattr(self, key))}"
                )
        if self.centres is not None and np.shape(self.centres) != (n, 3):
            raise ValueError(f"centres must have shape ({n}, 3), got {np.shape(self.centres)}")

    def __len__(self) -> int:
        return len(self.xyz)

    def match(self, classes: ViewClasses) -> SegmentMatch:
        """Segment matching with the evaluator's rules (:func:`match_segments`)."""
        return match_segments(
            self.pred_sem, self.pred_inst, self.gt_sem, self.gt_inst,
            num_classes=classes.num_classes, ignore=classes.ignore, min_points=classes.min_points,
        )  # fmt: skip


def scan_pq(scan: ViewScan, classes: ViewClasses) -> float:
    """PQ of one scan: mean over the classes that occur in it (TP + FP + FN > 0), in [0, 1].

    Averaging over every class (as over a whole split) would rank a scan low only for the classes
    it lacks; NaN when no class occurs.
    """
    stats = panoptic_stats(
        scan.pred_sem, scan.pred_inst, scan.gt_sem, scan.gt_inst,
        num_classes=classes.num_classes, ignore=classes.ignore, min_points=classes.min_points,
    )  # fmt: skip
    res = stats.compute()
    seen = [c for c in res.include if stats.tp[c] + stats.fp[c] + stats.fn[c] > 0]
    return float(np.mean(res.pq[seen])) if seen else float("nan")
