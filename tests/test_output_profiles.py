"""Output profiles (``output.profile``): each file read back by a reader written here from that project's
own loader (field names, dtypes, label values), never by our own code, and checked against our labels."""

import csv
import dataclasses
import json

import laspy
import numpy as np
import pytest
import yaml
from conftest import ROOT
from helpers import scene_file

from mitsuforest.classes import BUSH, DEADWOOD, GROUND, ROCK, STUMP, TREE_LEAVES, TREE_WOOD
from mitsuforest.config.types import OUTPUT_PROFILES
from mitsuforest.config.types import IntensityMapping
from mitsuforest.pipeline import render
from mitsuforest.scan.radiometry import RIEGL_DB_MAP, intensity_counts
from mitsuforest.write.output_profiles import PROFILES, ForestFormer3DStream, TreeLearnStream, write_profile
from mitsuforest.write.pcd import read_pcd

OFFSET = [320000.0, 5812000.0, 100.0]
TREES = (TREE_WOOD, TREE_LEAVES)
DB = IntensityMapping(**RIEGL_DB_MAP)   # the plot's sensor writes RIEGL's reflectance in dB, as a twin of UAS_Clip does


@pytest.fixture(scope="module")
def plot(tmp_path_factory):
    """A 12 m plot with two trees and every understory kind, rendered with the FOR-instance profile into
    a dataset-like folder: (folder, scene, our PCD points, stem object ids from _ids.csv); the sensor's
    intensity is RIEGL's reflectance in dB (:data:`DB`)."""
    tmp = tmp_path_factory.mktemp("profiles")
    sensor = yaml.safe_load((ROOT / "sensors" / "riegl_vux-1uav22.yaml").read_text()) | {"intensity": RIEGL_DB_MAP}
    path = scene_file(tmp, sensor=sensor, area={"size": [12, 12]},
                      forest={"trees": 2, "min_spacing": 5.0},
                      origin={"offset": OFFSET, "crs": "EPSG:28355"},
                      understory={"bushes": 2, "rocks": 2, "deadwood": 2, "stumps": 1},
                      survey={"pulse_frequency": 100000, "lines": [[[6, -3], [6, 15]]]},
                      simulation={"beam_samples": 7},
                      output={"dir": str(tmp / "plots" / "test"), "formats": ["pcd"], "profile": "for-instance"})
    result = render(path, progress=False, log=lambda *_: None)
    folder = tmp / "plots" / "test"
    with open(folder / "test_ids.csv", newline="") as f:
        stems = {int(r["object_id"]) for r in csv.DictReader(f) if r["kind"] == "stem"}
    points = read_pcd(folder / "test.pcd")
    assert set(np.unique(points["classification"])) == {GROUND, TREE_WOOD, TREE_LEAVES, DEADWOOD, ROCK, STUMP, BUSH}
    return folder, result.scene, points, stems


def test_the_registry_holds_every_profile_the_scene_file_accepts():
    assert set(PROFILES) == set(OUTPUT_PROFILES) - {"ours"}


# --- FOR-instance ------------------------------------------------------------------------------------
# Reader written from the FOR-instance loaders: TreeLearn's tree_learn/util/data_preparation.py
# (load_data: laspy, `treeID != 0` is a tree, `classification` 1 or 2 is non-tree, anything else is
# ignored) and SegmentAnyTree's sample_data_conversion.py (las_to_ply: classification 0 and 3 ->
# unclassified, 1 and 2 -> non-tree, 4, 5, 6 -> tree; `treeID` read as the instance), both on GitHub
# (ecker-lab/TreeLearn, SmartForest-no/SegmentAnyTree); superpoint_transformer's FOR-instance reader
# indexes a 7-entry table by `classification`, so no code above 6 may appear.

FOR_INSTANCE_SEMANTIC = np.array([0, 1, 1, 0, 2, 2, 2])   # unclassified 0, non-tree 1, tree 2


