"""Low sign posts along the kerbs (world key ``sign_posts``, session 41).

On the 55 real scans traffic-sign is 0.16 % of the points and sits low: the median sign point is
about 1.9 m above the road plane (3-20 m away), most of it 1-2.7 m, on posts beside the road
(plates on their own posts, stacked plates, the large boards of the highway in sequence 01).
The worlds of rows 38-53 hold signs on 0.018 % of their points, one 0.64 m plate per post with
its centre 2.5-3.1 m above the kerb. The real signs 1-2 m up are called person (they stand
where the worlds' persons are, and the worlds hold no sign there).

:func:`sign_posts` adds posts beside the kerb after the rest of the street is built, from a
stream of its own, so that every other primitive of the street stays as it was (the sensor's
per-primitive material draws are made over the whole list, so the materials of the other
primitives are drawn anew, from the same distributions). Each post is a thin pole carrying one
or two plates stacked on it, facing along the street (towards the traffic), some turned.

Plate faces (session 42): the real sign points 3-20 m away spread over the whole remission range
(median 0.39, a tenth under 0.18, 13 % above 0.8, those bright points on a few plates seen from
the front), the worlds' plates sit at 0.35-0.60. ``sign_back_reflect`` (> 0) makes each post
plate two-sided: a front half-plate of the plate's reflectivity and a back one of this
reflectivity; ``sign_bright`` is the share of post plates whose front is retro-reflective
(:data:`BRIGHT_REFLECT`). Which way a front faces and which fronts are bright come from a stream
spawned from the posts' stream, so the posts stand where they stood without the keys.
"""

from __future__ import annotations

import numpy as np

from panoptic_bench.datasets.synthetic.raw_ids import POLE, SIGN
from panoptic_bench.datasets.synthetic.shapes import BOX, CYLINDER

__all__ = ["sign_posts"]

#: Reflectivity of the plates (retro-reflective) and of their posts, before the class gains.
PLATE_REFLECT, POST_REFLECT = 0.95, 0.4
#: Plate thickness (half, m), post radius (m), gap between stacked plates (m).
PLATE_HALF_T, POST_R, STACK_GAP = 0.01, 0.035, 0.05
#: Reflectivity of a retro-reflective front (saturates the remission over most incidences).
BRIGHT_REFLECT = 2.5
#: Lateral place of a post behind the kerb line (m).
POST_SETBACK = (0.3, 0.8)


def sign_posts(b, rng: np.random.Generator, plan, x0: float, x1: float) -> int:
    """Add sign posts along both kerbs of a street.

    Parameters
    ----------
    b : street builder
        Receives the rows (``b.add(kind, center, half, label, reflect, yaw=...)``).
    rng : numpy.random.Generator
        The sign posts' own stream.
    plan : StreetPlan
        The street (kerb lines and heights, ``profile.sign_posts`` mean spacing per side in
        metres, ``profile.sign_post_z`` range of the lowest plate's centre above the kerb,
        ``profile.sign_post_half`` range of a plate's half width, ``profile.sign_back_reflect``
        reflectivity of a two-sided plate's back (0: one-sided plates), ``profile.sign_bright``
        share of plates with a retro-reflective front).
    x0, x1 : float
        Extent of the street along x (m).

    Returns
    -------
    int
        Number of posts built.
    """
    from panoptic_bench.datasets.synthetic.street import curb_at, kerb_at

    prof = plan.profile
    lo, hi = prof.sign_post_half
    faces = rng.spawn(1)[0] if prof.sign_back_reflect or prof.sign_bright else None
    n_posts = 0
    for side in (-1, 1):
        for _ in range(rng.poisson((x1 - x0) / prof.sign_posts)):
            x = float(rng.uniform(x0, x1))
            y = side * (curb_at(plan, side, x) + float(rng.uniform(*POST_SETBACK)))
            kz = kerb_at(plan, side, x)
            # facing along the street (either way), a third of them turned towards the road
            yaw = float(rng.normal(0.0, 0.15)) + (np.pi / 2 if rng.random() < 1 / 3 else 0.0)
            z = kz + float(rng.uniform(*prof.sign_post_z))
            top = z
            for k in range(1 if rng.random() < 0.6 else 2):
                hw = float(rng.uniform(lo, hi))
                hh = float(rng.uniform(lo, hw))
                if k:
                    z = top + STACK_GAP + hh
                if faces is None:
                    b.add(BOX, (x, y, z), (PLATE_HALF_T, hw, hh), SIGN, PLATE_REFLECT, yaw=yaw)
                else:
                    _plate(b, faces, prof, (x, y, z), (hw, hh), yaw)
                top = z + hh
            xp = x - np.cos(yaw) * (PLATE_HALF_T + POST_R)
            yp = y - np.sin(yaw) * (PLATE_HALF_T + POST_R)
            h = top - kz
            b.add(CYLINDER, (xp, yp, kz + h / 2), (POST_R, POST_R, h / 2), POLE, POST_REFLECT)
            n_posts += 1
    return n_posts


def _plate(b, faces: np.random.Generator, prof, center, size, yaw: float) -> None:
    """One plate with its faces: two half-thickness boxes back to back when
    ``prof.sign_back_reflect`` > 0 (the front towards +/- its normal, drawn), else one box; a
    front is retro-reflective with probability ``prof.sign_bright``."""
    front = BRIGHT_REFLECT if faces.random() < prof.sign_bright else PLATE_REFLECT
    if not prof.sign_back_reflect:
        b.add(BOX, center, (PLATE_HALF_T, *size), SIGN, front, yaw=yaw)
        return
    way = 1.0 if faces.random() < 0.5 else -1.0
    t = PLATE_HALF_T / 2
    normal = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    for side, reflect in ((way, front), (-way, prof.sign_back_reflect)):
        c = tuple(np.asarray(center, float) + side * t * normal)
        b.add(BOX, c, (t, *size), SIGN, reflect, yaw=yaw)
