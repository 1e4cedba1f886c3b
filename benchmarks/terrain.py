"""Terrain build time: a GeoTIFF DEM read, cropped and meshed, and a terrain mesh sampled on the 1 m grid.

    python benchmarks/terrain.py              # a 2,000 x 2,000 cell DEM; meshes of 2e5 and 2e6 triangles
    python benchmarks/terrain.py --quick      # 200 x 200 cells, 2e4 triangles (CI)
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import rasterio
import trimesh
from rasterio.transform import Affine

from mitsuforest.plan.terrain import make_terrain


def dem_file(folder: Path, cells: int, cell: float) -> Path:
    """A north-up float32 GeoTIFF of ``cells`` x ``cells`` smooth relief."""
    x = (np.arange(cells) + 0.5) * cell
    gx, gy = np.meshgrid(x, x[::-1])
    z = (5 * np.sin(gx / 37.0) * np.cos(gy / 53.0) + 0.01 * gx).astype(np.float32)
    path = folder / "dem.tif"
    with rasterio.open(path, "w", driver="GTiff", width=cells, height=cells, count=1, dtype="float32",
                       transform=Affine(cell, 0, 0, 0, -cell, cells * cell)) as dst:
        dst.write(z, 1)
    return path


def mesh_file(folder: Path, triangles: int, side: float) -> Path:
    """A grid mesh of about ``triangles`` triangles over ``side`` x ``side`` m, jittered so it is irregular."""
    n = int(np.sqrt(triangles / 2)) + 1
    g = np.linspace(-1, side + 1, n)
    gx, gy = np.meshgrid(g, g)
    vertices = np.column_stack([gx.ravel(), gy.ravel(), np.sin(gx.ravel() / 9.0)])
    i = np.arange(n - 1)
    a = (i[:, None] * n + i[None, :]).ravel()
    faces = np.vstack([np.column_stack([a, a + 1, a + n + 1]), np.column_stack([a, a + n + 1, a + n])])
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    path = folder / f"ground_{len(faces)}.ply"
    mesh.export(path)
    return path


def timed(fn, repeat: int = 1):
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return out, best


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args(argv)
    cells, triangle_counts = (200, (20_000,)) if args.quick else (2000, (200_000, 2_000_000))
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        cell = 0.5
        side = cells * cell - 2 * cell          # the plot lies one cell inside the DEM
        dem = dem_file(folder, cells, cell)
        settings = SimpleNamespace(type="dem", path=str(dem))
        origin = SimpleNamespace(offset=(cell, cell, 0.0), crs=None)
        terrain, seconds = timed(lambda: make_terrain(settings, (side, side), 0, origin=origin), 2)
        triangles = 2 * (len(terrain.x) - 1) * (len(terrain.y) - 1)
        print(f"dem: {cells} x {cells} cells of {cell} m -> plot {side:g} m, grid {len(terrain.x)} x "
              f"{len(terrain.y)} ({triangles:,} triangles): {seconds:.2f} s")
        _, mesh_seconds = timed(lambda: terrain.mesh(), 2)
        print(f"dem: ground mesh arrays: {mesh_seconds:.2f} s")
        for count in triangle_counts:
            path = mesh_file(folder, count, 100.0)
            settings = SimpleNamespace(type="mesh", path=str(path))
            terrain, seconds = timed(lambda: make_terrain(settings, (100.0, 100.0), 0))
            print(f"mesh: {count:,} triangles (file {path.name}) sampled on the 1 m grid of a 100 m plot: "
                  f"{seconds:.2f} s (read + sample)")


if __name__ == "__main__":
    main()
