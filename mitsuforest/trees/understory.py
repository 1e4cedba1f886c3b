"""Understory models: shrubs, rocks, stumps and deadwood (logs and fallen branches).

Each function is deterministic in its seed. Shrubs are small branching plants of several forms
(:data:`SHRUB_FORMS`), each stem a closed tube with leaves clumped at the shoot tips. Rocks are
irregular unions of convex hulls; stumps have an oblique cut and root buttresses; logs are bent,
knotty and snapped. Rocks, stumps and deadwood are closed meshes, and stumps and deadwood carry their
union wood volume like a tree.
"""

from __future__ import annotations

import manifold3d
import numpy as np

from .. import seeds
from ..classes import BUSH, DEADWOOD, ROCK, STUMP
from ..specs.understory import SHRUB_FORMS, ShrubForm
from .leaves import leaf_blades, leaf_count
from .models import Component, Model, Part, merge
from .skeleton import _curve, _direction
from .tubes import frustum_volume, tube
from .volume import to_manifold, wood_volume


MAX_SHRUB_REACH = 1.6       # m from the base (crowns up to 3 m across, leaves beyond the shoots): the plan keeps CLEARANCE["bush"] beyond it


def single_part_model(name, kind, classification, meshes, volume=None, meta=None) -> Model:
    """A model of one part and one labelled component: ``meshes`` ``[(vertices, faces), ...]`` merged."""
    v, f, _ = merge(meshes, [0] * len(meshes))
    part = Part(kind, v, f, np.zeros(len(f), np.uint16))
    return Model(name, [part], [Component(kind, classification)], volume, meta or {})


def shrub_skeleton(form: ShrubForm, rng) -> tuple[list[tuple[np.ndarray, np.ndarray]], int]:
    """Centrelines and radii of a shrub's stems and side shoots, and its stem count.

    Stems leave the root collar at up to ``spread`` from vertical and bend upward; side shoots leave
    the outer two thirds of each stem. The whole is then spread or drawn in horizontally to a crown
    diameter drawn from ``form.crown`` (less 0.2 m: the leaves reach past the shoots), at most
    :data:`MAX_SHRUB_REACH` from the base, and stretched vertically to the height drawn from
    ``form.height`` (the stems' drawn lengths and bends alone would leave it outside the form's range).
    """
    height = rng.uniform(*form.height)
    crown = rng.uniform(*form.crown)
    stems = int(rng.integers(form.stems[0], form.stems[1] + 1))
    pieces = []
    for k in range(stems):
        roll = 2 * np.pi * (k + rng.uniform(0.2, 0.8)) / stems
        angle = np.deg2rad(form.spread * rng.uniform(0.3, 1.0))
        d = _direction(np.array([0.0, 0.0, 1.0]), angle, roll)
        length = height * rng.uniform(0.75, 1.0) / max(np.cos(angle), 0.5)
        r0 = rng.uniform(0.006, 0.012) * (1 + height)
        pts, radii = _curve(np.zeros(3), d, length, r0, 0.002, 5, np.deg2rad(0.5 * np.rad2deg(angle)), rng, 0.08)
        pieces.append((pts, radii))
        for j in range(form.shoots):
            s = 0.35 + 0.6 * (j + rng.uniform(0.1, 0.9)) / form.shoots
            i = min(int(s * (len(pts) - 1)), len(pts) - 2)
            base = pts[i] + (pts[i + 1] - pts[i]) * (s * (len(pts) - 1) - i)
            sd = _direction((pts[i + 1] - pts[i]) / np.linalg.norm(pts[i + 1] - pts[i]),
                            np.deg2rad(form.shoot_angle + rng.normal(0, 8)), rng.uniform(0, 2 * np.pi))
            sl = length * rng.uniform(0.25, 0.45) * (1.2 - s)
            sr = max(radii[i] * 0.5, 0.0015)
            pieces.append(_curve(base, sd, sl, sr, 0.0015, 3, np.deg2rad(15), rng, 0.1))
    reach = max(float(np.hypot(p[:, 0], p[:, 1]).max()) for p, _ in pieces)
    top = max(float(p[:, 2].max()) for p, _ in pieces)
    target = min(crown / 2 - 0.1, MAX_SHRUB_REACH - 0.1)   # leaves add up to a leaf length and a clump beyond the shoots
    for p, _ in pieces:
        p[:, :2] *= target / reach
        p[:, 2] *= height / top
    return pieces, stems


