"""The ``height_above_ground`` field of every point output: a point's height above the scene's ground
surface as rendered, at the point's x, y (local frame), float32 metres."""

from __future__ import annotations

import numpy as np

FIELD = "height_above_ground"


def ground_surface(terrain):
    """A function ``(x, y) -> ground height`` (local frame, float64 arrays) of the plan's terrain: the
    rendered triangles of a :class:`~mitsuforest.plan.terrain.Terrain`, or of a ground that is only a
    mesh (a HELIOS++ scene's, its mean height beyond its triangles); flat at 0 without a terrain."""
    if terrain is None:
        return lambda x, y: np.zeros(len(x))
    if hasattr(terrain, "surface_height"):
        return terrain.surface_height
    from ..plan.terrain import TriangleSurface
    return TriangleSurface(*terrain.mesh(), fallback=terrain.mean_height)


def with_height_above_ground(points: np.ndarray, surface) -> np.ndarray:
    """``points`` (local frame) with the field ``height_above_ground`` (float32, m) appended, or filled
    in when it is there already."""
    if FIELD not in points.dtype.names:
        out = np.empty(len(points), np.dtype(points.dtype.descr + [(FIELD, "<f4")]))
        for name in points.dtype.names:
            out[name] = points[name]
        points = out
    if len(points):
        points[FIELD] = points["z"] - surface(points["x"], points["y"])
    return points
