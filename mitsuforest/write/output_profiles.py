"""Output profiles: point files that other projects' training code reads as it is (README, "Output
profiles"). ``output.profile`` names one; a render then writes ``<name><suffix>`` beside its usual files,
and a dataset writes one per tile too.

Each profile is one entry of :data:`PROFILES`: a file suffix and a stream class with ``write(points)``
(georeferenced points, as the PCD holds them, with ``height_above_ground``), ``close()`` and
``abort()``, so a render writes it batch by batch in bounded memory. The label mappings are lookup
tables over our classes (:mod:`mitsuforest.classes`); a tree's id in every profile is its ``instance``
(one id per tree, the same in every tile), and 0 on everything that is not a tree.

- ``for-instance``: LAS 1.4 / LAZ with the FOR-instance dataset's classes (0 unclassified, 1 low
  vegetation, 2 terrain, 3 out-points, 4 stem, 5 live branches, 6 woody branches) and its ``treeID``
  extra dimension, as ForAINet, SegmentAnyTree and TreeLearn read it.
- ``forestformer3d``: binary PLY with ``x y z`` (double), ``semantic_seg`` (1 ground, 2 wood, 3 leaf)
  and ``treeID`` (int), as ForestFormer3D's ``ForAINetV2`` loader reads it.
- ``treelearn``: a ``.npy`` array (N, 4) of ``x, y, z, label`` (float64; label 0 non-tree, 1.. trees),
  x, y, z in the local frame, as TreeLearn's ``load_data`` reads it.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import struct
from dataclasses import dataclass
from pathlib import Path

import laspy
import numpy as np

from ..classes import (BUSH, DEADWOOD, GROUND, GROUND_VEGETATION, ROCK, STUMP, TREE_LEAVES, TREE_WOOD)
from ..config.types import IntensityMapping
from ..fields import LAS_DIMENSION, SCAN_ANGLE_UNIT
from ..scan.radiometry import intensity_counts
from .atomic import atomic_path, naming_errors
from .closing import Closing
from .las import LAS_MAX_RETURNS, LasStream, extra_bytes, format6_header, point_reflectance

TREE_CLASSES = (TREE_WOOD, TREE_LEAVES)


def sensor_intensity(points: np.ndarray, intensity: IntensityMapping | None) -> np.ndarray:
    """(N,) uint16 intensity by the sensor's mapping (by default amplitude × 1e6), as in our LAS files."""
    return intensity_counts(points["intensity"], point_reflectance(points), intensity or IntensityMapping())


def _lookup(mapping: dict, default: int) -> np.ndarray:
    table = np.full(256, default, np.int32)
    for code, value in mapping.items():
        table[code] = value
    return table


def tree_ids(points: np.ndarray) -> np.ndarray:
    """(n,) int32: each point's tree (its ``instance``) on tree wood and leaves, else 0."""
    return np.where(np.isin(points["classification"], TREE_CLASSES), points["instance"], 0).astype(np.int32)


# --- FOR-instance (LAS/LAZ) -------------------------------------------------------------------------

FOR_INSTANCE_NAMES = {0: "unclassified", 1: "low vegetation", 2: "terrain", 3: "out-points", 4: "stem",
                      5: "live branches", 6: "woody branches"}
FOR_INSTANCE_STEM, FOR_INSTANCE_BRANCH = 4, 6
# Tree wood is 4 (stem) or 6 (woody branches) by its component, see for_instance_classes.
FOR_INSTANCE_CLASS = _lookup({GROUND: 2, TREE_WOOD: FOR_INSTANCE_BRANCH, TREE_LEAVES: 5, DEADWOOD: 1, ROCK: 2,
                              STUMP: 1, BUSH: 1, GROUND_VEGETATION: 1}, 0)


def for_instance_classes(points: np.ndarray, stems: np.ndarray) -> np.ndarray:
    """(n,) uint8 FOR-instance classes; tree wood is a stem (4) when its ``object_id`` is in ``stems``
    (sorted object ids of stem components), else a woody branch (6)."""
    out = FOR_INSTANCE_CLASS[points["classification"]]
    stem = (points["classification"] == TREE_WOOD) & np.isin(points["object_id"], stems)
    return np.where(stem, FOR_INSTANCE_STEM, out).astype(np.uint8)


