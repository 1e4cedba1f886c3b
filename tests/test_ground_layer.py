"""The ground layer (understory.grass, understory.litter): instanced patches on the terrain, scanned as
class ground_vegetation at the share their cover and the patches' covered area imply."""

import numpy as np
import pytest
from helpers import ROOT, scene_file

from mitsuforest.classes import GROUND, GROUND_VEGETATION
from mitsuforest.config import ConfigError, load_scene
from mitsuforest.pipeline import render
from mitsuforest.survey import make_plan
from mitsuforest.plan.transforms import apply
from mitsuforest.trees import build_model
from mitsuforest.trees.ground_layer import PATCH_SIZE, covered_share, grass_patch_model, litter_patch_model
from test_terrain import OFFSET, dem_scene, hill, write_dem

SIDE = 20.0


def _ground_scene(tmp_path, grass: float, litter: float, **sections):
    return load_scene(scene_file(tmp_path, area={"size": [SIDE, SIDE]},
                                 understory={"bushes": 0, "rocks": 0, "deadwood": 0, "stumps": 0,
                                             "grass": {"cover": grass}, "litter": {"cover": litter}},
                                 **sections))


def _patches(plan, kind=None):
    return [o for o in plan.objects if o.kind in ((kind,) if kind else ("grass", "litter"))]


def test_patches_are_instances_of_a_few_models_whatever_the_cover(tmp_path):
    plans = {c: make_plan(_ground_scene(tmp_path / str(c), c, c / 2)) for c in (0.1, 0.6)}
    for cover, plan in plans.items():
        cells = SIDE * SIDE / PATCH_SIZE ** 2
        assert len(_patches(plan, "grass")) == round(cover * cells)
        assert len(_patches(plan, "litter")) == round(cover / 2 * cells)
        assert sorted(n for n, s in plan.models.items() if s.kind in ("grass", "litter")) == \
            [f"grass{i:02d}" for i in range(1, 5)] + [f"litter{i:02d}" for i in range(1, 5)]
    # Six times the patches, the same distinct meshes: memory follows the models, not the cover.
    assert len(_patches(plans[0.6])) == 6 * len(_patches(plans[0.1]))
    # Cells are whole and not shared: no two patches at one centre (flat ground: centres are the cells').
    centres = {o.position[:2] for o in _patches(plans[0.6])}
    assert len(centres) == len(_patches(plans[0.6]))


def test_no_ground_layer_leaves_the_plan_as_it_was(tmp_path):
    scene = load_scene(ROOT / "scenes" / "demo.yaml")
    before = make_plan(scene)
    after = make_plan(scene.with_({"understory.grass.cover": 0.2}))
    assert after.objects[:len(before.objects)] == before.objects
    assert {o.kind for o in after.objects[len(before.objects):]} == {"grass"}


def test_patches_sit_on_a_dem_hill_and_stay_in_the_plot(tmp_path):
    """On a 3 m Gaussian hill (sigma 6 m), each patch's ground plane, moved by its placement, lies on
    the analytic surface within 1.5 cm over its whole square; grass roots are at most 2.5 cm off it,
    litter lies on it (never more than 1 cm below, at most 3 cm above); every vertex is in the plot."""
    dem = write_dem(tmp_path / "dem.tif", hill)
    scene = load_scene(dem_scene(tmp_path, dem)).with_(
        {"understory.grass.cover": 0.4, "understory.litter.cover": 0.3})
    plan = make_plan(scene)
    size = scene.area.size
    s = np.linspace(-PATCH_SIZE / 2, PATCH_SIZE / 2, 9)
    square = np.column_stack([*(a.ravel() for a in np.meshgrid(s, s)), np.zeros(81)])
    models = {n: build_model(n, spec) for n, spec in plan.models.items() if spec.kind in ("grass", "litter")}
    worst, tilted = 0.0, 0
    for obj in _patches(plan):
        ground = lambda p: hill(p[:, 0] + OFFSET[0], p[:, 1] + OFFSET[1]) - OFFSET[2]   # noqa: E731
        plane = apply(obj.matrix, square)
        worst = max(worst, float(np.abs(plane[:, 2] - ground(plane)).max()))
        tilted += max(map(abs, obj.tilt)) > 2
        v = apply(obj.matrix, models[obj.model].vertices())
        assert v[:, :2].min() >= -1e-9 and v[:, 0].max() <= size[0] + 1e-9 and v[:, 1].max() <= size[1] + 1e-9
        above = v[:, 2] - ground(v)
        if obj.kind == "litter":
            assert -0.01 < above.min() and above.max() < 0.03, (obj, above.min(), above.max())
        else:
            roots = models[obj.model].vertices()[:, 2] < 0
            assert np.abs(above[roots] + 0.01).max() < 0.025, obj
    assert worst < 0.015, worst
    assert tilted > 50          # the hill's slopes (up to 17°) really tilt the patches
    assert len(_patches(plan)) == round(0.7 * size[0] * size[1])


