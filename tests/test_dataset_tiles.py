"""Tiles written by a split plot's leg tasks (issue 30): the tile test done batch by batch, the points
as the plot's files read them back, the bytes that cutting the whole plot gives whatever the legs per
task, reruns that reuse finished parts and tiles, and a tiles-only plot.

The task functions run in this process, without Dask, on a tiny plot (12 m, 3 legs, thin beam); the
cluster runs are in ``test_dataset.py``.
"""

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT
from helpers import tiny_scene

BASE = tiny_scene(2, 2, 1, 1, 1, output="{formats: [pcd, laz], pictures: false}")
NAME = "plot_0000"


# --- the grid, batch by batch ---------------------------------------------------------------------

def _members_one_tile_at_a_time(x, y, area, size, buffer):
    """(tile, row) pairs as :func:`write_tiles` selected them before issue 30: each tile's extent tested
    on every point."""
    from mitsuforest.dataset.tiles import in_extent, tile_extent, tile_grid
    nx, ny = tile_grid(area, size)
    tiles, rows = [], []
    for i in range(nx):
        for j in range(ny):
            sel = np.flatnonzero(in_extent(x, y, tile_extent(i, j, area, size, buffer)))
            tiles.append(np.full(len(sel), i * ny + j))
            rows.append(sel)
    return np.concatenate(tiles), np.concatenate(rows)


@pytest.mark.parametrize("area, size, buffer", [
    ((12, 12), 5.0, 1.0),          # the last row and column shorter
    ((10, 7.5), 2.5, 3.0),         # a buffer wider than a tile: a point in up to 25 files
    ((20, 20), 4.0, 0.0),          # no buffer: every point in one file
    ((0.7, 0.3), 0.1, 0.05),       # edges that decimal sizes put off the grid by rounding
])
def test_tile_members_are_the_extent_test_of_every_tile(area, size, buffer):
    from mitsuforest.dataset.tiles import core_tile, tile_grid, tile_members
    rng = np.random.default_rng(7)
    w, h = area
    x, y = rng.uniform(-3, w + 3, 4000), rng.uniform(-3, h + 3, 4000)
    edges = np.concatenate([np.arange(0, w + size, size), np.arange(0, w + size, size) + buffer,
                            np.arange(0, w + size, size) - buffer, [w, 0.3, 0.6]])
    x = np.concatenate([x, np.repeat(edges, len(edges)), rng.uniform(0, w, 50)])
    y = np.concatenate([y, np.tile(edges, len(edges)), np.full(50, h)])
    tile, row = tile_members(x, y, area, size, buffer)
    expected_tile, expected_row = _members_one_tile_at_a_time(x, y, area, size, buffer)
    assert np.array_equal(tile, expected_tile) and np.array_equal(row, expected_row)
    ny = tile_grid(area, size)[1]
    ci, cj = core_tile(x, y, area, size)
    in_own_core = set(zip(tile.tolist(), row.tolist())) >= set(zip((ci * ny + cj).tolist(), range(len(x))))
    assert in_own_core                                     # every point is in its core tile's file
    if buffer == 0:
        assert np.array_equal(np.sort(row), np.arange(len(x)))     # and in no other


def test_a_batch_without_points_is_in_no_tile():
    """A leg's batch that met nothing (a heading that starts it outside the plot, say) sorts into no tile."""
    from mitsuforest.dataset.tiles import tile_members
    tile, row = tile_members(np.zeros(0), np.zeros(0), (20, 20), 10.0, 1.0)
    assert tile.shape == row.shape == (0,) and tile.dtype == row.dtype == np.int64


