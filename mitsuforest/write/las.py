"""LAS 1.4 / LAZ (point format 6) through laspy.

Every field's dimensions are declared in :mod:`mitsuforest.fields`, from which the header, the records
and the reader are made. Classification uses ASPRS codes where they fit — ground 2, ground vegetation 3 (low vegetation), bush 4
(medium vegetation), tree wood and leaves 5 (high vegetation) — and the user range for the rest: deadwood 64, rock 65, stump 66. Our own
classes (1-8, as in the PCD) are in the extra dimension ``label``; ``treeid``, ``instance``,
``object_id``, ``species`` (classes.SPECIES_CODES, also in the VLR) and ``height_above_ground`` (float32 m,
see write/ground.py) are extra dimensions too. Intensity is
the sensor's 16-bit counts (its ``intensity`` mapping: gain, offset and saturation applied to the
amplitude or the reflectance, :func:`~mitsuforest.scan.radiometry.intensity_counts`; the mapping is
written in the header's VLR): the float amplitude is kept exact in the extra dimension ``amplitude``,
and the RIEGL-style reflectance (dB) in ``reflectance``. Return numbers and counts above 15, which point format 6 cannot hold
(a pulse with more echoes than that needs over 15 sub-rays and ``max_returns`` 0 or above 15), are
written as 15; the PCD keeps them. Coordinates are stored at 0.1 mm with the
georeference in the header offsets. The scene's ``origin.crs`` is written as the standard OGC WKT
coordinate system VLR, which PDAL, QGIS and lidR read; each point's ``point_source_id`` is its flight
line (the leg's number from 1); the WKT bit of the global encoding is set,
as LAS 1.4 requires for point format 6 (with or without a CRS).
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import errno
import io
import json
import os
import struct
from pathlib import Path

import laspy
import numpy as np
from laspy._pointwriter import IPointWriter
from laspy.vlrs.known import LasZipVlr, WktCoordinateSystemVlr

from ..classes import BUSH, DEADWOOD, GROUND, GROUND_VEGETATION, ROCK, SPECIES_CODES, STUMP, TREE_LEAVES, TREE_WOOD
from ..config.types import IntensityMapping
from ..crs import crs_wkt
from ..errors import UserError
from ..fields import (COORDINATE_SCALE, LAS_DIMENSION, LAS_EXTRA_DIMENSIONS, LAS_FIELDS, LAS_FORMAT, LAS_READ_DTYPE,
                      LasDimension)
from ..scan.radiometry import intensity_counts, reflectance_db
from .atomic import atomic_path, naming_errors
from .closing import Closing

ASPRS_CODE = {GROUND: 2, TREE_WOOD: 5, TREE_LEAVES: 5, BUSH: 4, GROUND_VEGETATION: 3, DEADWOOD: 64, ROCK: 65, STUMP: 66}
LAS_MAX_RETURNS = (1 << LAS_DIMENSION["return_number"].width) - 1   # 15: 4 bits; the PCD keeps larger counts
DEFAULT_CREATION_DATE = datetime.date(2000, 1, 1)   # the header's date without SOURCE_DATE_EPOCH (not today)

try:
    import lazrs
    CODEC_ERRORS: tuple = (lazrs.LazrsError,)
except ImportError:          # laspy without the lazrs backend writes no LAZ
    lazrs = None
    CODEC_ERRORS = ()


def creation_date() -> datetime.date:
    """The header's file creation date: the UTC day of ``SOURCE_DATE_EPOCH`` when it is set (the
    reproducible-builds convention), else :data:`DEFAULT_CREATION_DATE`, never the day of the run, so a
    scene gives the same bytes on any day."""
    epoch = os.environ.get("SOURCE_DATE_EPOCH", "").strip()
    if not epoch:
        return DEFAULT_CREATION_DATE
    try:
        return datetime.datetime.fromtimestamp(int(epoch), datetime.timezone.utc).date()
    except (ValueError, OverflowError, OSError):
        raise UserError(f"SOURCE_DATE_EPOCH: must be whole seconds since 1970-01-01 UTC, got {epoch!r}") from None


def las_header(offset, crs: str | None = None, intensity: IntensityMapping | None = None) -> laspy.LasHeader:
    """A LAS 1.4 point format 6 header with our extra dimensions, the coding VLR (with the sensor's
    ``intensity`` mapping, by default amplitude × 1e6) and, when ``crs`` is given, its WKT VLR (see
    :func:`crs_wkt`, which raises :class:`UserError` for a bad one)."""
    intensity = intensity or IntensityMapping()
    note = {"intensity": dataclasses.asdict(intensity), "classification": {str(k): v for k, v in ASPRS_CODE.items()},
            "species": {str(v): k for k, v in SPECIES_CODES.items()}, "crs": crs}
    return format6_header(offset, crs, [extra_bytes(d) for d in LAS_EXTRA_DIMENSIONS],
                          laspy.VLR("mitsuforest", 1, "intensity and classes", json.dumps(note).encode()))


def extra_bytes(dimension: LasDimension) -> laspy.ExtraBytesParams:
    """laspy's declaration of an extra-bytes dimension of :mod:`mitsuforest.fields`."""
    return laspy.ExtraBytesParams(dimension.name, np.dtype(dimension.dtype), dimension.description)


