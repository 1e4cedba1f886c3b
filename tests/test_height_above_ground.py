"""height_above_ground: every point's height above the ground surface as rendered, in the PCD, the
LAS/LAZ (extra dimension) and the dataset tiles."""

import laspy
import numpy as np
import pytest
from helpers import scene_file

from mitsuforest.classes import GROUND
from mitsuforest.pipeline import render
from mitsuforest.survey import make_plan
from mitsuforest.config import load_scene
from mitsuforest.plan.terrain import Terrain, TriangleSurface
from mitsuforest.write.pcd import read_pcd

OFFSET = [300_000.0, 6_100_000.0, 50.0]


def test_surface_height_is_the_rendered_triangles_not_the_bilinear_patch():
    """One twisted cell (z = 1 at one corner only): the mesh's diagonal runs from (0, 0) to (1, 1), so
    the surface is 0.25 at both (0.75, 0.25) and (0.25, 0.75), where the bilinear patch is 0.1875."""
    t = Terrain("mesh", np.array([0.0, 1.0]), np.array([0.0, 1.0]), np.array([[0.0, 0.0], [0.0, 1.0]]))
    assert t.surface_height([0.75, 0.25, 0.5, 1.0], [0.25, 0.75, 0.5, 1.0]).tolist() == [0.25, 0.25, 0.5, 1.0]
    assert t.height([0.75], [0.25])[0] == pytest.approx(0.1875)


def test_triangle_surface_agrees_with_the_grid_surface_on_a_non_uniform_grid():
    """The mesh lookup (for HELIOS++ grounds) and the grid arithmetic are two computations of one
    surface."""
    rng = np.random.default_rng(3)
    x, y = np.sort(np.r_[0, rng.uniform(0, 30, 17), 30]), np.sort(np.r_[0, rng.uniform(0, 20, 11), 20])
    t = Terrain("dem", x, y, rng.normal(0, 2, (len(y), len(x))))
    px, py = rng.uniform(0, 30, 20_000), rng.uniform(0, 20, 20_000)
    mesh = TriangleSurface(*t.mesh(), fallback=-99.0)
    assert np.abs(mesh(px, py) - t.surface_height(px, py)).max() < 1e-9
    assert mesh(np.array([-1.0, 31.0]), np.array([5.0, 5.0])).tolist() == [-99.0, -99.0]


@pytest.fixture(scope="module")
def sloped(tmp_path_factory):
    """A 3 m noise relief tilted by the georeference datum, scanned with ranging noise (5 mm), with
    trees: its PCD, LAS, kept points and plan."""
    tmp = tmp_path_factory.mktemp("hag")
    path = scene_file(tmp, sensor="riegl_vux-1uav22.yaml", terrain={"type": "noise", "amplitude": 3.0,
                                                                     "wavelength": 15.0},
                      area={"size": [24, 24]}, forest={"type": "open", "trees": 2, "min_spacing": 5.0},
                      origin={"offset": OFFSET}, output={"dir": str(tmp / "plots" / "test"), "formats": ["pcd", "las"]},
                      survey={"altitude": 30, "pulse_frequency": 100000, "scan_frequency": 50, "speed": 8,
                              "lines": [[[12.0, -4.0], [12.0, 28.0]]]})
    result = render(path, progress=False, keep_points=True, log=lambda *_: None)
    plan = make_plan(load_scene(path))
    out = tmp / "plots" / "test"
    return result, read_pcd(out / "test.pcd"), laspy.read(str(out / "test.las")), plan


def test_ground_points_lie_at_zero_height_and_every_height_is_z_minus_the_surface(sloped):
    result, pcd, las, plan = sloped
    p = result.points
    x, y, z = (p[a] - o for a, o in zip("xyz", OFFSET))
    surface = plan.terrain.surface_height(x, y)
    assert np.ptp(surface) > 2.0                                      # the relief is really there
    expected = (z - surface).astype(np.float32)
    # Exact up to the float32 rounding, and near zero up to the float64 rounding of the georeference's
    # sums through which x, y, z come back here (one step of the offset, about 1e-9 m).
    tolerance = np.maximum(np.spacing(np.abs(expected)), np.spacing(np.abs(OFFSET).max()))
    assert np.all(np.abs(p["height_above_ground"] - expected) <= tolerance)
    ground = p["classification"] == GROUND
    assert ground.sum() > 5_000
    hag = p["height_above_ground"][ground]
    # Ranging noise (sigma 5 mm along the beam) is all that moves a ground point off the surface.
    assert np.abs(hag).max() < 6 * 0.005 + 1e-4
    assert 0.002 < hag.std() < 0.0055
    trees = np.isin(p["classification"], (2, 3))
    assert p["height_above_ground"][trees].max() > 5.0


