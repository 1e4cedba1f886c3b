"""Models of imported trees: a mesh split into wood and leaves, or a QSM with procedural leaves.

Both become a :class:`~.models.Model` like a procedural tree: a ``wood`` part whose triangles carry
one component per loose wood part (meshes) or per branch (QSMs), the stem first, and a ``leaves``
part with one component. Wood volume is the float64 manifold union of the (repaired) wood parts, with
the naive sum beside it; for a QSM the analytic column is the QSM's own cylinder sum. Models are
cached under the files' content hash (:func:`imported_model`).
"""

from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np

from .. import seeds
from ..classes import TREE_LEAVES, TREE_WOOD
from ..errors import display_path
from .cache import cached
from .leaves import leaves_on_twigs
from .meshfile import check_height, joined, read_pieces, split_by_patterns, stem_base, stem_lean, to_tree_frame
from .models import Component, Model, Part, merge
from .qsm import read_qsm
from .repair import PartRepair, UnrepairablePart, boundary_loops, loose_parts, repair_part
from ..specs.sources import MAX_RADIUS, MeshTree, ModelFileError, QsmTree, content_hash, source_name
from .tubes import signed_volume, tube
from .volume import WoodVolume, union_volume

__all__ = ["imported_model", "summary", "mesh_tree_model", "qsm_tree_model", "MeshTree", "QsmTree"]

log = logging.getLogger(__name__)
MAX_COMPONENTS = 65_535   # component indices are uint16 per triangle
_warned: set = set()      # (file, part) skipped parts, (file, "lean") lying trees already reported in this process
LYING = 60.0              # degrees from up of the wood's lowest quarter: upright stems lean 0-2°, trees on their side 76-87°


def imported_model(entry, name: str) -> Model:
    """The model of a ``forest.models`` entry, from the cache when its files' contents are known."""
    params = {k: v for k, v in dataclasses.asdict(entry).items() if k not in ("weight", "mesh", "wood", "qsm")}
    if isinstance(entry, MeshTree) and isinstance(entry.leaves, str):
        params.pop("leaves")
    params["sha256"] = content_hash(entry.files)
    kind = "mesh_tree" if isinstance(entry, MeshTree) else "qsm_tree"
    build = mesh_tree_model if isinstance(entry, MeshTree) else qsm_tree_model
    model = cached(kind, params, lambda: build(entry, name))
    model.name = name
    model.meta["source"] = source_name(entry)   # the entry may be a copy of another file with the same bytes
    if model.meta.get("stem_lean_deg", 0.0) > LYING and (entry.source, "lean") not in _warned:
        _warned.add((entry.source, "lean"))
        log.warning("mitsuforest: %s: the wood's lowest quarter runs %.0f° from up: does the tree lie on its side? "
                    "Check up (z or y; it is %s)", display_path(entry.source), model.meta["stem_lean_deg"], entry.up)
    for part in model.meta.get("repair", []):
        if part["action"] == "skipped" and (entry.source, part["part"]) not in _warned:
            _warned.add((entry.source, part["part"]))
            log.warning("mitsuforest: %s: part %d: %s; left out of the wood volume (repair: skip)",
                        display_path(entry.source), part["part"], part["reason"])
    return model


def summary(entry) -> tuple[np.ndarray, int]:
    """(k, 3) crown points (the model's convex hull corners) and the component count, for the plan."""
    model = imported_model(entry, "summary")
    return model.hull_corners(), len(model.components)


def mesh_tree_model(entry: MeshTree, name: str) -> Model:
    """A tree mesh: wood split into loose parts, each repaired and checked, leaves as given."""
    wood_pieces, leaf_pieces = _pieces(entry)
    wood_v, wood_f, wood_piece = joined(wood_pieces)
    leaf_v, leaf_f, _ = joined(leaf_pieces, merge=False)   # leaves are scanned, never closed
    if not len(wood_f):
        raise ModelFileError(entry.source, "", "no wood triangles")
    wood_v, leaf_v = (to_tree_frame(v, entry.units, entry.up) for v in (wood_v, leaf_v))
    base = stem_base(wood_v)
    wood_v, leaf_v = wood_v - base, leaf_v - base
    height = max(wood_v[:, 2].max(), leaf_v[:, 2].max(initial=0.0))
    check_height(entry.source, height, entry.units, entry.up)
    parts, first_faces = loose_parts(wood_v, wood_f)
    names = [wood_pieces[wood_piece[i]].names[0] for i in first_faces]
    parts, names = _stem_first(parts, names)
    if len(parts) + 1 > MAX_COMPONENTS:
        raise ModelFileError(entry.source, "", f"{len(parts):,} loose wood parts, more than the {MAX_COMPONENTS - 1:,} "
                             "a model can label; join touching parts in the file")
    fixed, reports = _repaired(entry, parts, names)
    kept = [p for p, r in zip(fixed, reports) if r.action != "skipped"]
    volume = WoodVolume(union=union_volume(kept, [f"{entry.source}: part {r.part}" for r in reports
                                                  if r.action != "skipped"]),
                        analytic=math.nan, naive=float(sum(signed_volume(v, f) for v, f in kept)), parts=len(kept),
                        repaired=sum(r.action in ("repaired", "reoriented") for r in reports),
                        skipped=sum(r.action == "skipped" for r in reports))
    components = [Component("stem", TREE_WOOD)] + [Component("branch", TREE_WOOD)] * (len(fixed) - 1)
    leaves = (leaf_v, leaf_f) if len(leaf_f) else None
    meta = {"source": source_name(entry), "height": float(height), "stem_lean_deg": stem_lean(wood_v, wood_f),
            "repair": [r.as_dict() for r in reports if r.action != "ok"],
            "parts_ok": sum(r.action == "ok" for r in reports)}
    return _model(name, fixed, range(len(fixed)), components, leaves, volume, meta)