def format6_header(offset, crs: str | None, extra_dims: list, note: laspy.VLR) -> laspy.LasHeader:
    """A LAS 1.4 point format 6 header: 0.1 mm coordinates from ``offset``, the ``extra_dims``
    (``laspy.ExtraBytesParams``) without partial statistics, our ``note`` VLR, the WKT VLR of ``crs``
    when given, and the :func:`creation_date`."""
    header = laspy.LasHeader(point_format=LAS_FORMAT, version="1.4")
    header.creation_date = creation_date()
    header.offsets = np.asarray(offset, float)
    header.scales = np.full(3, COORDINATE_SCALE)
    header.add_extra_dims(extra_dims)
    _without_extra_statistics(header)
    header.vlrs.append(note)
    header.global_encoding.wkt = True  # LAS 1.4 requires it for point formats 6-10; PDAL refuses files without
    if crs:
        header.vlrs.append(WktCoordinateSystemVlr(crs_wkt(crs)))
    return header


def _without_extra_statistics(header: laspy.LasHeader) -> None:
    """Clear the optional min/max of each extra dimension: laspy fills them from the first batch only
    (a LAZ file's VLRs are written before its points), which is wrong and depends on the batch size."""
    for struct in header.vlrs.get("ExtraBytesVlr")[0].extra_bytes_structs:
        struct.options &= ~(struct.MIN_BIT_MASK | struct.MAX_BIT_MASK)


def las_points(header: laspy.LasHeader, points: np.ndarray, intensity: IntensityMapping | None = None) -> laspy.LasData:
    """Georeferenced points (x, y, z include the offset) as a LasData of ``header``'s format, their
    intensity in counts by the sensor's ``intensity`` mapping (by default amplitude × 1e6)."""
    record = laspy.PackedPointRecord(las_records(header, points, intensity=intensity), header.point_format)
    return laspy.LasData(header, points=record)


def las_records(header: laspy.LasHeader, points: np.ndarray, out: np.ndarray | None = None,
                intensity: IntensityMapping | None = None) -> np.ndarray:
    """Georeferenced points as the packed point records of ``header``'s format (its
    ``point_format.dtype()``), computed as laspy computes them from scaled values, their intensity in
    counts by the sensor's ``intensity`` mapping (by default amplitude × 1e6); filled into ``out``
    (rows of a larger array, say) when given.

    :raises OverflowError: a coordinate that the header's scale and offset cannot hold.
    """
    out = np.empty(len(points), header.point_format.dtype()) if out is None else out
    if out.flags.c_contiguous:      # one pass over the bytes: a field at a time costs four times as much
        out.view(np.uint8).fill(0)
    else:
        for name in _unfilled(out.dtype):
            out[name] = 0
    names = points.dtype.names
    reflectance = point_reflectance(points)
    for field in LAS_FIELDS:
        if field.name == "reflectance":
            value = reflectance
        elif field.name in names:
            value = points[field.name]
        else:                      # points of an earlier version (no species, point_source_id...)
            value = np.full(len(points), field.missing, field.dtype)
        for dimension in field.las:
            _encode(out, dimension, value, header, reflectance, intensity)
    return out


def _unfilled(record: np.dtype) -> list[str]:
    """A record's fields that no field fills (classification_flags, user_data) and the bytes that
    fields are packed into (bit_fields): zeroed first."""
    filled = {d.name for f in LAS_FIELDS for d in f.las}
    return [n for n in record.names if n not in filled]


