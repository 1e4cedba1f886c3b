"""Repair of imported wood: loose parts, each made a closed, outward-oriented manifold.

Meshes from modelling tools are rarely closed (Sapling branches are open tubes, exported caps go
missing). The wood is split into its loose (edge-connected) parts and each is checked on its own:
a closed part with inward faces is turned round; an open or broken one is repaired with
pymeshfix, which fills holes and removes degenerate and self-intersecting faces (on one part at a
time: pymeshfix keeps only the largest component of what it is given). Every part's outcome is
recorded in a :class:`PartRepair`, so that no volume changes silently.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import manifold3d
import numpy as np

from ..interrupts import import_held


@dataclass(frozen=True)
class PartRepair:
    """What the repair did to one loose wood part (numbered from 1, the stem first)."""

    part: int
    piece: str               # the file's object, group or material the part belongs to
    action: str              # ok, reoriented (faces turned outward), repaired (pymeshfix), skipped
    faces_before: int
    faces_after: int
    holes: int               # boundary loops of the part as given (each one filled by a repair)
    faces_removed: int       # faces of the part as given that the repair dropped
    faces_added: int
    volume_before: float     # m³; NaN for an open part (its volume is not defined)
    volume_after: float      # m³; NaN when skipped
    reason: str = ""         # why a part was repaired or skipped

    def as_dict(self) -> dict:
        return asdict(self)


class UnrepairablePart(Exception):
    """A part that is still not a closed manifold with positive volume after repair."""


def loose_parts(vertices: np.ndarray, faces: np.ndarray) -> tuple[list[tuple[np.ndarray, np.ndarray]], list[int]]:
    """Split a mesh into edge-connected parts, in the order of their first face.

    :param vertices: (n, 3) float64, duplicate positions already merged.
    :param faces: (m, 3) integer.
    :returns: ``[(vertices (n_i, 3), faces (m_i, 3) int64), ...]``, each with its own vertex numbering,
        and the index of each part's first face in ``faces``.
    """
    trimesh = import_held("trimesh")      # here: a render of cached models needs none of it (0.45 s to import)
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    groups = trimesh.graph.connected_components(mesh.face_adjacency, nodes=np.arange(len(faces)),
                                                min_len=1)
    groups = sorted((np.sort(g) for g in groups), key=lambda g: g[0])
    parts = []
    for g in groups:
        used, local = np.unique(faces[g], return_inverse=True)
        parts.append((vertices[used], local.reshape(-1, 3).astype(np.int64)))
    return parts, [int(g[0]) for g in groups]


def boundary_loops(faces: np.ndarray) -> int:
    """Number of holes: loops of edges used by one face only."""
    edges = np.sort(np.vstack([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    border = unique[counts == 1]
    if not len(border):
        return 0
    trimesh = import_held("trimesh")
    return len(trimesh.graph.connected_components(border, min_len=1))


def closed_volume(vertices: np.ndarray, faces: np.ndarray) -> float | None:
    """Signed volume (m³) when the part is a closed 2-manifold, else ``None`` (float64 manifold3d)."""
    if len(faces) < 4:
        return None
    centre = vertices.mean(axis=0)
    mesh = manifold3d.Mesh64(vert_properties=np.ascontiguousarray(vertices - centre, np.float64),
                             tri_verts=np.ascontiguousarray(faces, np.uint64))
    part = manifold3d.Manifold(mesh)
    if part.status() != manifold3d.Error.NoError:
        return None
    return float(part.volume())   # negative when the faces point inward


def repair_part(vertices: np.ndarray, faces: np.ndarray, number: int, piece: str = ""):
    """Make one loose part closed and outward-facing.

    :returns: ``(vertices, faces, PartRepair)``.
    :raises UnrepairablePart: with the reason, when pymeshfix cannot close it.
    """
    before = closed_volume(vertices, faces)
    if before is not None and before > 0:
        return vertices, faces, PartRepair(number, piece, "ok", len(faces), len(faces), 0, 0, 0, before, before)
    if before is not None and before < 0:
        flipped = faces[:, ::-1].copy()
        return vertices, flipped, PartRepair(number, piece, "reoriented", len(faces), len(faces), 0, 0, 0, before, -before,
                                             "faces pointed inward")
    holes = boundary_loops(faces)
    fixed_v, fixed_f = _meshfix(vertices, faces)
    after = closed_volume(fixed_v, fixed_f) if len(fixed_f) else None
    if after is not None and after < 0:
        fixed_f, after = fixed_f[:, ::-1].copy(), -after
    if after is None or not after > 0:
        raise UnrepairablePart(f"{len(faces)} faces, {_holes(holes)}: pymeshfix could not make it a closed solid "
                               f"({'nothing left' if not len(fixed_f) else 'still open or empty'}); a flat "
                               "sheet such as a leaf has no volume")
    removed, added = _face_changes(vertices, faces, fixed_v, fixed_f)
    reason = _holes(holes) if holes else "not a closed manifold (non-manifold edges or degenerate faces)"
    return fixed_v, fixed_f, PartRepair(number, piece, "repaired", len(faces), len(fixed_f), holes, removed, added,
                                        float("nan"), after, reason)


def _holes(n: int) -> str:
    return f"{n} hole" + ("" if n == 1 else "s")


def _meshfix(vertices, faces):
    import pymeshfix
    fix = pymeshfix.MeshFix(np.ascontiguousarray(vertices, np.float64), np.ascontiguousarray(faces, np.int32))
    fix.repair(joincomp=False, remove_smallest_components=True)
    return np.asarray(fix.points, np.float64), np.asarray(fix.faces, np.int64).reshape(-1, 3)


def _face_changes(v0, f0, v1, f1) -> tuple[int, int]:
    """Faces of the first mesh missing from the second, and faces of the second not in the first
    (faces compared by their corner positions, in any order)."""
    _, ids = np.unique(np.vstack([v0, v1]), axis=0, return_inverse=True)
    ids = ids.ravel()
    a, b = np.sort(ids[:len(v0)][f0], axis=1), np.sort(ids[len(v0):][f1], axis=1)
    _, rows = np.unique(np.vstack([a, b]), axis=0, return_inverse=True)
    rows = rows.ravel()
    ra, rb = rows[:len(a)], rows[len(a):]
    return int((~np.isin(ra, rb)).sum()), int((~np.isin(rb, ra)).sum())
