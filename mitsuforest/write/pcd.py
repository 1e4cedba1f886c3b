"""PCD v0.7 point clouds (the Point Cloud Library's format): ours written binary, any read (binary or ascii)
with numpy."""

from __future__ import annotations

import os

import numpy as np

from ..fields import FIELD, numpy_type, pcd_type


COUNT_DIGITS = 20  # a streamed file's header is written first with its counts padded to this width


def pcd_header(dtype: np.dtype, count: int, digits: int = 0) -> str:
    """The header of a binary PCD of ``count`` points; ``digits`` zero-pads the counts, so that a
    header written before the count is known can be overwritten in place (readers parse them as
    integers: PCL, Open3D and pypcd4 accept the leading zeros). Our points' fields and their types are
    :data:`mitsuforest.fields.FIELDS`'s (see :func:`mitsuforest.fields.pcd_dtype`)."""
    names = dtype.names
    columns = [pcd_type(dtype[n]) for n in names]
    return "\n".join([
        "# .PCD v0.7 - Point Cloud Data file format",
        "VERSION 0.7",
        "FIELDS " + " ".join(names),
        "SIZE " + " ".join(str(size) for _, size in columns),
        "TYPE " + " ".join(kind for kind, _ in columns),
        "COUNT " + " ".join("1" for _ in columns),
        f"WIDTH {count:0{digits}d}",
        "HEIGHT 1",
        "VIEWPOINT 0 0 0 1 0 0 0",
        f"POINTS {count:0{digits}d}",
        "DATA binary",
    ]) + "\n"


class PointFileError(ValueError):
    """A point file that cannot be read as it claims to be; the message says why."""


_SIZES = {"U": (1, 2, 4, 8), "I": (1, 2, 4, 8), "F": (4, 8)}
MAX_HEADER_LINES = 64


def read_pcd(path) -> np.ndarray:
    """Read a PCD: ``DATA binary`` (such as a render writes) or ``DATA ascii`` (as other tools may write);
    its fields keep the file's names (:func:`our_names` gives ours).

    :raises PointFileError: a damaged or foreign header, ``DATA binary_compressed``, fewer points than the
        header promises (a truncated file, or one a render left when it was killed), a binary body of more
        (a header written twice, a SIZE or POINTS that does not describe the data), or an ascii body whose
        lines do not hold one value a field.
    """
    with open(path, "rb") as f:
        header = _pcd_header(f)
        dtype = _pcd_dtype(header)
        count = _pcd_count(header)
        if header["DATA"] == ["ascii"]:
            return _ascii_points(f.read(), dtype, count)
        held = (os.fstat(f.fileno()).st_size - f.tell()) // dtype.itemsize
        if held < count:
            raise PointFileError(f"truncated: the header promises {count:,} points, the file holds {held:,}")
        if count == 0 and held:
            raise PointFileError(f"the header counts 0 points but {held:,} follow: an unfinished file "
                                 "(a render stopped before it wrote its counts)")
        data = f.read(count * dtype.itemsize)
        if data.startswith((b"# .PCD", b"VERSION ")):
            raise PointFileError("its header is written twice: a second header follows its DATA line (a damaged file)")
        if held > count:
            raise PointFileError(f"the header promises {count:,} points of {dtype.itemsize} bytes, but {held:,} "
                                 "points' worth follow: its POINTS or SIZE do not describe its data (a damaged file)")
    return np.frombuffer(data, dtype, count)


def _ascii_points(body: bytes, dtype: np.dtype, count: int) -> np.ndarray:
    """The points of a ``DATA ascii`` body: a line a point, its values in FIELDS order, read as the header's
    types (the first ``count``, as a binary body's)."""
    try:
        lines = body.decode("ascii").splitlines()
    except UnicodeDecodeError:
        raise PointFileError("DATA ascii, but its points are not text") from None
    if not any(line.strip() for line in lines):
        points = np.zeros(0, dtype)
    else:
        try:
            points = np.loadtxt(lines, dtype=dtype, ndmin=1)
        except ValueError as e:
            raise PointFileError(_ascii_problem(lines, len(dtype.names), e)) from None
    if len(points) < count:
        raise PointFileError(f"truncated: the header promises {count:,} points, the file holds {len(points):,}")
    if count == 0 and len(points):
        raise PointFileError(f"the header counts 0 points but {len(points):,} follow")
    if len(points) > count:
        raise PointFileError(f"the header promises {count:,} points, but {len(points):,} follow: its POINTS does not "
                             "describe its data (a damaged file)")
    return points