def _pieces(entry: MeshTree):
    if entry.mesh:
        return split_by_patterns(entry.mesh, read_pieces(entry.mesh), entry.leaves or ())
    return read_pieces(entry.wood), (read_pieces(entry.leaves) if isinstance(entry.leaves, str) else [])


def _stem_first(parts, names):
    """The part reaching lowest (the stem, at the base) first, the others in the order read."""
    lowest = int(np.argmin([v[:, 2].min() for v, _ in parts]))
    order = [lowest] + [i for i in range(len(parts)) if i != lowest]
    return [parts[i] for i in order], [names[i] for i in order]


def _repaired(entry: MeshTree, parts, names):
    """Each part closed and outward-facing (or skipped), with its :class:`PartRepair`."""
    fixed, reports = [], []
    for number, ((v, f), name) in enumerate(zip(parts, names), start=1):
        try:
            v2, f2, report = repair_part(v, f, number, name)
        except UnrepairablePart as e:
            centre = ", ".join(f"{c:.2f}" for c in (v.min(0) + v.max(0)) / 2)
            reason = f"{e} (in {name!r}, centre {centre} m from the stem base)"
            if entry.repair != "skip":
                raise ModelFileError(entry.source, f"part {number}", reason + "; fix the mesh, or give "
                                     "repair: skip to leave such parts out of the wood volume") from None
            v2, f2, report = v, f, PartRepair(number, name, "skipped", len(f), len(f), boundary_loops(f), 0, 0,
                                              math.nan, math.nan, reason)
        fixed.append((v2, f2))
        reports.append(report)
    return fixed, reports


def qsm_tree_model(entry: QsmTree, name: str) -> Model:
    """A QSM: one closed tube per cylinder (its exact volume), one component per branch, procedural leaves."""
    cyl = read_qsm(entry.qsm, entry.units)   # in metres: each column in the unit its header names, else units
    start, end = (to_tree_frame(p, "m", entry.up) for p in (cyl.start, cyl.end))
    radius = cyl.radius
    widest = int(np.argmax(radius))
    if radius[widest] > MAX_RADIUS:   # before the tubes: a 1e9 m cylinder would be meshed and unioned
        raise ModelFileError(entry.qsm, f"line {cyl.line[widest]}", f"radius {radius[widest]:,.4g} m with units: "
                             f"{entry.units} is wider than any tree (at most {MAX_RADIUS:g} m); check units")
    lowest = int(np.argmin(np.minimum(start[:, 2], end[:, 2])))   # a table may list a cylinder top down
    base = min(start[lowest], end[lowest], key=lambda p: p[2]).copy()
    start, end = start - base, end - base
    cyl = dataclasses.replace(cyl, start=start, end=end, radius=radius)
    height = float(max(start[:, 2].max(), end[:, 2].max()))
    check_height(entry.qsm, height, entry.units, entry.up)
    tubes = [tube(np.array([s, e]), np.array([r, r])) for s, e, r in zip(start, end, radius)]
    stem = int(cyl.branch[lowest])
    branches = [stem] + [int(b) for b in np.unique(cyl.branch) if b != stem]
    component_of = {b: i for i, b in enumerate(branches)}
    union = union_volume(tubes, [f"{entry.qsm}: line {n}" for n in cyl.line])
    volume = WoodVolume(union=union, analytic=cyl.volume(), naive=float(sum(signed_volume(v, f) for v, f in tubes)),
                        parts=len(tubes))
    if len(branches) + 1 > MAX_COMPONENTS:
        raise ModelFileError(entry.qsm, "branch", f"{len(branches):,} branches, more than the {MAX_COMPONENTS - 1:,} "
                             "a model can label")
    components = [Component("stem", TREE_WOOD)] + [Component("branch", TREE_WOOD)] * (len(branches) - 1)
    leaves = _qsm_leaves(entry, cyl)
    meta = {"source": source_name(entry), "height": height, "cylinders": len(tubes), "branches": len(branches)}
    return _model(name, tubes, [component_of[int(b)] for b in cyl.branch], components, leaves, volume, meta)


def _qsm_leaves(entry: QsmTree, cyl):
    if entry.leaf_area <= 0:
        return None
    lines = cyl.branch_lines()
    terminal = cyl.terminal_branches()
    if len(lines) == 1 and len(cyl.radius) > 1:   # no branch column: the tip cylinders carry the leaves
        twigs = [np.array([cyl.start[i], cyl.end[i]]) for i in terminal]
    else:
        twigs = [lines[b] for b in terminal]
    if not twigs:   # the cylinders' parents make a tree (read_qsm), so only the branch ids can loop
        raise ModelFileError(entry.qsm, "branch", "every branch grows from another, so no branch ends in a tip to "
                             "carry leaves; check the branch column, or give leaf_area: 0")
    rng = seeds.rng(entry.seed, "leaves")
    return leaves_on_twigs(twigs, entry.leaf_area, entry.leaf_length, entry.leaf_width, entry.leaf_inclination,
                           entry.leaf_clumping, rng)


def _model(name, wood_meshes, wood_components, components, leaves, volume, meta) -> Model:
    wood = Part("wood", *merge(wood_meshes, list(wood_components)))
    parts = [wood]
    if leaves is not None:
        v, f = leaves
        components = components + [Component("leaves", TREE_LEAVES)]
        parts.append(Part("leaves", np.asarray(v, np.float64), np.asarray(f, np.uint32),
                          np.full(len(f), len(components) - 1, np.uint16)))
    return Model(name, parts, components, volume, meta)
