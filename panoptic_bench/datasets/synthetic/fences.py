"""Fences of a green or fence frontage: a solid panel or a see-through lattice.

Real SemanticKITTI fences are not all tall solid walls. By the ``synth stats`` rows of
:mod:`realism` the fence points of the 55 real training scans sit a median 0.54 m above the road
plane (in five of the ten sequences 90 % of them are below 1.1 m: guard rails and low walls), and
8.9 % of them have a ring neighbour more than 1 m farther away (the laser passes through a
lattice or mesh to what stands behind). The first synthetic fences were solid panels 1-2 m tall
(0.90 m, 0.3 %). :func:`build_fence` builds
either kind; the panel height range is ``WorldProfile.fence_height`` and the share of lattices
``WorldProfile.fence_lattice``, drawn from a stream of its own so that a world without
lattices is unchanged. :func:`build_guard_rail` builds the steel guard rails of real highway
verges (world key ``guard_rail``): on the highway of real sequence 01 most of the fence points
that the synthetic-only models call bicycle are such beams, 0.2-0.55 m above the road.
"""

from __future__ import annotations

import numpy as np

from panoptic_bench.datasets.synthetic.raw_ids import FENCE
from panoptic_bench.datasets.synthetic.shapes import BOX

__all__ = ["POST_SPACING", "RAIL_BEAM", "build_fence", "build_guard_rail"]

#: Thickness of a solid panel (m).
_PANEL = 0.06
#: Spacing range of a lattice's posts (m).
POST_SPACING = (2.0, 3.0)
#: Height of a guard rail's beam (m) and the range of its lower edge above the ground (m).
RAIL_BEAM = 0.3
_RAIL_BOTTOM = (0.3, 0.5)
#: Spacing range of a guard rail's posts (m).
_RAIL_POSTS = (2.0, 4.0)


def build_fence(
    b,
    x0: float,
    x1: float,
    y: float,
    side: int,
    height: float,
    reflect: float,
    lattice_rng: np.random.Generator | None = None,
    lattice_prob: float = 0.0,
) -> None:
    """Add one fence along ``[x0, x1]`` at lateral position ``y`` to the builder ``b``.

    Parameters
    ----------
    b : street._Builder
        Receives the primitive rows.
    x0, x1 : float
        Extent along the street (m).
    y : float
        Lateral position of the fence's street-side face (m); it extends away from the street.
    side : int
        -1 (right) or +1 (left).
    height : float
        Height of the fence's top above the ground (m).
    reflect : float
        Base reflectivity of its material.
    lattice_rng : numpy.random.Generator, optional
        Stream of the lattice draws (required when ``lattice_prob`` > 0).
    lattice_prob : float
        Probability that the fence is a lattice: posts every 2-3 m, a top rail, and vertical bars
        0.02-0.04 m wide every 0.12-0.3 m, so that most rays pass between the bars.
    """
    if not (lattice_prob and lattice_rng.random() < lattice_prob):
        b.box(x0, x1, y, y + side * _PANEL, 0.0, height, FENCE, reflect)
        return
    rng = lattice_rng
    ys = sorted((y, y + side * 0.04))
    yc, hy = (ys[0] + ys[1]) / 2, (ys[1] - ys[0]) / 2
    bar_w = float(rng.uniform(0.02, 0.04))
    spacing = float(rng.uniform(0.12, 0.3))
    post = float(rng.uniform(*POST_SPACING))
    rail = min(0.05, height / 4)
    b.box(x0, x1, y, y + side * 0.05, height - rail, height, FENCE, reflect)
    for xp in np.arange(x0, x1 + 1e-9, post):
        b.add(BOX, (xp, yc, height / 2), (0.04, 0.04, height / 2), FENCE, reflect)
    half = (height - rail) / 2
    for xb in np.arange(x0 + spacing / 2, x1, spacing):
        b.add(BOX, (xb, yc, half), (bar_w / 2, hy, half), FENCE, reflect)


def build_guard_rail(
    b, x0: float, x1: float, y: float, side: int, base: float, rng: np.random.Generator
) -> None:
    """Add a guard rail along ``[x0, x1]`` whose road-side face is at lateral position ``y``.

    A steel beam ``RAIL_BEAM`` tall and 0.08 m deep with its lower edge 0.3-0.5 m above
    ``base`` (the top of the verge it stands on), on posts 0.1 m square every 2-4 m that reach
    the beam's top; labelled fence (SemanticKITTI maps guard rails to fence), reflectivity
    0.25-0.45 (galvanised steel seen by the real scans: medians 0.3-0.4).

    Parameters
    ----------
    b : street._Builder
    x0, x1 : float
        Extent along the street (m).
    y : float
        Lateral position of the beam's road-side face (m); the rail extends away from the road.
    side : int
        -1 (right) or +1 (left).
    base : float
        Height of the ground the posts stand on (m).
    rng : numpy.random.Generator
        The guard rails' own stream.
    """
    bottom = base + float(rng.uniform(*_RAIL_BOTTOM))
    top = bottom + RAIL_BEAM
    reflect = float(rng.uniform(0.25, 0.45))
    b.box(x0, x1, y, y + side * 0.08, bottom, top, FENCE, reflect)
    yc = y + side * 0.13
    spacing = float(rng.uniform(*_RAIL_POSTS))
    for xp in np.arange(x0 + spacing / 2, x1, spacing):
        b.add(BOX, (xp, yc, (base + top) / 2), (0.05, 0.05, (top - base) / 2), FENCE, reflect)