def _ascii_problem(lines: list[str], width: int, error: ValueError) -> str:
    """Why an ascii body does not read: its first line of other than ``width`` values (ragged: a truncated
    or damaged file), else numpy's words for a value that is no number of its field's TYPE."""
    points = (line.split() for line in lines if line.strip())
    for i, values in enumerate(points, 1):
        if len(values) != width:
            return (f"ragged: point {i:,} holds {len(values)} values where FIELDS names {width} "
                    "(a truncated or damaged file)")
    return f"a value does not read as its field's TYPE: {error}"


def _pcd_header(f) -> dict:
    header = {}
    for _ in range(MAX_HEADER_LINES):
        line = f.readline()
        if not line:
            raise PointFileError("not a PCD file: the header ends before its DATA line")
        try:
            text = line.decode("ascii").strip()
        except UnicodeDecodeError:
            raise PointFileError("not a PCD file: its header is not text") from None
        if not text or text.startswith("#"):
            continue
        key, *values = text.split()
        header[key] = values
        if key == "DATA":
            if values == ["binary_compressed"]:
                raise PointFileError("DATA binary_compressed (LZF) is not supported: re-save the file as binary or "
                                     "ascii PCD (pcl_convert_pcd_ascii_binary IN OUT 1, CloudCompare, Open3D)")
            if values not in (["binary"], ["ascii"]):
                raise PointFileError(f"only DATA binary or ascii is supported, got DATA {' '.join(values)}")
            return header
    raise PointFileError("not a PCD file: no DATA line in its header")


def _pcd_dtype(header: dict) -> np.dtype:
    missing = [k for k in ("FIELDS", "SIZE", "TYPE", "POINTS") if k not in header]
    if missing:
        raise PointFileError(f"the PCD header lacks {', '.join(missing)}")
    names, sizes, types = header["FIELDS"], header["SIZE"], header["TYPE"]
    if not len(names) == len(sizes) == len(types):
        raise PointFileError(f"the PCD header names {len(names)} FIELDS but {len(sizes)} SIZE and "
                             f"{len(types)} TYPE entries")
    if any(c != "1" for c in header.get("COUNT", ["1"] * len(names))):
        raise PointFileError("only fields of COUNT 1 are supported")
    for name, size, kind in zip(names, sizes, types):
        if kind not in _SIZES or not size.isdigit() or int(size) not in _SIZES[kind]:
            raise PointFileError(f"field {name!r}: unsupported TYPE {kind} SIZE {size}")
    if not {"x", "y", "z"} <= set(our_names(names)):
        raise PointFileError("no x, y, z fields: not a point cloud this tool can read")
    if len(set(names)) != len(names):
        raise PointFileError("a field name appears twice in FIELDS")
    return np.dtype([(n, numpy_type(t, int(s))) for n, s, t in zip(names, sizes, types)])


def _pcd_count(header: dict) -> int:
    value = header["POINTS"][0] if header["POINTS"] else ""
    if not value.isdigit():
        raise PointFileError(f"POINTS must be a count, got {value!r}")
    return int(value)


# LAS dimensions that compare and twin read besides our fields, by the names they read them by
LAS_NAMES = ("scan_angle_rank", "withheld")


def _squashed(name: str) -> str:
    return name.lower().replace("_", "")


_OURS = {_squashed(n): n for n in (*FIELD, *LAS_NAMES)}


def our_names(names) -> list[str]:
    """A PCD's field ``names`` with each that differs from one of ours (:data:`~mitsuforest.fields.FIELD`,
    :data:`LAS_NAMES`) only in case and underscores given ours: another tool's (PDAL's ``X``, ``Intensity``,
    ``ReturnNumber``, ``GpsTime``, ``ScanAngleRank``; ``gpstime``) as compare and twin read them. Two names
    that would become one (``Intensity`` beside ``intensity``) both stay as they are."""
    names = list(names)
    renamed = [_OURS.get(_squashed(n), n) for n in names]
    return [new if renamed.count(new) == 1 else old for old, new in zip(names, renamed)]
