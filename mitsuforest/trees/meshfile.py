"""Reading tree meshes: pieces with names, wood and leaves apart, in metres with +z up.

Any format trimesh reads (OBJ with groups and materials, PLY, GLB/glTF, OFF, STL). A file is read as
named pieces: for OBJ, one per object, group and material (trimesh names them
``object_group_material``); for glTF, one per mesh primitive. Leaf pieces are picked by name patterns
matched against a piece's name and its material's name.
"""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..interrupts import import_held
from ..specs.sources import MAX_HEIGHT, MIN_HEIGHT, UNITS, ModelFileError, missing_companions

Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])   # +y becomes +z
BASE_SLICE = 0.1   # m: the stem base is the centre of the wood's lowest 10 cm (less for small trees)


@dataclass
class Piece:
    names: tuple[str, ...]     # the piece's own name and its material's
    vertices: np.ndarray       # (n, 3) float64, file units and axes
    faces: np.ndarray          # (m, 3) int64


def read_pieces(path) -> list[Piece]:
    """Every triangle piece of a mesh file, with the scene graph's transforms applied."""
    trimesh = import_held("trimesh")
    options = {"split_objects": True, "split_groups": True} if Path(path).suffix.lower() == ".obj" else {}
    try:
        scene = trimesh.load(str(path), force="scene", process=False, **options)
    except Exception as e:   # trimesh raises many kinds for a file it cannot parse
        raise ModelFileError(path, "", f"cannot read the mesh ({type(e).__name__}: {e})") from None
    pieces = []
    for node in scene.graph.nodes_geometry:
        transform, geometry = scene.graph[node]
        mesh = scene.geometry[geometry]
        if not hasattr(mesh, "faces") or not len(mesh.faces):
            continue
        material = getattr(getattr(mesh.visual, "material", None), "name", None)
        v = np.asarray(mesh.vertices, np.float64)
        if not np.array_equal(transform, np.eye(4)):
            v = v @ transform[:3, :3].T + transform[:3, 3]
        names = tuple(n for n in (str(node), str(geometry), material) if n)
        _check_finite(path, names[0], v)
        pieces.append(Piece(names, v, np.asarray(mesh.faces, np.int64)))
    if not pieces:
        raise ModelFileError(path, "", "no triangles in the file")
    return pieces


def _check_finite(path, piece: str, vertices: np.ndarray) -> None:
    """Refuse a piece with a nan or infinite coordinate (the reader may reorder vertices, so the
    point is given by its coordinates, not its index)."""
    bad = ~np.all(np.isfinite(vertices), axis=1)
    if bad.any():
        where = "" if piece == Path(path).name else f"piece {piece!r}"
        first = ", ".join(f"{c:g}" for c in vertices[np.argmax(bad)])
        count = f"{int(bad.sum()):,} vertices are" if bad.sum() > 1 else "a vertex is"
        raise ModelFileError(path, where, f"{count} not finite, the first at ({first})")


def split_by_patterns(path, pieces: list[Piece], patterns) -> tuple[list[Piece], list[Piece]]:
    """Wood and leaf pieces: a piece is leaves when any name of it matches any pattern (any case).

    :raises ModelFileError: when the patterns match no piece, or every piece.
    """
    patterns = [p.lower() for p in patterns]
    is_leaf = [any(fnmatch.fnmatchcase(n.lower(), p) for n in piece.names for p in patterns) for piece in pieces]
    if not patterns:
        return pieces, []
    found = sorted({piece.names[-1] for piece in pieces})
    listed = ", ".join(found[:8]) + (", ..." if len(found) > 8 else "")
    if not any(is_leaf):
        missing = [p.name for p in missing_companions(path)]
        unknown = f"; the material file {', '.join(missing)} is missing, so material names are unknown" if missing else ""
        raise ModelFileError(path, "leaves", f"the patterns {list(patterns)} match no piece (pieces and materials: "
                             f"{listed}){unknown}; name the leaf pieces, or give leaves: [] for a tree without leaves")
    if all(is_leaf):
        raise ModelFileError(path, "leaves", f"the patterns {list(patterns)} match every piece ({listed}), so "
                             "nothing is left for the wood; narrow them")
    return ([p for p, leaf in zip(pieces, is_leaf) if not leaf], [p for p, leaf in zip(pieces, is_leaf) if leaf])


def joined(pieces: list[Piece], merge: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One mesh of pieces, degenerate faces dropped and, with ``merge``, vertices at the same position
    merged (to 10 nm: exported meshes split vertices along UV and normal seams, which opens them) and
    faces on the same three vertices kept once.

    :returns: vertices (n, 3) float64, faces (m, 3) int64, and each face's piece (m,) (index into ``pieces``).
    """
    trimesh = import_held("trimesh")
    if not pieces:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.int64)
    base = np.cumsum([0] + [len(p.vertices) for p in pieces[:-1]])
    v = np.vstack([p.vertices for p in pieces])
    f = np.vstack([p.faces + b for p, b in zip(pieces, base)])
    piece = np.repeat(np.arange(len(pieces)), [len(p.faces) for p in pieces])
    mesh = trimesh.Trimesh(v, f, process=False)
    keep = np.ones(len(f), bool)
    if merge:
        mesh.merge_vertices(merge_tex=True, merge_norm=True)
        keep = mesh.unique_faces()     # a piece given twice (an exporter's copy) would close nothing
    keep &= mesh.nondegenerate_faces()
    return np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)[keep], piece[keep]


def to_tree_frame(vertices: np.ndarray, units: str, up: str) -> np.ndarray:
    """File coordinates in metres with +z up."""
    v = vertices * UNITS[units]
    return v @ Y_UP_TO_Z_UP.T if up == "y" else v


def stem_base(wood_vertices: np.ndarray) -> np.ndarray:
    """(3,) the stem base: the lowest wood point's height, at the centre of the wood's lowest slice."""
    z0 = wood_vertices[:, 2].min()
    height = np.ptp(wood_vertices[:, 2])
    low = wood_vertices[wood_vertices[:, 2] <= z0 + min(BASE_SLICE, 0.02 * height)]
    centre = (low[:, :2].min(axis=0) + low[:, :2].max(axis=0)) / 2
    return np.array([centre[0], centre[1], z0])


def stem_lean(wood_vertices: np.ndarray, wood_faces: np.ndarray, samples: int = 20_000) -> float:
    """The angle (degrees) from +z of the main axis of the wood's surface in its lowest quarter of height
    (points spread over the surface by area, as a stem's long faces have vertices only at their ends): a
    stem leans a few degrees, a tree lying on its side (``up`` wrong) about 90."""
    trimesh = import_held("trimesh")
    surface = trimesh.Trimesh(wood_vertices, wood_faces, process=False)
    points = np.asarray(trimesh.sample.sample_surface(surface, samples, seed=0)[0])
    z = points[:, 2]
    low = points[z <= z.min() + 0.25 * np.ptp(z)]
    spread = low - low.mean(axis=0)
    axis = np.linalg.eigh(spread.T @ spread)[1][:, -1]
    return float(np.degrees(np.arccos(min(abs(axis[2]), 1.0))))


def check_height(path, height: float, units: str, up: str) -> None:
    if not MIN_HEIGHT <= height <= MAX_HEIGHT:
        raise ModelFileError(path, "units", f"the tree is {height:,.4g} m tall with units: {units} and up: {up} "
                             f"(a tree is {MIN_HEIGHT:g}-{MAX_HEIGHT:g} m); check units and up")
