"""Training augmentation of one scan (DS-Net / Cylinder3D defaults), deterministic per generator.

In order: rotation about z by U[0, 360) degrees; flip of x, y, both or none (uniform over the
four); scaling of x and y by U[0.95, 1.05]; translation by N(0, 0.1 m) per axis.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch

Generator = np.random.Generator | torch.Generator


def _uniform(gen: Generator, lo: float, hi: float) -> float:
    if isinstance(gen, torch.Generator):
        return lo + (hi - lo) * float(torch.rand((), generator=gen, dtype=torch.float64))
    return float(gen.uniform(lo, hi))


def _normal(gen: Generator, std: float) -> float:
    if isinstance(gen, torch.Generator):
        return std * float(torch.randn((), generator=gen, dtype=torch.float64))
    return float(gen.normal(0.0, std))


def _choice4(gen: Generator) -> int:
    if isinstance(gen, torch.Generator):
        return int(torch.randint(4, (), generator=gen))
    return int(gen.integers(4))


def augmentation_matrix(
    generator: Generator,
    rotate: bool = True,
    flip: bool = True,
    scale_range: tuple[float, float] = (0.95, 1.05),
    translate_std: tuple[float, float, float] = (0.1, 0.1, 0.1),
) -> tuple[np.ndarray, np.ndarray]:
    """Draw one augmentation: ``xyz' = xyz @ A.T + t``.

    Returns
    -------
    A : numpy.ndarray
        Array of shape (3, 3), float64 (acts on x, y only).
    t : numpy.ndarray
        Array of shape (3,), float64.
    """
    a = np.eye(3)
    if rotate:
        angle = _uniform(generator, 0.0, 2 * math.pi)
        c, s = math.cos(angle), math.sin(angle)
        a = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ a
    if flip:
        kind = _choice4(generator)
        f = np.diag([-1.0 if kind in (1, 3) else 1.0, -1.0 if kind in (2, 3) else 1.0, 1.0])
        a = f @ a
    lo, hi = scale_range
    if (lo, hi) != (1.0, 1.0):
        k = _uniform(generator, lo, hi)
        a = np.diag([k, k, 1.0]) @ a
    t = np.array([_normal(generator, sd) if sd > 0 else 0.0 for sd in translate_std])
    return a, t


def augment_points(
    xyz: torch.Tensor | np.ndarray,
    generator: Generator,
    rotate: bool = True,
    flip: bool = True,
    scale_range: tuple[float, float] = (0.95, 1.05),
    translate_std: tuple[float, float, float] = (0.1, 0.1, 0.1),
) -> torch.Tensor | np.ndarray:
    """Augment the coordinates of one scan; same type, shape (n, 3), dtype and device.

    The same generator state gives the same result (numpy or torch generator). Instance
    centres must be computed *after* augmentation (they move with the points).
    """
    a, t = augmentation_matrix(generator, rotate, flip, scale_range, translate_std)
    if isinstance(xyz, torch.Tensor):
        at = torch.as_tensor(a, dtype=xyz.dtype, device=xyz.device)
        return xyz @ at.T + torch.as_tensor(t, dtype=xyz.dtype, device=xyz.device)
    return (xyz @ a.T + t).astype(xyz.dtype, copy=False)


def augment_remission(
    remission: np.ndarray,
    rng: np.random.Generator,
    gain: tuple[float, float] = (1.0, 1.0),
    gamma: tuple[float, float] = (1.0, 1.0),
    zero_prob: float = 0.0,
) -> np.ndarray:
    """Remission augmentation: ``clip(gain * r ** gamma, 0, 1)``, then random zeroing.

    ``gain`` ~ U[gain], ``gamma`` ~ U[gamma] per scan; each point is set to exactly 0 with
    probability ``zero_prob`` (real sensors record dark, far and grazing returns as 0).
    Draws nothing for an identity setting, so disabled augmentation leaves the stream unchanged.

    Parameters
    ----------
    remission : ndarray of shape (n,), float32
    rng : numpy.random.Generator

    Returns
    -------
    ndarray of shape (n,), float32
    """
    out = remission.astype(np.float32, copy=True)
    if tuple(gamma) != (1.0, 1.0):
        out = np.power(np.clip(out, 0.0, None), rng.uniform(*gamma)).astype(np.float32)
    if tuple(gain) != (1.0, 1.0):
        out = np.clip(out * rng.uniform(*gain), 0.0, 1.0).astype(np.float32)
    if zero_prob > 0:
        out[rng.random(out.size) < zero_prob] = 0.0
    return out


def class_ids(class_names: Sequence[str], names: Sequence[str], key: str) -> np.ndarray | None:
    """Train ids of the classes ``names`` among ``class_names``; ``None`` when ``names`` is empty.

    Raises :class:`~panoptic_bench.errors.InputError` naming ``key`` for an unknown name.
    """
    from panoptic_bench.errors import InputError

    if not names:
        return None
    for name in names:
        if name not in class_names:
            raise InputError(f"{key}: unknown class {name!r}; classes: " + ", ".join(class_names))
    return np.asarray([list(class_names).index(n) for n in names], dtype=np.int64)


def class_remission_gain(
    remission: np.ndarray,
    sem: np.ndarray,
    rng: np.random.Generator,
    gain: tuple[float, float] = (1.0, 1.0),
    only: np.ndarray | None = None,
) -> np.ndarray:
    """Per-class remission gain: every semantic class of a scan gets its own factor.

    For each train id present in ``sem`` (in ascending order) one gain is drawn log-uniformly
    from ``[gain[0], gain[1]]``; its points become ``clip(gain * r, 0, 1)``. This randomises how
    bright the materials of a world are relative to each other (road against sidewalk, fence
    against vegetation), so that a network cannot learn one world's material contrasts as a
    class cue. Draws nothing for ``(1, 1)``. With ``only``, the factors are drawn exactly as
    without it and then applied to the listed classes alone (every other point keeps its value).

    Parameters
    ----------
    remission : ndarray of shape (n,), float32
    sem : ndarray of shape (n,), integer
        Train ids of the points (0 = unlabelled is a class of its own here).
    rng : numpy.random.Generator
    gain : (float, float)
        ``0 < lo <= hi``.
    only : ndarray of int, optional
        Train ids whose points get their factor; ``None``: every class.

    Returns
    -------
    ndarray of shape (n,), float32
    """
    out = remission.astype(np.float32, copy=True)
    if tuple(gain) == (1.0, 1.0):
        return out
    classes, inverse = np.unique(sem, return_inverse=True)
    factors = np.exp(rng.uniform(math.log(gain[0]), math.log(gain[1]), size=classes.size))
    if only is not None:
        factors[~np.isin(classes, only)] = 1.0
    return np.clip(out * factors.astype(np.float32)[inverse.reshape(-1)], 0.0, 1.0).astype(
        np.float32
    )


def tilt_points(
    xyz: np.ndarray, rng: np.random.Generator, pitch_std_deg: float = 0.0, roll_std_deg: float = 0.0
) -> np.ndarray:
    """Pose augmentation: rotate a scan by a random pitch (about y) and roll (about x).

    Angles ~ N(0, std) degrees; draws nothing when both stds are 0.

    Parameters
    ----------
    xyz : ndarray of shape (n, 3), float32

    Returns
    -------
    ndarray of shape (n, 3), same dtype
    """
    if pitch_std_deg <= 0 and roll_std_deg <= 0:
        return xyz
    p = math.radians(rng.normal(0.0, pitch_std_deg)) if pitch_std_deg > 0 else 0.0
    r = math.radians(rng.normal(0.0, roll_std_deg)) if roll_std_deg > 0 else 0.0
    ry = np.array(
        [[math.cos(p), 0.0, math.sin(p)], [0.0, 1.0, 0.0], [-math.sin(p), 0.0, math.cos(p)]]
    )
    rx = np.array(
        [[1.0, 0.0, 0.0], [0.0, math.cos(r), -math.sin(r)], [0.0, math.sin(r), math.cos(r)]]
    )
    return (xyz @ (ry @ rx).T).astype(xyz.dtype, copy=False)
