"""Closed polygonal tubes along a polyline: the mesh of one branch.

A branch is one closed tube whose rings are mitred into the bisector plane of adjacent segments and
carried by parallel-transported frames, so bends leave no cracks and no overlaps. Ring radii are
scaled by :func:`area_correction` so that an n-sided tube has the volume of the round frustums.
"""

from __future__ import annotations

import numpy as np


def area_correction(sides: int) -> float:
    """Radius factor giving an n-gon the area of its circle: ``sqrt(2π / (n sin(2π/n)))``."""
    return float(np.sqrt(2 * np.pi / (sides * np.sin(2 * np.pi / sides))))


def sides_for_radius(radius: float) -> int:
    """Tube sides by radius: the stem is round to the laser, twigs are a few triangles.

    At 30 m the beam footprint is ~15 mm across, so a 5-sided 3 mm twig is indistinguishable from
    a round one while a 30 cm stem needs ~20 sides for its outline to stay within ~1 cm.
    """
    for limit, sides in ((0.15, 20), (0.06, 14), (0.025, 10), (0.01, 7)):
        if radius >= limit:
            return sides
    return 5


def frustum_volume(points: np.ndarray, radii: np.ndarray) -> float:
    """Analytic volume of the round frustums along a polyline: ``Σ πh/3 (r0² + r0 r1 + r1²)``.

    :param points: (n, 3) node positions.
    :param radii: (n,) radius at each node.
    """
    h = np.linalg.norm(np.diff(points, axis=0), axis=1)
    r0, r1 = radii[:-1], radii[1:]
    return float(np.sum(np.pi * h / 3.0 * (r0 * r0 + r0 * r1 + r1 * r1)))


def _perpendicular(t: np.ndarray) -> np.ndarray:
    a = np.array([1.0, 0.0, 0.0]) if abs(t[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(t, a)
    return u / np.linalg.norm(u)


def transported_frames(tangents: np.ndarray) -> np.ndarray:
    """Parallel-transport a normal vector along segment tangents (rotation-minimising frames).

    :param tangents: (m, 3) unit segment directions.
    :returns: (m, 3) unit vectors, each perpendicular to its tangent.
    """
    u = np.empty_like(tangents)
    u[0] = _perpendicular(tangents[0])
    for i in range(1, len(tangents)):
        a, b = tangents[i - 1], tangents[i]
        axis = np.cross(a, b)
        s, c = np.linalg.norm(axis), float(np.dot(a, b))
        v = u[i - 1]
        if s > 1e-12:  # Rodrigues rotation taking a onto b
            k = axis / s
            v = v * c + np.cross(k, v) * s + k * np.dot(k, v) * (1 - c)
        v = v - np.dot(v, b) * b
        u[i] = v / np.linalg.norm(v)
    return u


def tube(points: np.ndarray, radii: np.ndarray, sides: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Mesh a closed, outward-oriented tube through ``points``.

    :param points: (n, 3) float64 centreline nodes, n >= 2, no zero-length segments.
    :param radii: (n,) radius at each node (> 0).
    :param sides: polygon sides; by the base radius when None.
    :returns: vertices (n*sides + 2, 3) float64 and faces (2*(n-1)*sides + 2*sides, 3) int64.
    """
    points = np.asarray(points, np.float64)
    radii = np.asarray(radii, np.float64)
    n = len(points)
    sides = sides or sides_for_radius(float(radii[0]))
    seg = np.diff(points, axis=0)
    tangents = seg / np.linalg.norm(seg, axis=1, keepdims=True)
    u_seg = transported_frames(tangents)
    v_seg = np.cross(tangents, u_seg)
    # Ring i lies in the plane normal to the bisector of the segments meeting there.
    node_t = np.vstack([tangents[:1], tangents[:-1] + tangents[1:], tangents[-1:]])
    node_t /= np.linalg.norm(node_t, axis=1, keepdims=True)
    idx = np.minimum(np.arange(n), n - 2)  # each node takes the frame of its outgoing segment
    t, u, v = tangents[idx], u_seg[idx], v_seg[idx]
    phi = 2 * np.pi * np.arange(sides) / sides
    r = radii[:, None, None] * area_correction(sides)
    offset = r * (np.cos(phi)[None, :, None] * u[:, None, :] + np.sin(phi)[None, :, None] * v[:, None, :])
    # Slide each circle point along its segment direction onto the mitre plane.
    along = -np.einsum("nsk,nk->ns", offset, node_t) / np.einsum("nk,nk->n", t, node_t)[:, None]
    rings = points[:, None, :] + offset + along[..., None] * t[:, None, :]
    vertices = np.vstack([rings.reshape(-1, 3), points[0], points[-1]])
    k = np.arange(sides)
    k1 = (k + 1) % sides
    ring = np.arange(n - 1)[:, None] * sides
    a, b, c, d = ring + k, ring + k1, ring + sides + k1, ring + sides + k
    side = np.concatenate([np.stack([a, b, c], -1), np.stack([a, c, d], -1)], axis=1).reshape(-1, 3)
    start, end = n * sides, n * sides + 1
    cap0 = np.stack([np.full(sides, start), k1, k], -1)
    cap1 = np.stack([np.full(sides, end), (n - 1) * sides + k, (n - 1) * sides + k1], -1)
    return vertices, np.vstack([side, cap0, cap1]).astype(np.int64)


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Divergence-theorem volume of a closed triangle mesh (positive when faces point outward)."""
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    centre = vertices.mean(axis=0)  # shifting first keeps float64 exact far from the origin
    a, b, c = a - centre, b - centre, c - centre
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)