@pytest.mark.parametrize("size", [1.1, 2.2, 5.2])
def test_a_point_on_a_rounded_edge_is_in_the_core_its_bounds_say(size):
    """A decimal tile size puts ``k * size`` off ``x / size``'s rounding: a point (float32, as a PCD holds
    it) at 16.5 m with 1.1 m tiles has ``floor(16.5 / 1.1)`` 14, yet lies at core 14's upper bound
    (``core_bounds``' x1, 16.5) and so in tile 15's file alone without a buffer. Its core is the one whose
    bounds hold it, the tile whose file holds it: no point is lost from every core's count."""
    from mitsuforest.dataset.tiles import core_bounds, core_tile, tile_grid, tile_members
    area = (60.0, 10.0)
    nx, ny = tile_grid(area, size)
    at = (np.arange(1, nx) * size).astype(np.float32)
    x = np.concatenate([at, np.nextafter(at, np.float32(0)), np.nextafter(at, np.float32(99))]).astype(np.float64)
    y = np.full(len(x), 1.0)
    ci, cj = core_tile(x, y, area, size)
    bounds = np.array([core_bounds(i, 0, area, size) for i in ci.tolist()])
    assert np.all((x >= bounds[:, 0]) & ((x < bounds[:, 2]) | (ci == nx - 1)))
    tile, row = tile_members(x, y, area, size, 0.0)
    assert np.array_equal(np.sort(row), np.arange(len(x)))                       # one file each ...
    assert np.array_equal(tile[np.argsort(row)], ci * ny + cj)                   # ... that of its core


def test_boxes_combine_to_those_of_all_the_points():
    from mitsuforest.dataset.tiles import combine_boxes, instance_boxes
    rng = np.random.default_rng(2)
    ids = rng.integers(1, 40, 3000)
    x, y = rng.uniform(0, 50, 3000), rng.uniform(0, 50, 3000)
    whole = instance_boxes(ids, x, y, np.unique(ids))
    for inst, box in zip(np.unique(ids), whole):
        mine = ids == inst
        assert box.tolist() == [x[mine].min(), y[mine].min(), x[mine].max(), y[mine].max()]
    assert np.isnan(instance_boxes(ids, x, y, np.array([0, 40]))).all()      # listed, without points
    sets = np.array_split(rng.permutation(3000), 3)
    pieces = [(np.unique(ids[s]), instance_boxes(ids[s], x[s], y[s], np.unique(ids[s]))) for s in sets]
    nan = (np.array([5]), np.full((1, 4), np.nan))        # a set without points of instance 5
    got_ids, got = combine_boxes(np.concatenate([p[0] for p in [*pieces, nan]]),
                                 np.concatenate([p[1] for p in [*pieces, nan]]))
    assert np.array_equal(got_ids, np.unique(ids)) and np.array_equal(got, whole)


@pytest.mark.parametrize("area, size, count", [((12, 12), 5, 3), ((12, 12), 5, 20), ((300, 300), 20, 27)])
def test_tile_groups_hold_every_tile_once(area, size, count):
    from mitsuforest.dataset.runner import tile_groups
    from mitsuforest.dataset.spec import Tiles
    from mitsuforest.dataset.tiles import tile_grid
    groups = tile_groups(area, Tiles(size, 0.0, "laz"), count)
    n = np.prod(tile_grid(area, size))
    assert [t for a, b in groups for t in range(a, b)] == list(range(n))
    assert len(groups) == min(count, n)
    assert max(b - a for a, b in groups) - min(b - a for a, b in groups) <= 1
    assert tile_groups(area, None, count) == []


@pytest.mark.parametrize("formats, offset", [(("pcd", "laz"), (0, 0, 0)), (("pcd",), (500000.123, 6100000.456, 12.5)),
                                             (("laz",), (500000.123, 6100000.456, 12.5)), (("las",), (0, 0, 0))])
def test_points_as_read_are_what_the_plot_files_read_back(tmp_path, formats, offset):
    """Batches through the render's writer, then read back as tiles are cut from them: the same bytes
    as the batches turned into what they read back one by one (PCD: float32 local or float64
    georeferenced; LAS: its precision, no pulse_id or range)."""
    from mitsuforest.config import load_scene
    from mitsuforest.dataset.files import points_as_read, read_plot_points
    from mitsuforest.scan import POINT_DTYPE
    from mitsuforest.write import PointWriter, Staging
    from mitsuforest.write.ground import ground_surface
    scene = load_scene(ROOT / "scenes" / "demo.yaml").with_({"origin.offset": list(offset),
                                                             "output.formats": list(formats)})
    rng = np.random.default_rng(4)
    batches = []
    for n in (300, 0, 1, 250):
        p = np.zeros(n, POINT_DTYPE)
        for field in POINT_DTYPE.names:
            p[field] = rng.integers(1, 6, n)
        p["x"], p["y"], p["z"] = rng.uniform(-1, 21, n), rng.uniform(-1, 21, n), rng.uniform(0, 30, n)
        p["intensity"], p["range"] = rng.uniform(0, 0.08, n), rng.uniform(1, 60, n)
        p["gps_time"], p["scan_angle"] = rng.uniform(0, 100, n), rng.uniform(-60, 60, n)
        p["reflectance"] = rng.uniform(-30, 5, n)
        batches.append(p)
    staging = Staging(tmp_path, scene.name)
    writer = PointWriter(staging, scene, threads=1)
    for batch in batches:
        writer.add(batch)
    writer.close()
    staging.commit()
    read = read_plot_points(tmp_path, scene.name, formats)
    converted = np.concatenate([points_as_read(b, scene, ground_surface(None)) for b in batches])
    assert converted.dtype == read.dtype and converted.tobytes() == read.tobytes()
    assert ("pulse_id" in read.dtype.names) == ("pcd" in formats)