def _encode(out: np.ndarray, dimension: LasDimension, value: np.ndarray, header: laspy.LasHeader,
            reflectance: np.ndarray, intensity: IntensityMapping | None) -> None:
    """Store one field's ``value`` in ``dimension`` of the records ``out`` (see
    :class:`~mitsuforest.fields.LasDimension`), as laspy would from the scaled values."""
    name, encoding = dimension.name, dimension.encoding
    if encoding == "coordinate":
        axis = "XYZ".index(name)
        coordinate = np.round((value - header.offsets[axis]) / header.scales[axis])  # laspy's ScaledArrayView
        if len(coordinate) and (coordinate.max() > _INT32.max or coordinate.min() < _INT32.min):
            raise OverflowError("Values given do not fit after applying offset and scale")
        out[name] = coordinate
    elif encoding == "bits":
        out[dimension.packed] |= np.minimum(value, (1 << dimension.width) - 1) << dimension.shift
    elif encoding == "asprs":
        out[name] = _ASPRS_LOOKUP[value]
    elif encoding == "scaled":
        out[name] = np.round(value / dimension.scale).astype(out.dtype[name])
    elif encoding == "counts":
        out[name] = intensity_counts(value, reflectance, intensity or IntensityMapping())
    else:                                              # copy, extra
        out[name] = value


def point_reflectance(points: np.ndarray) -> np.ndarray:
    """The points' reflectance (dB): their own, or from amplitude and range, or NaN without a range."""
    names = points.dtype.names
    if "reflectance" in names:
        return points["reflectance"]
    if "range" in names:
        return reflectance_db(points["intensity"], points["range"]).astype(np.float32)
    return np.full(len(points), np.nan, np.float32)


_INT32 = np.iinfo(np.int32)
_ASPRS_LOOKUP = np.zeros(256, np.uint8)
for _code, _asprs in ASPRS_CODE.items():
    _ASPRS_LOOKUP[_code] = _asprs

LAZ_CHUNK = 50_000   # points per LAZ chunk (lazrs' default); chunks are compressed independently
MAX_CHUNKS_PER_CALL = 16   # LAZ records held back for one call: at most 37 MB


def laz_vlr(point_format) -> lazrs.LazVlr:
    """The LasZip VLR that lazrs writes for ``point_format`` (chunks of :data:`LAZ_CHUNK` points)."""
    return lazrs.LazVlr.new_for_compression(point_format.id, point_format.num_extra_bytes)


def compress_chunks(header: laspy.LasHeader, records: np.ndarray) -> tuple[bytes, list[tuple[int, int]]]:
    """Packed point ``records`` of ``header``'s format compressed as LAZ chunks of :data:`LAZ_CHUNK`
    points (each chunk on its own, as lazrs' writer compresses it): the chunks' bytes, and their (point
    count, byte count) entries of the chunk table, for :meth:`LasStream.write_chunks`."""
    vlr = laz_vlr(header.point_format)
    compressed = lazrs.compress_points(vlr, records.view(np.uint8).reshape(-1), False)
    table = lazrs.read_chunk_table(io.BytesIO(compressed), vlr)   # after the 8-byte offset to the table
    return bytes(compressed[8:8 + sum(size for _, size in table)]), table


@dataclasses.dataclass
class HeaderSummary:
    """What laspy's header takes from a file's points (``LasHeader.grow``), of some records alone: the
    count, the least and greatest X, Y, Z (stored integers), GPS times and the points by return number."""

    count: int
    lowest: tuple
    highest: tuple
    gps_time: tuple
    return_numbers: tuple

    @classmethod
    def of(cls, records: np.ndarray, point_format: laspy.PointFormat) -> HeaderSummary:
        points = laspy.PackedPointRecord(records, point_format)
        lowest = tuple(points[axis].min() for axis in "XYZ")
        highest = tuple(points[axis].max() for axis in "XYZ")
        return cls(len(records), lowest, highest, (points["gps_time"].min(), points["gps_time"].max()),
                   tuple(np.unique(points.return_number, return_counts=True)))

    def grow(self, header: laspy.LasHeader) -> None:
        """``header.grow`` of the records summed up, with its arithmetic."""
        for axis, low, high in zip("xyz", self.lowest, self.highest):
            scale, offset = getattr(header, axis + "_scale"), getattr(header, axis + "_offset")
            setattr(header, axis + "_max", max(getattr(header, axis + "_max"), (high * scale) + offset))
            setattr(header, axis + "_min", min(getattr(header, axis + "_min"), (low * scale) + offset))
        header.max_gps_time = max(header.max_gps_time, self.gps_time[1])
        header.min_gps_time = min(header.min_gps_time, self.gps_time[0])
        by_return = header.number_of_points_by_return
        for return_number, count in zip(*self.return_numbers):
            if return_number == 0:
                continue
            if return_number > len(by_return):
                break
            by_return[return_number - 1] += count
        header.point_count += self.count


