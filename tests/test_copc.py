"""COPC output (``formats: [copc]``): laspy's CopcReader reads back the points of the LAS file, and the
octree is one a reader can walk from the root."""

import json

import laspy
import numpy as np
import pytest
from helpers import scene_file

pytest.importorskip("copclib", reason="copclib (the test extra) writes COPC")

from mitsuforest.pipeline import render  # noqa: E402
from mitsuforest.scan import POINT_DTYPE  # noqa: E402
from mitsuforest.write import copc  # noqa: E402

OFFSET = [320000.0, 5812000.0, 100.0]


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("copc")
    path = scene_file(tmp, sensor="riegl_vux-1uav22.yaml", area={"size": [12, 12]},
                      forest={"trees": 2, "min_spacing": 5.0}, origin={"offset": OFFSET, "crs": "EPSG:28355"},
                      understory={"bushes": 2, "rocks": 1, "deadwood": 1, "stumps": 1},
                      survey={"pulse_frequency": 100000, "lines": [[[6, -3], [6, 15]]]},
                      simulation={"beam_samples": 7}, output={"formats": ["las", "copc"]})
    render(path, output_dir=tmp / "out", progress=False, log=lambda *_: None)
    return tmp / "out"


def _sorted(points):
    """Points in one order whatever the file's: by GPS time, then return number."""
    return points[np.lexsort([np.asarray(points.return_number), np.asarray(points.gps_time)])]


def test_copc_reader_reads_the_points_of_the_las_file(rendered):
    las = laspy.read(str(rendered / "test.las"))
    with laspy.CopcReader.open(str(rendered / "test.copc.laz")) as reader:
        points = reader.query()
        assert reader.header.point_format.id == 6
    assert len(points) == len(las.points) > 5000
    ours, theirs = _sorted(las.points), _sorted(points)
    for name in ("X", "Y", "Z", "intensity", "classification", "return_number", "number_of_returns", "gps_time",
                 "scan_angle", "label", "treeid", "instance", "object_id", "amplitude", "species",
                 "reflectance", "point_source_id", "height_above_ground"):
        assert np.array_equal(np.asarray(theirs[name]), np.asarray(ours[name])), name
    whole = laspy.read(str(rendered / "test.copc.laz"))       # a COPC is a LAZ too
    assert whole.header.parse_crs().to_epsg() == 28355
    assert list(whole.header.number_of_points_by_return[:3]) == list(las.header.number_of_points_by_return[:3])
    note = next(v for v in whole.header.vlrs if v.user_id == "mitsuforest")
    assert json.loads(note.record_data)["intensity"] == {"source": "amplitude", "gain": 1e6, "offset": 0.0,
                                                         "saturation": 65535}