# --- the task functions on a tiny plot --------------------------------------------------------------

def _dataset(folder: Path, body: str):
    """A one-plot dataset's scene file in ``folder/out`` (as the client writes it); the dataset."""
    from mitsuforest.dataset import files, load_dataset
    folder.mkdir(exist_ok=True)
    (folder / "base.yaml").write_text(BASE)
    (folder / "set.yaml").write_text("base: base.yaml\nplots: 1\nlegs_per_task: 1\n" + body)
    dataset = load_dataset(folder / "set.yaml")
    root = folder / "out"
    scene = dataset.plots[0].scene.with_({"output.dir": str(files.plot_folder(root, NAME))})
    files.write_scene_file(files.scene_file(root, NAME), scene)
    return root, dataset


def _legs(root, dataset, per_task: int) -> list[dict]:
    from mitsuforest.dataset import runner, tasks
    count = len(runner._legs(dataset.plots[0].scene))
    return [tasks.scan_legs(str(root), NAME, a, min(a + per_task, count), 1, dataset.tiles)
            for a in range(0, count, per_task)]


def _tile_groups(root, dataset, legs) -> list[dict]:
    from mitsuforest.dataset import runner, tasks
    return [tasks.write_tile_group(str(root), NAME, legs, dataset.tiles, a, b, 1)
            for a, b in runner.tile_groups(dataset.plots[0].scene.area.size, dataset.tiles, len(legs))]


def _split_plot(root, dataset, per_task: int) -> dict:
    """What the client's tasks for a split plot do, in order, in this process; the plot's record."""
    from mitsuforest.dataset import tasks
    legs = _legs(root, dataset, per_task)
    merged = tasks.merge_plot(str(root), NAME, legs, 1) if dataset.tiles.plot_files else None
    return tasks.finish_split_plot(str(root), NAME, legs, merged, _tile_groups(root, dataset, legs))


@pytest.mark.parametrize("tiles", [
    "tiles: {size: 5, buffer: 1, format: laz}\n",
    # a plot written as LAZ only (tiles from its LAS records), georeferenced, with a profile's files too
    "tiles: {size: 2.5, buffer: 3, format: pcd}\ngrid: {output.formats: [[laz]], "
    "origin.offset: [[500000.0, 4000000.0, 100.0]], output.profile: [for-instance]}\n",
])
def test_leg_tasks_write_the_tiles_cut_from_the_whole_plot(tmp_path, tiles):
    """Tiles from tasks of one leg (with the plot's files merged) and of two legs (tiles only): every
    record and file the same as those cut from the merged plot's files, which tiles-only leaves out."""
    from mitsuforest.dataset import files
    root, dataset = _dataset(tmp_path / "one", tiles)
    one = _split_plot(root, dataset, 1)
    scene = dataset.plots[0].scene.with_({"output.dir": str(files.plot_folder(root, NAME))})
    cut = json.loads(json.dumps(files.write_tiles(root, scene, dataset.tiles)))   # as a record holds them
    assert cut == one["tiles"]                                # cut again from the merged files

    two_root, tiles_only = _dataset(tmp_path / "two", tiles.replace("}\n", ", plot_files: false}\n", 1))
    two = _split_plot(two_root, tiles_only, 2)
    assert [r["legs"] for r in two["leg_tasks"]] == [[0, 2], [2, 3]]
    assert two["tiles"] == one["tiles"]
    assert (two["points"], two["classes"], two["pulses"]) == (one["points"], one["classes"], one["pulses"])
    assert sum(t["core_points"] for t in two["tiles"]) == two["points"]        # every point in one core
    tables = {k: v for k, v in one["files"].items() if k.endswith(("_volumes.csv", "_ids.csv", "_plan.json",
                                                                     "_trajectory.csv"))}
    assert two["files"] == tables and len(tables) == 4            # a tiles-only plot: its tables, no points
    folder = files.plot_folder(two_root, NAME)
    assert sorted(p.name for p in folder.iterdir()) == sorted([*(Path(k).name for k in tables), "tiles",
                                                               f"{NAME}_dataset.json"])
    assert files.valid_record(two_root, NAME) is not None and not (folder / ".parts").exists()


