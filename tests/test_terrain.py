"""Terrain from a GeoTIFF DEM and from a mesh: scanned ground points at the analytic height, clear refusals."""

import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio
import trimesh
from helpers import scene_file
from rasterio.transform import Affine

from mitsuforest.cli import main
from mitsuforest.config import ConfigError, load_scene
from mitsuforest.pipeline import render
from mitsuforest.survey import make_plan
from mitsuforest.plan.terrain import heights_under

EAST, NORTH = 500_000.0, 6_000_000.0        # the DEMs' world frame (metres of a projected CRS)
OFFSET = [EAST + 3.0, NORTH + 4.0, 100.0]    # the plot's SW corner in that frame, and a datum


def plane(x, y):
    return 130.0 + 0.08 * (x - EAST) - 0.05 * (y - NORTH)


def hill(x, y):
    """A Gaussian hill of 3 m, sigma 6 m, on a 120 m datum, centred in the plot."""
    r2 = (x - OFFSET[0] - 20.0) ** 2 + (y - OFFSET[1] - 20.0) ** 2
    return 120.0 + 3.0 * np.exp(-r2 / (2 * 6.0 ** 2))


def write_dem(path, surface, cell=0.25, size=48.0, crs="EPSG:28355", holes=False, nodata=-9999.0, hole=-9999.0):
    """A north-up GeoTIFF whose cell centres hold ``surface`` exactly, covering [EAST, EAST + size]^2; with
    ``holes``, the ``hole`` value in the middle cell (``nodata``: the value the file declares, or None)."""
    n = int(size / cell)
    x = EAST + (np.arange(n) + 0.5) * cell
    y = NORTH + size - (np.arange(n) + 0.5) * cell
    z = surface(*np.meshgrid(x, y)).astype(np.float32)
    if holes:
        z[n // 2, n // 2] = hole
    with rasterio.open(path, "w", driver="GTiff", width=n, height=n, count=1, dtype="float32", crs=crs,
                       transform=Affine(cell, 0, EAST, 0, -cell, NORTH + size), nodata=nodata) as dst:
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


def test_nodata_beyond_the_plot_edge_is_as_if_the_dem_ended_there(tmp_path):
    """The plot's east edge is at local x 40; the DEM (1 m cells) holds nodata east of it. The cell
    centred at x 40.5, read only to interpolate the edge, takes its inner neighbour's height, so the
    edge lies at the height of the last centre inside (x 39.5), as for a DEM that ends at the edge."""
    dem = write_dem(tmp_path / "dem.tif", plane, cell=1.0)
    with rasterio.open(dem, "r+") as data:
        z = data.read(1)
        z[:, 43:] = data.nodata                   # world x >= EAST + 43: local x >= 40
        data.write(z, 1)
    plan = make_plan(load_scene(dem_scene(tmp_path, dem, crs="EPSG:28355")))
    y = np.array([5.5, 20.5, 35.5])
    inner = plane(EAST + 3.0 + 39.5, NORTH + 4.0 + y) - OFFSET[2]
    assert np.allclose(plan.terrain.height(np.full(3, 40.0), y), inner, atol=1e-4)
    assert np.allclose(plan.terrain.height(np.full(3, 20.0), y), plane(EAST + 23.0, NORTH + 4.0 + y) - OFFSET[2],
                       atol=1e-4)


@pytest.mark.parametrize("width, height", [(1, 1), (1, 3), (3, 1)])
def test_a_dem_one_cell_wide_or_high_is_level_that_way(tmp_path, width, height):
    """A coarse DEM clipped to the plot can hold a single cell along an axis (here 100 m cells over the
    40 m plot); the ground is level along it at the cell's height (it raised an IndexError)."""
    dem = tmp_path / "dem.tif"
    z = (130.0 + np.arange(width * height).reshape(height, width)).astype(np.float32)
    with rasterio.open(dem, "w", driver="GTiff", width=width, height=height, count=1, dtype="float32",
                       crs="EPSG:28355", transform=Affine(100, 0, EAST - 20, 0, -100, NORTH + 80)) as dst:
        dst.write(z, 1)
    t = make_plan(load_scene(dem_scene(tmp_path, dem, crs="EPSG:28355"))).terrain
    assert t.x[0] == 0 and t.x[-1] == 40 and t.y[0] == 0 and t.y[-1] == 40
    if width == 1:
        assert np.ptp(t.z, axis=1).max() < 1e-9
    if height == 1:
        assert np.ptp(t.z, axis=0).max() < 1e-9
    assert 130.0 - OFFSET[2] - 1e-6 <= t.z.min() <= t.z.max() <= z.max() - OFFSET[2] + 1e-6


@pytest.mark.parametrize("case, reason", [
    ("missing", "file not found"),
    ("small", "the DEM does not cover the plot"),
    ("holes", "nodata cells over the plot"),
    ("undeclared -9999", "the DEM has 1 cells over the plot at heights no ground has (-9999, the first at local x "
                         "21.12, y 19.88): a nodata value the file does not declare? Declare it (gdal_edit.py "
                         "-a_nodata -9999), then fill the cells (gdal_fillnodata)"),
    ("undeclared float32 lowest", "at heights no ground has (-3.40282347e+38, the first at local x 21.12"),
    ("crs", "is not origin.crs"),
    ("no georeference", "the DEM has no georeference (no geotransform): give it its corners and CRS first"),
    ("text", "cannot read the DEM"),
    ("rotated", "the DEM's grid is rotated or sheared; warp it north-up first (gdalwarp)"),
])
def test_bad_dems_are_refused_in_one_line(tmp_path, capsys, case, reason):
    dem = tmp_path / "dem.tif"
    if case == "small":
        write_dem(dem, plane, size=30.0)
    elif case == "holes":
        write_dem(dem, plane, holes=True)
    elif case.startswith("undeclared"):
        write_dem(dem, plane, holes=True, nodata=None, hole=-9999.0 if "9999" in case else np.finfo(np.float32).min)
    elif case in ("crs",):
        write_dem(dem, plane, crs="EPSG:4326")
    elif case == "no georeference":    # a plain TIFF: rasterio gives the identity transform, with a warning
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with rasterio.open(dem, "w", driver="GTiff", width=64, height=64, count=1, dtype="float32") as dst:
                dst.write(np.zeros((64, 64), np.float32), 1)
    elif case == "text":
        dem.write_text("not a raster")
    elif case == "rotated":       # 0.25 m cells turned by 1 degree, covering the plot
        c, s = 0.25 * np.cos(np.deg2rad(1.0)), 0.25 * np.sin(np.deg2rad(1.0))
        with rasterio.open(dem, "w", driver="GTiff", width=240, height=240, count=1, dtype="float32", crs="EPSG:28355",
                           transform=Affine(c, s, EAST - 5, s, -c, NORTH + 55)) as dst:
            dst.write(np.full((240, 240), 130.0, np.float32), 1)
    path = dem_scene(tmp_path, dem, crs="EPSG:28355")
    code = main(["plan", str(path), "-o", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1
    assert "scene.yaml: terrain.path: " in err and reason in err
    assert not (tmp_path / "out").exists()


def test_an_undeclared_nodata_value_beyond_the_plot_edge_is_as_if_the_dem_ended_there(tmp_path):
    """-9999 east of the plot in a file that declares no nodata value: a hole like a declared one there
    (the edge at its inner neighbour's height), not a 10 km cliff down from the edge."""
    dem = write_dem(tmp_path / "dem.tif", plane, cell=1.0, nodata=None)
    with rasterio.open(dem, "r+") as data:
        z = data.read(1)
        z[:, 43:] = -9999.0
        data.write(z, 1)
    plan = make_plan(load_scene(dem_scene(tmp_path, dem, crs="EPSG:28355")))
    y = np.array([5.5, 20.5, 35.5])
    assert np.allclose(plan.terrain.height(np.full(3, 40.0), y), plane(EAST + 3.0 + 39.5, NORTH + 4.0 + y) - OFFSET[2],
                       atol=1e-4)


def test_a_dem_without_a_crs_under_a_scene_with_one_is_warned_of_once(tmp_path, caplog):
    import logging
    dem = write_dem(tmp_path / "dem.tif", plane, crs=None)
    scene = load_scene(dem_scene(tmp_path, dem, crs="EPSG:28355"))
    with caplog.at_level(logging.WARNING):
        make_plan(scene)
        make_plan(scene)
    assert caplog.text.count("dem.tif: the DEM names no CRS; its coordinates are taken to be in origin.crs "
                             "(EPSG:28355)") == 1


def test_dem_needs_a_path(tmp_path):
    with pytest.raises(ConfigError, match="terrain.path: is required when terrain.type is dem"):
        load_scene(scene_file(tmp_path, terrain={"type": "dem"}))


@pytest.mark.parametrize("kind", [None, "flat", "noise"])
def test_a_terrain_path_is_refused_where_the_terrain_type_reads_none(tmp_path, kind):
    """``terrain: {path: dem.tif}`` without ``type: dem`` planned flat ground, the file unread."""
    dem = write_dem(tmp_path / "dem.tif", plane)
    terrain = {"path": str(dem), **({"type": kind} if kind else {})}
    with pytest.raises(ConfigError, match=r"scene.yaml: terrain.path: is read only with terrain.type dem \(a GeoTIFF\) "
                                          rf"or mesh; terrain.type is {kind or 'flat'}"):
        load_scene(scene_file(tmp_path, terrain=terrain))


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


@pytest.mark.parametrize("text", ["hello world\nnot a mesh\n", ""])
def test_a_terrain_mesh_without_triangles_is_named_so(tmp_path, text):
    """Garbage that trimesh reads as an empty mesh was called 'does not cover the whole plot'."""
    (tmp_path / "ground.obj").write_text(text)
    with pytest.raises(ConfigError, match=r"terrain.path: .*ground.obj: the terrain mesh has no triangles"):
        make_plan(load_scene(scene_file(tmp_path, terrain={"type": "mesh", "path": "ground.obj"})))


def test_leg_reach_uses_the_dem_height_range(tmp_path):
    """A DEM rising 40 m across the plot: a leg's reach is set by the depth from the platform to the
    DEM's lowest point in the plot (30 m altitude above the mean, plus mean - lowest), not by
    ``terrain.amplitude`` (1.5 m, which a DEM does not use). With the 70.4° Livox that is 35 m: a leg
    28 m east of the plot is flown, one 40 m east is refused at the reach the DEM gives."""
    dem = write_dem(tmp_path / "dem.tif", lambda x, y: 100.0 + (x - EAST))
    def scene(x):
        return load_scene(scene_file(tmp_path, "livox_mid-70.yaml", terrain={"type": "dem", "path": str(dem)},
                                     origin={"offset": OFFSET},
                                     survey={"altitude": 30, "pulse_frequency": 100000, "speed": 10,
                                             "lines": [[[x, 0.0], [x, 40.0]]]}))
    plan = make_plan(scene(68.0))
    z = plan.terrain.z
    assert z.min() == pytest.approx(3.0, abs=1e-6) and z.max() == pytest.approx(43.0, abs=1e-6)
    depth = 30 + plan.terrain.mean_height - z.min()
    reach = depth * np.tan(np.deg2rad(70.4 / 2))
    assert 34 < reach < 36 and plan.legs[0].start[2] - z.min() == pytest.approx(depth)
    assert 1.5 * np.tan(np.deg2rad(70.4 / 2)) + 30 * np.tan(np.deg2rad(70.4 / 2)) < 28   # what amplitude gave
    with pytest.raises(ConfigError, match=rf"survey.lines\[0\]: the leg passes 40.0 m from the plot, beyond the "
                                          rf"sensor's reach of {reach:.1f} m at this altitude"):
        make_plan(scene(80.0))


def test_ground_rising_above_the_flight_is_refused(tmp_path):
    """A DEM rising 80 m across the 40 m plot (6 to 86 m, mean 46) under a flight 30 m above its mean:
    its top lies above the platform (the ideal sensor: no minimum range), so the scene is refused before
    any work; 1 m above the top, it is flown."""
    dem = write_dem(tmp_path / "dem.tif", lambda x, y: 100.0 + 2.0 * (x - EAST))
    scene = load_scene(dem_scene(tmp_path, dem))
    with pytest.raises(ConfigError, match="survey.altitude: the ground rises 40.0 m above its mean height, higher "
                                          "than the flight at survey.altitude 30 m; fly higher"):
        make_plan(scene)
    assert make_plan(scene.with_({"survey.altitude": 41})).legs[0].start[2] == pytest.approx(87.0)


@pytest.mark.slow
def test_the_example_dem_scene_renders(tmp_path):
    """examples/dem.yaml on examples/data/dem.tif (made by examples/data/make_dem.py), cut to one 20 s
    leg: ground points lie on the DEM's analytic surface (95 % within 2 cm), in its CRS's metres; trees, shrubs
    and the ground layer are all scanned."""
    import importlib.util
    from mitsuforest.classes import BUSH, GROUND, GROUND_VEGETATION, TREE_LEAVES, TREE_WOOD
    root = Path(__file__).resolve().parents[1]
    spec = importlib.util.spec_from_file_location("make_dem", root / "examples" / "data" / "make_dem.py")
    make_dem = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(make_dem)
    scene = load_scene(root / "examples" / "dem.yaml").with_(
        {"survey.lines": [[[20.0, -5.0], [20.0, 45.0]]], "survey.speed": 2.5, "output.dir": str(tmp_path)})
    result = render(scene, write=False, progress=False, log=lambda *_: None)
    p = result.points
    ground = p[p["classification"] == GROUND]
    x, y = ground["x"] - make_dem.EAST, ground["y"] - make_dem.NORTH
    error = np.abs(ground["z"] - make_dem.surface(x, y))
    print(np.quantile(error, [0.5, 0.9, 0.95, 0.99]))
    # Mixed echoes (ground with grass or litter within the 0.6 m echo separation) sit between the two.
    assert len(ground) > 100_000 and np.median(error) < 0.005 and np.quantile(error, 0.95) < 0.02
    assert {GROUND, TREE_WOOD, TREE_LEAVES, BUSH, GROUND_VEGETATION} <= set(np.unique(p["classification"]))
    assert result.manifest["realism"]["class_shares"]["ground_vegetation"] > 0.02


def test_a_dem_georeferenced_only_by_control_points_is_refused(tmp_path, capsys):
    """A TIFF placed by ground control points has no geotransform: rasterio gives it the identity, which
    read its pixel numbers as local metres (south-up, 1 m cells) and planned the plot on them."""
    from rasterio.control import GroundControlPoint
    dem = tmp_path / "dem.tif"
    gcps = [GroundControlPoint(r, c, EAST + 0.25 * c, NORTH + 48 - 0.25 * r) for r in (0, 192) for c in (0, 192)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with rasterio.open(dem, "w", driver="GTiff", width=192, height=192, count=1, dtype="float32",
                           gcps=gcps, crs="EPSG:28355") as dst:
            dst.write(np.full((192, 192), 130.0, np.float32), 1)
    path = scene_file(tmp_path, terrain={"type": "dem", "path": str(dem)},
                      survey={"altitude": 30, "pulse_frequency": 100000, "speed": 10, "lines": [[[20.0, -5.0], [20.0, 45.0]]]})
    code = main(["plan", str(path), "-o", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert "scene.yaml: terrain.path: " in err
    assert "the DEM is placed by ground control points, not a geotransform: warp it north-up first (gdalwarp)" in err


@pytest.mark.parametrize("crs, reason", [
    ("EPSG:2227", "has its axes in US survey foot"),
    ("EPSG:4326", "is geographic, in degrees"),
])
def test_a_dem_in_a_crs_not_in_metres_is_refused_without_origin_crs(tmp_path, capsys, crs, reason):
    """With no origin.crs to compare with, a DEM in a state plane in feet was read as if its feet were
    metres (the plot 3.28 times too small on it) and one in degrees as if degrees were metres."""
    dem = write_dem(tmp_path / "dem.tif", plane, crs=crs)
    code = main(["plan", str(dem_scene(tmp_path, dem)), "-o", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert "scene.yaml: terrain.path: " in err and f"the DEM's CRS ({crs}) {reason}" in err


def test_a_dem_with_a_scale_and_offset_holds_their_heights(tmp_path):
    """GDAL's band scale and offset: a DEM of centimetres above 100 m in int16 (scale 0.01, offset 100)
    holds heights ``raw * 0.01 + 100``; the raw integers were read as metres (the plane's 30 m rise
    became 3,000 m)."""
    dem = write_dem(tmp_path / "dem.tif", plane)
    with rasterio.open(dem) as data:
        z, profile = data.read(1).astype(np.float64), data.profile
    raw = np.round((z - 100.0) * 100.0).astype(np.int16)
    profile.update(dtype="int16", nodata=None)
    scaled = tmp_path / "scaled.tif"
    with rasterio.open(scaled, "w", **profile) as dst:
        dst.write(raw, 1)
        dst.scales, dst.offsets = (0.01,), (100.0,)
    t = make_plan(load_scene(dem_scene(tmp_path, scaled, crs="EPSG:28355"))).terrain
    gx, gy = np.meshgrid(t.x, t.y)
    assert np.abs(t.z - (plane(gx + OFFSET[0], gy + OFFSET[1]) - OFFSET[2])).max() < 0.006   # half a centimetre


@pytest.mark.parametrize("unit, metres", [("ft", 0.3048), ("US survey foot", 1200 / 3937), ("m", 1.0), ("metre", 1.0)])
def test_dem_heights_in_feet_are_read_in_metres(tmp_path, unit, metres):
    """A band whose unit is feet (GDAL's unit type, as US DEMs in NAVD88 feet have) holds heights in
    feet: they were read as metres, the plane 3.28 times too high and too steep."""
    dem = write_dem(tmp_path / "dem.tif", lambda x, y: plane(x, y) / metres)
    with rasterio.open(dem, "r+") as data:
        data.units = (unit,)
    t = make_plan(load_scene(dem_scene(tmp_path, dem, crs="EPSG:28355"))).terrain
    gx, gy = np.meshgrid(t.x, t.y)
    assert np.abs(t.z - (plane(gx + OFFSET[0], gy + OFFSET[1]) - OFFSET[2])).max() < 1e-3


def test_dem_heights_in_an_unknown_unit_are_refused(tmp_path):
    dem = write_dem(tmp_path / "dem.tif", plane)
    with rasterio.open(dem, "r+") as data:
        data.units = ("fathom",)
    with pytest.raises(ConfigError, match=r"terrain.path: .*dem.tif: the DEM's heights are in 'fathom', not metres "
                                          r"or feet: convert them to metres first \(gdal_calc.py\), or name their unit where they "
                                          r"are \(gdal_edit.py -units m\)"):
        make_plan(load_scene(dem_scene(tmp_path, dem, crs="EPSG:28355")))


@pytest.mark.parametrize("case", ["north-up", "south-up", "east to west", "cells off the plot's grid", "pixel is point"])
def test_dem_grids_of_every_orientation_hold_the_plane(tmp_path, case):
    """The tilted plane sampled at the cell centres of grids running north or south, east or west, with
    cells (0.7 x 0.9 m) whose edges miss the plot's, and of a PixelIsPoint file (its tiepoint a cell
    centre, which GDAL turns into the corner of a cell): the terrain holds the plane at its grid points and
    anywhere between them, to float32's precision."""
    transform, width, height = {
        "north-up": (Affine(0.5, 0, EAST, 0, -0.5, NORTH + 60), 120, 120),
        "south-up": (Affine(0.5, 0, EAST, 0, 0.5, NORTH), 120, 120),
        "east to west": (Affine(-0.5, 0, EAST + 60, 0, -0.5, NORTH + 60), 120, 120),
        "cells off the plot's grid": (Affine(0.7, 0, EAST + 0.13, 0, -0.9, NORTH + 60.3), 90, 70),
        "pixel is point": (Affine(0.5, 0, EAST, 0, -0.5, NORTH + 60), 120, 120),
    }[case]
    cols, rows = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    dem = tmp_path / "dem.tif"
    with rasterio.open(dem, "w", driver="GTiff", width=width, height=height, count=1, dtype="float32",
                       crs="EPSG:28355", transform=transform) as dst:
        dst.write(plane(*(transform @ (cols, rows))).astype(np.float32), 1)
        if case == "pixel is point":
            dst.update_tags(AREA_OR_POINT="Point")
    t = make_plan(load_scene(dem_scene(tmp_path, dem, crs="EPSG:28355"))).terrain
    assert t.x[0] == 0 and t.x[-1] == 40 and t.y[0] == 0 and t.y[-1] == 40
    gx, gy = np.meshgrid(t.x, t.y)
    assert np.abs(t.z - (plane(gx + OFFSET[0], gy + OFFSET[1]) - OFFSET[2])).max() < 2e-5
    px, py = np.random.default_rng(1).uniform(0, 40, (2, 2000))
    truth = plane(px + OFFSET[0], py + OFFSET[1]) - OFFSET[2]
    assert np.abs(t.surface_height(px, py) - truth).max() < 2e-5
    assert np.abs(t.height(px, py) - truth).max() < 2e-5


def test_dem_heights_in_the_feet_of_its_vertical_crs_are_read_in_metres(tmp_path):
    """A DEM in NAD83 / UTM 10N + NAVD88 height (ftUS) whose band names no unit holds heights in US
    survey feet, as its CRS says: they were read as metres (the plane 3.28 times too high and steep)."""
    dem = write_dem(tmp_path / "dem.tif", lambda x, y: plane(x, y) * 3937 / 1200, crs="EPSG:26910+6360")
    t = make_plan(load_scene(dem_scene(tmp_path, dem))).terrain
    gx, gy = np.meshgrid(t.x, t.y)
    assert np.abs(t.z - (plane(gx + OFFSET[0], gy + OFFSET[1]) - OFFSET[2])).max() < 1e-3


def test_logs_lie_along_a_sloping_dem(tmp_path):
    """Logs (deadwood, 1.5-7 m) on the plane rising 18 % (0.15 east, -0.10 north): each lies on the
    ground along its whole length, the underside of every 0.5 m of it between 10 cm under the plane and
    5 cm above it (the model rests 0.2 r sunk, r <= 0.2 m, with knots). Logs were laid level at the
    height of their centre, so their ends stood up to half their length times the slope (0.5 m for a
    7 m log) above or under the ground."""
    from mitsuforest.plan.transforms import apply
    from mitsuforest.trees import build_model

    def sloped(x, y):
        return 120.0 + 0.15 * (x - EAST) - 0.10 * (y - NORTH)

    scene = load_scene(dem_scene(tmp_path, write_dem(tmp_path / "dem.tif", sloped))).with_(
        understory={"deadwood": 6, "bushes": 0, "rocks": 0, "stumps": 0})
    plan = make_plan(scene)
    logs = [o for o in plan.objects if o.kind == "deadwood"]
    assert len(logs) == 6
    for log in logs:
        model = build_model(log.model, plan.models[log.model])
        v = model.vertices()
        w = apply(log.matrix, v)
        above = w[:, 2] - (sloped(w[:, 0] + OFFSET[0], w[:, 1] + OFFSET[1]) - OFFSET[2])
        along = np.floor(v[:, 0] / 0.5)
        lowest = np.array([above[along == k].min() for k in np.unique(along)])
        assert -0.10 < lowest.min() and lowest.max() < 0.05, (log.model, log.tilt, lowest.min(), lowest.max())
        assert w[:, :2].min() > 0 and w[:, :2].max() < 40          # still wholly inside the plot


def test_a_dem_in_a_local_grid_in_metres_is_read_without_origin_crs(tmp_path):
    """A DEM in a site's own grid (a LOCAL_CS in metres, as a terrestrial survey gives) under a scene with no
    origin.crs: its metres are the scene's, so it is read (the check of abfe793 refused it as 'not a
    projected CRS', which only origin.crs must be)."""
    from rasterio.crs import CRS as RasterCRS
    local = RasterCRS.from_wkt('LOCAL_CS["site grid",UNIT["metre",1],AXIS["Easting",EAST],AXIS["Northing",NORTH]]')
    dem = write_dem(tmp_path / "dem.tif", plane, crs=local)
    t = make_plan(load_scene(dem_scene(tmp_path, dem))).terrain
    gx, gy = np.meshgrid(t.x, t.y)
    assert np.abs(t.z - (plane(gx + OFFSET[0], gy + OFFSET[1]) - OFFSET[2])).max() < 2e-5
