"""Understory models: bushes, rocks, stumps and deadwood (logs and fallen branches).

Each function is deterministic in its seed. Rocks, stumps and deadwood are closed meshes; deadwood
carries its union wood volume like a tree.
"""

from __future__ import annotations

import numpy as np
import trimesh

from ..classes import BUSH, DEADWOOD, ROCK, STUMP
from .leaves import leaf_blades
from .models import Component, Model, Part, merge
from .skeleton import _curve, _direction
from .tubes import frustum_volume, tube
from .volume import to_manifold, wood_volume


UNDERSTORY_COMPONENTS = 1   # every understory model is one labelled component


def _single(name, kind, classification, meshes, volume=None, meta=None) -> Model:
    v, f, _ = merge(meshes, [0] * len(meshes))
    part = Part(kind, v, f, np.zeros(len(f), np.uint16))
    return Model(name, [part], [Component(kind, classification)], volume, meta or {})


def bush_model(seed: int, name: str) -> Model:
    """A multi-stemmed shrub 0.6-2 m tall with small leaves in an ellipsoidal crown (one component)."""
    rng = np.random.default_rng(seed)
    height, width = rng.uniform(0.6, 2.0), rng.uniform(0.8, 2.5)
    stems = []
    for _ in range(rng.integers(3, 8)):
        d = _direction(np.array([0.0, 0.0, 1.0]), np.deg2rad(rng.uniform(10, 45)), rng.uniform(0, 2 * np.pi))
        length = height * rng.uniform(0.7, 1.0) / max(d[2], 0.5)
        pts, radii = _curve(np.zeros(3), d, length, rng.uniform(0.008, 0.02), 0.003, 4, 0.2, rng)
        stems.append(tube(pts, radii))
    count = int(rng.uniform(1.5, 5.0) * width * height / (0.5 * 0.06 * 0.02))
    u = rng.normal(size=(count, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    u *= rng.random((count, 1)) ** (1 / 3)
    anchors = u * [width / 2, width / 2, height / 2] + [0, 0, height / 2]
    leaves = leaf_blades(anchors, 0.06, 0.02, 40.0, rng)
    return _single(name, "bush", BUSH, stems + [leaves], meta={"height": height})


def rock_model(seed: int, name: str) -> Model:
    """A rounded, lumpy boulder 0.3-1.2 m across, a third buried (closed)."""
    rng = np.random.default_rng(seed)
    ico = trimesh.creation.icosphere(subdivisions=3)
    v = np.asarray(ico.vertices, float)
    size = rng.uniform(0.3, 1.2)
    lumps = sum(rng.uniform(0.05, 0.15) * np.sin(v @ rng.normal(0, 2.5, 3) + rng.uniform(0, 6)) for _ in range(4))
    v = v * (1 + lumps)[:, None] * (size / 2) * [1.0, rng.uniform(0.6, 1.0), rng.uniform(0.4, 0.7)]
    v[:, 2] -= 0.3 * v[:, 2].max()
    faces = np.asarray(ico.faces, np.int64)
    to_manifold(v, faces, name)  # a rock is a closed part too
    return _single(name, "rock", ROCK, [(v, faces)], meta={"size": size})


def stump_model(seed: int, name: str) -> Model:
    """A cut stump: a short flared cylinder 0.2-0.8 m tall, 0.2-0.7 m across (closed)."""
    rng = np.random.default_rng(seed)
    r, h = rng.uniform(0.1, 0.35), rng.uniform(0.2, 0.8)
    z = np.linspace(-0.1, h, 6)
    radii = r * (1 + 0.3 * np.exp(-(z + 0.1) / 0.15))
    pts = np.column_stack([np.zeros_like(z), np.zeros_like(z), z])
    mesh = tube(pts, radii)
    return _single(name, "stump", STUMP, [mesh],
                   meta={"height": h, "radius": r})


def deadwood_model(seed: int, name: str, length: float = 4.0, radius: float = 0.1) -> Model:
    """A fallen log or branch of ``length`` and base ``radius`` lying along x on the ground, with 0-3
    side branches (each at most 1.5 m long, 30-60° off the log: they reach 1.3 m sideways at most);
    carries its wood volume."""
    rng = np.random.default_rng(seed)
    r = radius
    pts, radii = _curve([-length / 2, 0, r * 0.8], [1.0, 0, 0], length, r, r * 0.4, max(int(length / 0.5), 2),
                        0.0, rng, wobble=0.03)
    pts[:, 2] = r * 0.8 - np.linspace(0, 0.1 * r, len(pts))  # resting, slightly sunk into the litter
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
    return _single(name, "deadwood", DEADWOOD, meshes, volume=volume,
                   meta={"length": length, "radius": r})