def test_reruns_reuse_finished_parts_and_tiles_and_nothing_looks_finished_early(tmp_path, monkeypatch):
    from mitsuforest import survey
    from mitsuforest.dataset import files, parts, tasks
    root, dataset = _dataset(tmp_path, "tiles: {size: 5, buffer: 1, format: laz, plot_files: false}\n")
    legs = _legs(root, dataset, 1)
    scene_sha = files.sha256(files.scene_file(root, NAME))
    part = parts.part_path(root, NAME, 1, 2)
    tiled = part.with_suffix(".tiles").read_bytes()
    assert not part.with_suffix(".points").exists()              # tiles only: no points for a merge

    real_scan = survey.scan
    monkeypatch.setattr(survey, "scan", lambda *a, **k: pytest.fail("scanned again"))
    assert _legs(root, dataset, 1) == legs                       # every part reused
    assert parts.read_part(part, scene_sha, dataset.tiles, whole_points=True) is None   # not made for a merge
    grid = dataset.tiles.__class__(4.0, 1.0, "laz", False)
    assert parts.read_part(part, scene_sha, grid, whole_points=False) is None           # another grid
    pcd = dataset.tiles.__class__(5, 1, "pcd", True)                    # other files, the same grid
    assert parts.read_part(part, scene_sha, pcd, whole_points=False) == legs[1]
    part.with_suffix(".tiles").write_bytes(tiled[:-1])          # a killed task's file, cut short
    monkeypatch.setattr(survey, "scan", real_scan)
    again = tasks.scan_legs(str(root), NAME, 1, 2, 1, dataset.tiles)
    assert part.with_suffix(".tiles").read_bytes() == tiled and again["tile_chunks"] == legs[1]["tile_chunks"]

    groups = _tile_groups(root, dataset, legs)
    assert files.valid_record(root, NAME) is None               # tiles written, no record yet
    monkeypatch.setattr(files, "write_tile", lambda *a, **k: pytest.fail("tile written again"))
    assert _tile_groups(root, dataset, legs) == groups          # reused: their files are unchanged
    monkeypatch.undo()
    damaged = root / next(iter(groups[0]["records"][0]["files"]))
    damaged.write_bytes(b"damaged")
    assert _tile_groups(root, dataset, legs)[0]["records"] == groups[0]["records"]     # redone, same bytes

    stale = [files.tiles_folder(root, NAME) / n for n in (f"{NAME}_x9_y9.laz", f"{NAME}_x0_y0.laz.tmp-host-1")]
    for path in stale:
        path.write_bytes(b"an earlier layout's tile, a killed task's temporary file")
    record = tasks.finish_split_plot(str(root), NAME, legs, None, groups)
    assert files.valid_record(root, NAME) == json.loads(json.dumps(record)) and not any(p.exists() for p in stale)
    listed = {root / rel for t in record["tiles"] for rel in t["files"]}
    assert set(files.tiles_folder(root, NAME).iterdir()) == listed
    assert not parts.parts_folder(root, NAME).exists()


