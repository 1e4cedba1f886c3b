"""A part of a batch of points: what the point writer's threads (:mod:`.stream`) and its worker processes
(:mod:`.processes`) both do with their rows: georeference them, write their PCD records at their offset
in the file, and tally their statistics."""

from __future__ import annotations

import errno
import os

import numpy as np

from .atomic import naming_errors

SPACING_TILE = 5.0  # m, side of the tiles in which the mean nearest-neighbour spacing is measured


def georeference(points: np.ndarray, offset) -> np.ndarray:
    """Add the float64 origin offset to local-frame points: a copy, or ``points`` itself when the
    offset is zero."""
    if not np.any(offset):
        return points
    out = points.copy()
    for axis, o in zip("xyz", offset):
        out[axis] += o
    return out


def write_pcd_rows(fd: int, path, record: np.dtype, offset: int, geo: np.ndarray) -> None:
    """Georeferenced points ``geo`` as PCD records of dtype ``record``, written at byte ``offset`` of the
    open file ``fd`` (errors name ``path``)."""
    data = geo if record == geo.dtype else geo.astype(record)
    with naming_errors(path):
        write_at(fd, data, offset)


def write_at(fd: int, data: np.ndarray, offset: int) -> None:
    """Write a contiguous array at ``offset`` of file ``fd`` (``os.pwrite``: threads write their parts
    of one file at once)."""
    view = memoryview(np.ascontiguousarray(data).view(np.uint8))
    while view:
        written = os.pwrite(fd, view, offset)
        if written == 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        view, offset = view[written:], offset + written


def tallies(points: np.ndarray, counts, side, tiles: np.ndarray) -> tuple:
    """The statistics of a part of a batch, for :meth:`~.stream.PointWriter.merge_part`: (256,) points by
    class, (256,) pulses by their number of returns (from first returns), the ``counts`` by height and by
    return (:meth:`~.profile.ReturnCounts.tally`), the points in the ``side`` tile
    (:class:`~.quicklook.SideTile`) and (k, 3) x, y, z of those in each spacing tile of ``tiles`` ((4, 2)
    corners)."""
    first = points["return_number"] == 1
    return (np.bincount(points["classification"], minlength=256),
            np.bincount(points["number_of_returns"][first], minlength=256),
            counts.tally(points), side.select(points), in_tiles(points, tiles))


def in_tiles(points: np.ndarray, tiles: np.ndarray) -> list[np.ndarray]:
    """(k, 3) x, y, z of the points in each spacing tile (corners ``tiles``, side :data:`SPACING_TILE`)."""
    x, y = points["x"].copy(), points["y"].copy()      # contiguous: four times faster to compare
    out = []
    for x0, y0 in tiles:
        inside = (x >= x0) & (x < x0 + SPACING_TILE)
        inside &= y >= y0
        inside &= y < y0 + SPACING_TILE
        rows = np.flatnonzero(inside)
        out.append(np.column_stack([x[rows], y[rows], points["z"][rows]]))
    return out