class _ChunkWriter(IPointWriter):
    """laspy's point writer for a LAZ file whose chunks come compressed (:func:`compress_chunks`):
    written in order, then the chunk table and its offset, as lazrs' writer lays them out."""

    def __init__(self, dest, point_format):
        self.dest = dest
        self.vlr = laz_vlr(point_format)
        self._table: list = []
        self._table_offset_at = None

    @property
    def destination(self):
        return self.dest

    def write_initial_header_and_vlrs(self, header, encoding_errors) -> None:
        header.vlrs.append(LasZipVlr(self.vlr.record_data()))
        super().write_initial_header_and_vlrs(header, encoding_errors)
        self._table_offset_at = self.dest.tell()
        self.dest.write(struct.pack("<q", -1))         # the chunk table's offset, known once it is written

    def write_points(self, points) -> None:
        raise TypeError("this LAZ file takes compressed chunks (LasStream.write_chunks)")

    def write_chunks(self, data: bytes, table: list) -> None:
        self.dest.write(data)
        self._table += table

    def done(self) -> None:
        table_at = self.dest.tell()
        lazrs.write_chunk_table(self.dest, self._table, self.vlr)
        end = self.dest.tell()
        self.dest.seek(self._table_offset_at)
        self.dest.write(struct.pack("<q", table_at))
        self.dest.seek(end)


class _ChunkBackend:
    """A laspy LAZ backend (what ``laz_backend`` takes) whose writer takes compressed chunks."""

    def is_available(self) -> bool:
        return True

    def create_writer(self, dest, header) -> _ChunkWriter:
        return _ChunkWriter(dest, header.point_format)


