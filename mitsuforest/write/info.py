"""Summaries of point files we write (PCD or LAS/LAZ), for ``mitsuforest info``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..classes import CLASS_NAMES
from ..errors import UserError
from ..fields import CLASS_DESCRIPTION, FIELD
from .formats import format_of
from .pcd import PointFileError, our_names, read_pcd

# ASPRS LAS 1.4 classes, for files of other tools (ours carry our own classes in ``label``).
ASPRS_NAMES = {0: "never classified", 1: "unclassified", 2: "ground", 3: "low vegetation", 4: "medium vegetation",
               5: "high vegetation", 6: "building", 7: "low point (noise)", 9: "water", 10: "rail",
               11: "road surface", 13: "wire guard", 14: "wire conductor", 15: "transmission tower",
               17: "bridge deck", 18: "high noise"}
ASPRS_CLASSES = {k: f"{v} (ASPRS {k})" for k, v in ASPRS_NAMES.items()}   # another tool's file's class names
OUR_PCD_LABELS = ("classification", "instance", "object_id")               # every PCD we write holds them


def load_points(path) -> tuple[dict, list[str], dict]:
    """The file's columns by name, its field names, and the names of its class codes (ours where the
    file is ours: a LAS with our ``label``, a PCD with our label fields; else ASPRS's)."""
    path = Path(path)
    if not path.is_file():
        raise UserError(_not_a_file(path))
    load = _LOADERS.get(format_of(path))
    try:
        if load:
            return load(path)
    except PointFileError as e:
        raise UserError(f"{path}: {e}") from None
    except (ValueError, KeyError, OSError, MemoryError, EOFError) as e:
        raise UserError(f"{path}: cannot read: {e or type(e).__name__}") from None
    except Exception as e:  # laspy and lazrs raise their own kinds for damaged files
        raise UserError(f"{path}: cannot read: {type(e).__name__}: {e}") from None
    raise UserError(f"{path}: unknown point file type {path.suffix.lower()!r} (expected .pcd, .las or .laz)")


def intensity_mapping(path) -> dict | None:
    """The sensor's ``intensity`` mapping that our LAS or LAZ file keeps in its ``mitsuforest`` VLR
    (:func:`~.las.las_header`), or None: a PCD, another tool's file, an unreadable one."""
    import json
    import laspy
    if format_of(path) in (None, "pcd"):
        return None
    try:
        with laspy.open(str(path)) as reader:
            note = next((v for v in reader.header.vlrs if v.user_id == "mitsuforest"), None)
            return json.loads(note.record_data).get("intensity") if note is not None else None
    except Exception:     # a damaged header: load_points says what is wrong with the file
        return None


def _not_a_file(path: Path) -> str:
    """What is wrong with a path that is no regular file; for a folder, a point file in it to give."""
    if not path.exists():
        return f"{path}: file not found"
    if not path.is_dir():
        return f"{path}: not a regular file"
    try:
        found = sorted(p for p in path.iterdir() if format_of(p) and p.is_file())
    except OSError:
        found = []
    if found:
        return f"{path}: is a folder; give one of its point files, such as {found[0]}"
    return f"{path}: is a folder, with no point file in it; give a .pcd, .las or .laz file"


def _load_pcd(path: Path) -> tuple[dict, list[str], dict]:
    """Our PCD's fields as they are, with our classes; another tool's by our names (:func:`~.pcd.our_names`:
    ``X``, ``GpsTime`` as ``x``, ``gps_time``), with ASPRS classes."""
    pts = read_pcd(path)
    names = list(pts.dtype.names)
    if _pcd_is_ours(names):
        return {n: pts[n] for n in names}, names, CLASS_NAMES
    renamed = our_names(names)
    return {new: pts[old] for old, new in zip(names, renamed)}, renamed, ASPRS_CLASSES


def _pcd_is_ours(names: list[str]) -> bool:
    """Whether a PCD's fields are a render's: our label fields (:data:`OUR_PCD_LABELS`, by our exact names),
    not another tool's ``classification`` alone (ASPRS classes, ground 2), as a LAS is ours by its ``label``
    (:func:`_described_as_ours`)."""
    return set(OUR_PCD_LABELS) <= set(names)


def _load_las(path: Path) -> tuple[dict, list[str], dict]:
    import laspy
    if problem := _record_counts_problem(path):     # before laspy, which would read on past the file's end
        raise PointFileError(problem)
    with laspy.open(str(path)) as reader:
        header = reader.header
        size = path.stat().st_size
        if size < header.offset_to_point_data:
            raise PointFileError(f"truncated: the file ends at byte {size:,}, before its points, which the header "
                                 f"puts at byte {header.offset_to_point_data:,}")
        need = header.offset_to_point_data + header.point_count * header.point_format.size
        if not header.are_points_compressed and size < need:
            held = (size - header.offset_to_point_data) // header.point_format.size
            raise PointFileError(f"truncated: the header promises {header.point_count:,} points, the file "
                                 f"holds {held:,}")
        problem = _uncounted_points(path, header) if not header.are_points_compressed else _laz_problem(path, header)
        if problem:
            raise PointFileError(problem)
        las = reader.read()
    names = list(las.point_format.dimension_names)
    cols = {n: np.asarray(las[n]) for n in names}
    cols["x"], cols["y"], cols["z"] = np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)
    ours = FIELD["classification"].read_from           # our class, beside the ASPRS classification
    if ours in cols and _described_as_ours(las.point_format, ours):
        cols["classification"] = cols[ours]
        return cols, names, CLASS_NAMES
    return cols, names, ASPRS_CLASSES


