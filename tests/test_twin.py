"""mitsuforest twin: a scene from a scan recovers the trees, ground and survey of one of our own scans."""

import json
import shutil
import sys
from types import SimpleNamespace

import laspy
import numpy as np
import pytest
import yaml

from conftest import ROOT, _demo_scene

LEGS = [[[4.0, 0.0], [4.0, 20.0]], [[16.0, 20.0], [16.0, 0.0]]]    # 12 m apart, 30 m above the flat ground


PINES = [{"species": "pinus_radiata", "base": k} for k in (1, 2, 3)]


@pytest.fixture(scope="module")
def demo_twin(tmp_path_factory):
    """The demo plot with upright pines (single leaders: a tree's top stands over its stem) and bushes,
    scanned along two legs 12 m apart with 7 sub-rays (a thin beam gives one return a pulse, and the
    trajectory needs pulses with two), and its twin."""
    from mitsuforest.pipeline import render
    from mitsuforest.twin import make_twin
    scene = _demo_scene(tmp_path_factory, "llvm_ad_mono", rocks=0, deadwood=0, stumps=0).with_(
        {"survey.lines": LEGS, "output.formats": ["laz", "pcd"], "forest.tilt": 0, "forest.archetypes": PINES})
    result = render(scene, progress=False, log=lambda *_: None)
    laz = next(f for f in map(str, result.files) if f.endswith(".laz"))
    out = tmp_path_factory.mktemp("twin")
    report = make_twin(laz, out, species=["pinus_radiata"], log=lambda *_: None)
    return result, laz, out, report


def test_twin_finds_the_trees_where_and_as_tall_as_they_are(demo_twin):
    from mitsuforest.twin.detection import match, scores
    result, _, out, _ = demo_twin
    plan = result.plan
    truth = np.array([t.position[:2] for t in plan.trees])
    heights = np.array([plan.models[t.model].archetype.height for t in plan.trees])
    rows = np.genfromtxt(out / "trees.csv", delimiter=",", names=True, dtype=None, encoding=None)
    found = np.column_stack([rows["x"], rows["y"]]).reshape(-1, 2)
    assert scores(found, truth, 1.5)["f1"] >= 0.9
    i, j = match(found, truth, 1.5)
    rmse = float(np.sqrt(np.mean((np.atleast_1d(rows["height"])[i] - heights[j]) ** 2)))
    assert rmse < 1.0, rmse


def test_our_pcd_and_laz_give_the_same_ground_points(demo_twin):
    from mitsuforest.twin.points import read_scan
    result, laz, _, _ = demo_twin
    pcd = next(f for f in map(str, result.files) if f.endswith(".pcd"))
    a, b = read_scan(laz), read_scan(pcd)
    assert a.ground.sum() == b.ground.sum() > 0     # our ground class in the PCD (where 2 is wood), ASPRS 2 in the LAZ


def test_twin_dem_is_the_ground_within_5_cm(demo_twin):
    import rasterio
    _, _, out, report = demo_twin
    with rasterio.open(out / f"{report_name(out)}_dem.tif") as d:
        z = d.read(1)
    assert np.abs(z).max() < 0.05          # the demo's ground is flat at z = 0


def report_name(out):
    return next(out.glob("*.yaml")).stem


def test_twin_estimates_altitude_and_line_spacing_of_the_survey(demo_twin):
    _, _, out, report = demo_twin
    survey = report["survey"]
    assert survey["altitude"]["source"] == "estimated"
    assert abs(survey["altitude"]["value"] - 30.0) < 1.0          # flown at 30 m over flat ground
    assert abs(survey["speed"]["value"] - 2.0) < 0.1
    scene = yaml.safe_load((out / f"{report_name(out)}.yaml").read_text())
    xs = sorted(np.mean([p[0] for p in leg]) for leg in scene["survey"]["lines"])
    assert len(xs) == 2 and abs((xs[1] - xs[0]) - 12.0) < 0.5   # the legs 12 m apart, within 0.5 m
    assert abs(scene["survey"]["scan_frequency"] - 50.0) < 1.0
    assert abs(scene["survey"]["pulse_frequency"] - 100_000) < 5_000


def test_twin_scene_loads_and_plans_one_model_per_tree(demo_twin):
    from mitsuforest.config import load_scene
    from mitsuforest.survey import make_plan
    _, _, out, report = demo_twin
    scene = load_scene(out / f"{report_name(out)}.yaml")
    plan = make_plan(scene)
    inside = [t for t in plan.trees if 0 <= t.position[0] <= scene.area.size[0] and 0 <= t.position[1] <= scene.area.size[1]]
    assert len(inside) == report["trees"]["count"] == len({t.model for t in plan.trees})
    assert scene.forest.surround > 0 and len(plan.trees) > len(inside)      # the stand around the plot: copies


def test_one_calibration_render_rescales_leaf_width_and_depth_by_its_rules(demo_twin, tmp_path):
    """One render of the twin of our own scan, measured against that scan: the step written to
    ``twin.json`` and ``trees.csv`` is the one the update rules give for the measures it reports."""
    import shutil
    from mitsuforest.twin import analyse, calibrate as c
    from mitsuforest.twin.points import read_scan
    _, laz, out, report = demo_twin
    folder = tmp_path / "twin"
    shutil.copytree(out, folder)
    before = c.read_trees(folder / "trees.csv")
    scan = read_scan(laz)
    record = c.calibrate(scan, analyse(scan), folder, report_name(out), 1, log=lambda *_: None)
    real, (step,) = record["real"], record["steps"]
    assert real["spread"] > 1.0 and step["spread"] > 1.0 and 0 < step["gap_fraction"] < 1
    assert json.loads((folder / "twin.json").read_text())["calibration"] == json.loads(json.dumps(record))
    assert not record["converged"]        # the demo's twin: spread 3.8 m against the scan's 6.3 m
    assert record["leaf_from"] == "echoes" and step["echoes_per_pulse"] > 1.02
    assert step["lai_factor"] == pytest.approx(c.leaf_scale(real, step))
    assert step["crown_factor"] == pytest.approx(c.crown_scale(real["cover"], step["cover"]))
    assert record["crown_contrast"] == pytest.approx(c.contrast_step(0.0, real["spread"], step["spread"]))
    after = c.read_trees(folder / "trees.csv")
    base = c.base_crown_ratios(before, report["trees"]["crown_ratio"])
    dominant = c.dominant_crowns([float(r["crown_radius"]) for r in before])
    expected = c.contrast_ratios(base, dominant, record["crown_contrast"])
    assert [float(r["crown_ratio"]) for r in after] == pytest.approx(expected, abs=5e-4)
    assert [float(r["crown_radius"]) for r in after] == pytest.approx(
        [float(r["crown_radius"]) * step["crown_factor"] for r in before], abs=5e-4)


