"""Canopy cover: the rasterised union of crown projections over the plot.

A crown's projection is the convex hull of its branch skeleton (tips widened by a leaf length),
placed with the tree's rotation and tilt. Cover is measured on a 0.25 m grid: the fraction of cell
centres inside the plot covered by at least one crown (National Forest Inventory "crown cover",
crowns taken as opaque).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from .transforms import apply

COVER_CELL = 0.25  # m


def crown_outline(points: np.ndarray) -> np.ndarray:
    """Counter-clockwise convex hull (k, 2) of points' xy."""
    xy = np.asarray(points)[:, :2]
    hull = ConvexHull(xy)
    return xy[hull.vertices]


class PlacedOutlines:
    """The outlines of crowns placed again and again: each crown's (k, 3) points reduced, on its first
    placement, to those that can be a corner of the outline of any placement of it (the vertices of its
    convex hull and the points qhull finds on its facets; the hull of a projection is the projection of
    the hull). A crown of 2,000-4,000 points keeps about 40: a quarter of the time a tree, the same outline.

    :param crowns: the crowns' (n_i, 3) points, model frame.
    """

    def __init__(self, crowns):
        self._crowns = crowns
        self._rows = {}

    def outline(self, k: int, matrix: np.ndarray) -> np.ndarray:
        """:func:`crown_outline` of crown ``k`` placed by the 4×4 ``matrix``."""
        if k not in self._rows:
            self._rows[k] = hull_rows(self._crowns[k])
        # Every point is placed and the rows taken after: the numbers of placing them all (a matrix
        # product of fewer rows may round otherwise).
        return crown_outline(apply(matrix, self._crowns[k])[self._rows[k]])


def hull_rows(points: np.ndarray) -> np.ndarray | slice:
    """Sorted rows of the (n, 3) ``points`` that are vertices of their convex hull or lie on its facets
    (within qhull's tolerance); all rows (a slice) when the points span no volume."""
    try:
        hull = ConvexHull(points)
    except (QhullError, ValueError):
        return slice(None)
    return np.union1d(hull.vertices, hull.coplanar[:, 0])


class CoverGrid:
    """A boolean raster over the plot to which crown outlines are added one at a time."""

    def __init__(self, size, cell: float = COVER_CELL):
        self.cell = cell
        self.nx, self.ny = int(round(size[0] / cell)), int(round(size[1] / cell))
        self.covered = np.zeros((self.ny, self.nx), bool)

    def add(self, outline: np.ndarray) -> None:
        """Mark the cells whose centres lie inside a convex, counter-clockwise outline."""
        lo = np.floor(outline.min(0) / self.cell).astype(int)
        hi = np.ceil(outline.max(0) / self.cell).astype(int)
        i0, i1 = max(lo[0], 0), min(hi[0], self.nx)
        j0, j1 = max(lo[1], 0), min(hi[1], self.ny)
        if i0 >= i1 or j0 >= j1:
            return
        px = (np.arange(i0, i1) + 0.5) * self.cell          # a row of the cells' centres
        py = ((np.arange(j0, j1) + 0.5) * self.cell)[:, None]   # a column
        inside = np.ones((j1 - j0, i1 - i0), bool)
        for (ax, ay), (bx, by) in zip(outline.tolist(), np.roll(outline, -1, axis=0).tolist()):
            # Each factor on a row or a column, then broadcast: the same numbers as on the whole grid.
            inside &= (bx - ax) * (py - ay) - (by - ay) * (px - ax) >= 0
        self.covered[j0:j1, i0:i1] |= inside

    @property
    def fraction(self) -> float:
        return float(self.covered.mean())
