"""LAS 1.4 / LAZ (point format 6) through laspy.

Classification uses ASPRS codes where they fit — ground 2, ground vegetation 3 (low vegetation), bush 4
(medium vegetation), tree wood and leaves 5 (high vegetation) — and the user range for the rest: deadwood 64, rock 65, stump 66. Our own
classes (1-8, as in the PCD) are in the extra dimension ``label``; ``treeid``, ``instance``,
``object_id``, ``species`` (classes.SPECIES_CODES, also in the VLR) and ``height_above_ground`` (float32 m,
see write/ground.py) are extra dimensions too. Intensity is scaled to 16 bits by a fixed factor
(INTENSITY_SCALE, also written in the header's VLR and the file description): the float amplitude
is kept exact in the extra dimension ``amplitude``. Return numbers and counts above 15, which point format 6 cannot hold
(a pulse with more echoes than that needs over 15 sub-rays and ``max_returns`` 0 or above 15), are
written as 15; the PCD keeps them. Coordinates are stored at 0.1 mm with the
georeference in the header offsets. The scene's ``origin.crs`` is written as the standard OGC WKT
coordinate system VLR, which PDAL, QGIS and lidR read; the WKT bit of the global encoding is set,
as LAS 1.4 requires for point format 6 (with or without a CRS).
"""

from __future__ import annotations

import contextlib
import errno
import json
from pathlib import Path

import laspy
import numpy as np
from laspy.vlrs.known import WktCoordinateSystemVlr

from ..classes import BUSH, DEADWOOD, GROUND, GROUND_VEGETATION, ROCK, SPECIES_CODES, STUMP, TREE_LEAVES, TREE_WOOD
from ..errors import UserError
from .atomic import atomic_path, naming_errors

ASPRS_CODE = {GROUND: 2, TREE_WOOD: 5, TREE_LEAVES: 5, BUSH: 4, GROUND_VEGETATION: 3, DEADWOOD: 64, ROCK: 65, STUMP: 66}
INTENSITY_SCALE = 1e-6   # amplitude units per LAS intensity count (65535 ≙ a 6.5 % full-beam target at 1 m)
COORDINATE_SCALE = 1e-4  # m
LAS_MAX_RETURNS = 15     # point format 6 has 4 bits for each return field; the PCD keeps larger counts

try:
    from lazrs import LazrsError
    CODEC_ERRORS: tuple = (LazrsError,)
except ImportError:          # laspy without the lazrs backend writes no LAZ
    CODEC_ERRORS = ()


def crs_wkt(text: str) -> str:
    """The OGC WKT of the coordinate reference system ``text`` (``origin.crs``: ``"EPSG:7855"``, a
    PROJ string, WKT...), in WKT1 as GDAL and PDAL write it, which every LAS reader understands
    (WKT2 only for a system WKT1 cannot express).

    :raises UserError: ``origin.crs: ...`` when pyproj cannot make a coordinate system of ``text``, or
        when it is not projected in metres (see :func:`_metric_projection_problem`).
    """
    import pyproj  # here, so that scenes without a CRS do not pay for importing it
    try:
        crs = pyproj.CRS.from_user_input(text)
    except pyproj.exceptions.CRSError as e:
        raise UserError(f"origin.crs: {text!r} is not a coordinate reference system ({_proj_reason(e)}); "
                        "give an EPSG code such as 'EPSG:7855', a PROJ string or WKT") from None
    problem = _metric_projection_problem(crs)
    if problem:
        raise UserError(f"origin.crs: {text!r} ({crs.name}) {problem}; the scene is simulated in metres east, "
                        "north and up, so give a projected CRS in metres, such as a UTM or MGA zone ('EPSG:7855')")
    return crs.to_wkt("WKT1_GDAL") or crs.to_wkt()


def _metric_projection_problem(crs) -> str | None:
    """Why ``crs`` cannot hold our coordinates (the local frame plus ``origin.offset``, in metres), or
    None. A compound CRS is judged by its horizontal part."""
    horizontal = crs.sub_crs_list[0] if crs.is_compound else crs
    if not horizontal.is_projected:
        return "is geographic, in degrees" if horizontal.is_geographic else "is not a projected CRS"
    units = {axis.unit_name for axis in horizontal.axis_info[:2]}
    if units - {"metre", "meter"}:
        return f"has its axes in {', '.join(sorted(units))}"
    return None


def _proj_reason(error: Exception) -> str:
    """PROJ's own words from a pyproj error, without pyproj's repetition of the input."""
    return str(error).rpartition("proj_create: ")[2].removesuffix(")") or str(error)


def las_header(offset, crs: str | None = None) -> laspy.LasHeader:
    """A LAS 1.4 point format 6 header with our extra dimensions, the coding VLR and, when ``crs``
    is given, its WKT VLR (see :func:`crs_wkt`, which raises :class:`UserError` for a bad one)."""
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.offsets = np.asarray(offset, float)
    header.scales = np.full(3, COORDINATE_SCALE)
    header.add_extra_dims([
        laspy.ExtraBytesParams("label", np.uint8, "mitsuforest class 1-8"),
        laspy.ExtraBytesParams("treeid", np.uint16, "archetype 1-10, deadwood 11"),
        laspy.ExtraBytesParams("instance", np.uint32, "object instance id"),
        laspy.ExtraBytesParams("object_id", np.uint32, "component id"),
        laspy.ExtraBytesParams("amplitude", np.float32, "echo amplitude (white at 1 m=1)"),
        laspy.ExtraBytesParams("species", np.uint8, "tree family code, 0 none"),
        laspy.ExtraBytesParams("height_above_ground", np.float32, "m above the terrain"),
    ])
    _without_extra_statistics(header)
    header.vlrs.append(laspy.VLR("mitsuforest", 1, "intensity and classes", json.dumps(
        {"intensity_scale": INTENSITY_SCALE, "classification": {str(k): v for k, v in ASPRS_CODE.items()},
         "species": {str(v): k for k, v in SPECIES_CODES.items()}, "crs": crs}).encode()))
    header.global_encoding.wkt = True  # LAS 1.4 requires it for point formats 6-10; PDAL refuses files without
    if crs:
        header.vlrs.append(WktCoordinateSystemVlr(crs_wkt(crs)))
    return header