def test_surround_repeats_the_listed_trees_around_the_plot_with_its_period(tmp_path):
    """``forest.surround: 15`` around a 20 x 20 m plot: a tree at (5, 5) has copies at 5 + 20 i, 5 + 20 j
    within 15 m outside the plot (i, j in -1..1, not both 0: 8), one at (14, 12) at 14 + 20 i, 12 + 20 j
    (-6 and 32 are within 15 m, so 8 too); same models, on the ground; the listed trees keep their ids.
    Without a tree list the key is refused."""
    from mitsuforest.config import load_scene
    from mitsuforest.errors import ConfigError
    from mitsuforest.survey import make_plan
    from mitsuforest.twin.scene import surround_width
    (tmp_path / "trees.csv").write_text("x,y,height,crown_radius\n1005,2005,12,2.5\n1014,2012,18,3.0\n")
    base = ("area: {size: [20, 20]}\norigin: {offset: [1000, 2000, 0]}\n"
            "understory: {bushes: 0, rocks: 0, deadwood: 0, stumps: 0}\n"
            f"sensor: {ROOT / 'sensors' / 'ideal.yaml'}\nsurvey: {{lines: [[[10, -5], [10, 25]]]}}\n")
    (tmp_path / "s.yaml").write_text(base + "forest: {trees_file: trees.csv}\n")
    alone = make_plan(load_scene(tmp_path / "s.yaml"))
    (tmp_path / "s.yaml").write_text(base + "forest: {trees_file: trees.csv, surround: 15}\n")
    plan = make_plan(load_scene(tmp_path / "s.yaml"))
    assert plan.trees[:2] == alone.trees and len(plan.trees) == 2 + 8 + 8
    for model, (x0, y0) in (("tree01", (5.0, 5.0)), ("tree02", (14.0, 12.0))):
        copies = sorted(t.position[:2] for t in plan.trees[2:] if t.model == model)
        assert copies == sorted((x0 + 20 * i, y0 + 20 * j) for i in (-1, 0, 1) for j in (-1, 0, 1) if (i, j) != (0, 0))
    assert all(t.position[2] == -0.05 for t in plan.trees)      # flat ground
    (tmp_path / "s.yaml").write_text(base + "forest: {trees: 3, surround: 10}\n")
    with pytest.raises(ConfigError, match="forest.surround: repeats the trees of forest.trees_file"):
        load_scene(tmp_path / "s.yaml")
    assert surround_width([12.0, 30.0], 140.0) == pytest.approx(round(30 * np.tan(np.radians(70)), 1))
    assert surround_width([30.0], 60.0) == pytest.approx(round(30 * np.tan(np.radians(30)), 1))
    assert surround_width([80.0], 160.0) == 100.0 and surround_width([], 90.0) == 0.0


def test_tree_list_places_each_tree_grown_to_its_size(tmp_path):
    from mitsuforest.config import load_scene
    from mitsuforest.survey import make_plan
    (tmp_path / "trees.csv").write_text("x,y,height,crown_radius,species\n1005,2005,12,2.5,pinus_radiata\n"
                                        "1014,2012,18,3.0,\n")
    (tmp_path / "s.yaml").write_text(
        "area: {size: [20, 20]}\norigin: {offset: [1000, 2000, 0]}\nforest: {trees_file: trees.csv}\n"
        "understory: {bushes: 0, rocks: 0, deadwood: 0, stumps: 0}\n"
        f"sensor: {ROOT / 'sensors' / 'ideal.yaml'}\nsurvey: {{lines: [[[10, -5], [10, 25]]]}}\n")
    plan = make_plan(load_scene(tmp_path / "s.yaml"))
    got = [(t.position[:2], plan.models[t.model].archetype) for t in plan.trees]
    assert [p for p, _ in got] == [(5.0, 5.0), (14.0, 12.0)]
    assert [(a.height, a.crown_diameter, a.species) for _, a in got] == [(12.0, 5.0, "pinus_radiata"),
                                                                          (18.0, 6.0, "eucalyptus")]


def _run(capsys, *args):
    """``mitsuforest ARGS`` in this process: (exit code, stderr)."""
    from mitsuforest.cli import main
    capsys.readouterr()
    code = main([str(a) for a in args])
    return SimpleNamespace(returncode=code, stderr=capsys.readouterr().err)


@pytest.mark.parametrize("far, span", [(1e5, "100,000"), (1e10, "10,000,000,000"), (1e300, "1e+300")])
def test_a_stray_coordinate_beyond_a_plot_is_refused_before_the_ground_filter(tmp_path, capsys, far, span):
    """Our PCD without ground classes (its points not filtered, as another tool's are), one point at x = ``far``:
    refused in one line before the lowest-point filter grids the extent (numpy's warnings and a second line,
    hundreds of GiB, a ValueError)."""
    from test_compare import _forest, _our_pcd
    points = _forest()
    points["classification"] = 3
    points["x"][0] = far
    path = _our_pcd(tmp_path / "far.pcd", points)
    import warnings
    with warnings.catch_warnings(record=True) as caught:     # the command prints them: more lines
        warnings.simplefilter("always")
        r = _run(capsys, "twin", path, "-o", tmp_path / "out")
    assert not caught, [str(w.message) for w in caught]
    assert r.returncode == 2 and r.stderr == (f"mitsuforest: {path}: its points span {span} x 20 m; a twin's plot is "
                                              "at most 2,000 m a side: clip the file to the plot\n"), r.stderr
    assert not (tmp_path / "out").exists()


