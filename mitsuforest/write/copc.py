"""COPC (cloud-optimised point cloud) output, ``formats: [copc]``: ``<name>.copc.laz``, the points of
our LAS file (same records, classes and extra dimensions, :mod:`.las`) in an octree of LAZ chunks that
viewers stream level by level and laspy's ``CopcReader`` queries by box and level.

laspy (2.7) reads COPC but does not write it; copc-lib (``copclib`` on PyPI) writes it. Memory stays
bounded: batches are spooled to a temporary file beside the output as packed LAS records; on close
one pass over the spool sorts them into spool files: one per level above a level ``P`` chosen so
that each x, y column of level ``P`` holds about :data:`PARTITION_POINTS` points, and one per such
column. Each is then read (a large level's one column at a time) and added node by node.

Octree: the root cube holds every point; a node takes from the points inside it that no coarser node
took the first (in write order) of each cell of an ``R × R × R`` grid over it (``R`` =
:data:`GRID`), the rest go on to its children; the deepest level takes what is left. So every node
with points has a parent with points (a reader walks the hierarchy from the root), and each level is
an even thinning of the cloud.
"""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path

import numpy as np

from ..errors import UserError
from .atomic import naming_errors
from .closing import Closing
from .las import crs_wkt, las_header, las_records

GRID = 128                  # sample cells per node side (COPC spacing at the root = cube side / GRID)
MAX_LEVEL = 14              # the deepest level takes every point left (cells of level 13 are 0.1 mm in a 100 m cube)
PARTITION_POINTS = 1_000_000
CHUNK = 1_000_000           # spooled records read at a time
EXTRA_BYTES = ("LASF_Spec", 4)
POINTS_BY_RETURN = 255      # byte offset of the LAS 1.4 header's 15 points-by-return counts


class CopcStream(Closing):
    """A ``.copc.laz`` written batch by batch (:meth:`write` spools, :meth:`close` builds the octree);
    closing, aborting and refusing writes once closed as :class:`~.closing.Closing`.

    :param path: the output file; its spool is ``path`` + ``.spool`` until close.
    """

    def __init__(self, path, offset, crs: str | None = None, intensity=None):
        try:
            import copclib  # noqa: F401  (here, before a render scans: it is needed only on close)
        except ImportError:
            raise UserError("output.formats: copc needs the copclib package: pip install copclib "
                            "(or mitsuforest[copc])") from None
        self.path = Path(path)
        self.crs = crs
        self.intensity = intensity                  # the sensor's mapping, as in the LAS files
        self.header = las_header(offset, crs, intensity)
        self.record = self.header.point_format.dtype()
        self.count = 0
        self.returns = np.zeros(15, np.int64)      # points by return number, for the header
        self.lo, self.hi = np.full(3, np.iinfo(np.int64).max), np.full(3, np.iinfo(np.int64).min)
        self._spool_path = self.path.with_name(self.path.name + ".spool")
        with naming_errors(self._spool_path):
            self._spool = open(self._spool_path, "wb")   # noqa: SIM115 (closed in close/abort)

    def write(self, points: np.ndarray) -> None:
        self._refuse_if_closed()
        if not len(points):
            return
        records = las_records(self.header, points, intensity=self.intensity)
        xyz = np.column_stack([records["X"], records["Y"], records["Z"]]).astype(np.int64)
        self.lo, self.hi = np.minimum(self.lo, xyz.min(0)), np.maximum(self.hi, xyz.max(0))
        self.returns += np.bincount(np.asarray(las_return_numbers(records)) - 1, minlength=15)[:15]
        with naming_errors(self._spool_path):
            self._spool.write(records.tobytes())
        self.count += len(records)

    def _finish(self) -> None:
        with naming_errors(self._spool_path):
            self._spool.close()
        try:
            with naming_errors(self.path):
                self._write_octree()
        finally:
            self._spool_path.unlink(missing_ok=True)

    def _discard(self) -> None:
        if not self._spool.closed:
            self._spool.close()
        self._spool_path.unlink(missing_ok=True)

    # --- the octree -----------------------------------------------------------------------------------

    def _write_octree(self) -> None:
        import copclib
        if not self.count:                           # no point: a header without nodes
            self.lo = self.hi = np.zeros(3, np.int64)
        scale, offset = np.asarray(self.header.scales), np.asarray(self.header.offsets)
        lo, hi = self.lo * scale + offset, self.hi * scale + offset
        centre = (lo + hi) / 2
        half = max(float((hi - lo).max()) / 2, 1.0) * (1 + 1e-9)
        cube = Cube(centre - half, 2 * half, scale, offset)
        eb_bytes = self.record.itemsize - 30          # point format 6 is 30 bytes before the extra bytes
        config = copclib.CopcConfigWriter(6, copclib.Vector3(*scale), copclib.Vector3(*offset),
                                          crs_wkt(self.crs) if self.crs else "", copclib.EbVlr(eb_bytes))
        writer = copclib.FileWriter(str(self.path), config)
        header = writer.copc_config.las_header
        header.min, header.max = copclib.Vector3(*lo), copclib.Vector3(*hi)
        day = self.header.creation_date                 # our LAS files' date (copc-lib writes day 0 of year 0)
        header.creation_day, header.creation_year = day.timetuple().tm_yday, day.year
        info = writer.copc_config.copc_info
        info.center_x, info.center_y, info.center_z = centre
        info.halfsize, info.spacing = half, 2 * half / GRID
        try:
            for records, keys in self._nodes(cube):
                for key, chunk in _groups(records, keys):
                    writer.AddNode(copclib.VoxelKey(*key), copclib.VectorChar(np.frombuffer(chunk.tobytes(), np.int8)))
        finally:
            writer.Close()
        name_extra_bytes(self.path, self.header)
        with open(self.path, "r+b") as f:             # copc-lib counts no returns in packed records
            f.seek(POINTS_BY_RETURN)
            f.write(struct.pack("<15Q", *self.returns))

    def _nodes(self, cube):
        """``(records, keys (n, 4) level x y z)`` of whole nodes, from spool files beside the output:
        one per level above the column level ``P`` (points taken as the spool is read), then one per
        x, y column of level ``P`` with the levels from ``P`` down."""
        top = _column_level(self.count)
        taken = [np.zeros(0, np.int64) for _ in range(top)]       # occupied sample cells of levels < top
        keyed = np.dtype([("key", "<i8", (4,)), ("record", self.record)])
        spools = Spools(self._spool_path)
        try:
            for records in self._read_spool():
                unit = cube.unit(records)
                level = np.full(len(records), -1, np.int64)
                for lev in range(top):
                    free = np.flatnonzero(level < 0)
                    cells = cube.cells(unit[free], lev, GRID)
                    first = _first_new(cells, taken[lev])
                    level[free[first]] = lev
                    taken[lev] = np.union1d(taken[lev], cells[first])
                for lev in range(top):
                    at = level == lev
                    rows = np.zeros(at.sum(), keyed)
                    rows["key"], rows["record"] = cube.keys(unit[at], level[at]), records[at]
                    spools.add(f"level{lev}", rows)
                rest = level < 0
                column = cube.column(unit[rest], top)
                for c in np.unique(column):
                    spools.add(f"column{c}", records[rest][column == c])
            for lev in range(top):
                for rows in spools.read(f"level{lev}", keyed, by_column=lev):
                    yield rows["record"], rows["key"]
            for name in spools.names("column"):
                records = next(spools.read(name, self.record))
                yield records, _levels_below(cube, records, top)
        finally:
            spools.remove()

    def _read_spool(self):
        size = self.record.itemsize
        with open(self._spool_path, "rb") as f:
            while block := f.read(CHUNK * size):
                yield np.frombuffer(block, self.record)