def for_instance_header(offset, crs: str | None, intensity: IntensityMapping | None = None) -> laspy.LasHeader:
    """LAS 1.4 point format 6 with the extra dimensions ``treeID`` (int32), ``label`` (our class) and
    ``height_above_ground``; offsets, scales, the CRS, the creation date and the intensity mapping as in
    our LAS files."""
    note = {"profile": "for-instance", "classification": FOR_INSTANCE_NAMES,
            "intensity": dataclasses.asdict(intensity or IntensityMapping())}
    return format6_header(offset, crs, [
        laspy.ExtraBytesParams("treeID", np.int32, "tree id, 0 for non-tree"),
        extra_bytes(LAS_DIMENSION["label"]),                      # as in our own LAS files
        extra_bytes(LAS_DIMENSION["height_above_ground"]),
    ], laspy.VLR("mitsuforest", 2, "FOR-instance classes", json.dumps(note).encode()))


def for_instance_points(header: laspy.LasHeader, points: np.ndarray, stems: np.ndarray,
                        intensity: IntensityMapping | None = None) -> laspy.ScaleAwarePointRecord:
    """Georeferenced points as FOR-instance records of ``header``: their intensity by the sensor's mapping, and
    return numbers, GPS time, scan angle and flight line (``point_source_id``) as in our LAS files."""
    las = laspy.ScaleAwarePointRecord.zeros(len(points), header=header)
    las.x, las.y, las.z = points["x"], points["y"], points["z"]
    las.classification = for_instance_classes(points, stems)
    las.return_number = np.minimum(points["return_number"], LAS_MAX_RETURNS)
    las.number_of_returns = np.minimum(points["number_of_returns"], LAS_MAX_RETURNS)
    las.intensity = sensor_intensity(points, intensity)
    las.gps_time = points["gps_time"]
    las.scan_angle = np.round(points["scan_angle"] / SCAN_ANGLE_UNIT).astype(np.int16)
    las.point_source_id = points["point_source_id"]
    las.treeID = tree_ids(points)
    las.label = points["classification"]
    las.height_above_ground = points["height_above_ground"]
    return las


class ForInstanceStream(LasStream):
    """A FOR-instance style ``.las``/``.laz`` written batch by batch (:func:`for_instance_header`); closing,
    aborting and error reports as our own LAS stream's."""

    def __init__(self, path, offset, crs: str | None, stems: np.ndarray, intensity: IntensityMapping | None = None):
        super().__init__(path, offset, crs, threads=1, header=for_instance_header(offset, crs, intensity),
                         intensity=intensity)
        self.stems = np.asarray(stems)

    def write(self, points: np.ndarray) -> None:
        self.write_records(for_instance_points(self.header, points, self.stems, self.intensity).array)


# --- ForestFormer3D (binary PLY) ---------------------------------------------------------------------

FF3D_NAMES = {1: "ground", 2: "wood", 3: "leaf"}
FF3D_CLASS = _lookup({GROUND: 1, TREE_WOOD: 2, TREE_LEAVES: 3}, 1)   # everything else is ground (stuff)
FF3D_FIELDS = [("x", "<f8", "double"), ("y", "<f8", "double"), ("z", "<f8", "double"),
               ("semantic_seg", "<i4", "int"), ("treeID", "<i4", "int"),
               ("intensity", "<u2", "ushort"), ("return_number", "u1", "uchar"),
               ("number_of_returns", "u1", "uchar"), ("height_above_ground", "<f4", "float")]
FF3D_DTYPE = np.dtype([(n, t) for n, t, _ in FF3D_FIELDS])
COUNT_DIGITS = 20   # the vertex count is written zero-padded, then filled in on close


def ply_header(count: int) -> bytes:
    """A binary little-endian PLY header of one ``vertex`` element of :data:`FF3D_FIELDS`. No comment
    lines: ForestFormer3D's reader takes any header line holding "element" or "property" as one."""
    lines = ["ply", "format binary_little_endian 1.0", f"element vertex {count:0{COUNT_DIGITS}d}",
             *(f"property {kind} {name}" for name, _, kind in FF3D_FIELDS), "end_header"]
    return ("\n".join(lines) + "\n").encode("ascii")


class _CountedFile(Closing):
    """A binary file whose header holds the record count, rewritten in place on close; closing, aborting
    and refusing writes once closed as :class:`~.closing.Closing`."""

    def __init__(self, path, header):
        self.path, self._header, self.count = Path(path), header, 0
        with naming_errors(self.path):
            self._file = open(self.path, "wb")   # noqa: SIM115 (closed in close/abort)
            self._file.write(header(0))

    def append(self, records: np.ndarray) -> None:
        self._refuse_if_closed()
        with naming_errors(self.path):
            self._file.write(np.ascontiguousarray(records).data)
        self.count += len(records)

    def _finish(self) -> None:
        with naming_errors(self.path):
            self._file.seek(0)
            self._file.write(self._header(self.count))
            self._file.close()

    def _discard(self) -> None:
        self._file.close()


