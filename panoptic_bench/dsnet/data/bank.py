"""Instance bank: rare thing instances pasted into training scans (GT sampling, class-balanced).

Few real scans hold almost no bicycles, motorcycles, persons or trucks, and a held-out place
often holds the only ones there are. :class:`InstanceBank` collects the thing instances of
chosen classes from a labelled root (the training scans themselves, or a synthetic root whose
sensor model matches the real one) and pastes a few of them into a training scan:

* a class is drawn uniformly among the bank's classes, then one of its instances uniformly
  (class-balanced: a class with three instances is pasted as often as one with three hundred);
* the copy is rotated about the sensor's vertical axis by a random angle, so its range, height
  and ring pattern stay those of a real return (PolarMix's rotate-pasting);
* a placement is kept only where the scan has ground under the copy's footprint and nothing above
  it (:func:`placement_ok`); otherwise another angle is tried, up to ``tries`` times, and the
  instance is skipped when none fits. Scan points in the footprint above the copy's base are
  removed (there are at most ``max_clutter`` of them).

Everything is in the sensor frame, before the usual augmentation; a given generator gives the
same scan. Instance ids of the copies are offset past the scan's largest id.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from panoptic_bench.dsnet.data.soft_labels import one_hot
from panoptic_bench.errors import InputError

__all__ = [
    "BankInstance",
    "InstanceBank",
    "footprint_mask",
    "open_bank",
    "placement_ok",
    "rotate_z",
]

# a placement needs this many scan points within the band around the copy's base, in its
# footprint grown by SUPPORT_MARGIN (ground rings are ~0.5-1 m apart at 10-20 m)
MIN_SUPPORT = 2
SUPPORT_MARGIN = 0.5
# the copy's base band: [zmin - BELOW, zmin + ABOVE] metres
BASE_BELOW, BASE_ABOVE = 0.3, 0.15
# footprint margin around the copy's xy extent for the free-space check (m)
MARGIN = 0.1


@dataclass(frozen=True)
class BankInstance:
    """One thing instance, points in its source scan's sensor frame.

    Attributes
    ----------
    xyz : ndarray of shape (n, 3), float32
    remission : ndarray of shape (n,), float32
    sem : int
        Train id of the instance's class.
    """

    xyz: np.ndarray
    remission: np.ndarray
    sem: int


def rotate_z(xyz: np.ndarray, angle: float) -> np.ndarray:
    """Points rotated about the z axis by ``angle`` radians; (n, 3) float32 out."""
    c, s = math.cos(angle), math.sin(angle)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return (xyz.astype(np.float64) @ rot.T).astype(np.float32)


def footprint_mask(scan_xyz: np.ndarray, obj_xyz: np.ndarray, margin: float = MARGIN) -> np.ndarray:
    """Scan points inside the object's axis-aligned xy box grown by ``margin``.

    Parameters
    ----------
    scan_xyz : ndarray of shape (n, 3)
    obj_xyz : ndarray of shape (m, 3), m >= 1

    Returns
    -------
    ndarray of shape (n,), bool
    """
    lo = obj_xyz[:, :2].min(0) - margin
    hi = obj_xyz[:, :2].max(0) + margin
    xy = scan_xyz[:, :2]
    return np.all((xy >= lo) & (xy <= hi), axis=1)


def placement_ok(
    scan_xyz: np.ndarray, obj_xyz: np.ndarray, max_clutter: int = 2
) -> tuple[bool, np.ndarray]:
    """Whether ``obj_xyz`` can stand in the scan: ground under it, (almost) nothing above.

    Ground: at least ``MIN_SUPPORT`` scan points in the base band ``[zmin - BASE_BELOW,
    zmin + BASE_ABOVE]`` within the footprint grown by ``SUPPORT_MARGIN``. Free space: at most
    ``max_clutter`` scan points above the band within the footprint grown by ``MARGIN``.

    Parameters
    ----------
    scan_xyz : ndarray of shape (n, 3)
    obj_xyz : ndarray of shape (m, 3)
        The placed copy.
    max_clutter : int
        Most scan points allowed in the footprint above the base band.

    Returns
    -------
    ok : bool
    above : ndarray of shape (n,), bool
        Scan points in the footprint above the base band (to remove when the copy is placed).
    """
    inside = footprint_mask(scan_xyz, obj_xyz)
    zmin = float(obj_xyz[:, 2].min())
    z = scan_xyz[:, 2]
    base = footprint_mask(scan_xyz, obj_xyz, SUPPORT_MARGIN)
    base &= (z >= zmin - BASE_BELOW) & (z <= zmin + BASE_ABOVE)
    above = inside & (z > zmin + BASE_ABOVE)
    return bool(base.sum() >= MIN_SUPPORT and above.sum() <= max_clutter), above


class InstanceBank:
    """Thing instances of chosen classes, pasted class-balanced into scans.

    Parameters
    ----------
    instances : sequence of BankInstance
    """

    def __init__(self, instances: Sequence[BankInstance]):
        self.instances = list(instances)
        by_class: dict[int, list[int]] = {}
        for i, inst in enumerate(self.instances):
            by_class.setdefault(inst.sem, []).append(i)
        self.by_class = {c: by_class[c] for c in sorted(by_class)}

    @classmethod
    def from_dataset(
        cls,
        dataset,
        class_ids: Sequence[int],
        min_points: int = 20,
        source: str = "bank",
        progress: bool = False,
    ) -> InstanceBank:
        """Collect every instance of ``class_ids`` with at least ``min_points`` points.

        Parameters
        ----------
        dataset : LidarDataset
            Labelled scans (instance ids unique per scan over all classes).
        class_ids : sequence of int
            Train ids of thing classes.
        min_points : int
        source : str
            Named in the error raised when no instance is found.
        progress : bool
            Show a progress bar over the scans.

        Raises
        ------
        InputError
            When the dataset holds no instance of any of the classes.
        """
        wanted = np.zeros(max(list(class_ids) + [0]) + 1, dtype=bool)
        wanted[list(class_ids)] = True
        found = []
        from tqdm import tqdm

        for i in tqdm(range(len(dataset)), desc="instance bank", disable=not progress, leave=False):
            s = dataset.load(i)
            sel = (s.inst > 0) & (s.sem < len(wanted))
            sel[sel] = wanted[s.sem[sel]]
            ids, counts = np.unique(s.inst[sel], return_counts=True)
            for iid in ids[counts >= min_points]:
                m = s.inst == iid
                found.append(
                    BankInstance(
                        s.xyz[m].astype(np.float32),
                        s.remission[m].astype(np.float32),
                        int(np.bincount(s.sem[m]).argmax()),
                    )
                )
        if not found:
            raise InputError(
                f"no instance of train ids {sorted(class_ids)} with >= {min_points} points; "
                "name other classes in augment.paste_classes, lower augment.paste_min_points "
                "or use another augment.paste_bank",
                source,
            )
        return cls(found)

    def __len__(self) -> int:
        return len(self.instances)

    def counts(self) -> dict[int, int]:
        """Instances per class train id."""
        return {c: len(v) for c, v in self.by_class.items()}

    def draw(self, rng: np.random.Generator) -> BankInstance:
        """One instance: a class uniformly, then one of its instances uniformly."""
        classes = list(self.by_class)
        members = self.by_class[classes[int(rng.integers(len(classes)))]]
        return self.instances[members[int(rng.integers(len(members)))]]

    def paste(self, sample, rng: np.random.Generator, count: int, tries: int = 20):
        """``sample`` with up to ``count`` bank instances pasted (see the module docstring).

        Parameters
        ----------
        sample : LidarSample
        rng : numpy Generator
        count : int
            Instances to try to paste (each skipped when no placement fits in ``tries``).

        Returns
        -------
        LidarSample
            A new sample (the input is not modified); key of ``sample``. Teacher probabilities
            (``sample.soft``) travel with the kept points; pasted points get probability 1 on
            their class.
        """
        from panoptic_bench.dsnet.data.datasets import LidarSample

        xyz, rem, sem, inst = sample.xyz, sample.remission, sample.sem, sample.inst
        soft = sample.soft
        next_id = int(inst.max(initial=0)) + 1
        for _ in range(count):
            obj = self.draw(rng)
            # a rotation about z keeps each point's range: only scan points in the object's
            # range annulus (plus the footprint margin) can fall in its footprint
            r_obj = np.hypot(obj.xyz[:, 0], obj.xyz[:, 1])
            r_scan = np.hypot(xyz[:, 0], xyz[:, 1])
            near = np.flatnonzero(
                (r_scan >= r_obj.min() - 2 * SUPPORT_MARGIN)
                & (r_scan <= r_obj.max() + 2 * SUPPORT_MARGIN)
            )
            for _ in range(tries):
                placed = rotate_z(obj.xyz, float(rng.uniform(0.0, 2 * math.pi)))
                ok, above_near = placement_ok(xyz[near], placed)
                if ok:
                    keep = np.ones(len(xyz), dtype=bool)
                    keep[near[above_near]] = False
                    n = len(placed)
                    xyz = np.concatenate([xyz[keep], placed])
                    rem = np.concatenate([rem[keep], obj.remission])
                    sem = np.concatenate([sem[keep], np.full(n, obj.sem, dtype=sem.dtype)])
                    inst = np.concatenate([inst[keep], np.full(n, next_id, dtype=inst.dtype)])
                    if soft is not None:  # a pasted point's class is certain
                        sure = one_hot(np.full(n, obj.sem), soft.shape[1])
                        soft = np.concatenate([soft[keep], sure])
                    next_id += 1
                    break
        return LidarSample(
            xyz=xyz.astype(np.float32, copy=False),
            remission=rem.astype(np.float32, copy=False),
            sem=sem,
            inst=inst,
            key=sample.key,
            soft=soft,
        )


def open_bank(augment, train, progress: bool = False) -> InstanceBank | None:
    """The instance bank of ``augment.paste_*`` (None when pasting is off).

    The classes are named in ``augment.paste_classes`` (class names of ``train``'s class map,
    thing classes only); instances come from every sequence of the SemanticKITTI-format root
    ``augment.paste_bank``, or from the training scans when it is empty. ``progress`` shows a
    progress bar while the bank is read.

    Raises
    ------
    InputError
        An unknown or non-thing class name, an unreadable or unlabelled bank root, a bank with
        another class map, or no instance of the classes in the bank.
    """
    from panoptic_bench.dsnet.data.datasets import SemanticKittiDataset

    if augment.paste_prob <= 0:
        return None
    cmap = train.class_map
    ids = []
    for name in augment.paste_classes:
        if name not in cmap.class_names:
            raise InputError(
                f"augment.paste_classes: unknown class {name!r}; classes: "
                + ", ".join(cmap.class_names)
            )
        cid = cmap.class_names.index(name)
        if cid not in cmap.thing_ids:
            things = ", ".join(cmap.class_names[i] for i in cmap.thing_ids)
            raise InputError(
                f"augment.paste_classes: {name!r} is not a thing class; thing classes: {things}"
            )
        ids.append(cid)
    if augment.paste_bank:
        root = Path(augment.paste_bank)
        if not root.is_dir():
            raise InputError("augment.paste_bank: not a directory", root)
        try:
            source = SemanticKittiDataset(root)
        except InputError as err:
            raise InputError(f"augment.paste_bank: {err}") from None
        if len(source) == 0:
            raise InputError("augment.paste_bank: no scans under sequences/*/velodyne", root)
        if source.class_map.class_names != cmap.class_names:
            raise InputError(
                "augment.paste_bank: its class map differs from the training data's", root
            )
        name = str(root)
    else:
        source, name = train, "the training scans"
    return InstanceBank.from_dataset(
        source, ids, augment.paste_min_points, source=name, progress=progress
    )