def test_pcd_field_and_las_extra_dimension_hold_the_same_heights(sloped):
    result, pcd, las, _ = sloped
    assert pcd.dtype["height_above_ground"] == np.float32
    assert np.array_equal(pcd["height_above_ground"], result.points["height_above_ground"])
    assert las.point_format.dimension_by_name("height_above_ground").dtype == np.float32
    assert np.array_equal(np.asarray(las.height_above_ground), pcd["height_above_ground"])


def test_dataset_tiles_carry_the_heights_from_the_pcd_and_from_the_las(sloped):
    """A dataset's tiles are cut from the plot's PCD (or its LAS/LAZ when it has none): either way each
    tile's points keep their height_above_ground."""
    from mitsuforest.dataset.files import plot_folder, read_plot_points, write_tiles
    from mitsuforest.dataset.spec import Tiles
    from mitsuforest.dataset.tiles import in_extent, tile_extent
    result, pcd, _, plan = sloped
    root = next(p for p in result.files if p.name == "test.pcd").parents[2]
    from_las = read_plot_points(plot_folder(root, "test"), "test", ["las"])
    assert np.array_equal(from_las["height_above_ground"], pcd["height_above_ground"])
    records = write_tiles(root, result.scene, Tiles(size=12.0, buffer=1.0, format="las"))
    assert len(records) == 4
    x, y = pcd["x"] - OFFSET[0], pcd["y"] - OFFSET[1]
    for r in records:
        tile = laspy.read(str(plot_folder(root, "test") / "tiles" / f"{r['tile']}.las"))
        sel = in_extent(x, y, tile_extent(r["i"], r["j"], (24, 24), 12.0, 1.0))
        assert len(tile.points) == sel.sum() > 1000
        assert np.array_equal(np.asarray(tile.height_above_ground), pcd["height_above_ground"][sel])


def test_heights_over_a_tilted_dem_plane_are_z_less_the_plane_and_beyond_the_plot_the_edge(tmp_path):
    """A GeoTIFF of the plane z = 130 + 0.15 dx - 0.1 dy (0.5 m cells, origin 10 m west of the world
    frame's 0) under a 20 m plot with two listed trees repeated 6 m around it: every point's height is
    its z less the plane at its x, y (the analytic plane, not the terrain's own arithmetic), and beyond
    the plot, where the repeated trees stand on the height of the plot's nearest edge, z less the plane
    there. Ground points lie on the plane (the ideal sensor: no ranging noise)."""
    import rasterio
    from rasterio.transform import Affine
    east, north = 500_000.0, 6_000_000.0
    offset = [east + 3.0, north + 4.0, 100.0]

    def plane(x, y):
        return 130.0 + 0.15 * (x - east) - 0.1 * (y - north)

    transform = Affine(0.5, 0, east - 10, 0, -0.5, north + 50)
    cols, rows = np.meshgrid(np.arange(120) + 0.5, np.arange(120) + 0.5)
    with rasterio.open(tmp_path / "dem.tif", "w", driver="GTiff", width=120, height=120, count=1, dtype="float64",
                       crs="EPSG:28355", transform=transform) as dst:
        dst.write(plane(*(transform @ (cols, rows))), 1)
    (tmp_path / "trees.csv").write_text(f"x,y,height,crown_radius\n{offset[0] + 5},{offset[1] + 6},8,1.5\n"
                                        f"{offset[0] + 14},{offset[1] + 13},10,2\n")
    path = scene_file(tmp_path, terrain={"type": "dem", "path": "dem.tif"}, area={"size": [20, 20]},
                      origin={"offset": offset, "crs": "EPSG:28355"},
                      forest={"trees": None, "trees_file": "trees.csv", "surround": 6, "tilt": 0},
                      survey={"altitude": 30, "pulse_frequency": 100000, "scan_frequency": 50, "speed": 10,
                              "lines": [[[10.0, -10.0], [10.0, 30.0]]]},
                      output={"dir": str(tmp_path / "out"), "formats": ["laz"], "pictures": False})
    render(path, progress=False, log=lambda *_: None)
    las = laspy.read(str(tmp_path / "out" / "test.laz"))
    x, y, z = (np.asarray(las[a], np.float64) for a in "xyz")
    hag = np.asarray(las["height_above_ground"], np.float64)
    lx, ly = x - offset[0], y - offset[1]
    beyond = (lx < 0) | (lx > 20) | (ly < 0) | (ly > 20)
    edge = plane(np.clip(lx, 0, 20) + offset[0], np.clip(ly, 0, 20) + offset[1])
    assert (~beyond).sum() > 15_000 and beyond.sum() > 100          # points of the repeated trees
    assert np.abs(hag - (z - edge)).max() < 2e-4                    # LAS: 0.1 mm coordinates, float32 heights
    assert np.abs(hag - (z - plane(x, y)))[beyond].max() > 0.1       # beyond: not the plane there
    ground = np.asarray(las["label"]) == GROUND
    assert ground.sum() > 10_000 and np.abs(z[ground] - plane(x[ground], y[ground])).max() < 2e-4
    assert hag[np.isin(np.asarray(las["label"]), (2, 3))].max() > 7.0
