"""Canopy cover: the rasterised union of crown projections over the plot.

A crown's projection is the convex hull of its branch skeleton (tips widened by a leaf length),
placed with the tree's rotation and tilt. Cover is measured on a 0.25 m grid: the fraction of cell
centres inside the plot covered by at least one crown (National Forest Inventory "crown cover",
crowns taken as opaque).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull

COVER_CELL = 0.25  # m


def crown_outline(points: np.ndarray) -> np.ndarray:
    """Counter-clockwise convex hull (k, 2) of points' xy."""
    xy = np.asarray(points)[:, :2]
    hull = ConvexHull(xy)
    return xy[hull.vertices]


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
        cx = (np.arange(i0, i1) + 0.5) * self.cell
        cy = (np.arange(j0, j1) + 0.5) * self.cell
        px, py = np.meshgrid(cx, cy)
        inside = np.ones(px.shape, bool)
        nxt = np.roll(outline, -1, axis=0)
        for (ax, ay), (bx, by) in zip(outline, nxt):
            inside &= (bx - ax) * (py - ay) - (by - ay) * (px - ax) >= 0
        self.covered[j0:j1, i0:i1] |= inside

    @property
    def fraction(self) -> float:
        return float(self.covered.mean())