def _described_as_ours(point_format, name: str) -> bool:
    """Whether the extra dimension ``name`` is our class, by its description (``mitsuforest class 1-8``,
    ``1-7`` in early files), not another tool's dimension of that name (a segmentation's ``label``)."""
    return point_format.dimension_by_name(name).description.startswith(CLASS_DESCRIPTION)


def _record_counts_problem(path: Path) -> str | None:
    """A header's count of VLRs (54 bytes or more each) or of LAS 1.4's EVLRs (60 or more) that the file
    cannot hold: laspy reads that many, past the file's end (4,294,967,295 took minutes). A header too short
    to hold them is left to laspy to refuse."""
    size = path.stat().st_size
    with open(path, "rb") as f:
        header = f.read(247)
    if len(header) < 104 or header[:4] != b"LASF":
        return None
    counts = [("VLRs", 54, int.from_bytes(header[100:104], "little"))]
    if header[24:26] >= bytes([1, 4]) and len(header) == 247:
        counts.append(("EVLRs", 60, int.from_bytes(header[243:247], "little")))
    for what, least, count in counts:
        if count * least > size:
            return (f"damaged: the header counts {count:,} {what} of at least {least} bytes, more than the file's "
                    f"{size:,} bytes can hold")
    return None


UNFINISHED = "an unfinished file (its writer stopped before closing it, as a killed render's does)"


def _uncounted_points(path: Path, header) -> str | None:
    """An uncompressed file whose header counts 0 points while points follow (laspy reads none)."""
    end = header.start_of_first_evlr if getattr(header, "number_of_evlrs", 0) else path.stat().st_size
    held = max(end - header.offset_to_point_data, 0) // header.point_format.size
    if header.point_count == 0 and held:
        return f"the header counts 0 points but {held:,} follow: {UNFINISHED}"
    return None


def _laz_problem(path: Path, header) -> str | None:
    """What makes a LAZ file unreadable before its points are decompressed: no chunk table (a LAZ file
    gets it when it is closed, so one of a killed render has none, and laspy would read 0 points), a chunk
    count its bytes cannot hold (lazrs would allocate its table: 32 GB for 2^31, an abort), or a point count
    its chunks cannot hold (laspy would try to allocate it)."""
    start, size = header.offset_to_point_data, path.stat().st_size
    with open(path, "rb") as f:
        f.seek(start)
        raw = f.read(8)
        if len(raw) < 8:
            return f"the file ends where its compressed points begin: {UNFINISHED}"
        table = int.from_bytes(raw, "little", signed=True)
        if table == -1 and size >= start + 16:   # LASzip's streamed files keep the offset in their last 8 bytes
            f.seek(size - 8)
            table = int.from_bytes(f.read(8), "little", signed=True)
        if not start + 8 <= table <= size - 8:
            return f"no chunk table (its offset reads {table:,}), so the points cannot be found: {UNFINISHED}"
        f.seek(table)
        chunks = int.from_bytes(f.read(8)[4:], "little")
    if chunks > table - start - 8:      # each chunk takes a byte at least; lazrs would allocate 16 bytes a chunk first
        return (f"damaged: its chunk table counts {chunks:,} chunks, more than its {table - start - 8:,} bytes of "
                "compressed points can hold")
    vlr = next((v for v in header.vlrs if v.user_id == "laszip encoded"), None)
    chunk_size = int.from_bytes(vlr.record_data_bytes()[12:16], "little") if vlr else 0xFFFFFFFF
    if chunk_size != 0xFFFFFFFF and chunk_size > max(header.point_count, 1 << 20):   # lazrs allocates a chunk
        return (f"damaged: its LASzip record gives chunks of {chunk_size:,} points, more than the "
                f"{header.point_count:,} the header counts")
    if chunk_size != 0xFFFFFFFF and header.point_count > chunks * chunk_size:
        return (f"damaged: the header counts {header.point_count:,} points, more than its {chunks:,} compressed "
                f"chunk{'s' if chunks != 1 else ''} of {chunk_size:,} can hold")
    return None


def summary(path) -> str:
    pts, names, class_names = load_points(path)
    n = len(pts["x"])
    lines = [f"{path}: {n:,} points", "fields: " + ", ".join(names)]
    if n == 0:
        return "\n".join(lines)
    lo = [float(np.min(pts[a])) for a in "xyz"]
    hi = [float(np.max(pts[a])) for a in "xyz"]
    lines.append("bounds: " + "  ".join(f"{a} {l:.3f} .. {h:.3f}" for a, l, h in zip("xyz", lo, hi)))
    area = (hi[0] - lo[0]) * (hi[1] - lo[1])
    if area > 0:
        lines.append(f"density: {n / area:.1f} points/m2 over the x-y bounding box ({area:.1f} m2; a render reports "
                     "its density over its plot, which the points overrun)")
    if "classification" in pts:
        counts = np.bincount(np.asarray(pts["classification"]).astype(int))
        lines.append("classes: " + ", ".join(f"{class_names.get(k, f'class {k}')} {v:,} ({v / n:.1%})"
                                              for k, v in enumerate(counts) if v))
    if "number_of_returns" in names and "return_number" in names:
        first = np.asarray(pts["return_number"]) == 1
        counts = np.bincount(np.asarray(pts["number_of_returns"])[first].astype(int))
        lines.append("pulses by number of returns: " + ", ".join(f"{k}: {v:,}" for k, v in enumerate(counts) if v))
    return "\n".join(lines)


_LOADERS = {"pcd": _load_pcd, "las": _load_las, "laz": _load_las, "copc": _load_las}   # by point format
