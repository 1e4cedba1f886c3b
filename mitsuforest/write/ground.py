"""The ``height_above_ground`` field of every point output: a point's height above the scene's ground
surface as rendered, at the point's x, y (local frame), float32 metres."""

from __future__ import annotations

import numpy as np

from ..fields import with_writer_fields

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


def with_room_for_height(points: np.ndarray) -> np.ndarray:
    """``points`` themselves when they hold ``height_above_ground``, else an empty (unfilled) array of
    their fields and that one, for :func:`fill_height` to fill by row ranges (on several threads)."""
    if FIELD in points.dtype.names:
        return points
    return np.empty(len(points), with_writer_fields(points.dtype))


def fill_height(points: np.ndarray, out: np.ndarray, surface) -> np.ndarray:
    """``out`` (rows of :func:`with_room_for_height`'s array) holding ``points`` (local frame) and
    their ``height_above_ground`` (float32, m): z less the ``surface`` at x, y."""
    if out is not points:
        copy_fields(points, out)
    if len(out):
        out[FIELD] = out["z"] - surface(out["x"], out["y"])
    return out



def copy_fields(points: np.ndarray, out: np.ndarray) -> None:
    """``out[name] = points[name]`` for every field of ``points``: as one copy of each row's bytes where
    ``out``'s records begin with ``points``' (as :func:`with_room_for_height` makes them), twice as fast
    as field by field."""
    source, target = points.dtype, out.dtype
    same_start = all(target.fields.get(name) == source.fields[name] for name in source.names)
    if same_start and points.flags.c_contiguous and out.flags.c_contiguous and len(points):
        rows = len(points)
        out.view(np.uint8).reshape(rows, target.itemsize)[:, :source.itemsize] = \
            points.view(np.uint8).reshape(rows, source.itemsize)
        return
    for name in source.names:
        out[name] = points[name]