def bush_model(seed: int, name: str, form: int = 0) -> Model:
    """A shrub of form ``SHRUB_FORMS[form]``: several branching stems (closed tubes) and leaves
    clumped at the shoot tips (one component, class bush)."""
    rng = seeds.rng(seed, "bush")
    shape = SHRUB_FORMS[form]
    pieces, stems = shrub_skeleton(shape, rng)
    wood = [tube(p, r) for p, r in pieces]
    points = np.vstack([p for p, _ in pieces])
    height = float(points[:, 2].max())
    width = 2 * float(np.hypot(points[:, 0], points[:, 1]).max())
    envelope = np.pi / 6 * width * width * height   # the ellipsoid the shrub fills
    count = leaf_count(shape.leaf_area_density * envelope, shape.leaf_length, shape.leaf_width)
    tips = np.array([p[-1] for p, _ in pieces])
    outer = [p[int(0.6 * (len(p) - 1)):] for p, _ in pieces]
    which = rng.integers(0, len(pieces), count)
    along = rng.random(count) ** 0.5     # nearer the tip of each shoot
    anchors = np.empty((count, 3))
    for k, seg in enumerate(outer):
        sel = which == k
        t = along[sel] * (len(seg) - 1)
        i = np.minimum(t.astype(int), len(seg) - 2) if len(seg) > 1 else np.zeros(sel.sum(), int)
        f = (t - i)[:, None]
        anchors[sel] = seg[i] + f * (seg[np.minimum(i + 1, len(seg) - 1)] - seg[i]) if len(seg) > 1 else tips[k]
    anchors += rng.normal(0, 0.5 * shape.leaf_length, anchors.shape)
    anchors[:, 2] = np.maximum(anchors[:, 2], 0.02)
    leaves = leaf_blades(anchors, shape.leaf_length, shape.leaf_width, shape.leaf_inclination, rng)
    wv, wf, _ = merge(wood, [0] * len(wood))
    parts = [Part("wood", wv, wf, np.zeros(len(wf), np.uint16)),
             Part("leaves", leaves[0], leaves[1].astype(np.uint32), np.zeros(len(leaves[1]), np.uint16))]
    return Model(name, parts, [Component("bush", BUSH)], None,
                 {"height": height, "width": width, "stems": stems, "shoots": len(pieces) - stems, "form": form,
                  "leaves": count})


def _hull(points: np.ndarray) -> manifold3d.Manifold:
    return manifold3d.Manifold.hull_points(np.ascontiguousarray(points, np.float64))


def rock_model(seed: int, name: str) -> Model:
    """An irregular boulder 0.3-1.2 m across: the union of two to four faceted convex lumps, a third
    of its height buried (closed)."""
    rng = seeds.rng(seed, "rock")
    size = rng.uniform(0.3, 1.2)
    lumps = []
    for k in range(int(rng.integers(2, 5))):
        u = rng.normal(size=(int(rng.integers(14, 30)), 3))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        axes = size / 2 * rng.uniform(0.45, 0.75) * np.array([1.0, rng.uniform(0.6, 1.0), rng.uniform(0.4, 0.7)])
        centre = np.zeros(3) if k == 0 else np.clip(rng.normal(0, size * 0.18, 3), -size / 4, size / 4) * [1, 1, 0.4]
        lumps.append(_hull(centre + u * axes * rng.uniform(0.85, 1.0, (len(u), 1))))
    mesh = manifold3d.Manifold.batch_boolean(lumps, manifold3d.OpType.Add).to_mesh64()
    v = np.asarray(mesh.vert_properties, np.float64)[:, :3].copy()
    faces = np.asarray(mesh.tri_verts, np.int64)
    v[:, 2] -= v[:, 2].min() + 0.3 * np.ptp(v[:, 2])
    to_manifold(v, faces, name)  # a rock is a closed part too
    return single_part_model(name, "rock", ROCK, [(v, faces)], meta={"size": size, "lumps": len(lumps)})