class ForestFormer3DStream(Closing):
    """A ForestFormer3D PLY (:data:`FF3D_FIELDS`), written batch by batch; x, y, z georeferenced."""

    def __init__(self, path, offset, crs: str | None, stems: np.ndarray, intensity: IntensityMapping | None = None):
        self._file = _CountedFile(path, ply_header)
        self.path = self._file.path
        self.intensity = intensity

    def write(self, points: np.ndarray) -> None:
        self._refuse_if_closed()
        out = np.zeros(len(points), FF3D_DTYPE)
        for axis in "xyz":
            out[axis] = points[axis]
        out["semantic_seg"] = FF3D_CLASS[points["classification"]]
        out["treeID"] = tree_ids(points)
        out["intensity"] = sensor_intensity(points, self.intensity)
        out["return_number"] = np.minimum(points["return_number"], 255)
        out["number_of_returns"] = np.minimum(points["number_of_returns"], 255)
        out["height_above_ground"] = points["height_above_ground"]
        self._file.append(out)

    def _finish(self) -> None:
        self._file.close()

    def _discard(self) -> None:
        self._file.abort()


# --- TreeLearn (.npy) ---------------------------------------------------------------------------------

NPY_HEADER_BYTES = 128   # magic, version, length and the padded dict: room for a 20-digit row count


def npy_header(rows: int) -> bytes:
    """A version 1.0 ``.npy`` header of a C-ordered float64 (rows, 4) array, always 128 bytes long."""
    text = "{'descr': '<f8', 'fortran_order': False, 'shape': (%d, 4), }" % rows
    room = NPY_HEADER_BYTES - 10
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", room) + (text.ljust(room - 1) + "\n").encode("latin1")


class TreeLearnStream(Closing):
    """A TreeLearn ``.npy``: float64 rows ``x, y, z, label`` (local frame; label 0 for non-tree points,
    the tree's id from 1 on), written batch by batch."""

    def __init__(self, path, offset, crs: str | None, stems: np.ndarray, intensity: IntensityMapping | None = None):
        self.offset = np.asarray(offset, np.float64)
        self._file = _CountedFile(path, npy_header)
        self.path = self._file.path

    def write(self, points: np.ndarray) -> None:
        self._refuse_if_closed()
        rows = np.column_stack([points["x"] - self.offset[0], points["y"] - self.offset[1],
                                points["z"] - self.offset[2], tree_ids(points)]).astype(np.float64)
        self._file.append(rows)

    def _finish(self) -> None:
        self._file.close()

    def _discard(self) -> None:
        self._file.abort()


# --- the registry ----------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Profile:
    suffix: str        # after the render's or tile's name
    stream: type       # (path, offset, crs, stems, intensity) -> a stream with write (a :class:`~.closing.Closing`)


PROFILES = {
    "for-instance": Profile("_forinstance.laz", ForInstanceStream),
    "forestformer3d": Profile("_ff3d.ply", ForestFormer3DStream),
    "treelearn": Profile("_treelearn.npy", TreeLearnStream),
}
PROFILE_SUFFIXES = tuple(p.suffix for p in PROFILES.values())


def write_profile(path, name: str, points: np.ndarray, offset, crs: str | None, stems,
                  intensity: IntensityMapping | None = None) -> None:
    """Write ``points`` (georeferenced) at once as profile ``name``'s file, atomically, their intensity by
    the sensor's mapping ``intensity`` (by default amplitude × 1e6)."""
    with atomic_path(path) as tmp, PROFILES[name].stream(tmp, offset, crs, stems, intensity) as stream:
        stream.write(points)


def stem_ids(plan, models: dict) -> np.ndarray:
    """Sorted object ids of the stem components of the plan's objects (FOR-instance class 4)."""
    ids = [obj.object_id + k for obj in plan.objects
           for k, comp in enumerate(models[obj.model].components) if comp.kind == "stem"]
    return np.unique(np.asarray(ids, np.int64))


def stem_ids_from_table(path) -> np.ndarray:
    """Sorted object ids of the stems listed in a render's ``_ids.csv``."""
    with open(path, newline="") as f:
        ids = [int(row["object_id"]) for row in csv.DictReader(f) if row["kind"] == "stem"]
    return np.unique(np.asarray(ids, np.int64))
