"""How each point file format reads back and is written whole, one entry a format (the names and suffixes
are :data:`~mitsuforest.fields.POINT_FORMATS`): a new format is one entry here.

>>> read_points("out/demo/demo.laz").dtype.names[:3]          # doctest: +SKIP
('x', 'y', 'z')
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..fields import POINT_FORMATS
from .atomic import atomic_path
from .las import read_las_points, write_las
from .pcd import pcd_header, read_pcd


@dataclass(frozen=True)
class PointFile:
    read: Callable[[Path], np.ndarray]      # path → its points (structured; the PCD's fields, or our LAS's)
    write: Callable | None                  # (path, points, offset, crs, intensity) → None, atomically


def _read_pcd(path) -> np.ndarray:
    return np.array(read_pcd(path))


def _write_pcd(path, points: np.ndarray, offset, crs, intensity) -> None:
    """The points as they are (the dtype's fields and types, x, y, z included), with their header."""
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(pcd_header(points.dtype, len(points)).encode("ascii"))
        f.write(np.ascontiguousarray(points).data)


READERS: dict[str, PointFile] = {
    "pcd": PointFile(_read_pcd, _write_pcd),
    "las": PointFile(read_las_points, write_las),
    "laz": PointFile(read_las_points, write_las),
    "copc": PointFile(read_las_points, None),            # COPC is LAZ to a reader; written by its stream only
}
assert READERS.keys() == POINT_FORMATS.keys()


def format_of(path) -> str | None:
    """The format of a point file by its name (``x.copc.laz`` is COPC), or None."""
    name = Path(path).name.lower()
    return max((f for f, suffix in POINT_FORMATS.items() if name.endswith(suffix)),
               key=lambda f: len(POINT_FORMATS[f]), default=None)


def read_points(path) -> np.ndarray:
    """The points of one of our point files (a render's, a tile's), by its format (:func:`format_of`).

    :raises ValueError: a name of no point format.
    """
    fmt = format_of(path)
    if fmt is None:
        raise ValueError(f"{path}: not a point file ({', '.join(POINT_FORMATS.values())})")
    return READERS[fmt].read(path)


def write_points(path, points: np.ndarray, offset, crs=None, intensity=None) -> None:
    """Write ``points`` (georeferenced) at once, atomically, in the format of ``path``'s name."""
    writer = READERS[format_of(path)].write
    if writer is None:
        raise ValueError(f"{path}: written batch by batch only")
    writer(path, points, offset, crs, intensity)