def _without_extra_statistics(header: laspy.LasHeader) -> None:
    """Clear the optional min/max of each extra dimension: laspy fills them from the first batch only
    (a LAZ file's VLRs are written before its points), which is wrong and depends on the batch size."""
    for struct in header.vlrs.get("ExtraBytesVlr")[0].extra_bytes_structs:
        struct.options &= ~(struct.MIN_BIT_MASK | struct.MAX_BIT_MASK)


def las_points(header: laspy.LasHeader, points: np.ndarray) -> laspy.LasData:
    """Georeferenced points (x, y, z include the offset) as a LasData of ``header``'s format."""
    las = laspy.LasData(header, points=laspy.ScaleAwarePointRecord.zeros(len(points), header=header))
    las.x, las.y, las.z = points["x"], points["y"], points["z"]
    las.classification = _ASPRS_LOOKUP[points["classification"]]
    las.return_number = np.minimum(points["return_number"], LAS_MAX_RETURNS)
    las.number_of_returns = np.minimum(points["number_of_returns"], LAS_MAX_RETURNS)
    las.intensity = np.clip(np.round(points["intensity"] / INTENSITY_SCALE), 0, 65535).astype(np.uint16)
    las.gps_time = points["gps_time"]
    las.scan_angle = np.round(points["scan_angle"] / 0.006).astype(np.int16)
    las.label = points["classification"]
    las.treeid = points["treeid"]
    las.instance = points["instance"]
    las.object_id = points["object_id"]
    las.amplitude = points["intensity"]
    if "species" in points.dtype.names:
        las.species = points["species"]
    if "height_above_ground" in points.dtype.names:
        las.height_above_ground = points["height_above_ground"]
    return las


_ASPRS_LOOKUP = np.zeros(256, np.uint8)
for _code, _asprs in ASPRS_CODE.items():
    _ASPRS_LOOKUP[_code] = _asprs


class LasStream:
    """A ``.las`` or ``.laz`` file written batch by batch (laspy updates the header on close)."""

    def __init__(self, path, offset, crs: str | None = None, compress: bool | None = None):
        """:param compress: LAZ compression; by default when ``path`` ends in ``.laz``."""
        self.path = Path(path)
        self.header = las_header(offset, crs)
        compress = str(path).endswith(".laz") if compress is None else compress
        self._writer = laspy.open(str(path), mode="w", header=self.header, do_compress=compress)

    def write(self, points: np.ndarray) -> None:
        if len(points):
            with self._io_errors():
                self._writer.write_points(las_points(self.header, points).points)

    def close(self) -> None:
        with self._io_errors():
            self._writer.close()

    def abort(self) -> None:
        """Close, unless closed already (laspy cannot close twice); any error of a broken file is moot
        (closing flushes, and on a full disk the LAZ compressor fails again)."""
        try:
            self._writer.close()
        except Exception:   # noqa: BLE001
            pass

    @contextlib.contextmanager
    def _io_errors(self):
        """Write failures as OSErrors naming this file, the LAZ compressor's (a full disk) included."""
        try:
            with naming_errors(self.path):
                yield
        except CODEC_ERRORS as e:
            raise OSError(errno.EIO, f"the LAZ compressor could not write ({e})", str(self.path)) from e


def write_las(path, points: np.ndarray, offset, crs: str | None = None) -> None:
    """Write georeferenced points (x, y, z already include ``offset``) to ``.las`` or ``.laz`` at once."""
    with atomic_path(path) as tmp:
        stream = LasStream(tmp, offset, crs, compress=str(path).endswith(".laz"))
        stream.write(points)
        stream.close()


def read_las_points(path) -> np.ndarray:
    """The points of one of our ``.las``/``.laz`` files (a tile's too) under the PCD's field names:
    ``classification`` is our class (the ``label`` dimension), ``intensity`` the float amplitude; x, y,
    z georeferenced. No ``pulse_id`` or ``range``, which the LAS file does not hold."""
    las = laspy.read(str(path))
    dtype = [("treeid", "<u2"), ("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("classification", "u1"),
             ("instance", "<u4"), ("object_id", "<u4"), ("number_of_returns", "u1"), ("return_number", "u1"),
             ("intensity", "<f4"), ("gps_time", "<f8"), ("scan_angle", "<f4"), ("height_above_ground", "<f4")]
    out = np.zeros(len(las.points), dtype)
    for key, value in (("treeid", las.treeid), ("x", las.x), ("y", las.y), ("z", las.z),
                       ("classification", las.label), ("instance", las.instance), ("object_id", las.object_id),
                       ("number_of_returns", las.number_of_returns), ("return_number", las.return_number),
                       ("intensity", las.amplitude), ("gps_time", las.gps_time),
                       ("scan_angle", np.asarray(las.scan_angle) * 0.006)):
        out[key] = np.asarray(value)
    names = set(las.point_format.dimension_names)      # files of versions before the field: NaN
    out["height_above_ground"] = las.height_above_ground if "height_above_ground" in names else np.nan
    return out
