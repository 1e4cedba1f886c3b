"""The ground of a plan. Surfaces: flat, smooth noise relief, or a user mesh, as a height field over the plot.

The ground is a regular grid mesh (1 m cells by default) covering the plot; :class:`Terrain` also
answers heights at any point so the plan can set objects on it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from ..errors import UserError


@dataclass(frozen=True)
class Terrain:
    type: str            # flat | noise | mesh (the scene's terrain.type)
    x: np.ndarray        # (nx,) grid x coordinates, local frame
    y: np.ndarray        # (ny,) grid y coordinates
    z: np.ndarray        # (ny, nx) heights

    def height(self, px, py) -> np.ndarray:
        """Bilinear height at points (same triangulation-independent value the plan uses)."""
        px, py = np.asarray(px, float), np.asarray(py, float)
        fx = np.clip(np.interp(px, self.x, np.arange(len(self.x))), 0, len(self.x) - 1.000001)
        fy = np.clip(np.interp(py, self.y, np.arange(len(self.y))), 0, len(self.y) - 1.000001)
        i, j = fx.astype(int), fy.astype(int)
        u, v = fx - i, fy - j
        z = self.z
        return ((1 - u) * (1 - v) * z[j, i] + u * (1 - v) * z[j, i + 1]
                + (1 - u) * v * z[j + 1, i] + u * v * z[j + 1, i + 1])

    @property
    def mean_height(self) -> float:
        return float(self.z.mean())

    def mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """Vertices (nx*ny, 3) and faces (2(nx-1)(ny-1), 3), counter-clockwise from above."""
        gx, gy = np.meshgrid(self.x, self.y)
        vertices = np.column_stack([gx.ravel(), gy.ravel(), self.z.ravel()])
        nx = len(self.x)
        j, i = np.meshgrid(np.arange(len(self.y) - 1), np.arange(nx - 1), indexing="ij")
        a = (j * nx + i).ravel()
        faces = np.concatenate([np.stack([a, a + 1, a + nx + 1], 1), np.stack([a, a + nx + 1, a + nx], 1)])
        return vertices, faces.astype(np.uint32)


def make_terrain(settings, size, seed: int, cell: float = 1.0) -> Terrain:
    """The terrain of a scene's ``terrain`` section (:class:`~mitsuforest.config.types.TerrainSettings`)
    over a plot of ``size`` (m)."""
    nx, ny = (max(int(np.ceil(s / cell)), 1) + 1 for s in size)
    x, y = np.linspace(0, size[0], nx), np.linspace(0, size[1], ny)
    kind = settings.type
    if kind == "flat":
        return Terrain(kind, np.array([0.0, size[0]]), np.array([0.0, size[1]]), np.zeros((2, 2)))
    if kind == "noise":
        return Terrain(kind, x, y, _relief(x, y, settings.amplitude, settings.wavelength, seed))
    return Terrain(kind, x, y, _mesh_heights(settings.path, x, y))


def _relief(x, y, amplitude, wavelength, seed):
    """Smooth relief: a few random plane waves around ``wavelength``, scaled to peak-to-peak ``amplitude``."""
    rng = np.random.default_rng([seed, 17])
    gx, gy = np.meshgrid(x, y)
    z = np.zeros_like(gx)
    for _ in range(6):
        k = 2 * np.pi / (wavelength * rng.uniform(0.7, 1.6))
        a = rng.uniform(0, 2 * np.pi)
        z += rng.uniform(0.5, 1.0) * np.sin(k * (np.cos(a) * gx + np.sin(a) * gy) + rng.uniform(0, 2 * np.pi))
    span = z.max() - z.min()
    return (z - z.mean()) * (amplitude / span if span > 0 else 0.0)


def _mesh_heights(path, x, y):
    try:
        mesh = trimesh.load(path, force="mesh")
    except Exception as e:  # trimesh raises many kinds for unreadable files
        raise UserError(f"{path}: cannot read terrain mesh: {e}") from None
    gx, gy = np.meshgrid(x, y)
    # Heights by barycentric lookup of the triangle under each grid point.
    tri = mesh.triangles[:, :, :2]
    z = np.full(gx.shape, np.nan)
    pts = np.column_stack([gx.ravel(), gy.ravel()])
    out = z.ravel()
    for t, zt in zip(tri, mesh.triangles[:, :, 2]):
        lo, hi = t.min(0), t.max(0)
        sel = np.nonzero(np.all((pts >= lo) & (pts <= hi), axis=1))[0]
        if not len(sel):
            continue
        m = np.array([t[1] - t[0], t[2] - t[0]]).T
        if abs(np.linalg.det(m)) < 1e-12:
            continue
        b = np.linalg.solve(m, (pts[sel] - t[0]).T).T
        ok = (b >= -1e-9).all(1) & (b.sum(1) <= 1 + 1e-9)
        out[sel[ok]] = zt[0] + b[ok] @ (zt[1:] - zt[0])
    if np.isnan(out).any():
        raise UserError(f"{path}: terrain mesh does not cover the whole plot")
    return out.reshape(gx.shape)
