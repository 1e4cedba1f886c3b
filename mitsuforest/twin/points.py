"""Reading a real scan for a twin: the columns the twin needs, in float64 file coordinates (I/O only)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..classes import CLASS_NAMES, GROUND
from ..crs import file_crs, length_units, projection_problem
from ..errors import UserError


@dataclass(frozen=True)
class RealScan:
    """A point file's columns, shapes (n,); optional columns are ``None`` when the file lacks them."""

    path: str
    x: np.ndarray                       # float64, the file's coordinates (m)
    y: np.ndarray
    z: np.ndarray
    ground: np.ndarray | None           # bool: ASPRS class 2 (our ground class in our files); None: unclassified
    return_number: np.ndarray
    number_of_returns: np.ndarray
    gps_time: np.ndarray | None         # s
    scan_angle: np.ndarray | None       # deg from nadir
    point_source_id: np.ndarray | None
    intensity: np.ndarray | None
    crs: str | None                     # WKT of the file's CRS
    tree_id: np.ndarray | None = None   # a reference segmentation (``treeID``, ``treeid``), for benchmarks
    first_only: bool = False            # one point a pulse, its first (compare.metrics.first_returns_only)
    notes: tuple[str, ...] = ()         # the points left out, in words (noise, withheld, repeated, isolated, stray)

    def __len__(self) -> int:
        return len(self.x)


def read_scan(path) -> RealScan:
    """The columns of a LAS/LAZ or PCD file (ours or another tool's); an empty, damaged or unreadable file
    is a one-line :class:`~mitsuforest.errors.UserError`."""
    from ..write.formats import format_of
    from ..write.info import load_points
    from ..compare.cloud import LEFT_OUT, first_only_note, scan_angle_degrees, usable_points
    from ..compare.metrics import first_returns_only
    cols, _, class_names = load_points(path)
    if len(cols["x"]) == 0:
        raise UserError(f"{path}: holds no points")
    crs, unplaced = _scene_crs(file_crs(path), path)
    cols, notes = usable_points(cols, foreign=class_names is not CLASS_NAMES)
    notes += [unplaced] if unplaced else []
    n = len(cols["x"])
    if n == 0:
        raise UserError(f"{path}: holds no points other than {LEFT_OUT} ({'; '.join(notes)})")
    x, y, z = (np.asarray(cols[k], np.float64) for k in ("x", "y", "z"))
    classes = np.asarray(cols["classification"]) if "classification" in cols else None
    ground = None
    if classes is not None and classes.any():
        ground = classes == (GROUND if class_names is CLASS_NAMES else 2)    # ours (PCD, LAS label) or ASPRS
    gps_time = _varying(cols.get("gps_time"))
    returns = np.maximum(_column(cols, "return_number", n, 1), 1)     # 0: a writer that did not fill it
    counts = np.maximum(_numbers_of_returns(cols, returns, gps_time, notes), returns)
    first_only = first_returns_only(returns, counts, gps_time)
    notes += [first_only_note(counts)] if first_only else []
    return RealScan(
        path=str(path), x=x, y=y, z=z, ground=ground, return_number=returns, number_of_returns=counts,
        gps_time=gps_time, scan_angle=_varying(scan_angle_degrees(cols, pcd=format_of(path) == "pcd")),
        point_source_id=_varying(cols.get("point_source_id")), intensity=_varying(cols.get("intensity")),
        crs=crs,
        tree_id=next((np.asarray(cols[k]) for k in ("treeID", "treeid") if k in cols), None), notes=tuple(notes),
        first_only=first_only)


def _scene_crs(wkt: str | None, path) -> tuple[str | None, str | None]:
    """The file's CRS ``wkt`` as the twin's ``origin.crs``, or None with the note that says why (a local grid
    in metres: a twin, but not georeferenced).

    :raises UserError: a CRS not in metres: a twin's x, y and heights are the file's, and a scene is
        simulated in metres.
    """
    if wkt is None:
        return None, None
    try:
        name, words, across, up = length_units(wkt)
    except ValueError as e:
        problem = str(e)
    else:
        problem = None if across == 1 and up == 1 else f"its CRS ({name}) is in {words}"
    if problem:
        raise UserError(f"{path}: {problem}; a twin is built in metres: reproject the file to a projected CRS "
                        "in metres (such as its UTM zone) first")
    if unplaced := projection_problem(wkt):
        return None, f"its CRS ({name}) {unplaced}: the twin's scene has no origin.crs"
    return wkt, None


def _numbers_of_returns(cols: dict, returns: np.ndarray, times: np.ndarray | None, notes: list) -> np.ndarray:
    """The file's numbers of returns; where it left them 0 but numbered its returns, those of the points
    that share a GPS time (and a note saying so), else 0."""
    from ..compare.cloud import NUMBERS_FROM_TIMES
    from ..compare.metrics import numbers_of_returns_by_time
    counts = _column(cols, "number_of_returns", len(returns), 1)
    if counts.any() or returns.max() < 2 or times is None:
        return counts
    found = numbers_of_returns_by_time(returns, times, cols.get("point_source_id"))
    if found is None:
        return counts
    notes.append(NUMBERS_FROM_TIMES)
    return found


def _column(cols: dict, name: str, n: int, default: int) -> np.ndarray:
    return np.asarray(cols[name], np.int64) if name in cols else np.full(n, default, np.int64)


def _varying(column) -> np.ndarray | None:
    """A column that carries information: present and not one value for every point."""
    if column is None:
        return None
    column = np.asarray(column)
    return column if len(column) and np.any(column != column[0]) else None
