"""Terrain from a GeoTIFF DEM and from a mesh: scanned ground points at the analytic height, clear refusals."""

import numpy as np
import pytest
import rasterio
import trimesh
from helpers import scene_file
from rasterio.transform import Affine

from mitsuforest.cli import main
from mitsuforest.config import ConfigError, load_scene
from mitsuforest.pipeline import render
from mitsuforest.plan import make_plan
from mitsuforest.plan.terrain import heights_under

EAST, NORTH = 500_000.0, 6_000_000.0        # the DEMs' world frame (metres of a projected CRS)
OFFSET = [EAST + 3.0, NORTH + 4.0, 100.0]    # the plot's SW corner in that frame, and a datum


def plane(x, y):
    return 130.0 + 0.08 * (x - EAST) - 0.05 * (y - NORTH)


def hill(x, y):
    """A Gaussian hill of 3 m, sigma 6 m, on a 120 m datum, centred in the plot."""
    r2 = (x - OFFSET[0] - 20.0) ** 2 + (y - OFFSET[1] - 20.0) ** 2
    return 120.0 + 3.0 * np.exp(-r2 / (2 * 6.0 ** 2))


def write_dem(path, surface, cell=0.25, size=48.0, crs="EPSG:28355", holes=False):
    """A north-up GeoTIFF whose cell centres hold ``surface`` exactly, covering [EAST, EAST + size]^2."""
    n = int(size / cell)
    x = EAST + (np.arange(n) + 0.5) * cell
    y = NORTH + size - (np.arange(n) + 0.5) * cell
    z = surface(*np.meshgrid(x, y)).astype(np.float32)
    if holes:
        z[n // 2, n // 2] = -9999.0
    with rasterio.open(path, "w", driver="GTiff", width=n, height=n, count=1, dtype="float32", crs=crs,
                       transform=Affine(cell, 0, EAST, 0, -cell, NORTH + size), nodata=-9999.0) as dst:
        dst.write(z, 1)
    return path


def dem_scene(tmp_path, dem, **origin):
    return scene_file(tmp_path, terrain={"type": "dem", "path": str(dem)},
                      origin={"offset": OFFSET, **origin},
                      survey={"altitude": 30, "pulse_frequency": 100000, "scan_frequency": 50, "speed": 10,
                              "lines": [[[20.0, -5.0], [20.0, 45.0]]]})


@pytest.mark.parametrize("surface", [plane, hill])
def test_dem_ground_points_lie_at_the_analytic_height(tmp_path, surface):
    path = dem_scene(tmp_path, write_dem(tmp_path / "dem.tif", surface), crs="EPSG:28355")
    result = render(path, write=False, progress=False, log=lambda *_: None)
    p = result.points
    inside = ((p["x"] > OFFSET[0] + 1) & (p["x"] < OFFSET[0] + 39)
              & (p["y"] > OFFSET[1] + 1) & (p["y"] < OFFSET[1] + 39))
    p = p[inside]
    assert len(p) > 20_000
    error = np.abs(p["z"] - surface(p["x"], p["y"]))
    assert error.max() < 0.01
    # The hill is really there: the points span its 3 m.
    if surface is hill:
        assert np.ptp(p["z"]) > 2.9


def test_dem_heights_honour_the_offset_and_carry_objects(tmp_path):
    dem = write_dem(tmp_path / "dem.tif", hill)
    scene = load_scene(dem_scene(tmp_path, dem)).with_(forest={"trees": 3}, understory={"rocks": 5})
    plan = make_plan(scene)
    t = plan.terrain
    assert t.type == "dem" and t.x[0] == 0 and t.x[-1] == 40 and t.y[-1] == 40
    gx, gy = np.meshgrid(t.x, t.y)
    assert np.abs(t.z - (hill(gx + OFFSET[0], gy + OFFSET[1]) - OFFSET[2])).max() < 0.01
    for obj in plan.objects:
        x, y, z = obj.position
        ground = hill(x + OFFSET[0], y + OFFSET[1]) - OFFSET[2]
        assert ground - 0.06 < z < ground + 0.01


@pytest.mark.parametrize("case, reason", [
    ("missing", "file not found"),
    ("small", "the DEM does not cover the plot"),
    ("holes", "nodata cells over the plot"),
    ("crs", "is not origin.crs"),
    ("text", "cannot read the DEM"),
])
def test_bad_dems_are_refused_in_one_line(tmp_path, capsys, case, reason):
    dem = tmp_path / "dem.tif"
    if case == "small":
        write_dem(dem, plane, size=30.0)
    elif case == "holes":
        write_dem(dem, plane, holes=True)
    elif case in ("crs",):
        write_dem(dem, plane, crs="EPSG:4326")
    elif case == "text":
        dem.write_text("not a raster")
    path = dem_scene(tmp_path, dem, crs="EPSG:28355")
    code = main(["plan", str(path), "-o", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1
    assert "scene.yaml: terrain.path: " in err and reason in err
    assert not (tmp_path / "out").exists()


def test_dem_needs_a_path(tmp_path):
    with pytest.raises(ConfigError, match="terrain.path: is required when terrain.type is dem"):
        load_scene(scene_file(tmp_path, terrain={"type": "dem"}))


def test_mesh_heights_are_barycentric_and_gaps_are_refused():
    # An irregular triangulation of a tilted plane: every grid point gets the plane's height.
    rng = np.random.default_rng(3)
    xy = np.vstack([rng.uniform(0, 10, (400, 2)), [[0, 0], [10, 0], [0, 10], [10, 10]]])
    from scipy.spatial import Delaunay
    faces = Delaunay(xy).simplices
    vertices = np.column_stack([xy, 2.0 + 0.3 * xy[:, 0] - 0.2 * xy[:, 1]])
    grid = np.linspace(0, 10, 41)
    z = heights_under(vertices[faces], grid, grid, chunk=500)    # small chunks: many passes
    gx, gy = np.meshgrid(grid, grid)
    assert np.abs(z - (2.0 + 0.3 * gx - 0.2 * gy)).max() < 1e-9
    # A triangle over half the plot leaves the other half NaN.
    half = heights_under(np.array([[[0, 0, 1], [10, 0, 1], [0, 10, 1]]], float), grid, grid)
    assert np.isnan(half[gx + gy > 10 + 1e-9]).all() and (half[gx + gy <= 10] == 1).all()


def test_mesh_terrain_from_a_file(tmp_path):
    xy = np.stack(np.meshgrid(np.linspace(-1, 41, 43), np.linspace(-1, 41, 43)), -1).reshape(-1, 2)
    from scipy.spatial import Delaunay
    mesh = trimesh.Trimesh(np.column_stack([xy, 0.1 * xy[:, 0]]), Delaunay(xy).simplices, process=False)
    mesh.export(tmp_path / "ground.ply")
    plan = make_plan(load_scene(scene_file(tmp_path, terrain={"type": "mesh", "path": "ground.ply"})))
    gx, _ = np.meshgrid(plan.terrain.x, plan.terrain.y)
    assert np.abs(plan.terrain.z - 0.1 * gx).max() < 1e-6     # PLY stores float32
