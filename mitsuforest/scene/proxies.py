"""Proxies: coarse, conservative stand-ins of the models, for the scan to aim pulses at.

A model's proxy is the set of cells of a grid in its own frame that its triangles' bounding boxes
overlap: every surface of the model lies inside a cell of it. The scan traces each pulse's beam axis
against the proxies of the placed objects, each cell grown by the widest sub-ray's distance from the
axis, and casts the sub-rays of the pulses that meet one (:func:`mitsuforest.scan.pulses.aimed_at`): a
pulse that meets none has no sub-ray that can hit the object, so dropping it changes no point. Cells
are much tighter than an object's bounding box around an open crown, whose box most pulses cross
without touching a leaf.
"""

from __future__ import annotations

import itertools
from typing import NamedTuple

import mitsuba as mi
import numpy as np

from .meshes import mitsuba_mesh

CELL = 0.5    # m, a proxy cell's side in the model's frame
SMALL = 2.5   # m: a model no larger than this a side has its box for proxy (model_cells)
MAX_GRID = 1 << 24   # cells of a model's box at most: larger models get larger cells (model_cells)

#: (8, 3) the corners of a unit cube, corner i at (i & 1, i >> 1 & 1, i >> 2 & 1)
_CORNERS = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)])
#: (12, 3) a closed cube's triangles over :data:`_CORNERS`, wound outwards
_CUBE = np.array([t for a, b, c, d in [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4),
                                       (1, 5, 7, 3)] for t in ((a, b, c), (a, c, d))])


def box_mesh(boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The surfaces of ``k`` axis-aligned boxes (k, 2, 3): vertices (8k, 3) and faces (12k, 3)."""
    vertices = np.where(_CORNERS[None], boxes[:, None, 1], boxes[:, None, 0]).reshape(-1, 3)
    return vertices, (_CUBE[None] + 8 * np.arange(len(boxes))[:, None, None]).reshape(-1, 3)


def occupied_cells(vertices: np.ndarray, faces: np.ndarray, cell: float = CELL) -> np.ndarray:
    """(k, 3) int32 indices (``floor(x / cell)``) of the grid cells that the bounding box of some
    triangle overlaps, each once, in lexicographic order.

    :param vertices: (n, 3) float; ``faces``: (m, 3) int.
    """
    if len(faces) == 0:
        return np.zeros((0, 3), np.int32)
    corners = vertices[faces]                                            # (m, 3, 3)
    lo = np.floor(corners.min(axis=1) / cell).astype(np.int64)
    hi = np.floor(corners.max(axis=1) / cell).astype(np.int64)
    base = lo.min(axis=0)
    lo -= base
    extra = hi - base - lo                                               # cells past the first, per axis
    grid = np.zeros(hi.max(axis=0) - base + 1, bool)
    grid[lo[:, 0], lo[:, 1], lo[:, 2]] = True
    spanning = np.flatnonzero(extra.any(axis=1))      # most triangles (leaves) lie in one cell
    lo, extra = lo[spanning], extra[spanning]
    for step in itertools.product(*(range(n + 1) for n in extra.max(axis=0, initial=0))):   # mostly 0-1 a side
        if any(step):
            at = lo[np.all(extra >= step, axis=1)] + step
            grid[at[:, 0], at[:, 1], at[:, 2]] = True
    return (np.argwhere(grid) + base).astype(np.int32)


class Cells(NamedTuple):
    """A model's proxy: the indices (k, 3) int32 of the cells of side ``size`` (m, model frame) it occupies."""

    index: np.ndarray
    size: float


def _cells_of_part(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    return occupied_cells(vertices, faces)


def model_cells(model) -> Cells:
    """The cells of :data:`CELL` that a :class:`~mitsuforest.trees.models.Model`'s parts occupy (kept with a
    cached model's read-only parts, so a worker finds them once), or of a side doubled until its box
    spans at most :data:`MAX_GRID` of them (a large imported mesh). A model within :data:`SMALL` m a side
    (a shrub, a rock: drawn anew for each plot, and about as full as its box) takes every cell of its box
    instead."""
    corners = model.hull_corners()
    extent = np.ptp(corners, axis=0) if len(corners) else np.zeros(3)
    size = CELL
    while np.prod(np.floor(extent / size) + 2) > MAX_GRID:
        size *= 2
    if len(corners) and np.all(extent <= SMALL):
        lo, hi = (np.floor(f(corners, axis=0) / size).astype(np.int64) for f in (np.min, np.max))
        return Cells((np.indices(hi - lo + 1).reshape(3, -1).T + lo).astype(np.int32), size)
    if size == CELL:
        cells = [p.of_mesh(_cells_of_part) for p in model.parts]
    else:
        cells = [occupied_cells(p.vertices, p.faces, size) for p in model.parts]
    cells = np.concatenate(cells) if cells else np.zeros((0, 3), np.int32)
    return Cells(np.unique(cells, axis=0) if len(model.parts) > 1 else cells, size)


def smallest_scale(matrix: np.ndarray) -> float:
    """The least a 4 × 4 placement shrinks any length: its linear part's smallest singular value."""
    return float(np.linalg.svd(np.asarray(matrix)[:3, :3], compute_uv=False).min())


def proxy_scene(cells: dict[str, np.ndarray], placements: list[tuple[str, np.ndarray]], grow: float,
                boxes: np.ndarray) -> mi.Scene:
    """The placed proxies, each cell grown by ``grow`` m in the world frame, and ``boxes`` (k, 2, 3)
    grown alike, as one Mitsuba scene; call under a Mitsuba variant.

    :param cells: model name → its :class:`Cells` (:func:`model_cells`).
    :param placements: (model name, 4 × 4 matrix) of each placed object.
    :param boxes: the world-frame boxes of what has no proxy (the ground).
    """
    scale = {}
    for name, matrix in placements:
        scale[name] = min(scale.get(name, np.inf), smallest_scale(matrix))
    d = {"type": "scene"}
    if len(boxes):
        d["boxes"] = mitsuba_mesh("boxes", *box_mesh(boxes + np.array([[-grow] * 3, [grow] * 3])))
    for name in sorted(scale):
        index, size = cells[name]
        if len(index):
            g = grow / scale[name]                       # a world ball of radius grow, in the model's frame
            grown = np.stack([index * size - g, (index + 1) * size + g], axis=1)
            d[f"proxy_{name}"] = {"type": "shapegroup", "cells": mitsuba_mesh(f"proxy_{name}", *box_mesh(grown))}
    for k, (name, matrix) in enumerate(placements):
        if f"proxy_{name}" in d:
            d[f"placed_{k:07d}"] = {"type": "instance", "shape": {"type": "ref", "id": f"proxy_{name}"},
                                    "to_world": mi.ScalarTransform4f(np.asarray(matrix).tolist())}
    return mi.load_dict(d)