def _steep(x, y):
    """A plane rising 0.25 m per m east and north (19° of slope, 14° about each axis), on a 100 m datum."""
    return 100.0 + 0.25 * (x - OFFSET[0]) + 0.25 * (y - OFFSET[1])


@pytest.mark.parametrize("where", ["steep plane", "examples/dem.yaml"])
def test_patches_keep_their_own_cells_and_the_plot_on_slopes(tmp_path, where):
    """Each patch stays centred in its own 1 m cell (no two closer than a cell) and wholly inside the plot:
    at the plot's edges a tilted patch is tilted less rather than pushed into its neighbour's cell."""
    if where == "steep plane":
        scene = load_scene(dem_scene(tmp_path, write_dem(tmp_path / "dem.tif", _steep))).with_(
            {"understory.grass.cover": 0.6, "understory.litter.cover": 0.4, "understory.grass.height": 0.6})
    else:
        scene = load_scene(ROOT / "examples" / "dem.yaml")
    plan = make_plan(scene)
    size = scene.area.size
    patches = _patches(plan)
    xy = np.array([o.position[:2] for o in patches])
    apart = np.abs(xy[:, None] - xy[None]).max(-1) + np.eye(len(xy)) * PATCH_SIZE
    assert apart.min() >= PATCH_SIZE - 1e-9
    models = {n: build_model(n, spec) for n, spec in plan.models.items() if spec.kind in ("grass", "litter")}
    flattened = 0
    for obj in patches:
        v = apply(obj.matrix, models[obj.model].vertices())
        assert v[:, :2].min() >= -1e-9 and v[:, 0].max() <= size[0] + 1e-9 and v[:, 1].max() <= size[1] + 1e-9
        flattened += max(map(abs, obj.tilt)) < 10
    if where == "steep plane":     # 14° about each axis inside; less only in the edge cells that need it
        assert 0 < flattened < 4 * size[0]


def test_covers_that_do_not_fit_are_refused(tmp_path):
    with pytest.raises(ConfigError, match="understory.litter.cover: grass and litter patches do not overlap: their "
                                          "covers add up to 1.2"):
        _ground_scene(tmp_path, 0.7, 0.5)
    with pytest.raises(ConfigError, match="understory.grass.cover: must be <= 1, got 1.5"):
        _ground_scene(tmp_path, 1.5, 0.0)



@pytest.mark.parametrize("grass, litter, expected", [(1.0, 0.0, (100, 0)), (0.5, 0.5, (50, 50)),
                                                     (0.255, 0.745, (26, 74))])
def test_covers_are_shares_of_the_whole_cells(tmp_path, grass, litter, expected):
    """A 10.5 m plot has 100 whole 1 m cells (a 0.25 m strip at each edge stays free): covers adding up to
    1 fill them exactly, however the two round."""
    scene = load_scene(scene_file(tmp_path, area={"size": [10.5, 10.5]},
                                  understory={"bushes": 0, "rocks": 0, "deadwood": 0, "stumps": 0,
                                              "grass": {"cover": grass}, "litter": {"cover": litter}}))
    patches = _patches(make_plan(scene))
    assert (len([o for o in patches if o.kind == "grass"]), len([o for o in patches if o.kind == "litter"])) == expected


def test_patch_models_are_what_their_docstrings_say():
    grass, litter = grass_patch_model(3, "g", 0.3), litter_patch_model(3, "l")
    for model in (grass, litter):
        v = model.vertices()
        assert np.abs(v[:, :2]).max() <= PATCH_SIZE / 2 + 1e-12
        assert model.components[0].classification == GROUND_VEGETATION
    assert grass.vertices()[:, 2].min() == pytest.approx(-0.01) and 0.3 < grass.vertices()[:, 2].max() < 0.42
    assert grass.meta["blades"] >= 36 * 14
    z = litter.vertices()[:, 2]
    assert z.min() >= 0.001 and z.max() < 0.02
    # Seen from above, grass covers a fifth of its square and litter two fifths (rasterised at 0.25 mm).
    assert 0.15 < covered_share(grass) < 0.25 and 0.35 < covered_share(litter) < 0.45


