"""Square tiles of a plot's points, for learning.

The plot's local frame (SW corner at the origin) is cut into an ``nx × ny`` grid of ``size`` m
squares starting at the origin; the last column and row end at the plot's edge. Tile ``(i, j)``'s
*core* is ``[x0, x1) × [y0, y1)``; the edge tiles' cores reach out without bound, so that points
beyond the plot (overshoot on the ground) belong to the nearest tile. Every point is in exactly one
core. A tile's file holds its core plus a ``buffer`` m band around it (the same points are then also
in the neighbours' files): its extent is ``[x0 - buffer, x1 + buffer) × [y0 - buffer, y1 + buffer)``,
unbounded on the plot's outer sides like the core.

:func:`tile_members` lists, for points batch by batch, the tiles whose files hold them: a plot split
by flight legs has each leg task sort its points into tiles that way, so that no process holds the
whole plot (:mod:`.tasks`).

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
    return _axis_core(x, nx, size), _axis_core(y, ny, size)


def _axis_core(v: np.ndarray, n: int, size: float) -> np.ndarray:
    """The core number along one axis of each value: how many of the inner core edges ``k * size``
    (k = 1 .. n-1, the float64 values of :func:`core_bounds` and the extents) lie at or below it. Not
    ``floor(v / size)``, whose rounding differs from ``k * size``'s for a decimal size (16.5 / 1.1 is
    14.999..., while 15 * 1.1 is 16.5): a point on such an edge would have a core whose bounds and file
    do not hold it."""
    return np.searchsorted(np.arange(1, n) * size, np.asarray(v, np.float64), side="right").astype(np.int64)


def core_bounds(i: int, j: int, area_size, size: float) -> tuple[float, float, float, float]:
    """``(x0, y0, x1, y1)``: tile ``(i, j)``'s core inside the plot (the edge tiles reach further, see
    the module docstring)."""
    w, h = area_size
    return i * size, j * size, min((i + 1) * size, w), min((j + 1) * size, h)


def tile_extent(i: int, j: int, area_size, size: float, buffer: float) -> tuple[float, float, float, float]:
    """``(x0, y0, x1, y1)``: the tile's file extent, core plus ``buffer``, ±inf on the plot's outer sides."""
    return tuple(float(v) for v in tile_extents(np.array(i), np.array(j), area_size, size, buffer))


def tile_extents(i: np.ndarray, j: np.ndarray, area_size, size: float, buffer: float) -> tuple[np.ndarray, ...]:
    """``(x0, y0, x1, y1)``, each shaped like ``i`` and ``j`` (int arrays): :func:`tile_extent` of many
    tiles at once, the same float64 values."""
    nx, ny = tile_grid(area_size, size)
    (x0, x1), (y0, y1) = (_axis_extent(i, nx, area_size[0], size, buffer),
                          _axis_extent(j, ny, area_size[1], size, buffer))
    return x0, y0, x1, y1


def _axis_extent(k: np.ndarray, n: int, length: float, size: float, buffer: float) -> tuple[np.ndarray, np.ndarray]:
    """``(low, high)`` of the file extents of tiles number ``k`` (of ``n``) along one axis of ``length`` m."""
    return (np.where(k == 0, -np.inf, k * size - buffer),
            np.where(k == n - 1, np.inf, np.minimum((k + 1) * size, length) + buffer))


def tile_members(x: np.ndarray, y: np.ndarray, area_size, size: float, buffer: float) -> tuple[np.ndarray, np.ndarray]:
    """Every (point, tile) pair of a point inside a tile's file extent (:func:`in_extent` of
    :func:`tile_extent`, the test :func:`~.files.write_tiles` makes), ordered by tile then point.

    An extent is a product of one range in x and one in y, so each point is tested against the
    columns and the rows around its core tile's, one axis at a time.

    :param x, y: (n,) local frame.
    :returns: ``(tile, row)``, (m,) int64 each: the tile's flat number ``i * ny + j`` and the point's
        row; m ≥ n less the points in no extent (none unless rounding puts one on a core's edge).
    """
    if len(x) == 0:              # a leg's batch that met nothing
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    nx, ny = tile_grid(area_size, size)
    ci, cj = core_tile(x, y, area_size, size)
    reach = int(np.ceil(buffer / size)) + 1       # tiles a point's extent test can pass, and one for rounding
    columns = _axis_members(x, ci, nx, area_size[0], size, buffer, reach)
    rows = _axis_members(y, cj, ny, area_size[1], size, buffer, reach)
    tiles, members = [], []
    for i, in_column in columns:
        for j, in_row in rows:
            both = np.flatnonzero(in_column & in_row)
            tiles.append(i[both] * ny + j[both])
            members.append(both)
    tile, row = np.concatenate(tiles), np.concatenate(members)
    order = np.argsort(tile * len(x) + row)      # by tile, then row (one key: faster than a lexsort)
    return tile[order], row[order]


def _axis_members(v: np.ndarray, core: np.ndarray, n: int, length: float, size: float, buffer: float,
                  reach: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """For each shift ``d`` in ``-reach .. reach``: the tile numbers ``core + d`` along one axis, and
    whether each point lies in that tile's extent along it (False where there is no such tile)."""
    low, high = _axis_extent(np.arange(n), n, length, size, buffer)
    out = []
    for d in range(-reach, reach + 1):
        k = core + d
        at = np.clip(k, 0, n - 1)
        inside = (k == at) & (v >= low[at]) & (v < high[at])
        if inside.any():
            out.append((k, inside))
    return out


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
    instances = np.asarray(instances, np.int64)
    lo, hi = np.searchsorted(sorted_ids, instances), np.searchsorted(sorted_ids, instances + 1)
    has = hi > lo
    if has.any():
        # reduceat over [lo, hi) of each: the even results of the interleaved bounds (one value past the end)
        bounds = np.column_stack([lo[has], hi[has]]).ravel()
        for column, (values, reduce) in enumerate([(x, np.minimum), (y, np.minimum), (x, np.maximum),
                                                   (y, np.maximum)]):
            padded = np.append(values[order], 0.0)
            out[has, column] = reduce.reduceat(padded, bounds)[::2]
    return out


def combine_boxes(ids: np.ndarray, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Boxes of the same instances from several sets of points (:func:`instance_boxes` of each) as the
    boxes of all the points: ``(unique ids, (k, 4) boxes)``, each the smallest box holding that id's
    boxes (NaN where all of them are)."""
    ids = np.asarray(ids, np.int64)
    boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
    order = np.argsort(ids, kind="stable")
    ids, boxes = ids[order], boxes[order]
    unique, starts = np.unique(ids, return_index=True)
    if not len(unique):
        return unique, np.zeros((0, 4))
    low = np.fmin.reduceat(boxes[:, :2], starts, axis=0)
    high = np.fmax.reduceat(boxes[:, 2:], starts, axis=0)
    return unique, np.hstack([low, high])


def box_inside(box, extent) -> bool:
    """Whether a point box ``(xmin, ymin, xmax, ymax)`` lies inside a half-open extent."""
    x0, y0, x1, y1 = extent
    return bool(box[0] >= x0 and box[1] >= y0 and box[2] < x1 and box[3] < y1)
