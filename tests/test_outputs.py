"""What a render writes: independent readers, label consistency, determinism, atomicity."""

import contextlib
import json
import signal
import subprocess
import sys
import time

import laspy
import numpy as np
import pytest
from helpers import scene_file

from mitsuforest.cli import main
from mitsuforest.write import Staging, output_files, read_pcd

FIELDS = ["treeid", "x", "y", "z", "classification", "instance", "object_id", "number_of_returns",
          "return_number", "intensity"]
OFFSET = [320000.0, 5812000.0, 100.0]


def _small_scene(tmp_path, **survey):
    return scene_file(tmp_path, sensor="riegl_vux-1uav22.yaml", area={"size": [12, 12]},
                      forest={"trees": 2, "min_spacing": 5.0,   # one Eucalyptus and one Pinus radiata
                              "archetypes": [{"base": 4}, {"species": "pinus_radiata", "base": 3}]},
                      origin={"offset": OFFSET, "crs": "EPSG:28355"},
                      understory={"bushes": 2, "rocks": 2, "deadwood": 2, "stumps": 1},
                      survey={"pulse_frequency": 100000, "lines": [[[6, -3], [6, 15]]], **survey},
                      simulation={"beam_samples": 7}, output={"formats": ["pcd", "las"]})


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("render")
    path = _small_scene(tmp)
    assert main(["render", str(path), "-o", str(tmp / "a"), "--quiet"]) == 0
    assert main(["render", str(path), "-o", str(tmp / "b"), "--quiet"]) == 0
    return tmp


def test_all_files_written(rendered):
    from mitsuforest.write.output_profiles import PROFILES
    names = sorted(p.name for p in (rendered / "a").iterdir())
    profiles = tuple(p.suffix for p in PROFILES.values())      # written only with an output.profile
    optional = (".laz", *profiles, "_waveforms.npz", "_pulses.npz")   # and with output.waveforms, output.pulses
    assert names == sorted(f for f in output_files("test") if not f.endswith(optional))


def test_pcd_header_and_independent_reader(rendered):
    from pypcd4 import PointCloud
    path = rendered / "a" / "test.pcd"
    head = path.read_bytes()[:600].decode("ascii", "replace")
    assert "FIELDS " + " ".join(FIELDS) in head and "DATA binary" in head and "VIEWPOINT 0 0 0 1 0 0 0" in head
    ours = read_pcd(path)
    pc = PointCloud.from_path(path)
    assert list(pc.fields[:10]) == FIELDS and pc.points == len(ours) > 1000
    theirs = pc.numpy(pc.fields)
    for i, name in enumerate(pc.fields):
        assert np.array_equal(theirs[:, i], ours[name].astype(np.float64)), name
    assert ours["x"].dtype == np.float64 and ours["x"].min() > OFFSET[0] - 5


def test_species_round_trip_through_pcd_las_and_tables(rendered):
    """Every point's species (after the paper's ten fields in the PCD; an extra dimension in the LAS)
    is the species its instance has in _ids.csv, and _volumes.csv names the same species per tree."""
    import csv
    from mitsuforest.classes import SPECIES_CODES
    folder = rendered / "a"
    pcd, las = read_pcd(folder / "test.pcd"), laspy.read(folder / "test.las")
    assert pcd.dtype.names[:10] == tuple(FIELDS) and pcd.dtype.names[-4:] == ("species", "reflectance", "point_source_id", "height_above_ground")
    assert np.array_equal(np.asarray(las.species), pcd["species"])
    assert np.array_equal(np.asarray(las.point_source_id), pcd["point_source_id"]) and pcd["point_source_id"].min() == 1
    ids = list(csv.DictReader((folder / "test_ids.csv").open()))
    by_instance = {int(r["instance"]): SPECIES_CODES[r["species"]] for r in ids}
    expected = np.array([by_instance[i] for i in pcd["instance"]], np.uint8)
    assert np.array_equal(pcd["species"], expected)
    trees = np.isin(pcd["classification"], (2, 3))   # tree wood and leaves
    assert set(np.unique(pcd["species"][trees]).tolist()) == {1, 3}   # both families, nothing else
    assert not pcd["species"][~trees].any()                            # ground, understory, deadwood: 0
    volumes = [r for r in csv.DictReader((folder / "test_volumes.csv").open()) if r["row"] == "tree"]
    assert {(int(r["instance"]), SPECIES_CODES[r["species"]]) for r in volumes} == \
        {(i, c) for i, c in by_instance.items() if c}


