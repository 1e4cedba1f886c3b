"""Understory of a real scan: how many bushes its low returns call for (pure functions).

Returns between ``LOW`` and ``HIGH`` m above the ground are shrubs (or low branches and stems). A
``CELL`` m cell is shrubby when it holds at least ``SHARE`` of the returns of the median cell that has
any, and the bush count is the shrubby area over the area of a mean bush crown (1.8 m across, the
middle of our shrub forms' 0.6-3.0 m). The scene format places bushes at random, clear of stems: the
twin keeps how much understory there is, not where.
"""

from __future__ import annotations

import numpy as np

from .ground import grid_index

LOW, HIGH = 0.5, 3.0      # m above ground
CELL = 1.0                # m
SHARE = 0.25
BUSH_CROWN = 1.8          # m across


def shrub_cells(x, y, h, x0: float, y0: float, shape) -> np.ndarray:
    """Shrubby cells (ny, nx) bool of a ``CELL`` m grid with SW corner (x0, y0)."""
    row, col = grid_index(x, y, x0, y0, CELL, shape)
    band = (h >= LOW) & (h <= HIGH)
    low = np.zeros(shape)
    np.add.at(low, (row[band], col[band]), 1)
    every = np.zeros(shape)
    np.add.at(every, (row, col), 1)
    typical = np.median(every[every > 0]) if (every > 0).any() else 0.0
    return low >= max(SHARE * typical, 1.0)


def bush_count(cells: np.ndarray) -> int:
    """Bushes whose mean crowns cover the shrubby cells."""
    return int(round(cells.sum() * CELL ** 2 / (np.pi * (BUSH_CROWN / 2) ** 2)))