def test_twin_refuses_an_empty_or_damaged_file_in_one_line(tmp_path, capsys):
    empty = tmp_path / "empty.las"
    las = laspy.create(point_format=6, file_version="1.4")
    las.write(str(empty))
    damaged = tmp_path / "damaged.laz"
    damaged.write_bytes(b"LASF" + b"\0" * 50)
    for f, words in ((empty, "holds no points"), (damaged, "cannot read"), (tmp_path / "none.laz", "file not found")):
        r = _run(capsys, "twin", f, "-o", tmp_path / "out")
        assert r.returncode == 2 and r.stderr.count("\n") == 1 and words in r.stderr, r.stderr
        assert not (tmp_path / "out").exists()
    good = tmp_path / "good.las"
    las = laspy.create(point_format=1, file_version="1.2")
    las.x, las.y, las.z = np.arange(10.0), np.arange(10.0), np.zeros(10)
    las.write(str(good))
    for args, words in ((["--species", "oak"], "--species: must be one of eucalyptus, acacia, pinus_radiata, got 'oak'"),
                        (["--name", ".hidden"], "--name: must not start with a dot"),
                        (["--calibrate", "-1"], "--calibrate: must be within 0-20 (each is a render of the twin; "
                                                "calibration converges in 2-4), got -1"),
                        (["--calibrate", "1000"], "--calibrate: must be within 0-20 (each is a render of"),
                        (["--sensor", tmp_path / "none.yaml"], "none.yaml: file not found"),
                        (["--sensor", "leica_als50"], "--sensor: unknown built-in sensor 'leica_als50'; built-in "
                                                      "sensors: ideal, leica_als50-ii, livox_mid-70,")):
        r = _run(capsys, "twin", good, "-o", tmp_path / "out", *args)
        assert r.returncode == 2 and r.stderr.count("\n") == 1 and words in r.stderr, r.stderr
        assert not (tmp_path / "out").exists()


def test_twin_sensor_by_its_built_in_name_is_written_by_that_name(tmp_path, capsys):
    """``--sensor riegl_minivux-1uav`` takes the built-in sensor, as a scene's ``sensor:`` does, and the
    twin's scene names it so (it renders on another machine); a file's path is written whole. The Leica
    ALS50-II sees nothing nearer than 200 m: for this clip (no GPS time, so flown at the default 30 m) it is
    refused in one line, before anything is written."""
    _shrubby_clip(tmp_path / "clip.las", 20.0)
    own = tmp_path / "own.yaml"
    own.write_text((ROOT / "sensors" / "ideal.yaml").read_text())
    for sensor, written in (("riegl_minivux-1uav", "riegl_minivux-1uav"), (own, str(own.resolve()))):
        r = _run(capsys, "twin", tmp_path / "clip.las", "-o", tmp_path / "out", "--sensor", sensor)
        assert r.returncode == 0, r.stderr
        scene = yaml.safe_load((tmp_path / "out" / "clip.yaml").read_text())
        assert scene["sensor"] == written
        assert json.loads((tmp_path / "out" / "twin.json").read_text())["survey"]["sensor"]["value"] == written
        shutil.rmtree(tmp_path / "out")
    r = _run(capsys, "twin", tmp_path / "clip.las", "-o", tmp_path / "out", "--sensor", "leica_als50-ii")
    assert r.returncode == 2 and r.stderr == ("mitsuforest: --sensor: Leica ALS50-II sees nothing nearer than 200 m, "
                                              "and the scan was flown 30 m above its ground; give a sensor for that "
                                              "range\n")
    assert not (tmp_path / "out").exists()


def test_twin_without_ground_points_or_gps_time_says_so_and_uses_named_fallbacks(tmp_path, capsys):
    rng = np.random.default_rng(1)
    n = 20_000
    x, y = rng.uniform(0, 30, n), rng.uniform(0, 30, n)
    z = 100.0 + 0.1 * x + np.where(rng.uniform(size=n) < 0.3, rng.uniform(0, 8, n), 0.0)
    las = laspy.create(point_format=1, file_version="1.2")
    las.header.offsets, las.header.scales = [500_000, 6_000_000, 0], [0.001] * 3
    las.x, las.y, las.z = x + 500_000, y + 6_000_000, z
    f = tmp_path / "plain.las"
    las.write(str(f))
    r = _run(capsys, "twin", f, "-o", tmp_path / "out")
    assert r.returncode == 0, r.stderr
    assert "lowest-point filter" in r.stderr and "no GPS time" in r.stderr
    report = json.loads((tmp_path / "out" / "twin.json").read_text())
    assert report["survey"]["altitude"] == {"value": 30.0, "source": "default (the file has no GPS time)"}
    import rasterio
    with rasterio.open(tmp_path / "out" / "plain_dem.tif") as d:
        dem, t = d.read(1), d.transform
    cols = np.arange(dem.shape[1])
    inner = dem[2:-2, 2:-2]
    expected = 100.0 + 0.1 * (t.c + (cols[2:-2] + 0.5) * t.a - 500_000)
    assert np.abs(inner - expected[None, :]).max() < 0.1      # the sloping ground, vegetation filtered out


def _shrubby_clip(path, width: float, length: float = 30.0) -> None:
    """A flat clip ``width`` x ``length`` m whose returns are half ground, half shrubs 1-2 m tall."""
    rng = np.random.default_rng(2)
    n = int(200 * width * length)
    x, y = rng.uniform(0, width, n), rng.uniform(0, length, n)
    z = 100.0 + np.where(np.arange(n) % 2 == 0, 0.0, rng.uniform(1.0, 2.0, n))
    las = laspy.create(point_format=1, file_version="1.2")
    las.header.offsets, las.header.scales = [500_000, 6_000_000, 0], [0.001] * 3
    las.x, las.y, las.z = x + 500_000, y + 6_000_000, z
    las.classification = np.where(z == 100.0, 2, 1)
    las.write(str(path))