def test_each_tree_is_in_the_core_of_one_tile_however_many_hold_it_whole(tmp_path):
    """A tile's tree table says which tile owns each object (``core``: its position in that tile's core),
    so that a plot's volumes summed over its tiles count each object once: ``whole_inside`` is 1 in every
    file holding all its points, and a deadwood piece on a core's edge, within the buffer of both tiles,
    is whole inside two."""
    from types import SimpleNamespace
    from mitsuforest.classes import DEADWOOD, GROUND, TREE_LEAVES, TREE_WOOD
    from mitsuforest.dataset import files
    from mitsuforest.dataset.spec import Tiles
    from mitsuforest.dataset.tiles import tile_members
    from mitsuforest.scan import POINT_DTYPE
    from mitsuforest.write.ground import fill_height, with_room_for_height
    rng = np.random.default_rng(4)
    scene = SimpleNamespace(name=NAME, area=SimpleNamespace(size=(12, 12)), output=SimpleNamespace(profile="ours"),
                            origin=SimpleNamespace(offset=(500000.0, 6000000.0, 0.0), crs=None),
                            sensor=SimpleNamespace(intensity=None))
    tiles = Tiles(5.0, 1.0, "pcd")
    # a tree at (4, 4) whose crown reaches x 6.5 (into tile 1's core), a deadwood piece at (2, 5.2) lying
    # from y 4.6 to 5.4 (whole inside the files of tiles (0, 0) and (0, 1)), and ground
    objects = [(1, TREE_WOOD, (3.8, 4.2, 3.8, 4.2)), (1, TREE_LEAVES, (2.0, 6.5, 2.0, 6.0)),
               (2, DEADWOOD, (1.5, 2.5, 4.6, 5.4)), (0, GROUND, (-1.0, 13.0, -1.0, 13.0))]
    points = []
    for instance, cls, (x0, x1, y0, y1) in objects:
        p = np.zeros(200, POINT_DTYPE)
        p["x"], p["y"], p["z"] = rng.uniform(x0, x1, 200), rng.uniform(y0, y1, 200), rng.uniform(0, 9, 200)
        p["classification"], p["instance"] = cls, instance
        p["return_number"] = p["number_of_returns"] = 1
        points.append(p)
    points = fill_height(np.concatenate(points), with_room_for_height(np.concatenate(points)),
                         lambda x, y: np.zeros(len(x)))
    for axis, o in zip("xy", scene.origin.offset[:2]):
        points[axis] += o
    folder = files.plot_folder(tmp_path, NAME)
    files.tiles_folder(tmp_path, NAME).mkdir(parents=True)
    (folder / f"{NAME}_volumes.csv").write_text(
        "row,model,instance,volume_union_m3,treeid,x,y,z\n"
        "tree,tree01,1,0.75,1,500004.0000,6000004.0000,0.0\ndeadwood,deadwood001,2,0.05,11,500002.0000,6000005.2000,0.0\n")
    labels = files.tile_labels(folder / f"{NAME}_volumes.csv", None, "ours",
                               *files.object_boxes(points, scene.origin.offset))
    tile, row = tile_members(points["x"] - 500000.0, points["y"] - 6000000.0, (12, 12), 5.0, 1.0)
    counted, whole = {}, {}
    for t in range(9):
        files.write_tile(tmp_path, scene, tiles, labels, t // 3, t % 3, points[row[tile == t]])
        table = files.tiles_folder(tmp_path, NAME) / f"{NAME}_x{t // 3}_y{t % 3}_trees.csv"
        for r in csv.DictReader(table.open()):
            if r["whole_inside"] == "1":
                whole.setdefault(r["instance"], []).append(t)
            if r.get("core") == "1":
                counted.setdefault(r["instance"], []).append((t, float(r["volume_union_m3"])))
    assert whole == {"2": [0, 1]}                                  # whole inside two files ...
    assert counted == {"1": [(0, 0.75)], "2": [(1, 0.05)]}         # ... owned by one tile each


# --- the objects a leg task loads: those its pulses can reach ----------------------------------------

def _narrow_sensor(folder: Path, mount: str = "") -> Path:
    """The Leica ALS50-II (75° field of view, so the reach cull leaves objects out) made to fly at 30 m."""
    text = (ROOT / "sensors" / "leica_als50-ii.yaml").read_text()
    text = text.replace("range_min: 200.0", "range_min: 3.0").replace("range_max: 6000.0", "range_max: 1000.0")
    path = folder / "narrow.yaml"
    path.write_text(text + mount)
    return path


def _scan_bytes(scene, legs, cull: bool, monkeypatch) -> tuple[bytes, int]:
    """The points of ``legs`` (None: the whole survey) prepared with the reach cull or with every object."""
    import mitsuforest.scene as scan_scene
    from mitsuforest.survey import make_plan, prepare_plan, scan
    from mitsuforest.trees import build_models
    plan = make_plan(scene)
    with monkeypatch.context() as patch:
        if not cull:
            patch.setattr(scan_scene, "reachable", lambda bounds, *args: np.ones(np.shape(bounds)[:-2], bool))
        prepared = prepare_plan(scene, plan, build_models(plan), legs=legs)
        points = np.concatenate(list(scan(prepared)))
    return points.tobytes(), prepared.scan_scene.loaded


LAWNMOWER = "altitude: 30, speed: 10, pulse_frequency: 60000, scan_frequency: 40, line_spacing: 10, margin: 2"


@pytest.mark.parametrize("survey, mount", [
    (LAWNMOWER + ", attitude: {roll: 8}", ""),                            # the swath leans 4.2 m west
    (LAWNMOWER + ", attitude: {roll: {mean_deg: 2, amplitude_deg: 6, period_s: 3}, pitch: 4}", ""),
    (LAWNMOWER, "mount: {lever_arm: [0, 0, 0], boresight: [10, 0, 0]}\n"),  # the sensor mounted rolled
    (LAWNMOWER + ", attitude: {roll: 8}, lines: [[[40, -2], [40, 42]]]", ""),   # one line: the render's own cull
    ("pulse_frequency: 60000, scan_frequency: 40, trajectory: bow.csv", ""),   # a line bowing 10 m west
])
def test_a_leg_loses_no_point_to_the_objects_left_out_of_its_reach(tmp_path, monkeypatch, survey, mount):
    """A leg task loads only the objects its pulses can reach, and a render only those some leg reaches:
    its points must be the bytes the same leg makes with every object loaded. The east leg (x = 40 m,
    flying north at 30 m) of a rolled platform or a sensor mounted rolled sends its pulses up to
    30·tan(37.5° + 8°) = 29.6 m west (32.7 m at 10°), not the 23.0 m of a level 75° field of view:
    trees 23-30 m from it were left out, and their pulses went through them to the ground. A trajectory
    file's line from (40, -2) to (40, 42) that bows out to x = 30 on the way reaches 10 m further west
    than the straight line between its ends."""
    from mitsuforest.config import load_scene
    from mitsuforest.survey import make_plan
    sensor = _narrow_sensor(tmp_path, mount)
    t = np.linspace(0.0, 4.4, 23)
    (tmp_path / "bow.csv").write_text("time,x,y,z,roll,pitch,yaw\n" + "".join(
        f"{a:.3f},{40 - 10 * np.sin(np.pi * a / 4.4):.4f},{10 * a - 2:.4f},30,0,0,0\n" for a in t))
    lines = ["name: reach", "seed: 11", "area: {size: [40, 40]}", "terrain: {type: noise, amplitude: 3, wavelength: 20}",
             "forest: {type: open, trees: 8, min_spacing: 6}", "understory: {bushes: 4, rocks: 3, deadwood: 4, stumps: 2}",
             f"sensor: {sensor}",
             f"survey: {{{survey}}}",
             "simulation: {beam_samples: 1, beam_pattern: fixed, variant: llvm_ad_mono}"]
    (tmp_path / "scene.yaml").write_text("\n".join(lines) + "\n")
    scene = load_scene(tmp_path / "scene.yaml")
    last = len(make_plan(scene).legs) - 1
    legs = None if "lines" in survey or "trajectory" in survey else range(last, last + 1)
    culled, loaded = _scan_bytes(scene, legs, True, monkeypatch)
    every, all_objects = _scan_bytes(scene, legs, False, monkeypatch)
    assert loaded < all_objects                  # the cull left objects out: the test is of something
    assert culled == every


def test_the_reach_of_a_leg_is_its_cone_widened_by_tilt_spread_and_lever_arm():
    """Analytic reach of a northbound leg along x = 0 at 30 m over a box on the ground (z 0 to 1, 0.2 m
    across): level, a 75° field of view reaches 30·tan(37.5°) = 23.02 m; a beam of 30 mrad spreads its
    widest sub-ray 3 half divergences (0.045 rad) further, to 30·tan(37.5° + 2.58°) = 25.24 m; 10° of roll
    to 30·tan(47.5° + 2.58°) = 35.85 m on one side; a 2 m lever arm adds up to 2 m of height and 2 m across
    (32·tan(40.08°) + 2 = 28.92 m)."""
    from types import SimpleNamespace
    from mitsuforest.config.types import Attitude, Mount, Wave
    from mitsuforest.plan.types import Leg
    from mitsuforest.plan.reach import leg_swaths
    from mitsuforest.scene import reachable
    leg = Leg((0.0, -5.0, 30.0), (0.0, 45.0, 30.0), 0.0, 5.0)
    sensor = SimpleNamespace(half_fov=np.radians(37.5), range_max=1000.0, beam_divergence=(0.03, 0.03), mount=Mount())

    def reach(sensor, attitude=None, side=-1):
        """The farthest box edge (m, on the ``side`` of the leg, -1 west) that the leg reaches, to 1 cm."""
        xs = np.arange(5.0, 60.0, 0.01)
        boxes = np.array([[[side * x - 0.1, 19.9, 0.0], [side * x + 0.1, 20.1, 1.0]] for x in xs])
        near = reachable(boxes, leg_swaths([leg], sensor, attitude), sensor)
        return xs[near].max() - 0.1 * np.sqrt(2)             # the box's circle reaches its half diagonal closer

    spread = np.arctan(3 * 0.015)
    assert reach(sensor) == pytest.approx(30 * np.tan(np.radians(37.5) + spread), abs=0.011)
    roll = Attitude(roll=Wave(10.0))               # right wing down: the nadir turns left (west, flying north)
    assert reach(sensor, roll) == pytest.approx(30 * np.tan(np.radians(47.5) + spread), abs=0.011)
    lever = SimpleNamespace(**{**vars(sensor), "mount": Mount(lever_arm=(0.0, 2.0, 0.0))})
    assert reach(lever) == pytest.approx(32 * np.tan(np.radians(37.5) + spread) + 2, abs=0.011)


def test_a_leg_leaning_towards_the_plot_is_flown_not_refused_as_out_of_reach(tmp_path):
    """A line 28 m west of a 40 m plot at 30 m with the 75° field of view reaches 30·tan(37.5°) = 23.0 m
    level, and is refused; rolled 15° left wing down its nadir turns right (east, flying north) and its
    pulses reach 30·tan(52.5°) = 39.1 m east, to x = 11.1 m in the plot: it was refused all the same."""
    from mitsuforest.config import load_scene
    from mitsuforest.errors import ConfigError
    from mitsuforest.survey import prepare, scan
    sensor = _narrow_sensor(tmp_path)

    def scene(attitude):
        (tmp_path / "scene.yaml").write_text("\n".join([
            "name: lean", "seed: 1", "area: {size: [40, 40]}", "terrain: {type: flat}",
            "forest: {type: open, trees: 1, min_spacing: 6}", "understory: {bushes: 0, rocks: 0, deadwood: 0, stumps: 0}",
            f"sensor: {sensor}",
            "survey: {altitude: 30, speed: 10, pulse_frequency: 20000, scan_frequency: 40, "
            f"lines: [[[-28, 0], [-28, 40]]]{attitude}}}",
            "simulation: {beam_samples: 1, beam_pattern: fixed, variant: llvm_ad_mono}"]) + "\n")
        return load_scene(tmp_path / "scene.yaml")

    with pytest.raises(ConfigError, match=r"survey.lines\[0\]: the leg passes 28.0 m from the plot, beyond the "
                                          r"sensor's reach of 23.0 m at this altitude"):
        prepare(scene(""))
    points = np.concatenate(list(scan(prepare(scene(", attitude: {roll: -15}")))))
    ground = points[points["classification"] == 1]
    edge = -28 + 30 * np.tan(np.radians(52.5))                  # 11.10 m; the points have 5 cm ranging noise
    assert edge - 0.5 < ground["x"].max() <= edge + 4 * 0.05 * np.sin(np.radians(52.5))
