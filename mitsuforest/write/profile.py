"""Counts behind the charts and the realism table, accumulated batch by batch: returns by height above
the ground and class, first returns by class, and points by return number and class."""

from __future__ import annotations

import numpy as np

BIN_M = 0.5            # height bin of the vertical profile
LOWEST_M = -2.0        # the profile's range: 2 m below the ground (noise, hollows) ...
BINS = 200             # ... to 98 m above it; points outside are counted in the end bins
MAX_RETURN = 16        # return numbers from 16 on share the last row


class GroundHeight:
    """The terrain's height at any point, bilinear on a regular grid of about 1 m, by arithmetic alone
    (``np.interp`` on every point would cost more than the rest of a batch's statistics)."""

    def __init__(self, terrain, area, cell: float = 1.0):
        w, h = area
        self.nx, self.ny = (max(int(np.ceil(s / cell)), 1) + 1 for s in (w, h))
        self.dx, self.dy = w / (self.nx - 1), h / (self.ny - 1)
        z = None if terrain is None else _grid_heights(terrain, np.linspace(0, w, self.nx), np.linspace(0, h, self.ny))
        self.z = z if z is not None and np.any(z) else None     # None: flat at 0

    def __call__(self, x, y) -> np.ndarray:
        if self.z is None:
            return np.zeros(len(x))
        fx = np.clip(np.asarray(x, np.float64) / self.dx, 0, self.nx - 1.000001)
        fy = np.clip(np.asarray(y, np.float64) / self.dy, 0, self.ny - 1.000001)
        i, j = fx.astype(np.int64), fy.astype(np.int64)
        u, v = fx - i, fy - j
        z = self.z
        return ((1 - v) * ((1 - u) * z[j, i] + u * z[j, i + 1]) + v * ((1 - u) * z[j + 1, i] + u * z[j + 1, i + 1]))


def _nonzero(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The flat indices of the non-zero cells of ``counts`` and the counts there."""
    cells = np.flatnonzero(counts)
    return cells, counts[cells]


def _grid_heights(terrain, x, y) -> np.ndarray:
    """(ny, nx) ground heights at the grid points: from the terrain's height field, or, for a ground
    that is only a mesh (a HELIOS++ scene's), from its triangles (their mean height where none is)."""
    if hasattr(terrain, "height"):
        return terrain.height(*np.meshgrid(x, y))
    from ..plan.terrain import heights_under
    vertices, faces = terrain.mesh()
    z = heights_under(np.asarray(vertices, np.float64)[np.asarray(faces)], x, y)
    return np.where(np.isnan(z), terrain.mean_height, z)


class ReturnCounts:
    """Per-batch counts of a render's points (see module docstring)."""

    def __init__(self, terrain=None, area=(1.0, 1.0)):
        self.ground = GroundHeight(terrain, area)
        self.by_height = np.zeros((BINS, 256), np.int64)         # [height bin, class]
        self.by_return = np.zeros((MAX_RETURN + 1, 256), np.int64)   # [return number, class]

    def add(self, points) -> None:
        self.merge(self.tally(points))

    def tally(self, points) -> tuple | None:
        """The counts of ``points`` alone, for :meth:`merge` (parts of a batch can be tallied side by side,
        in threads or processes): those by height and by return as the flat indices of their non-zero cells
        of :attr:`by_height` and :attr:`by_return` and the counts there, a few kB; None for no points."""
        if len(points) == 0:
            return None
        cls = points["classification"].astype(np.int64)
        height = points["z"] - self.ground(points["x"], points["y"])
        row = np.clip(((height - LOWEST_M) / BIN_M).astype(np.int64), 0, BINS - 1)
        by_height = np.bincount(row * 256 + cls, minlength=BINS * 256)
        rn = np.minimum(points["return_number"].astype(np.int64), MAX_RETURN)
        by_return = np.bincount(rn * 256 + cls, minlength=(MAX_RETURN + 1) * 256)
        return _nonzero(by_height), _nonzero(by_return)

    def merge(self, tally) -> None:
        if tally is not None:
            for total, (cells, counts) in zip((self.by_height, self.by_return), tally):
                total.flat[cells] += counts

    @property
    def first(self) -> np.ndarray:
        """(256,) first returns by class."""
        return self.by_return[1]

    @property
    def bin_edges(self) -> np.ndarray:
        """(BINS + 1,) heights above the ground (m) of the profile's bin edges."""
        return LOWEST_M + BIN_M * np.arange(BINS + 1)