def test_las_round_trip(rendered):
    pcd = read_pcd(rendered / "a" / "test.pcd")
    las = laspy.read(str(rendered / "a" / "test.las"))
    assert las.header.version.major == 1 and las.header.version.minor == 4 and las.header.point_format.id == 6
    assert np.allclose(las.header.offsets, OFFSET)
    assert las.header.global_encoding.wkt and las.header.parse_crs().to_epsg() == 28355  # origin.crs
    assert np.abs(np.asarray(las.x) - pcd["x"]).max() < 1e-4
    assert np.abs(np.asarray(las.z) - pcd["z"]).max() < 1e-4
    for name in ("treeid", "instance", "object_id"):
        assert np.array_equal(np.asarray(las[name]), pcd[name])
    assert np.array_equal(np.asarray(las.label), pcd["classification"])
    assert np.array_equal(np.asarray(las.return_number), pcd["return_number"])
    assert np.array_equal(np.asarray(las.number_of_returns), pcd["number_of_returns"])
    assert np.array_equal(np.asarray(las.amplitude), pcd["intensity"])
    asprs = {1: 2, 2: 5, 3: 5, 4: 64, 5: 65, 6: 66, 7: 4}
    assert all(asprs[c] == a for c, a in zip(pcd["classification"], np.asarray(las.classification)))


def test_labels_are_consistent(rendered):
    p = read_pcd(rendered / "a" / "test.pcd")
    tree = np.isin(p["classification"], [2, 3])
    assert set(np.unique(p["treeid"][tree])) <= set(range(1, 11))
    assert set(np.unique(p["treeid"][~tree & (p["classification"] != 4)])) == {0}
    assert set(np.unique(p["treeid"][p["classification"] == 4])) <= {11}
    assert np.all(p["return_number"] <= p["number_of_returns"]) and p["return_number"].min() == 1
    assert np.all(p["instance"][p["classification"] == 1] == 0)
    ids = {int(r.split(",")[0]): r.split(",") for r in (rendered / "a" / "test_ids.csv").read_text().splitlines()[1:]}
    for oid, inst, cls, treeid in zip(p["object_id"], p["instance"], p["classification"], p["treeid"]):
        row = ids[int(oid)]  # every point's object id is listed with the same labels
        assert (int(row[1]), int(row[3]), int(row[2])) == (inst, cls, treeid)
    # Wood and leaf points of one tree share its instance.
    for inst in np.unique(p["instance"][tree]):
        assert set(p["classification"][p["instance"] == inst]) <= {2, 3}


def test_same_scene_and_seed_give_identical_bytes(rendered):
    for name in ("test.pcd", "test.las", "test_plan.json", "test_ids.csv", "test_volumes.csv"):
        assert (rendered / "a" / name).read_bytes() == (rendered / "b" / name).read_bytes(), name


def test_manifest_and_tables(rendered):
    m = json.loads((rendered / "a" / "test_manifest.json").read_text())
    import mitsuba
    assert m["versions"]["mitsuba"] == mitsuba.__version__ and m["variant"] == "llvm_ad_mono"
    assert set(m["timings_s"]) >= {"plan", "trees", "scene", "scan", "write"}
    assert m["points"] == len(read_pcd(rendered / "a" / "test.pcd"))
    assert m["density_per_m2"] == pytest.approx(m["points"] / 144)
    assert 0.001 < m["mean_spacing_m"] < 0.5
    assert sum(m["returns_histogram"].values()) == m["pulses_with_returns"]
    vol = (rendered / "a" / "test_volumes.csv").read_text().splitlines()
    assert vol[0].startswith("row,model,instance,volume_union_m3")
    assert sum(r.startswith("tree,") for r in vol) == 2 and sum(r.startswith("deadwood,") for r in vol) == 2
    traj = np.loadtxt(rendered / "a" / "test_trajectory.csv", delimiter=",", skiprows=1)
    assert np.allclose(traj[:, 3], OFFSET[2] + 30) and np.allclose(np.diff(traj[:, 0]), 0.1)


def test_info_summarises_pcd_and_las(rendered, capsys):
    for name in ("test.pcd", "test.las"):
        assert main(["info", str(rendered / "a" / name)]) == 0
        out = capsys.readouterr().out
        assert "points" in out and "classes: ground" in out and "pulses by number of returns: 1:" in out