def _column_level(count: int) -> int:
    """``P``: the octree level whose x, y columns hold about :data:`PARTITION_POINTS` points each (at
    most 4: 256 columns)."""
    return int(np.clip(np.ceil(np.log(max(count, 1) / PARTITION_POINTS) / np.log(4)), 0, 4))


class Spools:
    """Named temporary files beside ``base`` (``base.NAME``), appended to as the spool is read."""

    def __init__(self, base: Path):
        self.base, self.files = base, {}

    def add(self, name: str, rows: np.ndarray) -> None:
        if len(rows):
            if name not in self.files:
                self.files[name] = open(f"{self.base}.{name}", "wb")   # noqa: SIM115 (closed in read/remove)
            self.files[name].write(rows.tobytes())

    def names(self, prefix: str) -> list[str]:
        return [n for n in self.files if n.startswith(prefix)]

    def read(self, name: str, dtype: np.dtype, by_column: int | None = None):
        """The file's rows at once; with ``by_column`` (a level) and more than
        :data:`PARTITION_POINTS` rows, one x, y column of that level at a time (rows keyed)."""
        if name not in self.files:
            return
        self.files[name].close()
        path = f"{self.base}.{name}"
        count = os.path.getsize(path) // dtype.itemsize
        if by_column is None or count <= PARTITION_POINTS:
            yield np.fromfile(path, dtype)
            return
        side = 1 << by_column
        for c in range(side * side):
            parts = []
            with open(path, "rb") as f:
                while block := f.read(CHUNK * dtype.itemsize):
                    rows = np.frombuffer(block, dtype)
                    parts.append(rows[rows["key"][:, 2] * side + rows["key"][:, 1] == c])
            yield np.concatenate(parts)

    def remove(self) -> None:
        for name, f in self.files.items():
            f.close()
            Path(f"{self.base}.{name}").unlink(missing_ok=True)