def test_every_node_has_a_parent_with_points_and_lies_in_its_voxel(rendered):
    with laspy.CopcReader.open(str(rendered / "test.copc.laz")) as reader:
        entries = {(k.level, k.x, k.y, k.z): e.point_count for k, e in reader.root_page.entries.items()}
        info = reader.copc_info
        assert max(level for level, *_ in entries) >= 1
        for (level, x, y, z), count in entries.items():
            assert count > 0
            if level:
                assert entries.get((level - 1, x // 2, y // 2, z // 2), 0) > 0
        # A box query returns exactly the points inside the box.
        lo = info.center - info.halfsize
        box = laspy.copc.Bounds(mins=lo + [4 + OFFSET[0] - lo[0], 0, 0], maxs=lo + [8 + OFFSET[0] - lo[0], 1e3, 1e3])
        inside = reader.query(bounds=box)
        everything = reader.query()
    x = np.asarray(everything.x)
    assert len(inside) == ((x >= box.mins[0]) & (x <= box.maxs[0])).sum() > 0


def test_partitioned_octree_holds_the_same_points(tmp_path, monkeypatch):
    """Above copc.PARTITION_POINTS the octree is built column by column from the spool: the points
    and the parent rule are the same as in one piece."""
    rng = np.random.default_rng(4)
    p = np.zeros(60_000, POINT_DTYPE)
    p["x"], p["y"] = rng.uniform(0, 40, len(p)) + OFFSET[0], rng.uniform(0, 40, len(p)) + OFFSET[1]
    p["z"] = rng.uniform(0, 3, len(p)) + OFFSET[2]
    p["gps_time"], p["return_number"], p["number_of_returns"] = np.arange(len(p)), 1, 1
    p["instance"] = rng.integers(0, 1000, len(p))
    counts = {}
    monkeypatch.setattr(copc, "CHUNK", 7_000)                # the spool is read in several pieces
    for limit in (10**9, 5_000):
        monkeypatch.setattr(copc, "PARTITION_POINTS", limit)
        stream = copc.CopcStream(tmp_path / f"{limit}.copc.laz", OFFSET)
        for part in np.array_split(p, 5):
            stream.write(part)
        stream.close()
        with laspy.CopcReader.open(str(tmp_path / f"{limit}.copc.laz")) as reader:
            q = _sorted(reader.query())
            entries = {(k.level, k.x, k.y, k.z): e.point_count for k, e in reader.root_page.entries.items()}
        assert len(q) == len(p) and np.array_equal(np.asarray(q.instance), p["instance"])
        assert np.abs(np.asarray(q.x) - p["x"]).max() < 1e-4
        assert all(entries.get((lv - 1, x // 2, y // 2, z // 2), 0) > 0 for lv, x, y, z in entries if lv)
        counts[limit] = entries
        assert not list(tmp_path.glob("*.spool*"))                 # the spools are gone
    assert max(k[0] for k in counts[5_000]) >= 1


def test_without_copclib_copc_is_refused_before_the_scan(tmp_path, monkeypatch):
    import sys
    from mitsuforest.errors import UserError
    monkeypatch.setitem(sys.modules, "copclib", None)        # as if it were not installed
    with pytest.raises(UserError, match="output.formats: copc needs the copclib package"):
        copc.CopcStream(tmp_path / "t.copc.laz", OFFSET)
    assert not list(tmp_path.iterdir())


def test_copc_intensity_follows_the_sensor_mapping(tmp_path):
    """The COPC's 16-bit intensity is the sensor's mapping of the amplitude, as in the LAS file (it was
    always the default amplitude × 1e6)."""
    from mitsuforest.config.types import IntensityMapping
    from mitsuforest.scan.radiometry import intensity_counts
    mapping = IntensityMapping(gain=2e5, offset=-10.0, saturation=40000)
    rng = np.random.default_rng(5)
    p = np.zeros(2_000, POINT_DTYPE)
    p["x"], p["y"], p["z"] = (rng.uniform(0, 10, len(p)) + o for o in OFFSET)
    p["gps_time"], p["return_number"], p["number_of_returns"] = np.arange(len(p)), 1, 1
    p["intensity"] = rng.uniform(0, 0.3, len(p)).astype(np.float32)
    stream = copc.CopcStream(tmp_path / "m.copc.laz", OFFSET, intensity=mapping)
    stream.write(p)
    stream.close()
    with laspy.CopcReader.open(str(tmp_path / "m.copc.laz")) as reader:
        q = _sorted(reader.query())
    assert np.array_equal(np.asarray(q.intensity), intensity_counts(p["intensity"], None, mapping))
    assert np.asarray(q.intensity).max() == 40000


def test_copc_keeps_the_intensity_mapping_with_a_crs_given_as_long_wkt(tmp_path):
    """With ``origin.crs`` given as WKT too long for the room our note has in the COPC file (a compound
    CRS, 2,900 characters), the note keeps the sensor's intensity mapping and class codes, without the CRS
    text, which the file holds in its WKT record: the note was blank (since the COPC output), so compare
    and ``mitsuforest info`` took the default amplitude × 1e6 for a Livox's reflectivity."""
    import dataclasses
    import pyproj
    from mitsuforest.config.types import IntensityMapping
    from mitsuforest.write.info import intensity_mapping
    from mitsuforest.write.las import las_header
    wkt = pyproj.CRS("EPSG:25832+5703").to_wkt()
    mapping = IntensityMapping(source="reflectance", gain=38400, saturation=65280)
    p = np.zeros(100, POINT_DTYPE)
    p["x"], p["y"], p["z"] = (np.linspace(0, 10, len(p)) + o for o in OFFSET)
    p["gps_time"], p["return_number"], p["number_of_returns"] = np.arange(len(p)), 1, 1
    stream = copc.CopcStream(tmp_path / "w.copc.laz", OFFSET, wkt, intensity=mapping)
    stream.write(p)
    stream.close()
    las_note = json.loads(next(v for v in las_header(OFFSET, wkt, mapping).vlrs if v.user_id == "mitsuforest").record_data)
    with laspy.open(str(tmp_path / "w.copc.laz")) as reader:
        note = json.loads(next(v for v in reader.header.vlrs if v.user_id == "mitsuforest").record_data)
        assert reader.header.parse_crs().equals(pyproj.CRS(wkt))
    assert note == {k: v for k, v in las_note.items() if k != "crs"} and note["intensity"] == dataclasses.asdict(mapping)
    assert intensity_mapping(tmp_path / "w.copc.laz") == dataclasses.asdict(mapping)


def test_copc_header_has_the_las_files_creation_date(tmp_path, monkeypatch):
    """The COPC header's creation date is our LAS files' (2000-01-01, or the day of SOURCE_DATE_EPOCH),
    not copc-lib's day 0 of year 0 (since the COPC output), which laspy reads as none."""
    import datetime
    p = np.zeros(10, POINT_DTYPE)
    p["x"], p["y"], p["z"] = (np.linspace(0, 1, len(p)) + o for o in OFFSET)
    p["return_number"], p["number_of_returns"] = 1, 1
    for epoch, day in ((None, datetime.date(2000, 1, 1)), ("1718841600", datetime.date(2024, 6, 20))):
        if epoch:
            monkeypatch.setenv("SOURCE_DATE_EPOCH", epoch)
        stream = copc.CopcStream(tmp_path / f"{day}.copc.laz", OFFSET)
        stream.write(p)
        stream.close()
        with laspy.open(str(tmp_path / f"{day}.copc.laz")) as reader:
            assert reader.header.creation_date == day == stream.header.creation_date