def test_refuses_to_overwrite_older_results(rendered, capsys):
    before = (rendered / "a" / "test.pcd").stat().st_mtime_ns
    assert main(["render", str(rendered / "scene.yaml"), "-o", str(rendered / "a"), "--quiet"]) == 2
    assert "pass --overwrite" in capsys.readouterr().err
    assert (rendered / "a" / "test.pcd").stat().st_mtime_ns == before


def test_render_follows_a_plan_into_the_same_folder(rendered, tmp_path):
    """README's workflow, ``plan`` then ``render`` into one folder: a lone plan is no earlier result, and
    the render replaces it with its own."""
    scene, out = str(rendered / "scene.yaml"), str(tmp_path / "out")
    assert main(["plan", scene, "-o", out, "--seed", "99"]) == 0
    assert main(["render", scene, "-o", out, "--quiet"]) == 0
    assert (tmp_path / "out" / "test_plan.json").read_bytes() == (rendered / "a" / "test_plan.json").read_bytes()


def test_plan_keeps_a_finished_renders_plan(rendered, capsys):
    """``plan`` into a finished render's folder would leave its points described by another plan:
    refused in one line, exit 2, the folder as it was."""
    folder = rendered / "a"
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    assert main(["plan", str(rendered / "scene.yaml"), "-o", str(folder), "--seed", "99"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "holds a finished render of 'test'" in err, err
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before


def _start(path, out):
    return subprocess.Popen([sys.executable, "-m", "mitsuforest", "render", str(path), "-o", str(out), "--quiet"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _staged_bytes(out) -> int:
    """Bytes in the point file a running render stages in ``out`` (0 until its first batch arrives)."""
    sizes = []
    for pcd in out.glob(".test.partial-*/test.pcd"):
        with contextlib.suppress(FileNotFoundError):
            sizes.append(pcd.stat().st_size)
    return max(sizes, default=0)


def _wait_for_points(proc, out, timeout=300):
    """Poll until the render streams points into its staging folder: it is then scanning, inside the
    part of the render that cleans up after itself, with nearly all of its survey still ahead."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if _staged_bytes(out) > 0:
            return
        if proc.poll() is not None:
            raise AssertionError(f"the render ended before scanning: {proc.communicate()[1]}")
        time.sleep(0.02)
    proc.kill()
    proc.wait()
    raise AssertionError("the render did not reach the scan")


@pytest.mark.slow
@pytest.mark.parametrize("how", ["kill", "interrupt", "terminate"])
def test_stopped_render_leaves_nothing_that_looks_complete(tmp_path, how):
    # 36 minutes of flight (624 M pulse slots): far longer than the wait for its first points on a CPU or GPU.
    path = _small_scene(tmp_path, pulse_frequency=300000, speed=0.2, lines=None, line_spacing=1)
    out = tmp_path / "out"
    proc = _start(path, out)
    _wait_for_points(proc, out)
    proc.send_signal({"kill": signal.SIGKILL, "interrupt": signal.SIGINT, "terminate": signal.SIGTERM}[how])
    _, err = proc.communicate(timeout=120)
    leftovers = sorted(p.name for p in out.iterdir()) if out.exists() else []
    assert not set(leftovers) & set(output_files("test"))
    if how != "kill":
        assert not out.exists()                              # the folder the render made goes with it
        assert proc.returncode == {"interrupt": 130, "terminate": 143}[how]
        what = {"interrupt": "interrupted", "terminate": "stopped (SIGTERM)"}[how]
        assert err.splitlines() == [(f"mitsuforest: {what}; no finished output was written (partial files "
                                     "removed). Run the same command again to redo it.")]
        assert leftovers == []
    else:
        assert proc.returncode == -signal.SIGKILL
        leftovers.remove(".test.lock")       # the lock of a killed render: the kernel released it
        [staged] = leftovers
        assert staged.startswith(".test.partial-") and staged.endswith(f"-{proc.pid}")
        Staging(out, "test").discard()  # the next render clears the killed one's folder
        assert [p.name for p in out.iterdir()] == [".test.lock"]


def test_laz_matches_las(rendered, tmp_path):
    from mitsuforest.write.las import write_las
    pcd = read_pcd(rendered / "a" / "test.pcd")
    write_las(tmp_path / "t.laz", pcd, OFFSET)
    laz = laspy.read(str(tmp_path / "t.laz"))
    assert (tmp_path / "t.laz").read_bytes()[104] & 0x80  # LAZ marks the point format as compressed
    assert np.abs(np.asarray(laz.x) - pcd["x"]).max() < 1e-4
    assert np.array_equal(np.asarray(laz.object_id), pcd["object_id"])


def open3d():
    """Open3D, a test extra; its wheel needs the system's libusb (README's first command installs it)."""
    try:
        import open3d
    except ImportError as e:
        raise AssertionError(f"open3d does not import ({e}): pip install -e '.[test]' and "
                             "apt-get install -y libusb-1.0-0") from e
    return open3d


def test_open3d_tensor_reader(rendered):
    o3d = open3d()
    path = rendered / "a" / "test.pcd"
    pc = o3d.t.io.read_point_cloud(str(path))
    ours = read_pcd(path)
    assert np.array_equal(pc.point["positions"].numpy(), np.column_stack([ours["x"], ours["y"], ours["z"]]))
    for name in ours.dtype.names:
        if name not in "xyz":
            assert np.array_equal(pc.point[name].numpy().ravel(), ours[name]), name


def test_background_writer_keeps_order_and_raises_the_workers_error():
    from mitsuforest.write.background import Background
    seen = []
    sink = Background(seen.append)
    for i in range(50):
        sink(i)
    sink.close()
    assert seen == list(range(50))

    def fail(batch):
        if batch == 3:
            raise OSError("disk full")
        seen.append(batch)
    seen.clear()
    sink = Background(fail, depth=1)
    with pytest.raises(OSError, match="disk full"):
        for i in range(100):
            sink(i)
        sink.close()
    assert seen == [0, 1, 2]


def test_every_class_has_its_asprs_code_and_extra_dimensions_carry_no_partial_statistics():
    """Class codes 1-8 map to ASPRS 2, 5, 5, 64, 65, 66, 4 and 3 (ground vegetation = low vegetation);
    the extra dimensions' optional min/max are left unset, since laspy would fill them from the first
    batch written only."""
    from mitsuforest.scan import POINT_DTYPE
    from mitsuforest.write.las import las_header, las_points
    points = np.zeros(8, POINT_DTYPE)
    points["classification"] = np.arange(1, 9)
    header = las_header([0.0, 0.0, 0.0])
    las = las_points(header, points)
    assert np.asarray(las.classification).tolist() == [2, 5, 5, 64, 65, 66, 4, 3]
    structs = header.vlrs.get("ExtraBytesVlr")[0].extra_bytes_structs
    assert len(structs) == 8 and all(s.options == 0 for s in structs)   # label, treeid, instance, object_id, amplitude, species, reflectance, height_above_ground


def test_riegl_reflectance_in_db_maps_minus_25_to_5_db_onto_16_bits():
    """source reflectance_db with PDAL readers.rxp's map: a white Lambertian plate filling the beam face-on
    reads 0 dB at any range, 54,612.5 counts (rounded to the even 54,612); a 0.33 plate at 60° reads
    10 log10(0.165) = -7.83 dB, (25 - 7.83) · 65535 / 30 = 37,518 counts; -25 dB and below read 0 (a zero
    amplitude too), +5 dB and above 65535."""
    from mitsuforest.config.types import IntensityMapping
    from mitsuforest.scan.radiometry import RIEGL_DB_MAP, intensity_counts, received_power, reflectance_db
    mapping = IntensityMapping(**RIEGL_DB_MAP)
    range_m = np.array([12.0, 80.0, 40.0, 40.0, 40.0, 40.0, 40.0])
    amplitude = received_power(1.0, np.array([1.0, 1.0, 0.33, 10 ** -2.5, 10 ** -2.6, 10 ** 0.6, 0.0]),
                               np.array([1.0, 1.0, 0.5, 1.0, 1.0, 1.0, 1.0]), range_m)
    reflectance = reflectance_db(amplitude, range_m)
    assert reflectance[:3] == pytest.approx([0.0, 0.0, 10 * np.log10(0.165)], abs=1e-9)
    counts = intensity_counts(amplitude, reflectance, mapping).tolist()
    assert counts == [54612, 54612, round((25 + 10 * np.log10(0.165)) * 65535 / 30), 0, 0, 65535, 0]
    assert counts[2] == 37518


def test_intensity_mapping_is_monotone_clips_at_saturation_and_reaches_the_las(tmp_path):
    """LAS intensity = clip(round(gain·q + offset), 0, saturation), q the amplitude or the linear
    reflectance: non-decreasing in q, strong returns at the saturation level, weak ones at 0; the LAS
    carries the counts, the exact amplitude and the reflectance (dB)."""
    import dataclasses as dc
    from mitsuforest.config.types import IntensityMapping
    from mitsuforest.scan import POINT_DTYPE
    from mitsuforest.scan.radiometry import intensity_counts, reflectance_db
    from mitsuforest.write.las import write_las
    amplitude = np.geomspace(1e-9, 1.0, 2001)
    rng = np.random.default_rng(3)
    range_m = rng.uniform(5, 100, amplitude.size)
    reflectance = reflectance_db(amplitude, range_m)
    default = IntensityMapping()
    counts = intensity_counts(amplitude, reflectance, default)
    assert counts.dtype == np.uint16 and (np.diff(counts.astype(int)) >= 0).all()
    assert np.array_equal(counts, np.clip(np.round(amplitude * 1e6), 0, 65535))   # as before the mapping
    sensor = IntensityMapping(gain=2e5, offset=-10.0, saturation=40000)
    counts = intensity_counts(amplitude, reflectance, sensor).astype(int)
    assert (np.diff(counts) >= 0).all() and counts.min() == 0 and counts.max() == 40000
    assert (counts[amplitude * 2e5 - 10 >= 40000] == 40000).all()
    assert np.array_equal(counts[amplitude < 0.1], np.clip(np.round(2e5 * amplitude - 10), 0, None)[amplitude < 0.1])
    by_reflectance = dc.replace(sensor, source="reflectance", gain=150 * 256)
    q = amplitude * range_m ** 2
    expected = np.clip(np.round(150 * 256 * q - 10), 0, 40000)
    assert np.abs(intensity_counts(amplitude, reflectance, by_reflectance) - expected).max() <= 1
    points = np.zeros(amplitude.size, POINT_DTYPE)
    points["intensity"], points["range"], points["reflectance"] = amplitude, range_m, reflectance
    write_las(tmp_path / "t.las", points, [0.0, 0.0, 0.0], intensity=sensor)
    las = laspy.read(tmp_path / "t.las")
    assert np.array_equal(np.asarray(las.intensity), intensity_counts(points["intensity"], points["reflectance"], sensor))
    assert np.array_equal(np.asarray(las.amplitude), points["intensity"])
    assert np.array_equal(np.asarray(las.reflectance), points["reflectance"])
    assert json.loads(las.header.vlrs.get_by_id("mitsuforest")[0].record_data)["intensity"] == dc.asdict(sensor)


def test_the_mean_spacing_is_each_points_distance_to_its_nearest_neighbour():
    """The spacing statistic: on a 0.1 m x 0.3 m grid every point's nearest neighbour is 0.1 m away; on
    scattered points with duplicates, the same distances as a plain k-d tree query, in the points' order
    (the query runs in cell order, and the manifest's mean must not change by a bit)."""
    from scipy.spatial import cKDTree

    from mitsuforest.write.stream import nearest_distances
    x, y = np.meshgrid(np.arange(50) * 0.1, np.arange(17) * 0.3)
    grid = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    np.testing.assert_allclose(nearest_distances(grid), 0.1, rtol=1e-9)
    rng = np.random.default_rng(5)
    xyz = rng.uniform(0, 5, (21_000, 3))
    xyz[::7] = xyz[1::7]                          # duplicates: distance 0
    expected = cKDTree(xyz).query(xyz, k=2)[0][:, 1]
    found = nearest_distances(xyz)
    assert np.array_equal(found, expected) and found.mean() == expected.mean()
    assert (found[::7] == 0).all()


def test_the_spacing_asks_a_random_sample_of_a_tiles_points_against_all_of_them():
    """A tile's spacing with 10,000 of its points asking: each asked point's distance is the plain k-d
    tree's over all the points, and the mean is Poisson's: for a uniform density λ in 3-D the mean
    distance to the nearest neighbour is Γ(4/3)·(3/(4πλ))^(1/3) (within 1 %: the box's faces widen it)."""
    import math

    from scipy.spatial import cKDTree

    from mitsuforest.write.stream import SPACING_QUERIES, nearest_distances, spacing_queries
    assert spacing_queries(SPACING_QUERIES, np.random.default_rng(0)) is None
    xyz = np.random.default_rng(3).uniform(0, 5, (200_000, 3))
    rows = spacing_queries(len(xyz), np.random.default_rng(1))
    assert len(rows) == SPACING_QUERIES and np.all(np.diff(rows) > 0)
    found = nearest_distances(xyz, rows)
    assert np.array_equal(found, cKDTree(xyz).query(xyz[rows], k=2)[0][:, 1])
    poisson = math.gamma(4 / 3) * (3 / (4 * math.pi * len(xyz) / 5 ** 3)) ** (1 / 3)
    assert 1.0 < found.mean() / poisson < 1.01