def stump_model(seed: int, name: str) -> Model:
    """A cut stump 0.2-0.8 m tall, 0.2-0.7 m across, with a flared base, a sloping saw cut and three to
    five root buttresses running into the ground (closed parts; carries its union wood volume)."""
    rng = seeds.rng(seed, "stump")
    r, h = rng.uniform(0.1, 0.35), rng.uniform(0.2, 0.8)
    z = np.linspace(-0.1, h, 6)
    radii = r * (1 + 0.3 * np.exp(-(z + 0.1) / 0.15))
    pts = np.column_stack([np.zeros_like(z), np.zeros_like(z), z])
    pts[-1, 0] += r * np.tan(np.deg2rad(rng.uniform(5, 25)))  # the last ring tilts: a sloping cut
    pieces = [(pts, radii)]
    for k in range(int(rng.integers(3, 6))):
        az = 2 * np.pi * (k + rng.uniform(0.2, 0.8)) / 5
        out = np.array([np.cos(az), np.sin(az), 0.0])
        reach = min(r * rng.uniform(1.2, 2.0), 0.5)   # roots end within 0.9 m of the axis
        root = np.array([out * r * 0.3 + [0, 0, 0.12], out * (r + 0.4 * reach) + [0, 0, 0.0],
                         out * (r + reach) + [0, 0, -0.08]])
        pieces.append((root, np.array([0.45 * r, 0.25 * r, 0.08 * r])))
    meshes = [tube(p, q) for p, q in pieces]
    volume = wood_volume(meshes, sum(frustum_volume(p, q) for p, q in pieces),
                         names=[f"{name} piece {i}" for i in range(len(meshes))])
    return single_part_model(name, "stump", STUMP, meshes, volume=volume,
                   meta={"height": h, "radius": r, "roots": len(pieces) - 1})


def deadwood_model(seed: int, name: str, length: float = 4.0, radius: float = 0.1) -> Model:
    """A fallen log or branch of ``length`` and base ``radius`` lying along x on the ground, bowed (at
    most 0.1 m), knotty (radius varying along it) and snapped (blunt at the thin end), with 0-3 side
    branches (each at most 1.5 m long, 30-60° off the log: they reach 1.3 m sideways at most);
    carries its wood volume."""
    rng = seeds.rng(seed, "deadwood")
    r = radius
    segments = max(int(length / 0.25), 4)
    pts, radii = _curve([-length / 2, 0, r * 0.8], [1.0, 0, 0], length, r, r * rng.uniform(0.45, 0.8), segments,
                        0.0, rng, wobble=0.04)
    pts[:, 2] = r * 0.8 - np.linspace(0, 0.1 * r, len(pts))  # resting, slightly sunk into the litter
    pts[:, 1] += rng.uniform(-0.1, 0.1) * np.sin(np.linspace(0, np.pi, len(pts)))  # a bow
    knots = np.convolve(rng.normal(0, 1, len(radii) + 2), np.ones(3) / 3, mode="valid")
    radii = radii * (1 + 0.12 * knots)  # swellings and necks; the snapped end stays blunt
    pieces = [(pts, radii)]
    for _ in range(rng.integers(0, 4)):
        s = rng.uniform(0.2, 0.8)
        i = int(s * (len(pts) - 1))
        d = _direction(np.array([1.0, 0, 0]), np.deg2rad(rng.uniform(30, 60)), rng.choice([-1, 1]) * np.pi / 2)
        d[2] = 0.05
        d /= np.linalg.norm(d)
        sub_len, sub_r = rng.uniform(0.4, 1.5), radii[i] * 0.45
        sp, sr = _curve(pts[i] + d * 0.5 * radii[i], d, sub_len, sub_r, sub_r * 0.4, 3, 0.0, rng, 0.03)
        pieces.append((sp, sr))
    meshes = [tube(p, q) for p, q in pieces]
    volume = wood_volume(meshes, sum(frustum_volume(p, q) for p, q in pieces),
                         names=[f"{name} piece {i}" for i in range(len(meshes))])
    return single_part_model(name, "deadwood", DEADWOOD, meshes, volume=volume,
                   meta={"length": length, "radius": r})