def test_ground_vegetation_points_at_the_share_the_patches_cover(tmp_path):
    """A bare flat 20 m plot with grass on 30 % and litter on 30 % of it, one leg, thin ideal beam.
    Each first return is put in its patch (the plan's cells) or on bare ground: none of the bare ground's
    returns is ground vegetation; in litter cells the share is the litter models' covered area (flat
    leaves: the same from any angle; measured 0.396 for 0.396), in grass cells near nadir the grass models'
    covered area (0.161 for 0.187: the raster's edge pixels count whole)."""
    scene = _ground_scene(tmp_path, 0.3, 0.3, simulation={"beam_samples": 1, "beam_pattern": "fixed"},
                          survey={"altitude": 30, "pulse_frequency": 100000, "scan_frequency": 50, "speed": 4,
                                  "lines": [[[10.0, -5.0], [10.0, 25.0]]]})
    result = render(scene, write=False, progress=False, log=lambda *_: None)
    p = result.points[result.points["return_number"] == 1]
    p = p[(p["x"] > 0) & (p["x"] < SIDE) & (p["y"] > 0) & (p["y"] < SIDE)]
    plan = result.plan
    models = {n: build_model(n, s) for n, s in plan.models.items()}
    cell_of = {}
    for obj in _patches(plan):
        cell_of[int(obj.position[0]), int(obj.position[1])] = obj
    where = [cell_of.get((int(x), int(y))) for x, y in zip(p["x"], p["y"])]
    kind = np.array([o.kind if o else "bare" for o in where])
    veg = p["classification"] == GROUND_VEGETATION
    assert set(np.unique(p["classification"])) == {GROUND, GROUND_VEGETATION}
    assert not veg[kind == "bare"].any() and (kind == "bare").sum() > 10_000
    share = {n: covered_share(models[n]) for n in plan.models if plan.models[n].kind in ("grass", "litter")}
    litter = kind == "litter"
    expected = np.mean([share[o.model] for o in where if o and o.kind == "litter"])
    assert litter.sum() > 10_000 and veg[litter].mean() == pytest.approx(expected, abs=0.03)
    nadir = (kind == "grass") & (np.abs(p["scan_angle"]) < 10)
    expected = np.mean([share[o.model] for o, n in zip(where, nadir) if n])
    assert nadir.sum() > 2_000 and veg[nadir].mean() == pytest.approx(expected, rel=0.25)


@pytest.mark.parametrize("slope", [(0.15, 0.0), (0.0, -0.15)])
def test_litter_lies_on_a_slope_along_the_plot_edges_too(tmp_path, slope):
    """Litter (at most 2 cm tall) on a plane rising 15 % along one axis: tilted to the slope (8.5°), a
    patch in a cell at the plot's edge stays inside the plot (its square's corners come in by 0.5 (1 -
    cos 8.5°) = 5.5 mm, more than its top leans out, 2 cm x sin 8.5° = 3.0 mm). Its top was still taken to
    lean out, so edge patches lay flat, half their leaves up to 7.5 cm under the ground and half up to
    7.5 cm above it; now every leaf lies on the plane (at most 1 cm under it, 3 cm above) in the plot."""
    p, q = slope
    dem = write_dem(tmp_path / "dem.tif", lambda x, y: 120.0 + p * (x - OFFSET[0]) + q * (y - OFFSET[1]))
    scene = load_scene(dem_scene(tmp_path, dem)).with_({"understory.litter.cover": 1.0})
    plan = make_plan(scene)
    size = scene.area.size
    models = {n: build_model(n, spec) for n, spec in plan.models.items() if spec.kind == "litter"}
    edge = 0
    for obj in _patches(plan, "litter"):
        v = apply(obj.matrix, models[obj.model].vertices())
        assert v[:, :2].min() >= -1e-9 and v[:, 0].max() <= size[0] + 1e-9 and v[:, 1].max() <= size[1] + 1e-9
        above = v[:, 2] - (120.0 + p * v[:, 0] + q * v[:, 1] - OFFSET[2])
        assert -0.01 < above.min() and above.max() < 0.03, (obj.position, obj.tilt, above.min(), above.max())
        edge += min(*obj.position[:2], size[0] - obj.position[0], size[1] - obj.position[1]) < 1
    assert edge == 4 * (size[0] - 1)
