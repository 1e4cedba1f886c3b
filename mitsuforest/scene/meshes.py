"""The one place that builds Mitsuba meshes from arrays (Mitsuba 3.10 changes this API)."""

from __future__ import annotations

import numpy as np


def mitsuba_mesh(name: str, vertices: np.ndarray, faces: np.ndarray):
    """A ``mi.Mesh`` from (n, 3) vertices and (m, 3) faces, no normals or texture coordinates."""
    import mitsuba as mi
    mesh = mi.Mesh(name, len(vertices), len(faces), has_vertex_normals=False, has_vertex_texcoords=False)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(np.ascontiguousarray(vertices, np.float32).ravel())
    params["faces"] = mi.UInt32(np.ascontiguousarray(faces, np.uint32).ravel())
    params.update()
    return mesh


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m, 3) float32 unit normals of triangles (zero for degenerate ones)."""
    a, b, c = (vertices[faces[:, i]].astype(np.float64) for i in range(3))
    n = np.cross(b - a, c - a)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return (n / np.where(length > 0, length, 1)).astype(np.float32)
