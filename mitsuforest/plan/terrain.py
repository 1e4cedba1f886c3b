"""The ground of a plan. Surfaces: flat, smooth noise relief, a user mesh or a GeoTIFF DEM, as a height
field over the plot.

The ground is a rectilinear grid mesh covering the plot: 1 m cells, or a DEM's own cells (its centres
inside the plot, and the plot's edges). :class:`Terrain` also answers heights at any point so the plan
can set objects on it. Everything here is vectorised numpy: a 2,000 x 2,000 DEM meshes in seconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import seeds
from ..errors import UserError
from ..interrupts import import_held


@dataclass(frozen=True)
class Terrain:
    type: str            # flat | noise | mesh | dem (the scene's terrain.type)
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

    def surface_height(self, px, py) -> np.ndarray:
        """Height of the ground as rendered: the plane of the triangle of :meth:`mesh` over each point
        (each cell is cut along its diagonal from ``(x[i], y[j])`` to ``(x[i+1], y[j+1])``). It differs
        from :meth:`height` inside a cell by up to a quarter of the cell's twist; a ground point lies on
        this surface up to its ranging noise. Points beyond the grid get the height at its edge."""
        px, py = np.asarray(px, float), np.asarray(py, float)
        fx = np.interp(px, self.x, np.arange(len(self.x)))      # clamped at the grid's edges
        fy = np.interp(py, self.y, np.arange(len(self.y)))
        i, j = np.minimum(fx.astype(int), len(self.x) - 2), np.minimum(fy.astype(int), len(self.y) - 2)
        u, v = fx - i, fy - j
        z = self.z
        z00, z11 = z[j, i], z[j + 1, i + 1]
        lower = u >= v              # the triangle (i, j), (i+1, j), (i+1, j+1)
        return np.where(lower, z00 + u * (z[j, i + 1] - z00) + v * (z11 - z[j, i + 1]),
                        z00 + v * (z[j + 1, i] - z00) + u * (z11 - z[j + 1, i]))

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


@dataclass(frozen=True)
class MeshGround:
    """A ground that is only a mesh, in place (a HELIOS++ scene's ground parts): no height grid; heights
    are those of its triangles, its mean height beyond them (see :class:`TriangleSurface`)."""

    vertices: np.ndarray   # (n, 3) float64, local frame
    faces: np.ndarray      # (m, 3) uint32
    type: str = "helios"

    def mesh(self) -> tuple[np.ndarray, np.ndarray]:
        return self.vertices, self.faces

    @property
    def mean_height(self) -> float:
        return float(self.vertices[:, 2].mean())


def make_terrain(settings, size, seed: int, cell: float = 1.0, origin=None) -> Terrain:
    """The terrain of a scene's ``terrain`` section (:class:`~mitsuforest.config.types.TerrainSettings`)
    over a plot of ``size`` (m).

    :param origin: the scene's ``origin`` (:class:`~mitsuforest.config.types.Origin`), which places a DEM
        in the local frame and names the CRS it must be in.
    :raises UserError: a mesh or DEM that cannot be read or does not cover the plot.
    """
    nx, ny = (max(int(np.ceil(s / cell)), 1) + 1 for s in size)
    x, y = np.linspace(0, size[0], nx), np.linspace(0, size[1], ny)
    kind = settings.type
    if kind == "flat":
        return Terrain(kind, np.array([0.0, size[0]]), np.array([0.0, size[1]]), np.zeros((2, 2)))
    if kind == "noise":
        return Terrain(kind, x, y, _relief(x, y, settings.amplitude, settings.wavelength, seed))
    if kind == "dem":
        from .dem import read_dem
        offset, crs = (origin.offset, origin.crs) if origin is not None else ((0.0, 0.0, 0.0), None)
        return dem_terrain(*read_dem(settings.path, size, offset, crs), size)
    return Terrain(kind, x, y, _mesh_heights(settings.path, x, y))


def dem_terrain(x, y, z, size) -> Terrain:
    """The terrain of DEM cell centres ``x`` (nx,), ``y`` (ny,) (ascending, local frame) and heights ``z``
    (ny, nx): grid lines at the centres inside the plot and at its edges, heights bilinear in the cells
    (the DEM's own values at its centres; held level beyond the outermost centres)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    cells = Terrain("dem", *_two_centres_each_way(x, y, np.asarray(z, float)))
    gx = np.unique(np.concatenate([[0.0], x[(x > 0) & (x < size[0])], [size[0]]]))
    gy = np.unique(np.concatenate([[0.0], y[(y > 0) & (y < size[1])], [size[1]]]))
    heights = cells.height(*np.meshgrid(gx, gy))
    return Terrain("dem", gx, gy, heights)


def _two_centres_each_way(x, y, z):
    """``x``, ``y``, ``z`` with an axis of a single centre (a DEM one cell wide or high) given a second
    centre 1 m beyond it at the same heights, which :meth:`Terrain.height` needs to interpolate: the
    ground is level along that axis, as beyond the outermost centres of any DEM."""
    if len(x) == 1:
        x, z = np.append(x, x[0] + 1.0), np.repeat(z, 2, axis=1)
    if len(y) == 1:
        y, z = np.append(y, y[0] + 1.0), np.repeat(z, 2, axis=0)
    return x, y, z


def _relief(x, y, amplitude, wavelength, seed):
    """Smooth relief: a few random plane waves around ``wavelength``, scaled to peak-to-peak ``amplitude``."""
    rng = seeds.rng(seed, "terrain")
    gx, gy = np.meshgrid(x, y)
    z = np.zeros_like(gx)
    for _ in range(6):
        k = 2 * np.pi / (wavelength * rng.uniform(0.7, 1.6))
        a = rng.uniform(0, 2 * np.pi)
        z += rng.uniform(0.5, 1.0) * np.sin(k * (np.cos(a) * gx + np.sin(a) * gy) + rng.uniform(0, 2 * np.pi))
    span = z.max() - z.min()
    return (z - z.mean()) * (amplitude / span if span > 0 else 0.0)


def _mesh_heights(path, x, y):
    trimesh = import_held("trimesh")      # here: only a terrain mesh needs it (0.45 s to import)
    try:
        mesh = trimesh.load(path, force="mesh")
    except Exception as e:  # trimesh raises many kinds for unreadable files
        raise UserError(f"{path}: cannot read terrain mesh: {e}") from None
    if not len(mesh.faces):   # trimesh reads text it cannot parse (an OBJ of garbage) as an empty mesh
        raise UserError(f"{path}: the terrain mesh has no triangles (not a mesh file trimesh can read?)")
    z = heights_under(mesh.triangles, x, y)
    if np.isnan(z).any():
        raise UserError(f"{path}: terrain mesh does not cover the whole plot")
    return z


def heights_under(triangles: np.ndarray, x: np.ndarray, y: np.ndarray, chunk: int = 2_000_000) -> np.ndarray:
    """Heights (ny, nx) of triangles (m, 3, 3) at the grid points ``x`` (nx,) x ``y`` (ny,) (ascending), by
    barycentric interpolation in the triangle over each point; NaN where none is. Where triangles overlap
    in plan view the later one wins.

    Each triangle is paired with the grid points of its bounding box, ``chunk`` pairs at a time, so the
    work is the number of triangles plus the grid points under them, all in numpy.
    """
    xy, zt = triangles[:, :, :2], triangles[:, :, 2]
    lo, hi = xy.min(1), xy.max(1)
    i0, i1 = np.searchsorted(x, lo[:, 0], "left"), np.searchsorted(x, hi[:, 0], "right")
    j0, j1 = np.searchsorted(y, lo[:, 1], "left"), np.searchsorted(y, hi[:, 1], "right")
    width = np.maximum(i1 - i0, 0)
    pairs = width * np.maximum(j1 - j0, 0)
    out = np.full(len(y) * len(x), np.nan)
    ends = np.cumsum(pairs)
    first = 0
    while first < len(triangles):
        stop = max(int(np.searchsorted(ends, ends[first] - pairs[first] + chunk, "right")), first + 1)
        t = np.repeat(np.arange(first, stop), pairs[first:stop])
        k = np.arange(len(t)) - np.repeat(ends[first:stop] - pairs[first:stop] - (ends[first] - pairs[first]),
                                          pairs[first:stop])
        gi, gj = i0[t] + k % width[t], j0[t] + k // width[t]
        b1, b2, ok = _barycentric(xy[t], x[gi], y[gj])
        z = zt[t, 0] + b1 * (zt[t, 1] - zt[t, 0]) + b2 * (zt[t, 2] - zt[t, 0])
        out[(gj * len(x) + gi)[ok]] = z[ok]
        first = stop
    return out.reshape(len(y), len(x))


def _barycentric(tri_xy: np.ndarray, px: np.ndarray, py: np.ndarray, eps: float = 1e-9):
    """Barycentric coordinates (b1, b2) of points in triangles (n, 3, 2), and whether each is inside
    (degenerate triangles contain nothing)."""
    v0 = tri_xy[:, 0]
    e1, e2 = tri_xy[:, 1] - v0, tri_xy[:, 2] - v0
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    dx, dy = px - v0[:, 0], py - v0[:, 1]
    valid = np.abs(det) > 1e-12
    safe = np.where(valid, det, 1.0)
    b1 = (dx * e2[:, 1] - dy * e2[:, 0]) / safe
    b2 = (e1[:, 0] * dy - e1[:, 1] * dx) / safe
    return b1, b2, valid & (b1 >= -eps) & (b2 >= -eps) & (b1 + b2 <= 1 + eps)


class TriangleSurface:
    """Heights of a triangle mesh seen from above, at scattered points: the barycentric height in the
    triangle over each point (where triangles overlap in plan view the later one wins, as in
    :func:`heights_under`), ``fallback`` where none is. For grounds that are only a mesh (a HELIOS++
    scene's); a :class:`Terrain` answers :meth:`Terrain.surface_height` directly.

    Triangles are binned on a square grid of about their median size, so a point is tested against
    the few triangles of its cell only.

    :param vertices: (n, 3) float.
    :param faces: (m, 3) int.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, fallback: float = 0.0):
        self.triangles = np.asarray(vertices, np.float64)[np.asarray(faces, np.int64)]
        self.fallback = float(fallback)
        xy = self.triangles[:, :, :2]
        lo, hi = xy.min(1), xy.max(1)
        extent = hi - lo
        self.cell = max(float(np.median(extent.max(1))) if len(xy) else 1.0, 1e-3)
        self.origin = lo.min(0) if len(xy) else np.zeros(2)
        self.shape = tuple(int(n) for n in (np.floor((hi.max(0) - self.origin) / self.cell) + 1)) if len(xy) else (1, 1)
        first, last = self._cells(lo), self._cells(hi)
        width, height = last[:, 0] - first[:, 0] + 1, last[:, 1] - first[:, 1] + 1
        pairs = width * height
        t = np.repeat(np.arange(len(xy)), pairs)
        k = np.arange(len(t)) - np.repeat(np.cumsum(pairs) - pairs, pairs)
        key = (first[t, 1] + k // width[t]) * self.shape[0] + first[t, 0] + k % width[t]
        order = np.argsort(key, kind="stable")
        self.members = t[order]                                   # triangle numbers, cell by cell
        self.starts = np.searchsorted(key[order], np.arange(self.shape[0] * self.shape[1] + 1))

    def _cells(self, xy: np.ndarray) -> np.ndarray:
        return np.floor((xy - self.origin) / self.cell).astype(np.int64)

    def __call__(self, px, py) -> np.ndarray:
        px, py = np.asarray(px, np.float64), np.asarray(py, np.float64)
        out = np.full(len(px), self.fallback)
        cells = self._cells(np.column_stack([px, py]))
        inside = np.flatnonzero((cells >= 0).all(1) & (cells[:, 0] < self.shape[0]) & (cells[:, 1] < self.shape[1]))
        key = cells[inside, 1] * self.shape[0] + cells[inside, 0]
        lo, count = self.starts[key], self.starts[key + 1] - self.starts[key]
        point = np.repeat(inside, count)
        k = np.arange(len(point)) - np.repeat(np.cumsum(count) - count, count)
        tri = self.members[np.repeat(lo, count) + k]
        b1, b2, ok = _barycentric(self.triangles[tri, :, :2], px[point], py[point])
        zt = self.triangles[tri, :, 2]
        z = zt[:, 0] + b1 * (zt[:, 1] - zt[:, 0]) + b2 * (zt[:, 2] - zt[:, 0])
        last = np.zeros(len(px), np.int64) - 1          # the latest triangle over each point
        np.maximum.at(last, point[ok], tri[ok])
        hit = point[ok]
        chosen = tri[ok] == last[hit]
        out[hit[chosen]] = z[ok][chosen]
        return out
