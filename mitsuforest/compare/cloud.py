"""Any point file (PCD, LAS, LAZ; ours or another tool's) as one common set of numpy fields."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from ..classes import CLASS_NAMES, GROUND
from ..errors import UserError, amount
from ..fields import FIELD, SCAN_ANGLE_UNIT
from .metrics import (CELL_M, ISOLATION_CELL_M, ISOLATION_OTHERS, STRAY_POINTS, STRAY_REACH_M, cell_keys,
                      first_returns, first_returns_only, isolated_points, numbers_of_returns_by_time, stray_clusters)

ASPRS_GROUND = 2
ASPRS_NOISE = (7, 18)         # low and high noise: left out of a comparison of another tool's file
MAX_SPAN_M = 2**31 - 1        # the widest x or y extent of a cloud's points, of 1 m cells (metrics.cell_keys)


@dataclass
class Cloud:
    """The fields a comparison reads, each (n,); None where the file has no such field.

    :param scheme: ``"mitsuforest"`` (our classes, ground 1) or ``"ASPRS"`` (ground 2).
    :param notes: what was missing and what stands in for it, in words.
    :param first_only: the file holds its pulses' first returns only (each with its pulse's count of returns).
    """

    name: str
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    return_number: np.ndarray
    number_of_returns: np.ndarray
    intensity: np.ndarray | None = None
    scan_angle: np.ndarray | None = None          # degrees
    classification: np.ndarray | None = None
    scheme: str = "ASPRS"
    notes: list[str] = field(default_factory=list)
    first_only: bool = False                      # one point a pulse, its first (:func:`~.metrics.first_returns_only`)

    def __len__(self) -> int:
        return len(self.x)

    @property
    def ground_code(self) -> int:
        return GROUND if self.scheme == "mitsuforest" else ASPRS_GROUND


def load_cloud(path) -> Cloud:
    """Read a ``.pcd``, ``.las`` or ``.laz`` file (through :func:`mitsuforest.write.info.load_points`).

    :raises UserError: a missing, damaged or foreign file, or one without points.
    """
    from ..crs import file_crs
    from ..write.info import load_points
    columns, _, class_names = load_points(path)
    if len(columns["x"]) == 0:
        raise UserError(f"{path}: the file holds no points")
    wkt = file_crs(path)
    columns, unit_note = in_metres(columns, wkt, path) if wkt else (columns, unread_crs_note(path))
    from ..write.formats import format_of
    if (angle := scan_angle_degrees(columns, pcd=format_of(path) == "pcd")) is not None:
        columns = {**columns, "scan_angle": angle}
    amplitude = FIELD["intensity"].read_from     # our LAS: from the exact amplitude (16-bit intensity rounds)
    unit_notes = []
    if amplitude in columns and class_names is CLASS_NAMES:
        intensity, unit = _in_sensor_units(columns, columns[amplitude], path)
        columns = {**columns, "intensity": intensity}
        unit_notes += [unit] if unit else []
    cloud = cloud_from_columns(columns, Path(path).name, "mitsuforest" if class_names is CLASS_NAMES else "ASPRS")
    cloud.notes[:0] = ([unit_note] if unit_note else []) + unit_notes
    return cloud


def _in_sensor_units(columns: dict, amplitude: np.ndarray, path) -> tuple[np.ndarray, str | None]:
    """Our LAS file's intensity in its sensor's units, unrounded (:func:`~mitsuforest.scan.radiometry.
    sensor_units` of the exact amplitude and reflectance by the mapping in its VLR, at least 0 as counts
    are: below -25 dB PDAL's map of RIEGL's reflectance reads 0; not clipped at the saturation, as our
    PCD's amplitude is not), and a note where that is not the amplitude times a gain:
    a twin of a RIEGL file writes the reflectance in dB, and the real file's counts compare with those, not
    with the amplitude. The amplitude where the file keeps no mapping (our PCD)."""
    from ..config.types import IntensityMapping
    from ..scan.radiometry import sensor_units
    from ..write.info import intensity_mapping
    found = intensity_mapping(path)
    if found is None or "reflectance" not in columns:
        return amplitude, None
    mapping = IntensityMapping(**found)
    units = np.maximum(sensor_units(amplitude, columns["reflectance"], mapping), 0.0)
    if mapping.source == "amplitude" and mapping.offset == 0:
        return units, None
    return units, (f"intensity in its sensor's units ({mapping.source} x {mapping.gain:g} + {mapping.offset:g}, "
                   "its LAS's mapping), not the amplitude of our PCD")


def scan_angle_degrees(columns: dict, pcd: bool) -> np.ndarray | None:
    """(n,) float64 scan angles in degrees of a file's ``columns``, or None where it has none: LAS 1.4's
    ``scan_angle`` in 0.006° counts, a PCD's ``scan_angle`` as written (ours, degrees), else LAS 0-5's (or
    PDAL's) ``scan_angle_rank`` in whole degrees."""
    if "scan_angle" in columns:
        return np.asarray(columns["scan_angle"], np.float64) * (1.0 if pcd else SCAN_ANGLE_UNIT)
    if "scan_angle_rank" in columns:
        return np.asarray(columns["scan_angle_rank"], np.float64)
    return None


def unread_crs_note(path) -> str | None:
    """The note on a file whose CRS :func:`~mitsuforest.crs.file_crs` did not read but that holds a CRS record
    (:func:`~mitsuforest.crs.unread_crs_record`), whose units are then unknown and taken as metres; None for
    a file without one."""
    from ..crs import unread_crs_record
    kind = unread_crs_record(path)
    return None if kind is None else (f"its CRS record ({kind}) cannot be read: its coordinates are taken as "
                                      "metres; give the file a CRS that names its units (such as its EPSG code)")


def in_metres(columns: dict, wkt: str, path) -> tuple[dict, str | None]:
    """The columns with x, y, z in metres, for a file whose CRS ``wkt`` is in other units (feet), and the
    note that says so (None for a CRS in metres).

    :raises UserError: a CRS whose x and y are not lengths (degrees): nothing to measure areas with.
    """
    from ..crs import length_units
    try:
        name, words, across, up = length_units(wkt)
    except ValueError as e:
        raise UserError(f"{path}: {e}; compare measures in metres: reproject the file to a projected CRS "
                        "(such as its UTM zone) first") from None
    if across == 1 and up == 1:
        return columns, None
    scaled = {"x": np.asarray(columns["x"]) * across, "y": np.asarray(columns["y"]) * across,
              "z": np.asarray(columns["z"]) * up}
    return {**columns, **scaled}, f"coordinates in {words} (CRS {name}): converted to metres"


def within_footprint(cloud: Cloud, of: Cloud, cell: float = 1.0, called: str | None = None) -> Cloud:
    """``cloud``'s points in the ``cell`` m cells that hold a point of ``of`` (its footprint), with a note
    naming ``of`` as ``called`` (default its name): a render with the stand around its plot, or of a circular
    clip's twin, measured where the real clip is.

    :raises UserError: no point of ``cloud`` within the footprint.
    """
    called = called or of.name
    origin = (float(np.floor(min(np.min(cloud.x), np.min(of.x)))), float(np.floor(min(np.min(cloud.y), np.min(of.y)))))
    keep = np.isin(cell_keys(cloud.x, cloud.y, cell, origin), cell_keys(of.x, of.y, cell, origin))
    if not keep.any():
        raise UserError(f"{cloud.name}: none of its points lies within {called}'s footprint (the {cell:g} m cells "
                        "holding its points): are the two files in one frame?")
    kept = {f.name: (v[keep] if isinstance(v := getattr(cloud, f.name), np.ndarray) else v) for f in fields(cloud)}
    note = (f"measured within {called}'s footprint (the {cell:g} m cells holding its points): "
            f"{int(keep.sum()):,} of {len(keep):,} points")
    return Cloud(**{**kept, "notes": [*cloud.notes, note]})


def first_only_note(number_of_returns: np.ndarray) -> str:
    """The note on a file of first returns only (:func:`~.metrics.first_returns_only`)."""
    return (f"first returns only: one point a pulse, each with its pulse's number of returns (up to "
            f"{int(np.max(number_of_returns))}), every return number 1 and no two points at one GPS time")


def first_returns_of(cloud: Cloud, called: str) -> Cloud:
    """``cloud``'s first returns, measured beside ``called``, a file of first returns only: the same
    pulses and their counts of returns, no later return among the heights, ground and intensities.

    :raises UserError: ``cloud`` holds no first return (a file of later returns alone).
    """
    keep = first_returns(cloud.return_number)
    if not keep.any():
        raise UserError(f"{cloud.name}: none of its {len(keep):,} points is a first return (return number 1) to "
                        f"measure beside {called}, which holds first returns only")
    kept = {f.name: (v[keep] if isinstance(v := getattr(cloud, f.name), np.ndarray) else v) for f in fields(cloud)}
    note = (f"measured on its first returns ({int(keep.sum()):,} of {len(keep):,} points), as {called} holds "
            "first returns only")
    return Cloud(**{**kept, "notes": [*cloud.notes, note], "first_only": True})


def like_for_like(a: Cloud, b: Cloud) -> tuple[Cloud, Cloud]:
    """``a`` and ``b``, where one holds first returns only and the other every return, with the other's
    first returns (:func:`first_returns_of`): a height profile, ground share or density of every return
    against one of first returns alone measures the files' contents, not the scans."""
    if a.first_only and not b.first_only:
        return a, first_returns_of(b, f"A ({a.name})")
    if b.first_only and not a.first_only:
        return first_returns_of(a, f"B ({b.name})"), b
    return a, b


def as_cloud(value, name: str = "cloud") -> Cloud:
    """A :class:`Cloud` of ``value``: a Cloud, a path, or points in memory (a structured array such as
    ``render(...).points``, or a mapping of columns), whose classes are taken as ours."""
    if isinstance(value, Cloud):
        return value
    if isinstance(value, (str, Path)):
        return load_cloud(value)
    names = value.dtype.names if isinstance(value, np.ndarray) else tuple(value)
    if not names or not {"x", "y", "z"} <= set(names):
        raise UserError(f"{name}: no x, y, z fields: not a point cloud")
    if len(value["x"]) == 0:
        raise UserError(f"{name}: no points")
    return cloud_from_columns({n: value[n] for n in names}, name, "mitsuforest")


def cloud_from_columns(columns: dict, name: str, scheme: str) -> Cloud:
    """A Cloud of a file's columns by name (scan angles already in degrees)."""
    columns, notes = usable_points(columns, foreign=scheme == "ASPRS")
    n = len(columns["x"])
    if n == 0:
        raise UserError(f"{name}: no points other than {LEFT_OUT} ({'; '.join(notes)})")
    span = max(float(np.ptp(np.asarray(columns[a], np.float64))) for a in "xy")
    if not span < MAX_SPAN_M:      # the cells' keys (metrics.cell_keys) hold 31 bits an axis
        raise UserError(f"{name}: its points span {amount(span)} m, more than the {CELL_M:g} m cells of a comparison "
                        f"can number ({MAX_SPAN_M:,} m): a damaged file, or one of stray coordinates")
    rn, nr = return_numbers(columns, notes)
    first_only = first_returns_only(rn, nr, columns.get("gps_time"))
    if first_only:
        notes.append(first_only_note(nr))
    intensity = _optional(columns, "intensity", np.float64, notes, "no intensity")
    if intensity is not None and not np.any(intensity):
        intensity = None
        notes.append("intensity is 0 everywhere: left out")
    scan_angle = _optional(columns, "scan_angle", np.float32, notes, "no scan angle")
    classification = np.asarray(columns["classification"], np.int16) if "classification" in columns else None
    return Cloud(name, *(np.asarray(columns[a], np.float64) for a in "xyz"), rn, nr, intensity, scan_angle,
                 classification, scheme, notes, first_only)


NUMBERS_FROM_TIMES = ("numbers of returns are 0 everywhere: taken from the return numbers of the points that "
                      "share a GPS time")
LEFT_OUT = "non-finite, noise, withheld, repeated, isolated or stray ones"     # what usable_points leaves out, for messages


def usable_points(columns: dict, foreign: bool = True) -> tuple[dict, list[str]]:
    """A file's columns less the points a measure of the scan must not see, and what was left out, in
    words: points without finite coordinates (PCL's organized clouds keep NaN in their empty cells), points
    flagged withheld and, in another tool's file (``foreign``), its ASPRS noise (classes
    7, 18), exact copies of a point (every field the same: a tile merged twice), isolated points
    (:func:`~.metrics.isolated_points`: a bird, a multipath echo, a stray coordinate) and then small
    clusters apart from the scan (:func:`~.metrics.stray_clusters`: a flock of birds above the canopy,
    multipath under the ground, a group of stray coordinates), whose height or place would stretch a
    grid or a canopy. Our own files have none of these but withheld points."""
    notes = []
    columns = _left_out(columns, ~np.all([np.isfinite(np.asarray(columns[a], np.float64)) for a in "xyz"], axis=0),
                        "points without coordinates (NaN or infinite: an organized cloud's empty cells)", notes)
    if foreign and "classification" in columns:
        columns = _left_out(columns, np.isin(columns["classification"], ASPRS_NOISE),
                            "noise points (ASPRS classes 7, 18)", notes)
    if "withheld" in columns:           # LAS: "should not be included in processing"
        columns = _left_out(columns, np.asarray(columns["withheld"], bool), "withheld points", notes)
    if foreign and len(columns["x"]):
        columns = _left_out(columns, repeated_points(columns), "repeated points (exact copies)", notes)
        xyz = (np.asarray(columns[a], np.float64) for a in "xyz")
        columns = _left_out(columns, isolated_points(*xyz), f"isolated points (fewer than {ISOLATION_OTHERS} "
                            f"others in the {ISOLATION_CELL_M:g} m cubes around them: birds, multipath, stray "
                            "coordinates)", notes)
    if foreign and len(columns["x"]):
        cluster = stray_clusters(*(np.asarray(columns[a], np.float64) for a in "xyz"))
        k = int(cluster.max()) + 1
        columns = _left_out(columns, cluster >= 0, f"points in {k:,} stray cluster{'' if k == 1 else 's'} (fewer "
                            f"than {STRAY_POINTS} points, apart from the scan's {ISOLATION_CELL_M:g} m cubes, above or "
                            f"below it within {STRAY_REACH_M:g} m or away from it: flocks, multipath, stray "
                            "coordinates)", notes)
    return columns, notes


def repeated_points(columns: dict) -> np.ndarray:
    """(n,) bool: every point that is an exact copy, in all of ``columns``, of one before it. A column may be
    (n, k): laspy reads a LAS's extra bytes so where its header hides their description (a VLR count of 0)."""
    arrays = [np.asarray(v) for v in columns.values()]
    records = np.empty(len(arrays[0]), [(f"f{i}", a.dtype, a.shape[1:]) for i, a in enumerate(arrays)])
    for i, a in enumerate(arrays):
        records[f"f{i}"] = a
    raw = records.view(np.dtype((np.void, records.dtype.itemsize)))
    repeated = np.ones(len(raw), bool)
    repeated[np.unique(raw, return_index=True)[1]] = False
    return repeated


def _left_out(columns: dict, drop: np.ndarray, what: str, notes: list) -> dict:
    if not drop.any():
        return columns
    notes.append(f"{int(drop.sum()):,} {what} left out")
    return {k: np.asarray(v)[~drop] for k, v in columns.items()}


def return_numbers(columns: dict, notes: list) -> tuple[np.ndarray, np.ndarray]:
    """(n,) int16 return numbers and numbers of returns of a file's ``columns``, with a note in ``notes``
    where they were not filled: numbers of returns left 0 are taken from the points sharing a GPS time
    (:func:`~.metrics.numbers_of_returns_by_time`); without those, every point is a single-return pulse."""
    n = len(columns["x"])
    single = np.ones(n, np.int16), np.ones(n, np.int16)
    if "return_number" not in columns or "number_of_returns" not in columns:
        notes.append("no return numbers: every point taken as a single-return pulse")
        return single
    rn, nr = (np.asarray(columns[k], np.int16) for k in ("return_number", "number_of_returns"))
    if rn.any() and nr.any():
        return rn, nr
    times = columns.get("gps_time")
    if not rn.any():                      # LAS writers that do not know them leave 0
        if first_returns_only(single[0], nr, times):
            notes.append("return numbers are 0 everywhere: taken as 1, the file's first returns")
            return single[0], nr
        notes.append("return numbers are 0 everywhere: every point taken as a single-return pulse")
        return single
    found = None if times is None or np.all(times == times[0]) else numbers_of_returns_by_time(
        rn, times, columns.get("point_source_id"))
    if found is None:
        notes.append("numbers of returns are 0 everywhere and no GPS time tells one pulse's points apart: "
                     "every point taken as a single-return pulse")
        return single
    notes.append(NUMBERS_FROM_TIMES)
    return rn, found.astype(np.int16)


def _optional(columns: dict, key: str, dtype, notes: list, missing: str):
    if key not in columns:
        notes.append(missing)
        return None
    return np.asarray(columns[key], dtype)