@pytest.mark.parametrize(("variant", "words"), [
    ("scalar_rgb", "--variant: must be auto or a Mitsuba llvm_* or cuda_* variant such as llvm_ad_mono, got 'scalar_rgb'"),
    ("llvm_nope", "--variant: 'llvm_nope' is not in this Mitsuba build"),
])
def test_a_calibration_variant_this_machine_cannot_run_is_refused_before_the_twin_is_written(tmp_path, capsys,
                                                                                             variant, words):
    """The variant was first checked by the calibration's render of the written twin: the twin's scene,
    DEM and trees.csv were left in the folder, and the line named the twin's scene file, not --variant."""
    _shrubby_clip(tmp_path / "clip.las", 10.0)
    r = _run(capsys, "twin", tmp_path / "clip.las", "-o", tmp_path / "out", "--calibrate", "1", "--variant", variant)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and r.stderr.startswith(f"mitsuforest: {words}"), r.stderr
    assert not (tmp_path / "out").exists()


def test_a_twin_asks_for_no_more_bushes_than_its_plot_can_place(tmp_path, capsys):
    """A clip thick with shrubs calls for more bushes than its plot can place (each keeps a 3.4 m clear
    disc): a 2 m wide one gets none and a 40 m wide one half the plan's capacity, said on stderr, and
    their scenes plan."""
    from mitsuforest.config import load_scene
    from mitsuforest.config import understory_capacity
    from mitsuforest.survey import make_plan
    for width in (2.0, 40.0):
        _shrubby_clip(tmp_path / f"clip{width:g}.las", width)
        r = _run(capsys, "twin", tmp_path / f"clip{width:g}.las", "-o", tmp_path / f"out{width:g}")
        assert r.returncode == 0, r.stderr
        report = json.loads((tmp_path / f"out{width:g}" / "twin.json").read_text())["understory"]
        scene = load_scene(tmp_path / f"out{width:g}" / f"clip{width:g}.yaml")
        assert report["bushes_called_for"] > 0 and scene.understory.bushes == report["bushes"]
        make_plan(scene)
        if width == 2.0:
            assert report["bushes"] == 0
            assert f"understory.bushes: {report['bushes_called_for']} called for, 0 fit in a 2 x 30 m plot" in r.stderr
        else:
            assert 0 < report["bushes"] == int(0.5 * understory_capacity((40, 30), "bush")) < report["bushes_called_for"]


def test_tree_list_refuses_a_tree_outside_the_plot_and_a_count_beside_it(tmp_path):
    from mitsuforest.config import load_scene
    from mitsuforest.errors import ConfigError
    from mitsuforest.survey import make_plan
    (tmp_path / "trees.csv").write_text("x,y,height,crown_radius\n5,5,12,2\n25,5,12,2\n")
    base = (f"area: {{size: [20, 20]}}\nsensor: {ROOT / 'sensors' / 'ideal.yaml'}\n"
            "understory: {bushes: 0, rocks: 0, deadwood: 0, stumps: 0}\n")
    (tmp_path / "s.yaml").write_text(base + "forest: {trees_file: trees.csv}\n")
    with pytest.raises(ConfigError, match=r"forest.trees_file: tree 2 stands at local x 25.00, y 5.00, outside the plot"):
        make_plan(load_scene(tmp_path / "s.yaml"))
    (tmp_path / "s.yaml").write_text(base + "forest: {trees_file: trees.csv, trees: 3}\n")
    with pytest.raises(ConfigError, match="forest.trees_file: places the trees it lists"):
        load_scene(tmp_path / "s.yaml")
    # more than 10 a square metre, as forest.trees: 4,001 rows in a 20 m plot (each would build its own crown)
    (tmp_path / "trees.csv").write_text("x,y,height,crown_radius\n" + "5,5,12,0.3\n" * 4001)
    (tmp_path / "s.yaml").write_text(base + "forest: {trees_file: trees.csv}\n")
    with pytest.raises(ConfigError, match=r"forest.trees_file: 4,001 trees in a 20 x 20 m plot is more than 10 a "
                                          r"square metre \(at most 4,000;"):
        make_plan(load_scene(tmp_path / "s.yaml"))


@pytest.mark.parametrize("text, message", [
    ("x;y;height;crown_radius\n5,5;5;12,1;2\n",      # a spreadsheet set to decimal commas
     "the tree list is separated by ';' (a spreadsheet set to decimal commas): save it as CSV with ','"),
    ("x,y,height,crown_radius,height\n5,5,12,2,14\n", "the tree list has the column height 2 times; keep one"),
    # a decimal comma in a comma-separated list: was read as height 12 and crown_radius 5, the 2 left out
    ("x,y,height,crown_radius\n5,5,12,5,2\n", "line 2: 5 cells, the header has 4 (a decimal comma, as in 12,5"),
])
def test_tree_list_in_other_separators_is_refused_saying_so(tmp_path, text, message):
    from mitsuforest.config import load_scene
    from mitsuforest.errors import ConfigError
    from mitsuforest.survey import make_plan
    (tmp_path / "trees.csv").write_text(text)
    (tmp_path / "s.yaml").write_text("area: {size: [20, 20]}\nsensor: ideal\nforest: {trees_file: trees.csv}\n")
    with pytest.raises(ConfigError) as e:
        make_plan(load_scene(tmp_path / "s.yaml"))
    assert e.value.key == "forest.trees_file" and message in e.value.reason


