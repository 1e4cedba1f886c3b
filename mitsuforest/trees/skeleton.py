"""The branching skeleton of a procedural tree: polylines with radii.

Weber & Penn-style recursion. Eucalyptus form: a straight tapering stem that forks into co-dominant
leaders at ``fork_height``; first-order branches only in the live crown (the lower stem self-prunes),
ascending and bending upward; second-order branches and third-order twigs along them; leaves hang from
the outer part of the terminal twigs. The other families change the crown envelope and the branch
arrangement (:func:`crown_radius`): Acacia a broad rounded crown over a low fork, Pinus radiata whorls of
branches on one leader under a cone. Radii follow the parent where a branch starts
(``branch_radius_ratio``, then halving per order) and taper linearly to ``min_radius`` at the tip.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import seeds
from ..specs.archetypes import Archetype

GOLDEN_ANGLE = np.pi * (3 - np.sqrt(5))


@dataclass
class Branch:
    points: np.ndarray   # (n, 3) centreline, tree frame (stem base at the origin, +z up)
    radii: np.ndarray    # (n,)
    order: int           # 0 stem, 1 first-order branch or leader, 2, 3
    component: int       # 0 the stem; 1.. one per first-order branch with all its descendants

    def at(self, s: float) -> tuple[np.ndarray, np.ndarray, float]:
        """Position, unit direction and radius at arc-length fraction ``s`` in [0, 1]."""
        seg = np.linalg.norm(np.diff(self.points, axis=0), axis=1)
        cum = np.concatenate([[0.0], np.cumsum(seg)])
        x = s * cum[-1]
        i = min(int(np.searchsorted(cum, x, side="right")) - 1, len(seg) - 1)
        f = (x - cum[i]) / seg[i]
        p = self.points[i] + f * (self.points[i + 1] - self.points[i])
        d = (self.points[i + 1] - self.points[i]) / seg[i]
        r = self.radii[i] + f * (self.radii[i + 1] - self.radii[i])
        return p, d, float(r)

    @property
    def length(self) -> float:
        return float(np.linalg.norm(np.diff(self.points, axis=0), axis=1).sum())


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a × b`` of two 3-vectors with np.cross's arithmetic (the same bits), without its overhead for
    one pair, which was most of the time spent growing a tree."""
    a0, a1, a2 = a.tolist()
    b0, b1, b2 = b.tolist()
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def _rotate(v: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    return v * np.cos(angle) + _cross(axis, v) * np.sin(angle) + axis * np.dot(axis, v) * (1 - np.cos(angle))


def _orthogonal(d: np.ndarray) -> np.ndarray:
    a = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = _cross(d, a)
    return u / np.linalg.norm(u)


def _direction(parent_dir: np.ndarray, angle: float, roll: float) -> np.ndarray:
    """A direction ``angle`` away from ``parent_dir``, rolled by ``roll`` about it."""
    side = _rotate(_orthogonal(parent_dir), parent_dir, roll)
    return _rotate(parent_dir, _cross(parent_dir, side), angle)


def _curve(start, direction, length, r0, r1, segments, bend, rng, wobble=0.04):
    """A polyline bending its direction toward +z by ``bend`` radians in total."""
    pts = [np.asarray(start, float)]
    d = np.asarray(direction, float)
    step = length / segments
    up = np.array([0.0, 0.0, 1.0])
    for _ in range(segments):
        axis = _cross(d, up)
        if np.linalg.norm(axis) > 1e-9:
            d = _rotate(d, axis, bend / segments)
        d = d + rng.normal(0, wobble, 3)
        d /= np.linalg.norm(d)
        pts.append(pts[-1] + step * d)
    radii = np.linspace(r0, r1, segments + 1)
    return np.array(pts), radii


BREAST_HEIGHT = 1.3   # m, where ``dbh`` is the stem's diameter


def stem_radius(a: Archetype, z) -> np.ndarray:
    """Stem radius at height ``z``: the taper profile through dbh at 1.3 m, with a basal flare (a quarter
    wider at the ground, decaying over 0.4 m and gone at 1.3 m, so that the diameter there is ``dbh``)."""
    z = np.asarray(z, float)
    rel = np.clip((a.height - z) / (a.height - BREAST_HEIGHT), 0.0, None) ** a.taper
    flare = 1.0 + 0.25 * np.clip(np.exp(-z / 0.4) - np.exp(-BREAST_HEIGHT / 0.4), 0.0, None)
    return np.maximum(0.5 * a.dbh * rel * flare, a.min_radius)


def _segments(length: float, radius: float) -> int:
    """Segments by curvature scale: thick wood bends slowly, so long segments are fine."""
    return int(np.clip(np.ceil(length / np.clip(6 * radius, 0.15, 0.6)), 1, 60))


BRANCHES_PER_WHORL = 4   # Pinus radiata: first-order branches per whorl


def crown_radius(a: Archetype, z: float) -> float:
    """Crown radius available at height z: the family's envelope over the live crown.

    Eucalyptus a half-ellipse widest just below mid-crown; Acacia a flatter, broader superellipse
    widest at 60 % of the crown; Pinus radiata a cone from the crown base to the top, blunter as
    ``crown_exponent`` falls below 1.
    """
    base = a.height * (1 - a.crown_ratio)
    radius = 0.5 * a.crown_diameter
    if a.species == "pinus_radiata":
        u = np.clip((z - base) / (a.height - base), 0, 1)
        return radius * (1.0 - u) ** a.crown_exponent
    widest, exponent = (0.6, 3.0) if a.species == "acacia" else (0.45, 2.0)
    mid, half = base + widest * (a.height - base), 0.5 * (a.height - base)
    u = np.clip(np.abs(z - mid) / (half * 1.1), 0, 1)
    return radius * (1 - u ** exponent) ** (1 / exponent)


def crown_volume_points(a: Archetype, stem: Branch, count: int, rng) -> np.ndarray:
    """(count, 3) points uniform in the volume of the crown envelope (:func:`crown_radius` about the
    stem's axis, from the crown base to the top), drawn by rejection from the enclosing cylinder."""
    base, radius = a.height * (1 - a.crown_ratio), 0.5 * a.crown_diameter
    if a.leaf_lift > 0:
        return _lifted_crown_points(a, stem, count, rng)
    out, have = np.empty((count, 3)), 0
    while have < count:
        n = 2 * (count - have) + 64
        z = rng.uniform(base, a.height, n)
        rho, phi = radius * np.sqrt(rng.random(n)), rng.uniform(0, 2 * np.pi, n)
        keep = rho <= crown_radius(a, z)
        z, rho, phi = z[keep][:count - have], rho[keep][:count - have], phi[keep][:count - have]
        out[have:have + len(z)] = _about_stem(stem, z, rho, phi)
        have += len(z)
    return out


def _about_stem(stem: Branch, z, rho, phi) -> np.ndarray:
    """(n, 3) points at heights ``z`` (n,), ``rho`` (n,) from the stem's axis at bearing ``phi`` (n,)."""
    axis_x = np.interp(z, stem.points[:, 2], stem.points[:, 0])
    axis_y = np.interp(z, stem.points[:, 2], stem.points[:, 1])
    return np.column_stack([axis_x + rho * np.cos(phi), axis_y + rho * np.sin(phi), z])


def _lifted_crown_points(a: Archetype, stem: Branch, count: int, rng) -> np.ndarray:
    """(count, 3) points through the crown envelope, as many in a metre of crown as its cross-section to
    the power ``1 - a.leaf_lift`` (``leaf_lift`` 1: the same number in every metre): heights by rejection,
    then uniform over the envelope's disc there."""
    base, radius = a.height * (1 - a.crown_ratio), 0.5 * a.crown_diameter
    z, have = np.empty(count), 0
    while have < count:
        n = 2 * (count - have) + 64
        zs = rng.uniform(base, a.height, n)
        keep = zs[rng.random(n) <= (crown_radius(a, zs) / radius) ** (2 * (1 - a.leaf_lift))][:count - have]
        z[have:have + len(keep)] = keep
        have += len(keep)
    rho, phi = crown_radius(a, z) * np.sqrt(rng.random(count)), rng.uniform(0, 2 * np.pi, count)
    return _about_stem(stem, z, rho, phi)


def _branch_site(a: Archetype, i: int, s_lo: float, rng) -> tuple[float, float]:
    """Arc-length fraction along the parent and roll increment of first-order branch ``i``: spread
    evenly (a golden-angle spiral), or in whorls of BRANCHES_PER_WHORL for Pinus radiata, from ``s_lo`` up
    to 93 % (95 %) of the parent, or half-way from ``s_lo`` to its tip where that is higher (a leader
    that just reaches the crown base)."""
    if a.species == "pinus_radiata":
        whorls = -(-a.branches // BRANCHES_PER_WHORL)
        w, k = divmod(i, BRANCHES_PER_WHORL)
        s = s_lo + (max(0.95, (1 + s_lo) / 2) - s_lo) * (w + 0.5 + rng.uniform(-0.08, 0.08)) / whorls
        turn = (GOLDEN_ANGLE if k == 0 else 2 * np.pi / BRANCHES_PER_WHORL) + rng.normal(0, 0.15)
        return s, turn
    s = s_lo + (max(0.93, (1 + s_lo) / 2) - s_lo) * (i + rng.uniform(0.2, 0.8)) / a.branches
    return s, GOLDEN_ANGLE + rng.normal(0, 0.3)


def grow(a: Archetype) -> list[Branch]:
    """All branches of one tree, stem first; deterministic in the archetype's parameters."""
    rng = seeds.rng(a.seed, "skeleton")
    branches: list[Branch] = []
    # Stem: straight with a slight random lean and sweep.
    z = np.linspace(0, a.height, _segments(a.height, a.dbh) + 1)
    lean = np.deg2rad(a.lean) * rng.normal(0, 0.5, 2)
    sweep = np.deg2rad(a.lean) * rng.normal(0, 0.5, 2)
    u = z / a.height
    xy = np.outer(u, lean) * a.height * 0.3 + np.outer(np.sin(np.pi * u), sweep) * a.height * 0.15
    stem = Branch(np.column_stack([xy, z]), stem_radius(a, z), 0, 0)
    branches.append(stem)
    parents = [stem]
    component = 1
    # Co-dominant leaders from the fork up to near the top.
    if a.forks > 1 and a.fork_height > 0:
        zf = a.fork_height * a.height
        for k in range(a.forks - 1):
            p, d, r = stem.at(a.fork_height)
            direction = _direction(d, np.deg2rad(rng.uniform(18, 28)), k * 2 * np.pi / (a.forks - 1) + rng.uniform(0, 1))
            length = (a.height - zf) * rng.uniform(0.85, 0.97)
            pts, radii = _curve(p, direction, length, 0.8 * r, a.min_radius * 2, _segments(length, r),
                                np.deg2rad(15), rng, wobble=0.02)
            leader = Branch(pts, radii, 1, component)
            component += 1
            branches.append(leader)
            parents.append(leader)
    # First-order branches in the live crown, spread over the stem and the leaders that reach it, each
    # bare below the crown base.
    crown_base = a.height * (1 - a.crown_ratio)
    parents = [p for p in parents if p.points[-1, 2] > crown_base]
    roll = rng.uniform(0, 2 * np.pi)
    for i in range(a.branches):
        parent = parents[i % len(parents)]
        s_lo = _fraction_at_height(parent, crown_base) if parent.order else crown_base / a.height
        s, turn = _branch_site(a, i, s_lo, rng)
        p, d, r = parent.at(s)
        roll += turn
        angle = np.deg2rad(a.branch_angle + rng.normal(0, 8))
        direction = _direction(np.array([0.0, 0.0, 1.0]), angle, roll)
        reach = max(crown_radius(a, p[2]), 0.4) * rng.uniform(0.75, 1.05)
        length = reach / max(np.sin(angle), 0.3)
        r0 = max(a.branch_radius_ratio * r * rng.uniform(0.8, 1.1), 2 * a.min_radius)
        start = p + direction * 0.5 * r  # start inside the parent, half-way to its surface
        pts, radii = _curve(start, direction, length, r0, a.min_radius * 1.5, _segments(length, r0),
                            np.deg2rad(a.curvature), rng)
        first = Branch(pts, radii, 1, component)
        branches.append(first)
        _children(a, first, rng, branches, order=2)
        component += 1
    for leader in parents[1:]:
        _children(a, leader, rng, branches, order=2, count=max(a.children // 2, 1),
                  s_lo=_fraction_at_height(leader, crown_base))
    _fit_height(branches, max(a.height * (1 - a.crown_ratio), BREAST_HEIGHT), a.height)
    return branches


def _fraction_at_height(branch: Branch, z: float) -> float:
    """Arc-length fraction along ``branch`` (rising, a leader) at which it reaches height ``z``: 0 where
    it starts at or above it. A leader forking below the crown base is bare up to it, as the stem is."""
    if branch.points[0, 2] >= z:
        return 0.0
    seg = np.linalg.norm(np.diff(branch.points, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)]) / seg.sum()
    return float(np.interp(z, np.maximum.accumulate(branch.points[:, 2]), cum))


def _fit_height(branches: list[Branch], crown_base: float, height: float) -> None:
    """Compress the crown vertically above ``crown_base`` so that the tree's top is ``height``.

    Upper branches grow past the stem tip; squeezing only the crown keeps ``height`` the tree's
    total height without changing the clear bole or the crown's footprint. (The caller passes breast
    height where the crown starts below it, so that the stem keeps its ``dbh`` there.)
    """
    top = max(float(b.points[:, 2].max()) for b in branches)
    if top <= height:
        return
    factor = (height - crown_base) / (top - crown_base)
    for b in branches:
        z = b.points[:, 2]
        above = z > crown_base
        z[above] = crown_base + (z[above] - crown_base) * factor


def _children(a: Archetype, parent: Branch, rng, out: list[Branch], order: int, count: int | None = None,
              s_lo: float = 0.0):
    """``count`` branches of ``order`` along ``parent`` between 25 % and 95 % of its length, or from ``s_lo``
    (an arc-length fraction: a leader's crown base) where that is higher."""
    count = (a.children if order == 2 else a.twigs) if count is None else count
    if count == 0 or order > 3:
        return
    roll = rng.uniform(0, 2 * np.pi)
    lo = max(s_lo, 0.25)
    for j in range(count):
        x = j + rng.uniform(0.1, 0.9)
        s = 0.25 + 0.7 * x / count if lo == 0.25 else lo + (0.95 - lo) * x / count
        p, d, r = parent.at(s)
        roll += GOLDEN_ANGLE * 2 + rng.normal(0, 0.4)
        direction = _direction(d, np.deg2rad(rng.uniform(30, 50)), roll)
        scale = 0.45 if order == 2 else 0.35
        length = max(parent.length * scale * (1.1 - 0.5 * s) * rng.uniform(0.8, 1.2), 0.15)
        r0 = max(0.55 * r, a.min_radius)
        start = p + direction * 0.5 * r
        pts, radii = _curve(start, direction, length, r0, a.min_radius, _segments(length, r0),
                            np.deg2rad(10 if order == 2 else -10), rng)
        child = Branch(pts, radii, order, parent.component)
        out.append(child)
        _children(a, child, rng, out, order + 1)


def terminal_branches(branches: list[Branch]) -> list[Branch]:
    """Branches that carry leaves: the highest order present, and leaders' tips."""
    top = max(b.order for b in branches)
    return [b for b in branches if b.order == top or (b.order == 1 and top == 1)]
