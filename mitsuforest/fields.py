"""The point schema: every per-point field once, with where it goes in each file and how it comes back.

A point array (:data:`POINT_DTYPE`, what a scan makes) holds the *scan* fields in :data:`FIELDS`
order; the writer adds the *writer* fields (``height_above_ground``) to every file (:data:`RECORD_DTYPE`).
Each field says:

- its numpy type, meaning and unit;
- its PCD column: ``TYPE``/``SIZE`` from the numpy type (:func:`pcd_type`), in the same order; x, y, z
  are float32 in the local frame (:func:`pcd_dtype`);
- its LAS 1.4 point-format-6 dimensions (:class:`LasDimension`): a standard dimension with its
  encoding (scaled, packed into bits, coded, counts), or an extra-bytes dimension with its type and
  description; a field may have both (our class is the ASPRS ``classification`` and the extra ``label``)
  or none (``pulse_id``, ``range``: PCD only);
- which dimension a reader of our LAS files takes it back from (:attr:`Field.read_from`), and what a
  file that lacks it (an earlier version's) reads (:attr:`Field.missing`).

The PCD header (:mod:`mitsuforest.write.pcd`), the LAS header and records (:mod:`mitsuforest.write.las`,
COPC and tiles included) and the LAS reader derive from :data:`FIELDS`: a new field is one entry here
(and the code that computes it). Imports nothing of the pipeline: the scan builds its points from it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SCAN, WRITER = "scan", "writer"   # who fills a field: the tracer, or the point writer (from the terrain)

# The point file formats, ``output.formats``'s names, each with its file's suffix after the render's (or
# tile's) name: the one list that the scene's check, the output files and the readers
# (:data:`mitsuforest.write.formats.READERS`) take them from.
POINT_FORMATS = {"pcd": ".pcd", "las": ".las", "laz": ".laz", "copc": ".copc.laz"}

LAS_FORMAT = 6                     # LAS 1.4 point format of our files
COORDINATE_SCALE = 1e-4            # m per LAS coordinate count (the offset is ``origin.offset``)
SCAN_ANGLE_UNIT = 0.006            # degrees per LAS 1.4 scan_angle count (point formats 6-10)


@dataclass(frozen=True)
class LasDimension:
    """One dimension of a LAS point-format-6 record that a field fills.

    :param name: laspy's name of the dimension (``X``, ``scan_angle``, ``label`` ...).
    :param encoding: how the value is stored: ``copy``; ``coordinate`` (the header's scale and offset);
        ``scaled`` (``round(value / scale)``); ``bits`` (``min(value, 2**width - 1)`` at ``shift`` in the
        byte ``packed``); ``asprs`` (our class as its ASPRS code); ``counts`` (16-bit intensity by the
        sensor's mapping); ``extra`` (an extra-bytes dimension, stored as its ``dtype``).
    :param dtype: an extra dimension's type.
    :param description: an extra dimension's description (at most 32 ASCII characters).
    :param slot: an extra dimension's place among the extra bytes (our files put ``label`` first).
    """

    name: str
    encoding: str = "copy"
    scale: float = 1.0
    packed: str = ""
    shift: int = 0
    width: int = 8
    dtype: str = ""
    description: str = ""
    slot: int = -1

    @property
    def is_extra(self) -> bool:
        return self.encoding == "extra"


def extra(name: str, dtype: str, description: str, slot: int) -> LasDimension:
    return LasDimension(name, "extra", dtype=dtype, description=description, slot=slot)


@dataclass(frozen=True)
class Field:
    """One per-point field (see the module docstring).

    :param name: the field's name in point arrays, PCD files and our readers.
    :param dtype: its numpy type (little-endian).
    :param meaning: what it holds, with its unit.
    :param filled_by: :data:`SCAN` or :data:`WRITER`.
    :param las: the LAS dimensions it fills, in that order (empty: not in LAS files).
    :param read_from: the LAS dimension a reader takes it from (default: the first of ``las``).
    :param missing: what a reader gives when a file lacks that dimension (an earlier version's file);
        a writer uses it too for points that lack the field.
    :param pcd_local: its PCD type in the local frame, when not ``dtype`` (x, y, z: float32).
    """

    name: str
    dtype: str
    meaning: str
    filled_by: str = SCAN
    las: tuple[LasDimension, ...] = ()
    read_from: str = ""
    missing: float = 0
    pcd_local: str = ""

    @property
    def read_dimension(self) -> LasDimension | None:
        """The LAS dimension a reader takes this field from (None: not in LAS files)."""
        if not self.las:
            return None
        return next(d for d in self.las if d.name == (self.read_from or self.las[0].name))


CLASS_DESCRIPTION = "mitsuforest class"   # our class dimension's description begins so (readers tell it by this)

FIELDS: tuple[Field, ...] = (
    Field("treeid", "<u2", "the tree's model number (archetypes from 1, then forest.models; a tree list's rows); "
          "deadwood classes.DEADWOOD_TREEID, or one past the last of N > 10 tree models; else 0",
          las=(extra("treeid", "<u2", "tree model; deadwood max(11,N+1)", 1),)),
    Field("x", "<f8", "m east (local frame; files add origin.offset)", pcd_local="<f4",
          las=(LasDimension("X", "coordinate", COORDINATE_SCALE),)),
    Field("y", "<f8", "m north (local frame; files add origin.offset)", pcd_local="<f4",
          las=(LasDimension("Y", "coordinate", COORDINATE_SCALE),)),
    Field("z", "<f8", "m up (local frame; files add origin.offset)", pcd_local="<f4",
          las=(LasDimension("Z", "coordinate", COORDINATE_SCALE),)),
    Field("classification", "u1", "our class 1-8 (classes.CLASS_NAMES)",
          las=(LasDimension("classification", "asprs"), extra("label", "u1", f"{CLASS_DESCRIPTION} 1-8", 0)),
          read_from="label"),
    Field("instance", "<u4", "the placed object's instance id (0: the ground)",
          las=(extra("instance", "<u4", "object instance id", 2),)),
    Field("object_id", "<u4", "the object's component id (from 1, the ground)",
          las=(extra("object_id", "<u4", "component id", 3),)),
    Field("number_of_returns", "u1", "echoes of the pulse (LAS: at most 15)",
          las=(LasDimension("number_of_returns", "bits", packed="bit_fields", shift=4, width=4),)),
    Field("return_number", "u1", "the echo's number in its pulse, from 1 (LAS: at most 15)",
          las=(LasDimension("return_number", "bits", packed="bit_fields", shift=0, width=4),)),
    Field("intensity", "<f4", "echo amplitude (a white Lambertian target at 1 m = 1); LAS: the sensor's counts",
          las=(LasDimension("intensity", "counts"), extra("amplitude", "<f4", "echo amplitude (white at 1 m=1)", 4)),
          read_from="amplitude"),
    Field("gps_time", "<f8", "s, the pulse's time", las=(LasDimension("gps_time"),)),
    Field("scan_angle", "<f4", "degrees: the beam's angle from the vertical across the heading, positive "
          "right (LAS 1.4; a Risley pair's off-nadir angle)",
          las=(LasDimension("scan_angle", "scaled", SCAN_ANGLE_UNIT),)),
    Field("pulse_id", "<u8", "the survey's pulse number"),
    Field("range", "<f4", "m from the sensor to the echo"),
    Field("species", "u1", "the tree's family code (classes.SPECIES_CODES), 0 elsewhere",
          las=(extra("species", "u1", "tree family code, 0 none", 5),)),
    Field("reflectance", "<f4", "dB: the amplitude over a white Lambertian target's at the same range",
          las=(extra("reflectance", "<f4", "dB: amplitude/white target's", 6),), missing=np.nan),
    # (a LAS writer given points without reflectance derives it from intensity and range: write/las.py)
    Field("point_source_id", "<u2", "the flight line: the leg's number from 1 (0: hand-made pulses)",
          las=(LasDimension("point_source_id"),)),
    Field("height_above_ground", "<f4", "m above the rendered ground at the point's x, y", filled_by=WRITER,
          las=(extra("height_above_ground", "<f4", "m above the terrain", 7),), missing=np.nan),
)

FIELD = {f.name: f for f in FIELDS}
SCAN_FIELDS = tuple(f for f in FIELDS if f.filled_by == SCAN)
WRITER_FIELDS = tuple(f for f in FIELDS if f.filled_by == WRITER)
LAS_FIELDS = tuple(f for f in FIELDS if f.las)          # what our LAS files hold, and their reader returns

POINT_DTYPE = np.dtype([(f.name, f.dtype) for f in SCAN_FIELDS])          # a scan's points
RECORD_DTYPE = np.dtype([(f.name, f.dtype) for f in FIELDS])              # every file's point, in memory
LAS_READ_DTYPE = np.dtype([(f.name, f.dtype) for f in LAS_FIELDS])        # our LAS files read back
LAS_DIMENSION = {d.name: d for f in FIELDS for d in f.las}               # by laspy's name
LAS_EXTRA_DIMENSIONS = tuple(sorted((d for f in FIELDS for d in f.las if d.is_extra), key=lambda d: d.slot))


def with_writer_fields(dtype: np.dtype) -> np.dtype:
    """``dtype`` (a scan's points) followed by the writer's fields."""
    return np.dtype(dtype.descr + [(f.name, f.dtype) for f in WRITER_FIELDS])


def pcd_dtype(dtype: np.dtype, local: bool) -> np.dtype:
    """A PCD's point record of points of ``dtype``: the fields as they are, but x, y, z as float32 in
    the ``local`` frame (``F 4``, which every PCD reader takes as positions); float64 georeferenced,
    which float32 cannot hold to the millimetre."""
    if not local:
        return dtype
    return np.dtype([(n, FIELD[n].pcd_local if n in FIELD and FIELD[n].pcd_local else dtype[n])
                     for n in dtype.names])


_PCD_TYPE = {"u": "U", "i": "I", "f": "F"}


def pcd_type(dtype) -> tuple[str, int]:
    """A numpy scalar type's PCD ``(TYPE, SIZE)``: ``U``, ``I`` or ``F`` and its bytes."""
    dtype = np.dtype(dtype)
    return _PCD_TYPE[dtype.kind], dtype.itemsize


def numpy_type(kind: str, size: int) -> np.dtype:
    """The numpy type of a PCD column's ``TYPE`` and ``SIZE`` (:func:`pcd_type` the other way)."""
    return np.dtype(f"<{kind.lower()}{size}")