@pytest.mark.parametrize("text, message", [
    ("x,y,height,crown_radius\n" + "1" * 200_000 + "\n", "not a CSV tree list (field larger than field limit"),
    # a quote left open runs to the end of the file: the header named every line of it
    ('"x,y,height,crown_radius\n5,5,12,2\n6,6,12,2\n', "the tree list lacks the column(s) x, y, height, crown_radius "
                                                       "(header: 'x,y,height,crown_radius\\n5,5,12,2\\n6,6,12,2')"),
])
def test_a_tree_list_that_is_no_csv_is_refused_in_one_line(tmp_path, text, message):
    """Found by fuzzing: a cell over 128 kB ended in csv.Error's traceback, and a header holding line breaks
    (an open quote, a binary file) was printed over several lines."""
    from mitsuforest.config import load_scene
    from mitsuforest.errors import ConfigError
    from mitsuforest.survey import make_plan
    (tmp_path / "trees.csv").write_text(text)
    (tmp_path / "s.yaml").write_text("area: {size: [20, 20]}\nsensor: ideal\nforest: {trees_file: trees.csv}\n")
    with pytest.raises(ConfigError) as e:
        make_plan(load_scene(tmp_path / "s.yaml"))
    assert e.value.key == "forest.trees_file" and message in e.value.reason and "\n" not in str(e.value)


def test_trees_command_on_a_tree_list_scene_says_it_shows_the_templates(tmp_path, capsys, monkeypatch):
    from mitsuforest.cli import main
    monkeypatch.chdir(tmp_path)
    (tmp_path / "trees.csv").write_text("x,y,height,crown_radius,species\n5,5,12,2,pinus_radiata\n")
    (tmp_path / "s.yaml").write_text("area: {size: [20, 20]}\nsensor: ideal\nforest: {trees_file: trees.csv, "
                                     "archetypes: [{species: pinus_radiata, base: 1}]}\n")
    capsys.readouterr()
    assert main(["trees", "--scene", "s.yaml", "-o", "gallery"]) == 0
    err = capsys.readouterr().err
    assert err.startswith("mitsuforest: trees.csv: these are the templates the listed trees grow from"), err