def read_for_instance(path):
    las = laspy.read(str(path))
    classes = np.asarray(las.classification)
    tree_id = np.asarray(las.treeID)
    assert classes.max() <= 6
    semantic = FOR_INSTANCE_SEMANTIC[classes]
    tree, non_tree = tree_id != 0, np.isin(classes, (1, 2))
    return las, classes, tree_id, semantic, tree, non_tree


def test_for_instance_las_has_its_classes_and_tree_ids(plot):
    folder, _, ours, stems = plot
    las, classes, tree_id, semantic, tree, non_tree = read_for_instance(folder / "test_forinstance.laz")
    assert len(classes) == len(ours) > 5000
    assert las.point_format.dimension_by_name("treeID").dtype == np.int32
    assert np.abs(np.asarray(las.x) - ours["x"]).max() < 1e-4 and las.header.parse_crs().to_epsg() == 28355
    # Every point is a tree or a non-tree, never unlabelled; tree points are exactly our trees.
    assert not np.any(tree & non_tree) and np.all(tree | non_tree)
    ours_tree = np.isin(ours["classification"], TREES)
    assert np.array_equal(tree, ours_tree) and np.array_equal(semantic == 2, ours_tree)
    assert np.array_equal(tree_id[tree], ours["instance"][ours_tree].astype(np.int32))
    assert len(np.unique(tree_id[tree])) == 2
    # Class by class: stems are the stem components of _ids.csv, live branches our leaves.
    stem = (ours["classification"] == TREE_WOOD) & np.isin(ours["object_id"], list(stems))
    assert stem.sum() > 100 and (ours_tree & ~stem & (ours["classification"] == TREE_WOOD)).sum() > 100
    expected = np.select([stem, ours["classification"] == TREE_WOOD, ours["classification"] == TREE_LEAVES,
                          np.isin(ours["classification"], (GROUND, ROCK))], [4, 6, 5, 2], 1)
    assert np.array_equal(classes, expected)
    assert set(np.unique(classes[np.isin(ours["classification"], (DEADWOOD, STUMP, BUSH))])) == {1}
    assert np.array_equal(np.asarray(las.height_above_ground), ours["height_above_ground"])


def test_for_instance_las_keeps_the_pulse_fields_of_our_las(plot):
    """The FOR-instance LAZ holds each point's return numbers, GPS time, scan angle and flight line
    (``point_source_id``) as our LAS file does, not the format's zeros (its flight line was 0 on every
    point from issue 27, which put the flight line in our PCD and LAS files, until the audit of outputs)."""
    folder, _, ours, _ = plot
    las = laspy.read(str(folder / "test_forinstance.laz"))
    assert set(np.unique(ours["point_source_id"])) == {1}       # the plot's one flight line
    assert np.array_equal(np.asarray(las.point_source_id), ours["point_source_id"])
    assert np.array_equal(np.asarray(las.gps_time), ours["gps_time"])
    assert np.array_equal(np.asarray(las.scan_angle), np.round(ours["scan_angle"] / 0.006).astype(np.int16))
    assert np.array_equal(np.asarray(las.return_number), ours["return_number"])
    assert np.array_equal(np.asarray(las.number_of_returns), ours["number_of_returns"])


def test_profiles_write_intensity_by_the_sensors_mapping(plot, tmp_path):
    """The FOR-instance LAZ of the render and a ForestFormer3D PLY carry the sensor's counts (here
    RIEGL's reflectance in dB, a ground echo near 44,000), not the default amplitude x 1e6, and the
    LAZ's note says which mapping."""
    folder, scene, ours, _ = plot
    assert scene.sensor.intensity == DB
    expected = intensity_counts(ours["intensity"], ours["reflectance"], DB)
    ground = ours["classification"] == GROUND
    assert 35_000 < np.median(expected[ground]) < 55_000
    las = laspy.read(str(folder / "test_forinstance.laz"))
    assert np.array_equal(np.asarray(las.intensity), expected)
    assert json.loads(las.header.vlrs.get_by_id("mitsuforest", [2])[0].record_data)["intensity"] == dataclasses.asdict(DB)
    write_profile(tmp_path / "t_ff3d.ply", "forestformer3d", ours, OFFSET, None, [], DB)
    assert np.array_equal(read_forestformer3d(tmp_path / "t_ff3d.ply")[0]["intensity"], expected)
    write_profile(tmp_path / "d_ff3d.ply", "forestformer3d", ours, OFFSET, None, [])
    assert np.array_equal(read_forestformer3d(tmp_path / "d_ff3d.ply")[0]["intensity"],
                          intensity_counts(ours["intensity"], None, IntensityMapping()))


