"""Ground of the synthetic world: a label/reflectivity raster over the plane ``z = 0``.

The flat ground (road, parking, terrain, other-ground) is one plane; which class a ground
return belongs to, and how bright it is (lane markings are bright), is looked up in a raster
painted with axis-aligned rectangles. Raised ground (sidewalks, kerbs) is made of boxes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["GroundMap"]


@dataclass
class GroundMap:
    """Raster of raw SemanticKITTI ids and reflectivities over a rectangle of the ground.

    Attributes
    ----------
    origin : tuple of float
        World ``(x, y)`` of the raster's lower-left corner, metres.
    cell : float
        Cell size, metres.
    label : ndarray of shape (nx, ny), uint16
        Raw id per cell.
    reflect : ndarray of shape (nx, ny), float32
        Base reflectivity per cell.
    default_label : int
        Id of the ground outside the raster (terrain).
    """

    origin: tuple[float, float]
    cell: float
    label: np.ndarray
    reflect: np.ndarray
    default_label: int = 72
    default_reflect: float = 0.45

    @classmethod
    def blank(
        cls, x_range: tuple[float, float], y_range: tuple[float, float], cell: float = 0.2
    ) -> GroundMap:
        """A raster covering ``x_range`` x ``y_range`` filled with the default terrain."""
        nx = int(np.ceil((x_range[1] - x_range[0]) / cell))
        ny = int(np.ceil((y_range[1] - y_range[0]) / cell))
        gm = cls(
            (x_range[0], y_range[0]),
            cell,
            np.zeros((nx, ny), np.uint16),
            np.zeros((nx, ny), np.float32),
        )
        gm.label[:] = gm.default_label
        gm.reflect[:] = gm.default_reflect
        return gm

    def _index(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        i = np.floor((np.asarray(x) - self.origin[0]) / self.cell).astype(np.int64)
        j = np.floor((np.asarray(y) - self.origin[1]) / self.cell).astype(np.int64)
        return i, j

    def paint(
        self,
        x0: float,
        x1: float,
        y0: float,
        y1: float,
        label: int | None = None,
        reflect: float | None = None,
    ) -> None:
        """Set the label and/or reflectivity of the rectangle ``[x0, x1) x [y0, y1)``."""
        win = self._window(x0, x1, y0, y1)
        if win is None:
            return
        if label is not None:
            self.label[win] = label
        if reflect is not None:
            self.reflect[win] = reflect

    def add_noise(
        self, x0: float, x1: float, y0: float, y1: float, rng: np.random.Generator, std: float
    ) -> None:
        """Add iid ``N(0, std)`` to the reflectivity of the cells of ``[x0, x1) x [y0, y1)``."""
        win = self._window(x0, x1, y0, y1)
        if win is not None:
            cells = self.reflect[win]
            cells += rng.normal(0.0, std, size=cells.shape).astype(np.float32)

    def _window(self, x0: float, x1: float, y0: float, y1: float) -> tuple[slice, slice] | None:
        (i0, i1), (j0, j1) = self._index(np.array([x0, x1]), np.array([y0, y1]))
        nx, ny = self.label.shape
        i0, i1 = max(int(i0), 0), min(int(i1), nx)
        j0, j1 = max(int(j0), 0), min(int(j1), ny)
        return None if i0 >= i1 or j0 >= j1 else (slice(i0, i1), slice(j0, j1))

    def lookup(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Raw id and reflectivity of ground points.

        Parameters
        ----------
        x, y : ndarray of shape (N,), float
            World coordinates.

        Returns
        -------
        label : ndarray of shape (N,), uint16
        reflect : ndarray of shape (N,), float32
        """
        i, j = self._index(x, y)
        nx, ny = self.label.shape
        ok = (i >= 0) & (i < nx) & (j >= 0) & (j < ny)
        label = np.full(i.shape, self.default_label, np.uint16)
        reflect = np.full(i.shape, self.default_reflect, np.float32)
        label[ok] = self.label[i[ok], j[ok]]
        reflect[ok] = self.reflect[i[ok], j[ok]]
        return label, reflect
