"""Square tiles of a plot's points, for learning.

The plot's local frame (SW corner at the origin) is cut into an ``nx × ny`` grid of ``size`` m
squares starting at the origin; the last column and row end at the plot's edge. Tile ``(i, j)``'s
*core* is ``[x0, x1) × [y0, y1)``; the edge tiles' cores reach out without bound, so that points
beyond the plot (overshoot on the ground) belong to the nearest tile. Every point is in exactly one
core. A tile's file holds its core plus a ``buffer`` m band around it (the same points are then also
in the neighbours' files): its extent is ``[x0 - buffer, x1 + buffer) × [y0 - buffer, y1 + buffer)``,
unbounded on the plot's outer sides like the core.

Pure functions of numpy arrays; the files are written by :mod:`.files`.
"""

from __future__ import annotations

import numpy as np


def tile_grid(area_size, size: float) -> tuple[int, int]:
    """``(nx, ny)``: tiles across x and y of a plot of ``area_size`` (m)."""
    return tuple(max(1, int(np.ceil(s / size - 1e-9))) for s in area_size)


def core_tile(x: np.ndarray, y: np.ndarray, area_size, size: float) -> tuple[np.ndarray, np.ndarray]:
    """``(i, j)``, (n,) int arrays: the tile whose core holds each point (local frame)."""
    nx, ny = tile_grid(area_size, size)
    i = np.clip(np.floor(np.asarray(x, np.float64) / size), 0, nx - 1).astype(np.int64)
    j = np.clip(np.floor(np.asarray(y, np.float64) / size), 0, ny - 1).astype(np.int64)
    return i, j


def core_bounds(i: int, j: int, area_size, size: float) -> tuple[float, float, float, float]:
    """``(x0, y0, x1, y1)``: tile ``(i, j)``'s core inside the plot (the edge tiles reach further, see
    the module docstring)."""
    w, h = area_size
    return i * size, j * size, min((i + 1) * size, w), min((j + 1) * size, h)


def tile_extent(i: int, j: int, area_size, size: float, buffer: float) -> tuple[float, float, float, float]:
    """``(x0, y0, x1, y1)``: the tile's file extent, core plus ``buffer``, ±inf on the plot's outer sides."""
    nx, ny = tile_grid(area_size, size)
    x0, y0, x1, y1 = core_bounds(i, j, area_size, size)
    return (-np.inf if i == 0 else x0 - buffer, -np.inf if j == 0 else y0 - buffer,
            np.inf if i == nx - 1 else x1 + buffer, np.inf if j == ny - 1 else y1 + buffer)


def in_extent(x: np.ndarray, y: np.ndarray, extent) -> np.ndarray:
    """(n,) bool: points inside a half-open extent ``(x0, y0, x1, y1)``."""
    x0, y0, x1, y1 = extent
    return (x >= x0) & (x < x1) & (y >= y0) & (y < y1)


def instance_boxes(instance: np.ndarray, x: np.ndarray, y: np.ndarray, instances: np.ndarray) -> np.ndarray:
    """(len(instances), 4) rows ``xmin, ymin, xmax, ymax`` of each listed instance's points (NaN when it
    has none)."""
    out = np.full((len(instances), 4), np.nan)
    order = np.argsort(instance, kind="stable")
    sorted_ids = instance[order]
    for row, inst in enumerate(instances):
        lo, hi = np.searchsorted(sorted_ids, [inst, inst + 1])
        if hi > lo:
            sel = order[lo:hi]
            out[row] = x[sel].min(), y[sel].min(), x[sel].max(), y[sel].max()
    return out


def box_inside(box, extent) -> bool:
    """Whether a point box ``(xmin, ymin, xmax, ymax)`` lies inside a half-open extent."""
    x0, y0, x1, y1 = extent
    return bool(box[0] >= x0 and box[1] >= y0 and box[2] < x1 and box[3] < y1)