# --- ForestFormer3D -------------------------------------------------------------------------------------
# Reader written from ForestFormer3D's loader (SmartForest-no/ForestFormer3D on GitHub,
# data/ForAINetV2/load_forainetv2_data_fast.py `export` and data/ForAINetV2/plyutils.py `read_ply`): a
# binary PLY whose second line is the format, one element (any header line holding "element" gives
# the count, any holding "property" a field of PLY type -> numpy type), then
# label = semantic_seg - 1 with 0 the ground (background; configs: classes ground, wood, leaf), and the
# instance = treeID, set to 0 on the ground.

PLY_TYPES = {b"char": "i1", b"uchar": "u1", b"short": "i2", b"ushort": "u2", b"int": "i4", b"uint": "u4",
             b"float": "f4", b"double": "f8"}


def read_forestformer3d(path):
    with open(path, "rb") as f:
        assert b"ply" in f.readline()
        fmt = f.readline().split()[1].decode()
        assert fmt in ("binary_little_endian", "binary_big_endian")
        ext = "<" if fmt == "binary_little_endian" else ">"
        count, fields, line = None, [], b""
        while b"end_header" not in line:
            line = f.readline()
            assert line, "header without end_header"
            if b"element" in line:
                count = int(line.split()[2])
            elif b"property" in line:
                words = line.split()
                fields.append((words[2].decode(), ext + PLY_TYPES[words[1]]))
        data = np.fromfile(f, dtype=fields, count=count)
    label = data["semantic_seg"].astype(np.int64) - 1
    instance = data["treeID"].astype(np.int64)
    instance[label == 0] = 0
    return data, label, instance


def test_forestformer3d_ply_has_ground_wood_leaf_and_tree_ids(plot, tmp_path):
    folder, scene, ours, _ = plot
    write_profile(tmp_path / "t_ff3d.ply", "forestformer3d", ours, OFFSET, None, [])
    data, label, instance = read_forestformer3d(tmp_path / "t_ff3d.ply")
    assert len(data) == len(ours)
    assert data.dtype["x"] == np.float64 and data.dtype["semantic_seg"] == np.int32 and data.dtype["treeID"] == np.int32
    assert np.array_equal(data["x"], ours["x"]) and np.array_equal(data["z"], ours["z"])
    c = ours["classification"]
    assert np.array_equal(label, np.select([c == TREE_WOOD, c == TREE_LEAVES], [1, 2], 0))
    assert np.array_equal(instance, np.where(np.isin(c, TREES), ours["instance"], 0))
    assert np.all(instance[label > 0] > 0)
    # Open3D's PLY reader sees the same positions and labels.
    import open3d as o3d
    pc = o3d.t.io.read_point_cloud(str(tmp_path / "t_ff3d.ply"))
    assert np.array_equal(pc.point["positions"].numpy()[:, 2], ours["z"])
    assert np.array_equal(pc.point["semantic_seg"].numpy().ravel(), data["semantic_seg"])


def test_streamed_files_are_the_bytes_of_one_write(plot, tmp_path):
    """The PLY and .npy headers hold the count, filled in on close: batches give the same file."""
    _, _, ours, _ = plot
    for stream, name in ((ForestFormer3DStream, "forestformer3d"), (TreeLearnStream, "treelearn")):
        s = stream(tmp_path / "batched", OFFSET, None, [])
        for part in np.array_split(ours, 3):
            s.write(part)
        s.write(ours[:0])
        s.close()
        write_profile(tmp_path / "whole", name, ours, OFFSET, None, [])
        assert (tmp_path / "batched").read_bytes() == (tmp_path / "whole").read_bytes(), name