class LasStream(Closing):
    """A ``.las`` or ``.laz`` file written batch by batch (laspy updates the header on close).

    As a context manager it is closed at the end of the block, or, after an error, closed without
    raising again; once closed it refuses writes.

    :param compress: LAZ compression; by default when ``path`` ends in ``.laz``.
    :param threads: LAZ compression threads: 1 compresses serially in the writing thread, more
        compresses ``threads`` chunks (at most 16) at a time with lazrs' parallel compressor (the
        same bytes).
    :param intensity: the sensor's intensity mapping (by default amplitude × 1e6).
    :param header: another header than ours (:func:`las_header`), for records the caller packs
        (:meth:`write_records`).
    :param chunks: a LAZ file that takes its points as chunks compressed elsewhere (:meth:`write_chunks`),
        and only so.
    """

    def __init__(self, path, offset, crs: str | None = None, compress: bool | None = None, threads: int = 2,
                 intensity: IntensityMapping | None = None, header: laspy.LasHeader | None = None,
                 chunks: bool = False):
        self.path = Path(path)
        self.intensity = intensity
        self.header = header or las_header(offset, crs, intensity)
        compress = str(path).endswith(".laz") if compress is None else compress
        backend = laspy.LazBackend.LazrsParallel if threads > 1 else laspy.LazBackend.Lazrs
        if chunks:
            backend, compress = _ChunkBackend(), True
        with self._io_errors():
            self._writer = laspy.open(str(path), mode="w", header=self.header, do_compress=compress,
                                      laz_backend=backend if compress else None)
        # Whole chunks for every thread per call: lazrs compresses the full chunks of one call in parallel.
        self._block = min(threads, MAX_CHUNKS_PER_CALL) * LAZ_CHUNK if compress and threads > 1 else 0
        self._buffer = np.empty(0, self.header.point_format.dtype())    # records not yet written, then room
        self._held = 0

    def write(self, points: np.ndarray) -> None:
        """Write georeferenced points (x, y, z include the offset)."""
        las_records(self.header, points, self.reserve(len(points)), self.intensity)
        self.commit(len(points))

    def write_chunks(self, data: bytes, table: list[tuple[int, int]], summary: HeaderSummary) -> None:
        """Write LAZ chunks compressed elsewhere (:func:`compress_chunks`), in the file's order, and their
        points' :class:`HeaderSummary` (a stream made with ``chunks``)."""
        self._refuse_if_closed()
        summary.grow(self._writer.header)
        with self._io_errors():
            self._writer.point_writer.write_chunks(data, table)

    def write_records(self, records: np.ndarray) -> None:
        """Write packed point records (:func:`las_records`)."""
        self.reserve(len(records))[:] = records
        self.commit(len(records))

    def reserve(self, count: int) -> np.ndarray:
        """Rows for the next ``count`` records, for the caller to fill (threads may fill parts of it)
        before :meth:`commit`: a buffer reused from batch to batch."""
        self._refuse_if_closed()
        need = self._held + count
        if len(self._buffer) < need:
            grown = np.empty(max(need, self._block + count), self._buffer.dtype)
            grown[:self._held] = self._buffer[:self._held]
            self._buffer = grown
        return self._buffer[self._held:need]

    def commit(self, count: int) -> None:
        """Write the ``count`` records filled in since :meth:`reserve`. A LAZ file compressed on
        several threads takes them once a whole chunk for every thread has gathered, and whole chunks
        only: lazrs compresses the full chunks of a call in parallel, but would complete a chunk left
        over from the call before on the calling thread alone."""
        self._refuse_if_closed()
        self._held += count
        if self._held and self._held >= self._block:
            self._write_held(whole_chunks=self._block > 0)

    def _write_held(self, whole_chunks: bool = False) -> None:
        ready = self._held - self._held % LAZ_CHUNK if whole_chunks else self._held
        records = laspy.PackedPointRecord(self._buffer[:ready], self._writer.header.point_format)
        with self._io_errors():
            self._writer.write_points(records)
        rest = self._held - ready                     # under one chunk, so it does not overlap its new place
        self._buffer[:rest] = self._buffer[ready:self._held]
        self._held = rest

    def _finish(self) -> None:
        """Write what is held back and finish the file."""
        if self._held:
            self._write_held()
        self._buffer = self._buffer[:0].copy()     # lets the buffer go
        with self._io_errors():
            self._writer.close()

    def _discard(self) -> None:
        """Close, unless closed already (laspy cannot close twice); any error of a broken file is moot
        (closing flushes, and on a full disk the LAZ compressor fails again)."""
        self._buffer, self._held = self._buffer[:0].copy(), 0
        if self._writer.done:
            return
        for finish in (self._writer.close, self._writer.dest.close):   # the file stays open if closing failed
            try:
                finish()
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


def write_las(path, points: np.ndarray, offset, crs: str | None = None, intensity: IntensityMapping | None = None) -> None:
    """Write georeferenced points (x, y, z already include ``offset``) to ``.las`` or ``.laz`` at once."""
    with atomic_path(path) as tmp:
        with LasStream(tmp, offset, crs, compress=str(path).endswith(".laz"),
                       intensity=intensity) as stream:
            stream.write(points)


def read_las_points(path) -> np.ndarray:
    """The points of one of our ``.las``/``.laz`` files (a tile's too) under the PCD's field names:
    ``classification`` is our class (the ``label`` dimension), ``intensity`` the float amplitude; x, y,
    z georeferenced. No ``pulse_id`` or ``range``, which the LAS file does not hold; a dimension that a
    file of an earlier version lacks reads 0 (``species``) or NaN (``reflectance``,
    ``height_above_ground``)."""
    return las_data_points(laspy.read(str(path)))


def las_data_points(las: laspy.LasData) -> np.ndarray:
    """:func:`read_las_points` of points in memory (:func:`las_points`): what a file of them reads back."""
    held = set(las.point_format.dimension_names)
    out = np.zeros(len(las.points), LAS_READ_DTYPE)
    for field in LAS_FIELDS:
        dimension = field.read_dimension
        if dimension.encoding == "coordinate":
            out[field.name] = np.asarray(getattr(las, field.name))      # scaled and offset by laspy
        elif dimension.name not in held:
            out[field.name] = field.missing
        elif dimension.encoding == "scaled":
            out[field.name] = np.asarray(las[dimension.name]) * dimension.scale
        else:
            out[field.name] = np.asarray(las[dimension.name])
    return out