def test_tree_list_refuses_a_tree_taller_than_the_procedural_trees_grow(tmp_path, capsys):
    """A list in centimetres (1,200 m) was grown to the archetypes' 80 m without a word; one line, exit 2,
    nothing written."""
    from mitsuforest.cli import main
    (tmp_path / "trees.csv").write_text("x,y,height,crown_radius\n5,5,12,2\n6,8,1200,250\n")
    (tmp_path / "s.yaml").write_text(f"area: {{size: [20, 20]}}\nsensor: {ROOT / 'sensors' / 'ideal.yaml'}\n"
                                     "understory: {bushes: 0, rocks: 0, deadwood: 0, stumps: 0}\n"
                                     "forest: {trees_file: trees.csv}\nsimulation: {variant: llvm_ad_mono}\n")
    capsys.readouterr()
    assert main(["render", str(tmp_path / "s.yaml"), "-o", str(tmp_path / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert "s.yaml: forest.trees_file: " in err
    assert "trees.csv: line 3: height 1,200 m is taller than the procedural trees grow (at most 80 m); the list is " \
           "in metres" in err
    assert not (tmp_path / "out").exists()


# shared/ lies beside the project (CI), or beside the folder of git worktrees that holds it (as in test_compare)
REAL = next((p for p in (ROOT.parent / "shared" / "data" / "real", ROOT.parent.parent / "shared" / "data" / "real")
             if p.is_dir()), ROOT.parent / "shared" / "data" / "real")


def _benchmark():
    import importlib.util
    spec = importlib.util.spec_from_file_location("twin_benchmark", ROOT / "benchmarks" / "twin.py")
    benchmark = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(benchmark)
    return benchmark


def test_benchmark_skips_absent_real_scans_with_the_reason(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["twin.py", "--real", str(tmp_path), "--out", str(tmp_path / "out")])
    _benchmark().main()
    out = capsys.readouterr().out
    assert out.count("skipped:") == 2 and f"{tmp_path / 'UAS_Clip.laz'} is absent" in out


@pytest.mark.skipif(not (REAL / "MixedConifer.laz").is_file(), reason=f"the real scans are not beside the project ({REAL})")
def test_tree_detection_on_mixedconifer_against_its_labels():
    scores = _benchmark().detection_scores(REAL / "MixedConifer.laz")
    assert scores["f1"] >= 0.8, scores


@pytest.mark.skipif(not (REAL / "UAS_Clip.laz").is_file() or not (REAL / "MixedConifer.laz").is_file(),
                    reason=f"the real scans are not beside the project ({REAL})")
def test_the_sweeps_of_the_real_scans_say_where_their_sensors_flew():
    """UAS_Clip's lines 103 and 104, whose beams fit tracks within 0.08 m, have sweeps that put the sensor
    within 2 m of those tracks' heights (2401.1 and 2417.1 m) and its nadir within 2 m of them across the
    flight; all its sweeps run one way (a rotating mirror). MixedConifer keeps first returns only: no
    track, so its four lines are placed by their sweeps, 817 m over its ground, their mirror sweeping
    both ways 127 times a second."""
    from mitsuforest.twin import survey
    from mitsuforest.twin.points import read_scan
    uas = read_scan(REAL / "UAS_Clip.laz")
    est = survey.estimate(uas, 0.0)
    assert est.deflector == "rotating" and est.line_sources.count("track") == 2
    good = [tr for tr in est.tracks if tr.residual < 0.1]
    assert len(good) == 2
    for track in good:
        source = np.bincount(uas.point_source_id[np.abs(uas.gps_time - track.t_mid) < 1.0]).argmax()
        g = uas.point_source_id == source
        line, parts = survey.nadir_line(uas.x[g], uas.y[g], uas.z[g], uas.gps_time[g], uas.scan_angle[g])
        assert line.sensor_z == pytest.approx(track.position[2], abs=2.0)
        placed = survey.place_nadir_line(line, parts, uas.x[g], uas.y[g], uas.z[g], uas.scan_angle[g], line.sensor_z)
        heading = np.radians(line.heading)
        across = np.array([np.cos(heading), -np.sin(heading)])
        assert (np.array(placed.position) - track.position[:2]) @ across == pytest.approx(0.0, abs=2.0)
    mixed = read_scan(REAL / "MixedConifer.laz")
    est = survey.estimate(mixed, 0.0)
    assert est.tracks == () and est.line_sources == ("scan lines",) * 4
    assert est.altitude == pytest.approx(817.1, abs=0.5) and est.deflector == "oscillating"
    assert est.scan_angle_side == "left"         # against LAS: the twin says so in its notes
    assert est.scan_frequency == pytest.approx(127.2, abs=0.1) and est.speed == pytest.approx(61.4, abs=0.1)


def test_crown_lai_inverts_beer_lambert():
    from mitsuforest.twin.foliage import G, crown_gap_fraction, effective_lai
    for lai, angle in ((1.0, 0.0), (4.0, 30.0), (2.5, 60.0)):
        gap = np.exp(-G * lai / np.cos(np.deg2rad(angle)))
        assert effective_lai(gap, angle) == pytest.approx(lai, rel=1e-12)
    h = np.array([0.1, 0.2, 5.0, 12.0, 0.3, 20.0])
    assert crown_gap_fraction(h, [True, False, True, True, True, False]) == 0.5   # 2 of 4 under crowns reach ground
    assert crown_gap_fraction(h, [False] * 6) is None


def test_tree_list_leaf_area_column_sets_each_trees_leaves(tmp_path):
    from mitsuforest.config import load_scene
    from mitsuforest.survey import make_plan
    (tmp_path / "trees.csv").write_text("x,y,height,crown_radius,leaf_area\n5,5,12,2.5,30\n14,12,18,3,\n")
    (tmp_path / "s.yaml").write_text(
        "area: {size: [20, 20]}\nforest: {trees_file: trees.csv}\n"
        "understory: {bushes: 0, rocks: 0, deadwood: 0, stumps: 0}\n"
        f"sensor: {ROOT / 'sensors' / 'ideal.yaml'}\nsurvey: {{lines: [[[10, -5], [10, 25]]]}}\n")
    plan = make_plan(load_scene(tmp_path / "s.yaml"))
    first, second = (plan.models[t.model].archetype for t in plan.trees)
    assert first.leaf_area == 30.0
    from mitsuforest.specs.archetypes import DEFAULT_ARCHETYPES
    template = min(DEFAULT_ARCHETYPES, key=lambda a: abs(a.height - 18))    # the nearest Eucalyptus in height
    volume = (6.0 / template.crown_diameter) ** 2 * 18 / template.height
    assert second.leaf_area == pytest.approx(template.leaf_area * volume, abs=0.01)   # by crown volume


def _stamped_bursts(prf, step, pulses, bursts, lost_stretch, rng):
    """First-return times of ``bursts`` scan lines (12 ms apart) of ``pulses`` pulses at ``prf``, each burst
    starting at a random phase and losing one contiguous stretch of ``lost_stretch`` of its pulses (their
    first returns outside the file), stamped down to multiples of ``step`` (s)."""
    out = []
    for k in range(bursts):
        t = 0.012 * k + rng.uniform(0, step) + np.arange(pulses) / prf
        start = rng.integers(0, pulses)
        keep = np.ones(pulses, bool)
        keep[start:start + int(lost_stretch * pulses)] = False
        out.append(np.floor(t[keep] / step) * step)
    return out


def test_pulse_rate_from_coarse_gps_stamps_counts_the_full_stamps():
    """UAS_Clip's GPS times are stamps 7.6-122 µs apart, each holding up to 100 pulses: a stamp inside a
    burst holds the pulse rate times the step, whatever stretches of pulses a burst lost elsewhere; a
    burst's pulses over its length count those losses and its two partial stamps against the rate."""
    from mitsuforest.twin.survey import pulse_rate, stamped_pulse_rate
    rng = np.random.default_rng(5)
    for prf, step in ((830_000.0, 2 ** -15), (830_000.0, 2 ** -13), (500_000.0, 2 ** -16)):
        bursts_ = _stamped_bursts(prf, step, 400, 200, 0.3, rng)
        assert pulse_rate(bursts_) == pytest.approx(prf, rel=0.02)
        whole = np.median([(len(b) - 1) / (b[-1] - b[0]) for b in bursts_])
        assert whole < 0.9 * prf                         # the estimate this replaces: the losses count
    fine = [0.012 * k + np.arange(300) / 600_000.0 for k in range(20)]
    assert pulse_rate(fine) == pytest.approx(600_000.0, rel=1e-9)   # times that tell pulses apart: their spacing
    coarse = [np.full(50, 0.012 * k) for k in range(20)] + [np.full(50, 0.012 * k + 0.003) for k in range(20)]
    assert stamped_pulse_rate(coarse) is None            # one stamp a scan line (UAS_Clip's line 106): no inner stamps
    assert stamped_pulse_rate([np.repeat(np.arange(5) * 1e-3, 20)]) is None   # a 1 ms step is no burst's inside


def test_tree_list_crown_ratio_column_sets_each_trees_crown(tmp_path):
    """An empty cell keeps the template's ratio; a ratio outside the archetype's 0.1-0.95 is refused in one line."""
    from mitsuforest.config import load_scene
    from mitsuforest.errors import UserError
    from mitsuforest.survey import make_plan
    (tmp_path / "s.yaml").write_text(
        "area: {size: [20, 20]}\nforest: {trees_file: trees.csv, archetypes: [{species: pinus_radiata, base: 1, "
        "crown_ratio: 0.45}]}\nunderstory: {bushes: 0, rocks: 0, deadwood: 0, stumps: 0}\n"
        f"sensor: {ROOT / 'sensors' / 'ideal.yaml'}\nsurvey: {{lines: [[[10, -5], [10, 25]]]}}\n")
    (tmp_path / "trees.csv").write_text("x,y,height,crown_radius,crown_ratio\n5,5,22,2.5,0.8\n14,12,22,3,\n")
    plan = make_plan(load_scene(tmp_path / "s.yaml"))
    assert [plan.models[t.model].archetype.crown_ratio for t in plan.trees] == [0.8, 0.45]
    (tmp_path / "trees.csv").write_text("x,y,height,crown_radius,crown_ratio\n5,5,22,2.5,0.99\n")
    with pytest.raises(UserError, match=r"trees.csv: line 2: crown_ratio must be within 0.1-0.95, got 0.99"):
        make_plan(load_scene(tmp_path / "s.yaml"))


def test_tree_list_refuses_a_leaf_area_beyond_what_a_procedural_tree_carries(tmp_path):
    """A listed leaf area above the archetypes' 2,000 m² was cut to 2,000 m² without a word (a tree asked
    to carry 3,000 m² carried two thirds of it); it is refused in one line, as a crown ratio out of range
    is. 2,000 m² itself is kept."""
    from mitsuforest.config import load_scene
    from mitsuforest.errors import UserError
    from mitsuforest.survey import make_plan
    (tmp_path / "s.yaml").write_text(
        "area: {size: [20, 20]}\nforest: {trees_file: trees.csv}\nunderstory: {bushes: 0, rocks: 0, deadwood: 0, "
        f"stumps: 0}}\nsensor: {ROOT / 'sensors' / 'ideal.yaml'}\nsurvey: {{lines: [[[10, -5], [10, 25]]]}}\n")
    (tmp_path / "trees.csv").write_text("x,y,height,crown_radius,leaf_area\n5,5,22,2.5,2000\n")
    plan = make_plan(load_scene(tmp_path / "s.yaml"))
    assert [plan.models[t.model].archetype.leaf_area for t in plan.trees] == [2000.0]
    (tmp_path / "trees.csv").write_text("x,y,height,crown_radius,leaf_area\n5,5,22,2.5,40\n9,9,30,4,3000\n")
    with pytest.raises(UserError, match=r"trees.csv: line 3: leaf_area 3,000 m² is more than a procedural tree "
                                        r"carries \(at most 2,000 m²\)"):
        make_plan(load_scene(tmp_path / "s.yaml"))


def test_an_oscillating_sensor_gets_half_the_scans_lines_per_second(tmp_path):
    """The scan's bursts come one a scan line. A turning mirror draws one line a turn, an oscillating one
    two a sweep there and back (its scan_frequency, as HELIOS++'s): 80 lines/s are 80 Hz and 40 Hz."""
    from mitsuforest.twin.scene import _rates_of
    text = (ROOT / "sensors" / "ideal.yaml").read_text()
    oscillating = tmp_path / "oscillating.yaml"
    oscillating.write_text(text.replace("deflector: rotating", "deflector: oscillating")
                           .replace("field_of_view: 360", "field_of_view: 60"))
    for sensor, hz in ((ROOT / "sensors" / "ideal.yaml", 80.0), (oscillating, 40.0)):
        report = {}
        rates = _rates_of(sensor, 123_000.0, 80.0, 30.0, report)
        assert rates == {"pulse_frequency": 100_000, "scan_frequency": hz}
        assert ("oscillating" in report["sensor"]["source"]) == (hz == 40.0)


def test_a_twin_leaves_out_noise_withheld_repeated_isolated_and_stray_points(tmp_path, capsys):
    """A flat clip with one 15 m dome crown, and a bird 500 m up (class 1), a high-noise point 300 m up
    (ASPRS 18), a withheld point 400 m up, a flock of 12 birds 60 m over the dome (class 1, within 2 m:
    too many to be isolated) and every point written twice: each is left out and said, and the twin's one
    tree is the dome, 15 m tall (before, the bird, the noise point, the withheld point and the flock stood
    beside it as trees 500, 300, 400 and 77 m tall)."""
    g = np.arange(0.25, 30.0, 0.5)
    x, y = (v.ravel() for v in np.meshgrid(g, g, indexing="ij"))
    r = np.hypot(x - 15, y - 15)
    crown = r < 3
    flock = np.random.default_rng(5).uniform(0, 2, (3, 12)) + [[20.0], [10.0], [75.0]]
    x, y = np.r_[x, x[crown], flock[0], 5.0, 25.0, 25.0], np.r_[y, y[crown], flock[1], 5.0, 5.0, 25.0]
    z = np.r_[np.zeros(len(r)), 15 - r[crown] ** 2 / 3, flock[2], 500.0, 300.0, 400.0] + 100.0
    classes = np.r_[np.full(len(r), 2), np.full(crown.sum(), 5), np.full(12, 1), 1, 18, 1]
    las = laspy.create(point_format=6, file_version="1.4")
    las.header.offsets, las.header.scales = [500_000, 6_000_000, 0], [0.001] * 3
    twice = np.r_[np.arange(len(x)), np.arange(len(x))]
    las.x, las.y, las.z = x[twice] + 500_000, y[twice] + 6_000_000, z[twice]
    las.classification = classes[twice]
    las.withheld = np.r_[np.zeros(len(x) - 1, bool), True][twice]
    las.write(str(tmp_path / "clip.laz"))
    run = _run(capsys, "twin", tmp_path / "clip.laz", "-o", tmp_path / "out")
    assert run.returncode == 0, run.stderr
    for said in ("2 noise points (ASPRS classes 7, 18) left out", "2 withheld points left out",   # both copies
                 f"{len(x) - 2:,} repeated points (exact copies) left out", "1 isolated points (fewer than 6 others",
                 "12 points in 1 stray cluster (fewer than 20 points"):
        assert f"twin: {said}" in run.stderr, run.stderr
    rows = np.genfromtxt(tmp_path / "out" / "trees.csv", delimiter=",", names=True, dtype=None, encoding=None)
    assert np.atleast_1d(rows["height"]).tolist() == pytest.approx([15.0], abs=0.2)
    report = json.loads((tmp_path / "out" / "twin.json").read_text())
    assert report["points"] == len(x) - 3 - 12 and report["notes"][0] == "2 noise points (ASPRS classes 7, 18) left out"


@pytest.mark.parametrize("epsg, words", [
    ("EPSG:2223", "its CRS (NAD83 / Arizona Central (ft)) is in foot"),
    ("EPSG:32612+6360", "its CRS (WGS 84 / UTM zone 12N + NAVD88 height (ftUS)) is in metre, heights in US survey foot"),
    ("EPSG:4326", "its CRS (WGS 84) is geographic: its x and y are in degree")])
def test_a_file_not_in_metres_is_refused_in_one_line_before_any_work(tmp_path, capsys, epsg, words):
    """A twin is built in metres: a file in feet, or with heights in feet (before: a twin 3.28 times too
    tall, as the scene checks only x and y), or in degrees is refused naming its CRS, nothing written."""
    import pyproj
    _shrubby_clip(tmp_path / "clip.las", 10.0)
    las = laspy.convert(laspy.read(str(tmp_path / "clip.las")), point_format_id=6, file_version="1.4")   # WKT
    las.header.add_crs(pyproj.CRS.from_user_input(epsg))
    las.write(str(tmp_path / "clip.las"))
    r = _run(capsys, "twin", tmp_path / "clip.las", "-o", tmp_path / "out")
    assert r.returncode == 2 and r.stderr == (f"mitsuforest: {tmp_path / 'clip.las'}: {words}; a twin is built in "
                                              "metres: reproject the file to a projected CRS in metres (such as its "
                                              "UTM zone) first\n"), r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.las"]


def test_a_file_wider_than_a_plot_is_refused_naming_it_before_any_grid(tmp_path, capsys):
    """Two shrubby clips 3 km apart: the twin says the file's span and the 2,000 m limit, naming the
    file (before: the scene's validation, naming the staging scene, after a 3 x 3 km grid of work)."""
    _shrubby_clip(tmp_path / "a.las", 10.0)
    las = laspy.read(str(tmp_path / "a.las"))
    far = laspy.read(str(tmp_path / "a.las"))
    far.x, far.y = np.asarray(far.x) + 3000.0, np.asarray(far.y) + 3000.0
    both = laspy.LasData(las.header)
    both.points = laspy.ScaleAwarePointRecord(np.concatenate([las.points.array, far.points.array]), las.point_format,
                                              las.header.scales, las.header.offsets)
    both.write(str(tmp_path / "two.las"))
    r = _run(capsys, "twin", tmp_path / "two.las", "-o", tmp_path / "out")
    assert r.returncode == 2 and r.stderr == (f"mitsuforest: {tmp_path / 'two.las'}: its points span 3,010 x 3,030 m; "
                                              "a twin's plot is at most 2,000 m a side: clip the file to the plot\n")
    assert not (tmp_path / "out").exists()


def test_a_copc_file_s_twin_is_named_without_copc(tmp_path, capsys):
    """``clip.copc.laz`` (read as any LAZ) makes the scene ``clip``, not ``clip.copc``."""
    _shrubby_clip(tmp_path / "clip.las", 10.0)
    laspy.read(str(tmp_path / "clip.las")).write(str(tmp_path / "clip.copc.laz"))
    r = _run(capsys, "twin", tmp_path / "clip.copc.laz", "-o", tmp_path / "out")
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["clip.yaml", "clip_dem.tif", "trees.csv", "twin.json"]


def test_a_file_on_a_local_grid_in_metres_gets_a_twin_without_a_crs(tmp_path, capsys):
    """A site grid in metres (an engineering CRS) is no CRS a scene can hold: the twin is written without
    ``origin.crs``, said (before: the scene's validation refused it, naming the staging scene)."""
    import pyproj
    _shrubby_clip(tmp_path / "clip.las", 10.0)
    las = laspy.convert(laspy.read(str(tmp_path / "clip.las")), point_format_id=6, file_version="1.4")
    las.header.add_crs(pyproj.CRS.from_wkt('LOCAL_CS["site grid",LOCAL_DATUM["site",0],UNIT["metre",1],'
                                           'AXIS["Easting",EAST],AXIS["Northing",NORTH]]'))
    las.write(str(tmp_path / "clip.las"))
    r = _run(capsys, "twin", tmp_path / "clip.las", "-o", tmp_path / "out")
    assert r.returncode == 0, r.stderr
    assert "twin: its CRS (site grid) is not a projected CRS: the twin's scene has no origin.crs\n" in r.stderr
    scene = yaml.safe_load((tmp_path / "out" / "clip.yaml").read_text())
    assert "crs" not in scene["origin"] and scene["origin"]["offset"][:2] == [500_000.0, 6_000_000.0]


@pytest.mark.parametrize("filled", ["numbers of returns", "return numbers and GPS times", "return numbers alone"])
def test_a_twin_counts_the_pulses_of_a_file_that_left_its_numbers_of_returns_0(tmp_path, filled):
    """A flat 30 × 30 m clip, a pulse every 0.5 m (4 pulses/m²), half of them returning from 5 m shrubs
    and then the ground. Whether the file counted each pulse's returns or left those counts 0, the twin
    finds 4 pulses/m² (before, a file that left them 0 gave 5: each second return counted as half a
    pulse), and with GPS times it takes each pulse's count from its points."""
    from mitsuforest.twin import analyse
    from mitsuforest.twin.points import read_scan
    g = np.arange(0.25, 30.0, 0.5)
    x, y = (v.ravel() for v in np.meshgrid(g, g, indexing="ij"))
    two = x < 15
    pulse = np.r_[np.arange(len(x)), np.flatnonzero(two)]
    rn = np.r_[np.ones(len(x), int), np.full(two.sum(), 2)]
    nr = np.r_[np.where(two, 2, 1), np.full(two.sum(), 2)]
    z = 100.0 + np.r_[np.where(two, 5.0, 0.0), np.zeros(two.sum())]
    las = laspy.create(point_format=6, file_version="1.4")
    las.header.offsets, las.header.scales = [500_000, 6_000_000, 0], [0.001] * 3
    las.x, las.y, las.z = x[pulse] + 500_000, y[pulse] + 6_000_000, z
    las.classification = np.where(z == 100.0, 2, 1)
    las.return_number = rn
    las.number_of_returns = nr if filled == "numbers of returns" else np.zeros_like(nr)
    if filled != "return numbers alone":
        las.gps_time = 1000.0 + pulse * 1e-5
    las.write(str(tmp_path / "clip.las"))
    scan = read_scan(tmp_path / "clip.las")
    assert analyse(scan)["pulse_density"] == pytest.approx(4.0)
    if filled != "return numbers alone":
        assert np.array_equal(scan.number_of_returns, nr)