# --- TreeLearn ---------------------------------------------------------------------------------------------
# Reader written from TreeLearn's loader (ecker-lab/TreeLearn on GitHub, tree_learn/util/data_preparation.py
# `load_data`, and docs/training.md): a .npy of N rows with 3 or 4 columns, x, y, z in metres and the
# label last: -1 unclassified (ignored), 0 non-tree, trees from 1.

def read_treelearn(path):
    data = np.load(path)
    assert data.ndim == 2 and data.shape[1] in (3, 4)
    return data[:, :3], data[:, 3]


def test_treelearn_array_has_local_coordinates_and_tree_labels(plot, tmp_path):
    _, _, ours, _ = plot
    write_profile(tmp_path / "t_treelearn.npy", "treelearn", ours, OFFSET, None, [])
    xyz, label = read_treelearn(tmp_path / "t_treelearn.npy")
    assert xyz.dtype == np.float64 and len(xyz) == len(ours)
    assert np.abs(xyz[:, 0] - (ours["x"] - OFFSET[0])).max() < 1e-9 and -6 < xyz[:, 0].min() < 12 + 3  # crowns overhang
    tree = np.isin(ours["classification"], TREES)
    assert np.array_equal(label, np.where(tree, ours["instance"], 0).astype(np.float64))
    assert set(np.unique(label)) == {0.0, *np.unique(ours["instance"][tree]).astype(float)} and label.min() == 0


def test_dataset_tiles_get_the_profile_file(plot):
    """A dataset's tiles carry the scene's profile file beside their own, listed with its checksum."""
    from mitsuforest.dataset.files import write_tiles
    from mitsuforest.dataset.spec import Tiles
    folder, scene, ours, _ = plot
    root = folder.parents[1]
    for name in ("treelearn", "for-instance"):
        records = write_tiles(root, scene.with_({"output.profile": name}), Tiles(size=6.0, buffer=0.0, format="laz"))
        suffix = PROFILES[name].suffix
        counts = []
        for r in records:
            listed = [f for f in r["files"] if f.endswith(suffix)]
            assert len(listed) == 1
            if name == "treelearn":
                xyz, label = read_treelearn(root / listed[0])
                counts.append(len(xyz))
                assert set(np.unique(label)) <= {0.0, *np.unique(ours["instance"]).astype(float)}
            else:
                counts.append(len(read_for_instance(root / listed[0])[1]))
        assert sum(counts) == len(ours)          # no buffer: the tiles partition the points


def test_an_unknown_profile_is_refused_in_one_line(tmp_path, capsys):
    from mitsuforest.cli import main
    path = scene_file(tmp_path, output={"profile": "forinstance"})
    assert main(["plan", str(path), "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("output.profile: must be one of ours, for-instance, forestformer3d, treelearn, got "
                        "'forinstance' (did you mean 'for-instance'?)") and "\n" not in err
    assert not (tmp_path / "o").exists()


def test_rendering_again_with_another_profile_removes_the_old_file(tmp_path):
    """A profile's file belongs to the render: --overwrite with another profile leaves no stale one."""
    from mitsuforest.cli import main
    path = scene_file(tmp_path, area={"size": [8, 8]}, survey={"pulse_frequency": 10000, "lines": [[[4, -2], [4, 10]]]},
                      output={"formats": ["pcd"], "profile": "treelearn"})
    out = tmp_path / "out"
    assert main(["render", str(path), "-o", str(out), "--quiet"]) == 0
    assert (out / "test_treelearn.npy").is_file()
    path.write_text(path.read_text().replace("profile: treelearn", "profile: forestformer3d"))
    assert main(["render", str(path), "-o", str(out), "--quiet", "--overwrite"]) == 0
    assert (out / "test_ff3d.ply").is_file() and not (out / "test_treelearn.npy").exists()
