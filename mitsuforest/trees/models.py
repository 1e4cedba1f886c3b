"""Models: the meshes of one tree archetype or understory object, split into labelled components.

A :class:`Model` is placed any number of times by the plan. Its parts are the meshes the scene loads
(``wood`` and ``leaves`` for a tree); each triangle carries the index of its component (the stem, a
first-order branch with its descendants, the leaves, a rock ...), so a hit's triangle gives its label.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from .. import seeds
from ..classes import TREE_LEAVES, TREE_WOOD
from ..specs.archetypes import Archetype
from .leaves import leaf_blades, leaf_count, leaves_on_twigs, lowered_under
from .skeleton import crown_volume_points, grow, terminal_branches
from .tubes import frustum_volume, tube
from .volume import WoodVolume, wood_volume


class DerivedStore(Protocol):
    """Where a part keeps what :meth:`Part.of_mesh` derives beyond the process (the model cache's
    :class:`~.cache.DerivedArrays`)."""

    def get(self, compute) -> np.ndarray | None: ...

    def put(self, compute, value: np.ndarray) -> None: ...


@dataclass
class Part:
    name: str
    vertices: np.ndarray   # (n, 3) float64, model frame: base at the origin, +z up
    faces: np.ndarray      # (m, 3) uint32
    component: np.ndarray  # (m,) uint16, index into Model.components
    _derived: dict = field(default_factory=dict, init=False, repr=False, compare=False)   # see of_mesh
    #: where a cached model's part keeps what :meth:`of_mesh` computes on disk (set by the model cache)
    store: DerivedStore | None = field(default=None, init=False, repr=False, compare=False)

    def of_mesh(self, compute):
        """``compute(vertices, faces)``, an array; kept with the part while its mesh is read-only (a cached
        model's, whose copies share their parts: a dataset worker computes its archetypes' normals and
        areas once, not once a plot), and in the model's cache entry (:attr:`store`: a later process reads
        it back); computed anew each call otherwise (a mesh that may still change). The array kept is
        read-only."""
        if self.vertices.flags.writeable or self.faces.flags.writeable:
            return compute(self.vertices, self.faces)
        if compute not in self._derived:
            value = self.store.get(compute) if self.store else None
            if value is None:
                value = compute(self.vertices, self.faces)
                if self.store:
                    self.store.put(compute, value)
            value.flags.writeable = False
            self._derived[compute] = value
        return self._derived[compute]


@dataclass
class Component:
    kind: str              # stem, branch, leaves, bush, rock, stump, deadwood
    classification: int


@dataclass
class Model:
    name: str
    parts: list[Part]
    components: list[Component]
    volume: WoodVolume | None = None
    meta: dict = field(default_factory=dict)
    hull: np.ndarray | None = field(default=None, repr=False, compare=False)   # hull_corners(), once known

    @property
    def triangles(self) -> int:
        return int(sum(len(p.faces) for p in self.parts))

    def vertices(self) -> np.ndarray:
        return np.vstack([p.vertices for p in self.parts])

    def hull_corners(self) -> np.ndarray:
        """(k, 3) the corners of the model's convex hull (all its vertices when it is flat or tiny): a
        rotated and moved copy has the bounds of its moved corners."""
        if self.hull is None:
            self.hull = _hull_corners(self.vertices())
        return self.hull


def _hull_corners(v: np.ndarray) -> np.ndarray:
    from scipy.spatial import ConvexHull, QhullError
    try:
        return v[ConvexHull(v).vertices]
    except (QhullError, ValueError):
        return v


def merge(meshes, components) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Concatenate ``[(vertices, faces), ...]`` with one component index per mesh."""
    verts, faces, comp, base = [], [], [], 0
    for (v, f), c in zip(meshes, components):
        verts.append(v)
        faces.append(f + base)
        comp.append(np.full(len(f), c, np.uint16))
        base += len(v)
    return np.vstack(verts), np.vstack(faces).astype(np.uint32), np.concatenate(comp)


def tree_components(archetype: Archetype, branches) -> list[Component]:
    """A tree's labelled components: the stem, one per first-order branch (with its descendants),
    then the leaves. The plan numbers object ids by this list, so it is the only place that counts them."""
    n_branches = max(b.component for b in branches)
    return [Component("stem", TREE_WOOD)] + [Component("branch", TREE_WOOD)] * n_branches + \
        ([Component("leaves", TREE_LEAVES)] if bears_leaves(archetype, branches) else [])


def bears_leaves(a: Archetype, branches) -> bool:
    return leaf_count(a.leaf_area, a.leaf_length, a.leaf_width) > 0 and bool(terminal_branches(branches))


def tree_model(archetype: Archetype, name: str) -> Model:
    """Mesh one archetype: a wood part (one closed tube per branch) and a leaf part, with volumes."""
    rng = seeds.rng(archetype.seed, "leaves")
    branches = grow(archetype)
    tubes = [tube(b.points, b.radii) for b in branches]
    volume = wood_volume(tubes, sum(frustum_volume(b.points, b.radii) for b in branches),
                         names=[f"{name} branch {i}" for i in range(len(tubes))])
    wood = Part("wood", *merge(tubes, [b.component for b in branches]))
    leaves = _leaves(archetype, branches, rng)
    components = tree_components(archetype, branches)
    parts = [wood]
    if leaves is not None:
        v, f = leaves
        v = lowered_under(v, archetype.height)   # the tree's height is its top, leaves included
        parts.append(Part("leaves", v, f.astype(np.uint32), np.full(len(f), len(components) - 1, np.uint16)))
    return Model(name, parts, components, volume,
                 meta={"height": archetype.height, "dbh": archetype.dbh, "species": archetype.species})


def _leaves(a: Archetype, branches, rng):
    """The leaf blades: on the terminal twigs, and with ``leaf_fill`` that share of the leaf area through
    the crown envelope's volume (:func:`~.skeleton.crown_volume_points`), where twigs on whorled branches
    leave gaps that no amount of leaf on them closes."""
    if not bears_leaves(a, branches):
        return None
    twigs = [t.points for t in terminal_branches(branches)]
    if a.leaf_fill <= 0:
        return leaves_on_twigs(twigs, a.leaf_area, a.leaf_length, a.leaf_width, a.leaf_inclination,
                               a.leaf_clumping, rng)
    on_twigs = a.leaf_area * (1.0 - a.leaf_fill)
    meshes = [leaves_on_twigs(twigs, on_twigs, a.leaf_length, a.leaf_width, a.leaf_inclination, a.leaf_clumping, rng)
              ] if leaf_count(on_twigs, a.leaf_length, a.leaf_width) else []
    spread = leaf_count(a.leaf_area - on_twigs, a.leaf_length, a.leaf_width)
    anchors = crown_volume_points(a, branches[0], spread, rng)
    meshes.append(leaf_blades(anchors, a.leaf_length, a.leaf_width, a.leaf_inclination, rng))
    vertices, faces, _ = merge(meshes, [0] * len(meshes))
    return vertices, faces
