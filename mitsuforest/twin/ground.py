"""The bare ground of a real scan: which points are ground, and a DEM from them (pure functions).

Ground points are the file's own (ASPRS class 2, or our ground class in our files). A file without any
gets :func:`lowest_point_filter`, a named fallback: the lowest return of each 2 m cell, kept where it lies
within 0.5 m of the median of its 5 x 5 neighbourhood of cell minima (a block-minimum filter, as in
Kraus & Pfeifer's first iteration), and every point within 0.3 m above the surface so found.
"""

from __future__ import annotations

import numpy as np
from scipy import interpolate, ndimage

LOWEST_POINT_CELL = 2.0        # m
LOWEST_POINT_TOLERANCE = 0.5   # m: a cell minimum this far above its neighbourhood's median is vegetation
GROUND_BAND = 0.3              # m above the fallback surface that still counts as ground


def grid_index(x, y, x0: float, y0: float, cell: float, shape) -> tuple[np.ndarray, np.ndarray]:
    """Row (y) and column (x) of each point in a grid of ``shape`` (ny, nx) whose SW corner is (x0, y0)."""
    col = np.clip(((np.asarray(x) - x0) / cell).astype(np.int64), 0, shape[1] - 1)
    row = np.clip(((np.asarray(y) - y0) / cell).astype(np.int64), 0, shape[0] - 1)
    return row, col


def lowest_point_filter(x, y, z) -> np.ndarray:
    """Ground points of an unclassified cloud, shape (n,) bool (see the module docstring)."""
    x0, y0 = float(np.min(x)), float(np.min(y))
    shape = (int((np.max(y) - y0) // LOWEST_POINT_CELL) + 1, int((np.max(x) - x0) // LOWEST_POINT_CELL) + 1)
    row, col = grid_index(x, y, x0, y0, LOWEST_POINT_CELL, shape)
    lowest = np.full(shape, np.inf)
    np.minimum.at(lowest, (row, col), z)
    filled = np.where(np.isfinite(lowest), lowest, np.nan)
    median = ndimage.generic_filter(filled, np.nanmedian, size=5, mode="nearest")
    good = np.isfinite(filled) & (filled <= median + LOWEST_POINT_TOLERANCE)
    surface = _filled(np.where(good, filled, np.nan))
    return z <= surface[row, col] + GROUND_BAND


def dem(x, y, z, x0: float, y0: float, shape, cell: float) -> np.ndarray:
    """Heights (ny, nx) of a grid of ``cell`` m cells with SW corner (x0, y0), row 0 south: the mean of the
    ground points in each cell, cells without any interpolated linearly between the others (nearest
    beyond their hull). ``x``, ``y``, ``z`` are ground points only."""
    row, col = grid_index(x, y, x0, y0, cell, shape)
    total, count = np.zeros(shape), np.zeros(shape)
    np.add.at(total, (row, col), z)
    np.add.at(count, (row, col), 1)
    return _filled(np.where(count > 0, total / np.maximum(count, 1), np.nan))


def _filled(grid: np.ndarray) -> np.ndarray:
    """``grid`` with its nan cells interpolated linearly from the others, nearest outside their hull."""
    holes = ~np.isfinite(grid)
    if not holes.any():
        return grid
    rows, cols = np.nonzero(~holes)
    known = np.column_stack([rows, cols]).astype(float)
    wanted = np.argwhere(holes).astype(float)
    out = grid.copy()
    if len(known) >= 3 and np.linalg.matrix_rank(known - known.mean(0)) == 2:
        out[holes] = interpolate.griddata(known, grid[~holes], wanted, method="linear")
    still = ~np.isfinite(out)
    if still.any():
        out[still] = interpolate.griddata(known, grid[~holes], np.argwhere(still).astype(float), method="nearest")
    return out


def ground_height(grid: np.ndarray, x0: float, y0: float, cell: float, x, y) -> np.ndarray:
    """The DEM's height under each point, bilinear between cell centres, shape (n,)."""
    fx = np.clip((np.asarray(x) - x0) / cell - 0.5, 0, grid.shape[1] - 1)
    fy = np.clip((np.asarray(y) - y0) / cell - 0.5, 0, grid.shape[0] - 1)
    return ndimage.map_coordinates(grid, [fy, fx], order=1, mode="nearest")