class Cube:
    """The octree's root cube: ``corner`` (3,) and ``side`` in metres; points as scaled integers."""

    def __init__(self, corner, side: float, scale, offset):
        self.corner, self.side, self.scale, self.offset = np.asarray(corner), side, scale, offset

    def unit(self, records) -> np.ndarray:
        """(n, 3) positions in the cube, in [0, 1)."""
        xyz = np.column_stack([records["X"], records["Y"], records["Z"]]) * self.scale + self.offset
        return np.clip((xyz - self.corner) / self.side, 0, np.nextafter(1.0, 0))

    def keys(self, unit, level) -> np.ndarray:
        """(n, 4) octree keys ``level, x, y, z`` of positions in the cube at their levels."""
        n = (2 ** level)[:, None]
        return np.column_stack([level, np.floor(unit * n).astype(np.int64)])

    @staticmethod
    def cells(unit, level: int, grid: int) -> np.ndarray:
        """(n,) int64 ids of the sample cells (``grid`` per node side) at ``level``."""
        ijk = np.floor(unit * (grid << level)).astype(np.int64)
        width = grid << level
        return (ijk[:, 2] * width + ijk[:, 1]) * width + ijk[:, 0]

    @staticmethod
    def column(unit, level: int) -> np.ndarray:
        """(n,) the x, y column of ``level`` holding each position."""
        ij = np.floor(unit[:, :2] * (1 << level)).astype(np.int64)
        return ij[:, 1] * (1 << level) + ij[:, 0]


def las_return_numbers(records) -> np.ndarray:
    """Return numbers (1-15) of packed point format 6 records (the low 4 bits of their flags byte)."""
    return np.maximum(np.asarray(records["bit_fields"]) & 0x0F, 1)


def _first_new(cells: np.ndarray, taken: np.ndarray) -> np.ndarray:
    """Indices of the first point in each cell that is not in ``taken`` (sorted)."""
    fresh = np.flatnonzero(~np.isin(cells, taken, assume_unique=False))
    _, first = np.unique(cells[fresh], return_index=True)
    return fresh[first]


def _levels_below(cube: Cube, records, top: int) -> np.ndarray:
    """(n, 4) keys of one column's points, levels ``top`` down: each node takes the first point of each
    sample cell, the deepest level the rest."""
    unit = cube.unit(records)
    level = np.full(len(records), -1, np.int64)
    for lev in range(top, MAX_LEVEL):
        free = np.flatnonzero(level < 0)
        if not len(free):
            break
        _, first = np.unique(cube.cells(unit[free], lev, GRID), return_index=True)
        level[free[first]] = lev
    level[level < 0] = MAX_LEVEL
    return cube.keys(unit, level)


def _groups(records, keys):
    """``(key tuple, records)`` per node, in key order."""
    if not len(records):
        return
    order = np.lexsort(keys.T[::-1])
    keys, records = keys[order], records[order]
    starts = np.flatnonzero(np.r_[True, np.any(keys[1:] != keys[:-1], axis=1)])
    for a, b in zip(starts, np.r_[starts[1:], len(keys)]):
        yield tuple(int(v) for v in keys[a]), records[a:b]


def name_extra_bytes(path, header) -> None:
    """Give the extra bytes of a copc-lib file our names and types, in place.

    copc-lib's Python API describes the extra bytes as one unnamed byte each (192 bytes of VLR per
    byte); ours describe one field each, so they are shorter. The rest of the slot becomes our
    ``mitsuforest`` VLR of the LAS file (intensity mapping and class codes; padded with spaces,
    :func:`fitting_note`), so no offset in the file moves.
    """
    ours = header.vlrs.get("ExtraBytesVlr")[0].record_data_bytes()
    note = next(v for v in header.vlrs if v.user_id == "mitsuforest")
    with open(path, "r+b") as f:
        head = f.read(375)
        header_size, = struct.unpack_from("<H", head, 94)
        vlr_count, = struct.unpack_from("<I", head, 100)
        at = header_size
        for _ in range(vlr_count):
            f.seek(at)
            vlr = f.read(54)
            user, record, length = vlr[2:18].rstrip(b"\0").decode(), *struct.unpack_from("<HH", vlr, 18)
            if (user, record) == EXTRA_BYTES:
                spare = length - len(ours) - 54
                if spare < 0:
                    raise ValueError("copc-lib's extra bytes VLR is too short to rename")
                f.seek(at + 20)
                f.write(struct.pack("<H", len(ours)))
                f.seek(at + 54)
                f.write(ours)
                data = fitting_note(note.record_data, spare)
                f.write(struct.pack("<H16sHH32s", 0, b"mitsuforest", note.record_id, spare,
                                    note.description.encode()[:32]))
                f.write(data.ljust(spare))
                f.seek(100)
                f.write(struct.pack("<I", vlr_count + 1))
                return
            at += 54 + length
    raise ValueError(f"{path}: no extra bytes VLR")


def fitting_note(data: bytes, room: int) -> bytes:
    """Our ``mitsuforest`` note (:func:`~.las.las_header`'s JSON) in at most ``room`` bytes: as it is, or
    without its ``crs`` (the scene's ``origin.crs`` as given: WKT can take thousands of bytes), which the
    file holds in its own WKT record, so that the intensity mapping and the class codes stay; empty
    only when even they do not fit."""
    if len(data) <= room:
        return data
    note = json.loads(data)
    note.pop("crs", None)
    data = json.dumps(note).encode()
    return data if len(data) <= room else b""
