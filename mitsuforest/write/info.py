"""Summaries of point files we write (PCD or LAS/LAZ), for ``mitsuforest info``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..classes import CLASS_NAMES
from ..errors import UserError
from .pcd import read_pcd


def load_points(path) -> tuple[dict, list[str]]:
    """The file's columns by name (our class codes under ``classification``) and its field names."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: file not found")
    suffix = path.suffix.lower()
    try:
        if suffix == ".pcd":
            pts = read_pcd(path)
            return {n: pts[n] for n in pts.dtype.names}, list(pts.dtype.names)
        if suffix in (".las", ".laz"):
            import laspy
            las = laspy.read(str(path))
            names = list(las.point_format.dimension_names)
            cols = {n: np.asarray(las[n]) for n in names}
            cols["x"], cols["y"], cols["z"] = np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)
            if "label" in cols:
                cols["classification"] = cols["label"]
            return cols, names
    except (ValueError, KeyError, OSError) as e:
        raise UserError(f"{path}: cannot read: {e}") from None
    raise UserError(f"{path}: unknown point file type {suffix!r} (expected .pcd, .las or .laz)")


def summary(path) -> str:
    pts, names = load_points(path)
    n = len(pts["x"])
    lines = [f"{path}: {n:,} points", "fields: " + ", ".join(names)]
    if n == 0:
        return "\n".join(lines)
    lo = [float(np.min(pts[a])) for a in "xyz"]
    hi = [float(np.max(pts[a])) for a in "xyz"]
    lines.append("bounds: " + "  ".join(f"{a} {l:.3f} .. {h:.3f}" for a, l, h in zip("xyz", lo, hi)))
    area = (hi[0] - lo[0]) * (hi[1] - lo[1])
    if area > 0:
        lines.append(f"density: {n / area:.1f} points/m2 over the x-y bounding box ({area:.1f} m2)")
    if "classification" in pts:
        counts = np.bincount(np.asarray(pts["classification"]).astype(int))
        lines.append("classes: " + ", ".join(f"{CLASS_NAMES.get(k, k)} {v:,} ({v / n:.1%})"
                                              for k, v in enumerate(counts) if v))
    if "number_of_returns" in names and "return_number" in names:
        first = np.asarray(pts["return_number"]) == 1
        counts = np.bincount(np.asarray(pts["number_of_returns"])[first].astype(int))
        lines.append("pulses by number of returns: " + ", ".join(f"{k}: {v:,}" for k, v in enumerate(counts) if v))
    return "\n".join(lines)
