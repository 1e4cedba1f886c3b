"""``mitsuforest compare``: distances of constructed clouds against their analytic values, files of
every kind read alike, bad input refused in one line, and the real scans where ../shared has them."""

from __future__ import annotations

import json
import math
from pathlib import Path

import laspy
import numpy as np
import pytest

from mitsuforest.cli import main
from mitsuforest.compare import Cloud, compare_clouds, compare_files, describe, load_cloud
from mitsuforest.compare import metrics as m

ROOT = Path(__file__).resolve().parents[1]
# shared/ lies beside the project (CI), or beside the folder of git worktrees that holds it
REAL = next((p for p in (ROOT.parent / "shared" / "data" / "real", ROOT.parent.parent / "shared" / "data" / "real")
             if p.is_dir()), ROOT.parent / "shared" / "data" / "real")
DISTANCES = {"returns_tv", "height_ks", "height_emd_m", "canopy_p95_m", "ground_share", "intensity_ks",
             "density_ratio"}
SIDE = 20.0     # the constructed plot, m
STEP = 0.5      # its pulses' spacing, m: 4 pulses in each 1 m cell


def _forest(canopy_m=10.0, two_returns="every other", slope=0.0):
    """A plot of SIDE × SIDE m scanned every STEP m: ground (z = slope·x) everywhere, one canopy layer
    ``canopy_m`` above it over the left half (x < 10). There, ``two_returns`` of the pulses ("every
    other", "all") return from the canopy and then the ground, the others from the canopy only;
    on the right half each pulse returns once from the ground.

    Returns our point array (POINT_DTYPE: classes ground 1, tree_leaves 3). With "every other":
    2,000 points, 1,600 pulses (1,200 with one return, 400 with two), 1,200 ground points and 800
    canopy points, half the plot canopy; intensity 1.0 ground, 0.5 canopy, 0.25 ground behind canopy.
    """
    from mitsuforest.scan import POINT_DTYPE
    cx, cy = np.meshgrid(np.arange(0.25, SIDE, STEP), np.arange(0.25, SIDE, STEP), indexing="ij")
    cx, cy = cx.ravel(), cy.ravel()
    column = np.round((cx - 0.25) / STEP).astype(int)
    under = cx < SIDE / 2
    two = under & ((column % 2 == 0) if two_returns == "every other" else np.ones_like(under))
    rows = []   # x, y, height above ground, class, return number, number of returns, intensity, angle
    for sel, h, cls, rn, nr, amp in ((~under, 0.0, 1, 1, 1, 1.0), (under & ~two, canopy_m, 3, 1, 1, 0.5),
                                     (two, canopy_m, 3, 1, 2, 0.5), (two, 0.0, 1, 2, 2, 0.25)):
        k = int(sel.sum())
        rows.append((cx[sel], cy[sel], np.full(k, h), np.full(k, cls), np.full(k, rn), np.full(k, nr),
                     np.full(k, amp), (cx[sel] - SIDE / 2) * 2.0))
    cols = [np.concatenate(c) for c in zip(*rows)]
    points = np.zeros(len(cols[0]), POINT_DTYPE)
    points["x"], points["y"] = cols[0], cols[1]
    points["z"] = cols[2] + slope * cols[0]
    points["classification"], points["return_number"], points["number_of_returns"] = cols[3], cols[4], cols[5]
    points["intensity"], points["scan_angle"] = cols[6], cols[7]
    return points


def test_a_cloud_against_itself_is_at_distance_zero():
    points = _forest()
    d = compare_clouds(points, points)["distance"]
    assert set(d) == DISTANCES
    assert {k: v for k, v in d.items() if k != "density_ratio"} == dict.fromkeys(DISTANCES - {"density_ratio"}, 0.0)
    assert d["density_ratio"] == 1.0


def test_the_constructed_forest_measures_as_built():
    s = compare_clouds(_forest(), _forest())["a"]
    assert s["points"] == 2000 and s["pulses"] == 1600
    assert s["covered_area_m2"] == 400 and s["density_per_m2"] == 5.0 and s["pulse_density_per_m2"] == 4.0
    assert s["spacing_m"] == pytest.approx(STEP)
    assert s["pulses_by_returns"] == {"1": 0.75, "2": 0.25}
    assert s["canopy_height_m"] == pytest.approx({"p50": 10.0, "p95": 10.0, "p99": 10.0}, abs=1e-9)
    assert s["canopy_cover_2m"] == 0.5
    assert s["ground_share"] == pytest.approx(1200 / 2000)
    assert s["ground_share_under_canopy"] == 0.5     # last returns under canopy: 400 ground, 400 canopy-only
    assert s["intensity"]["reference"] == 1.0 and s["intensity"]["by_return"]["2"]["p50"] == 0.25
    assert s["height_profile"]["lowest_m"] == 0.0 and s["height_profile"]["shares"][0] == 0.6
    assert s["height_profile"]["shares"][10] == 0.4 and sum(s["height_profile"]["shares"]) == pytest.approx(1)
    assert s["scan_angle_deg"]["max_abs"] == pytest.approx(19.5)
    assert s["ground"] == {"from": "class 1 (our ground)", "points": 1200} and s["notes"] == []


def test_ground_under_canopy_counts_returns_on_the_ground_not_their_class():
    """A file that leaves its ground under the canopy unclassified (UAS_Clip classifies 1.7 % of its
    points as ground, though 15 % lie within 0.5 m of its DEM): those last returns still reach the ground."""
    under_classified = _forest()
    hidden = (under_classified["return_number"] == 2) & (under_classified["classification"] == 1)
    under_classified["classification"][hidden] = 0
    s = compare_clouds(under_classified, under_classified)["a"]
    assert s["ground_share"] == pytest.approx(800 / 2000)          # by class
    assert s["near_ground_share"] == pytest.approx(1200 / 2000)    # by height
    assert s["ground_share_under_canopy"] == 0.5
    assert compare_clouds(_forest(), under_classified)["distance"]["ground_share"] == 0


@pytest.mark.parametrize("d", [0.5, 3.0])
def test_a_canopy_raised_by_d(d):
    """800 of 2,000 heights move up by d: EMD 0.4 d, KS 0.4 (the CDFs part between 10 and 10 + d)."""
    dist = compare_clouds(_forest(), _forest(canopy_m=10.0 + d))["distance"]
    assert dist["height_emd_m"] == pytest.approx(0.4 * d)
    assert dist["height_ks"] == pytest.approx(0.4)
    assert dist["canopy_p95_m"] == pytest.approx(d)
    assert dist["returns_tv"] == 0 and dist["ground_share"] == 0 and dist["density_ratio"] == 1


def test_another_returns_mix():
    """Every canopy pulse returning twice: pulses 50 % / 50 % against 75 % / 25 %, TV 0.25; under the
    canopy every last return is ground (1.0 against 0.5)."""
    dist = compare_clouds(_forest(), _forest(two_returns="all"))["distance"]
    assert dist["returns_tv"] == pytest.approx(0.25)
    assert dist["ground_share"] == pytest.approx(0.5)
    assert dist["density_ratio"] == pytest.approx(2400 / 2000)


def test_a_thinned_copy_has_half_the_density():
    points = _forest()
    dist = compare_clouds(points, points[::2])["distance"]   # each 1 m cell keeps points
    assert dist["density_ratio"] == 0.5


@pytest.mark.parametrize("canopy_m", [10.0, 2.0, 0.2])
def test_the_same_forest_on_a_high_datum_is_at_distance_zero(canopy_m):
    """The same points 2,287.31 m up (UAS_Clip's ground) measure as at 0 m: heights are z less a ground
    model, whose float noise (1e-13 m at that datum) split the forest's tied heights, so that height_ks read
    0.1 (canopy at 2 m: 0.1; at 0.2 m: 0.4) with an earth mover's distance of 1e-13 m."""
    points = _forest(canopy_m=canopy_m)
    high = points.copy()
    high["z"] += 2287.31
    result = compare_clouds(points, high)
    assert result["distance"]["height_ks"] == 0 and result["distance"]["height_emd_m"] == 0
    for key in ("canopy_cover_2m", "near_ground_share", "height_profile"):
        assert result["b"][key] == result["a"][key]


def test_without_ground_classes_the_lowest_point_filter_finds_a_sloped_ground():
    """A 20 % slope and no classes: the filter's ground gives the canopy its 10 m, as the classes do."""
    points = _forest(slope=0.2)
    classed = describe(load_cloud_like(points)).summary
    bare = describe(load_cloud_like(points, classes=False)).summary
    assert classed["canopy_height_m"]["p50"] == pytest.approx(10.0, abs=1e-6)
    assert bare["canopy_height_m"]["p50"] == pytest.approx(10.0, abs=0.02)
    assert bare["ground"]["points"] == 1200 and "lowest-point filter" in bare["ground"]["from"]
    assert any(n.startswith("no classes: ground from the lowest-point filter") for n in bare["notes"])


def test_near_ground_means_at_most_0_2_m_above_the_ground_model():
    """The ground returns behind the canopy, left unclassified, half 0.15 m and half 0.35 m up (litter, a
    low log): only those at most 0.2 m up (``GROUND_REACH_M``) reached the ground. Near the ground: the
    800 classified ground points and 200 of these, 1,000 of 2,000; under the canopy 200 of its 800 last
    returns (400 canopy-only, 400 of these)."""
    points = _forest()
    behind = points["return_number"] == 2
    low = behind & (np.round((points["y"] - 0.25) / STEP) % 2 == 0)
    points["classification"][behind] = 0
    points["z"][behind] = np.where(low[behind], 0.15, 0.35)
    s = compare_clouds(points, points)["a"]
    assert low.sum() == 200 and s["ground"]["points"] == 800
    assert s["near_ground_share"] == pytest.approx(1000 / 2000)
    assert s["ground_share_under_canopy"] == pytest.approx(200 / 800)


def test_canopy_begins_at_2_m_above_the_ground():
    """A canopy layer at exactly 2 m is canopy ("at least 2 m"): half the cells, its height 2 m; at
    1.9 m it is none."""
    at_2 = compare_clouds(_forest(canopy_m=2.0), _forest(canopy_m=1.9))
    assert at_2["a"]["canopy_cover_2m"] == 0.5
    assert at_2["a"]["canopy_height_m"] == pytest.approx({"p50": 2.0, "p95": 2.0, "p99": 2.0}, abs=1e-9)
    assert at_2["b"]["canopy_cover_2m"] == 0.0 and at_2["b"]["canopy_height_m"]["p50"] is None


def test_a_cell_is_canopy_by_its_highest_first_return():
    """Under the canopy every other pulse misses it and hits the ground first: each 1 m cell there still
    holds a 10 m first return, so the cover stays 0.5 (its highest first return, not its lowest), and
    every last return under the canopy reaches the ground."""
    points = _forest()
    gap = (points["x"] < SIDE / 2) & (points["number_of_returns"] == 1)
    points["z"][gap], points["classification"][gap] = 0.0, 1
    s = compare_clouds(points, points)["a"]
    assert gap.sum() == 400 and s["canopy_cover_2m"] == 0.5
    assert s["ground_share_under_canopy"] == 1.0


def test_canopy_height_percentiles_are_those_of_first_returns_from_2_m_up():
    """First returns uniform from 2 to 22 m above 1,000 ground returns: p50 12 m, p95 21 m, p99 21.8 m
    (linear percentiles of 2,001 evenly spaced heights); the ground does not count."""
    h = np.r_[np.zeros(1000), np.linspace(2.0, 22.0, 2001)]
    assert m.canopy_heights(h) == pytest.approx({"p50": 12.0, "p95": 21.0, "p99": 21.8}, abs=1e-9)


def test_the_vertical_profile_keeps_a_bird_and_a_pit_in_its_end_bins():
    """Heights beyond -20 and 200 m count in the end bins: 1 m bins from -20 to 200 m (221), a fifth of
    the points in each end bin, not 1,051 bins from -50 to 1,000 m."""
    edges, shares = m.vertical_profile(np.array([0.2, 0.7, 1.5, 1000.0, -50.0]))
    assert len(edges) == 221 and edges[0] == -20.0 and edges[-1] == 200.0
    assert shares[0] == shares[-1] == pytest.approx(0.2) and shares[20] == pytest.approx(0.4)


def load_cloud_like(points, classes=True) -> Cloud:
    from mitsuforest.compare.cloud import as_cloud
    cloud = as_cloud(points)
    if not classes:
        cloud.classification = None
    return cloud


# Files: ours and another tool's ---------------------------------------------------------------------

def _our_pcd(path, points):
    from mitsuforest.write.pcd import pcd_header
    path.write_bytes(pcd_header(points.dtype, len(points)).encode("ascii") + points.tobytes())
    return path


def _foreign_las(path, points, point_format=6, ground=True):
    """A LAS as another tool writes it: ASPRS classes (2 ground, 5 high vegetation), 16-bit intensity,
    no extra dimensions."""
    las = laspy.LasData(laspy.LasHeader(point_format=point_format, version="1.4" if point_format >= 6 else "1.2"))
    las.header.offsets, las.header.scales = [470000.0, 3810000.0, 2000.0], [0.001] * 3
    las.x, las.y, las.z = points["x"] + 470000.0, points["y"] + 3810000.0, points["z"] + 2000.0
    las.classification = np.where(points["classification"] == 1, 2 if ground else 1, 5).astype(np.uint8)
    las.return_number, las.number_of_returns = points["return_number"], points["number_of_returns"]
    las.intensity = np.round(points["intensity"] * 40000).astype(np.uint16)
    if "gps_time" in las.point_format.dimension_names:
        las.gps_time = points["gps_time"]
    if point_format >= 6:
        las.scan_angle = np.round(points["scan_angle"] / 0.006).astype(np.int16)
    else:
        las.scan_angle_rank = np.round(points["scan_angle"]).astype(np.int8)
    las.write(str(path))
    return path


@pytest.mark.parametrize("kind", ["foreign LAS 1.4 (format 6)", "foreign LAS 1.2 (format 1)",
                                  "foreign LAS 1.2 (format 0, no GPS time)", "our LAS", "our LAZ"])
def test_every_kind_of_file_reads_as_our_pcd(kind, tmp_path):
    """The same points from our PCD and from LAS/LAZ files of ours or another tool (ASPRS classes, no
    instance fields, a georeferenced offset) are at distance zero; scan angles are read in degrees."""
    from mitsuforest.write.las import write_las
    points = _forest()
    pcd = _our_pcd(tmp_path / "ours.pcd", points)
    if kind.startswith("foreign"):
        other = _foreign_las(tmp_path / "other.las", points, point_format=int(kind.split("format ")[1][0]))
    else:
        other = tmp_path / ("ours.laz" if "LAZ" in kind else "ours.las")
        write_las(other, points, offset=[0, 0, 0])
    result = compare_files(pcd, other)
    b = result["b"]
    assert b["classes"] == ("ASPRS" if kind.startswith("foreign") else "mitsuforest")
    assert b["ground"]["points"] == 1200 and b["canopy_height_m"]["p95"] == pytest.approx(10.0, abs=1e-3)
    assert b["scan_angle_deg"]["max_abs"] == pytest.approx(20.0 if "1.2" in kind else 19.5, abs=0.01)  # whole degrees
    d = result["distance"]
    assert d["returns_tv"] == 0 and d["ground_share"] == 0 and d["density_ratio"] == 1
    assert d["height_ks"] == 0 and d["height_emd_m"] < 1e-3 and d["intensity_ks"] == 0


def test_our_las_is_measured_in_its_sensor_s_units(tmp_path):
    """A LAS whose sensor writes RIEGL's reflectance in dB (PDAL's -25..+5 dB map) is read at
    (dB + 25) · 65535 / 30 of each echo's exact reflectance, unrounded and not clipped at the saturation
    (our PCD's amplitude is not), but at least 0 as counts are (an echo under -25 dB), and says so in its
    notes; one written with the default mapping (amplitude x 1e6) at its amplitude times 1e6, without a note."""
    from mitsuforest.compare.cloud import load_cloud
    from mitsuforest.config.types import IntensityMapping
    from mitsuforest.scan.radiometry import RIEGL_DB_MAP
    from mitsuforest.write.las import write_las
    points = _forest()
    points["range"] = 40.0
    points["intensity"][:10] = 1e-9                                 # -28 dB at 40 m
    points["reflectance"] = 10 * np.log10(points["intensity"] * 40.0 ** 2)
    write_las(tmp_path / "db.las", points, offset=[0, 0, 0], intensity=IntensityMapping(**RIEGL_DB_MAP))
    write_las(tmp_path / "amp.las", points, offset=[0, 0, 0])
    expected = np.maximum((points["reflectance"].astype(np.float64) + 25) * 65535 / 30, 0)
    db, amp = load_cloud(tmp_path / "db.las"), load_cloud(tmp_path / "amp.las")
    assert expected[:10].tolist() == [0.0] * 10 and expected.max() > 65535
    assert db.intensity == pytest.approx(expected, rel=1e-6)
    assert "intensity in its sensor's units (reflectance_db x 2184.5 + 54612.5" in db.notes[0]
    assert amp.intensity == pytest.approx(points["intensity"] * 1e6, rel=1e-6)
    assert not any("sensor's units" in n for n in amp.notes)


# PDAL's writers.pcd names (its dimensions'), as another tool's PCD holds them: ASPRS classes, 16-bit
# intensity, ScanAngleRank in degrees, georeferenced float64 coordinates, none of our label fields
PDAL_FIELDS = [("X", "<f8"), ("Y", "<f8"), ("Z", "<f8"), ("Intensity", "<u2"), ("ReturnNumber", "u1"),
               ("NumberOfReturns", "u1"), ("Classification", "u1"), ("GpsTime", "<f8"), ("ScanAngleRank", "<f4"),
               ("PointSourceId", "<u2")]


def _foreign_pcd(path, las_path, data="binary"):
    """The points of a LAS as another tool's PCD (:data:`PDAL_FIELDS`), ``DATA binary`` or ``ascii``."""
    from mitsuforest.write.pcd import pcd_header
    las = laspy.read(str(las_path))
    points = np.zeros(len(las.points), PDAL_FIELDS)
    for name, value in zip(points.dtype.names, (las.x, las.y, las.z, las.intensity, las.return_number,
                                                las.number_of_returns, las.classification, las.gps_time,
                                                np.asarray(las.scan_angle) * 0.006, las.point_source_id)):
        points[name] = value
    header = pcd_header(points.dtype, len(points)).replace("DATA binary", f"DATA {data}").encode("ascii")
    if data == "binary":
        path.write_bytes(header + points.tobytes())
    else:                       # as PCL writes ascii: shortest round-trip digits, integers as integers
        rows = [" ".join(str(v) for v in point.tolist()) for point in points]
        path.write_bytes(header + "\n".join(rows).encode("ascii") + b"\n")
    return path


def _noisy_las(path):
    """The constructed plot as another tool's LAS, its first point (ground) classed noise (ASPRS 7)."""
    las = laspy.read(str(_foreign_las(path, _forest())))
    las.classification[:1] = 7
    las.write(str(path))
    return path


def test_a_foreign_pcd_compares_as_the_same_points_in_a_foreign_las(tmp_path):
    """Another tool's PCD (PDAL's field names, ASPRS classes: ground 2, a noise point 7) measures as the
    same points in its LAS: ASPRS ground, the noise point left out, every summary and note the same, every
    distance zero. Before, it was refused (no ``x``), and read as ours had it its names (ground 1, noise kept)."""
    las = _noisy_las(tmp_path / "other.las")
    pcd = _foreign_pcd(tmp_path / "other.pcd", las)
    result = compare_files(pcd, las)
    a, b = result["a"], result["b"]
    assert a["file"] == "other.pcd" and {**a, "file": b["file"]} == b
    assert a["classes"] == "ASPRS" and a["points"] == 1999 and a["ground"] == {"from": "class 2 (ASPRS ground)",
                                                                                "points": 1199}
    assert a["notes"] == ["1 noise points (ASPRS classes 7, 18) left out"]
    assert a["scan_angle_deg"]["max_abs"] == pytest.approx(19.5) and a["canopy_height_m"]["p95"] == pytest.approx(10)
    assert a["pulses_by_returns"] == pytest.approx({"1": 1199 / 1599, "2": 400 / 1599})
    d = result["distance"]
    assert d["returns_tv"] == 0 and d["ground_share"] == 0 and d["density_ratio"] == 1
    assert d["height_ks"] == 0 and d["height_emd_m"] == 0 and d["intensity_ks"] == 0


def test_the_twin_reads_a_foreign_pcd_as_its_las_and_our_pcd_s_angles_in_degrees(tmp_path):
    """The twin's reader finds the same ground, returns, scan angles (degrees) and notes in another tool's
    PCD as in its LAS; our PCD's scan angles are degrees as written (before, they were taken for LAS
    counts: 19.5 degrees read as 0.117)."""
    from mitsuforest.twin.points import read_scan
    las = _noisy_las(tmp_path / "other.las")
    a, b = read_scan(_foreign_pcd(tmp_path / "other.pcd", las)), read_scan(las)
    assert a.notes == b.notes == ("1 noise points (ASPRS classes 7, 18) left out",)
    assert a.ground.sum() == b.ground.sum() == 1199 and len(a) == len(b) == 1999
    for column in ("x", "y", "z", "return_number", "number_of_returns", "intensity"):
        assert np.array_equal(getattr(a, column), getattr(b, column)), column
    assert a.scan_angle == pytest.approx(b.scan_angle, abs=1e-6) and np.max(np.abs(a.scan_angle)) == pytest.approx(19.5)
    points = _forest()
    ours = read_scan(_our_pcd(tmp_path / "ours.pcd", points))
    assert np.array_equal(ours.scan_angle, points["scan_angle"]) and ours.ground.sum() == 1200


def test_an_ascii_pcd_reads_as_the_binary_one(tmp_path):
    """``DATA ascii`` (as PCL, Open3D, CloudCompare may write): the same columns, names and classes as the
    same points ``DATA binary``; before, only binary was read."""
    from mitsuforest.write.info import ASPRS_CLASSES, load_points
    las = _noisy_las(tmp_path / "other.las")
    binary = load_points(_foreign_pcd(tmp_path / "binary.pcd", las))
    text = load_points(_foreign_pcd(tmp_path / "ascii.pcd", las, data="ascii"))
    assert text[1] == binary[1] == ["x", "y", "z", "intensity", "return_number", "number_of_returns",
                                    "classification", "gps_time", "scan_angle_rank", "point_source_id"]
    assert text[2] is binary[2] is ASPRS_CLASSES and text[2][2] == "ground (ASPRS 2)"
    for name in binary[1]:
        assert text[0][name].dtype == binary[0][name].dtype and np.array_equal(text[0][name], binary[0][name]), name
    assert len(text[0]["x"]) == 2000 and text[0]["x"].dtype == np.float64 and text[0]["classification"][0] == 7


def test_our_own_pcd_keeps_our_classes_and_names(tmp_path):
    """Our PCD (our label fields, ``classification`` with ``instance`` and ``object_id``): our classes and
    fields as they are; without ``instance`` and ``object_id`` its ``classification`` is another tool's."""
    from mitsuforest.classes import CLASS_NAMES
    from mitsuforest.write.info import ASPRS_CLASSES, load_points
    points = _forest()
    columns, names, classes = load_points(_our_pcd(tmp_path / "ours.pcd", points))
    assert classes is CLASS_NAMES and names == list(points.dtype.names)
    assert np.array_equal(columns["classification"], points["classification"])
    from numpy.lib.recfunctions import repack_fields    # the fields' bytes alone, as the header describes them
    other = repack_fields(points[[n for n in points.dtype.names if n not in ("instance", "object_id")]])
    assert load_points(_our_pcd(tmp_path / "other.pcd", other))[2] is ASPRS_CLASSES


def test_field_names_are_ours_where_they_differ_only_in_case_and_underscores():
    """PDAL's and snake-case names become ours; ours and unknown names stay; two that would become one
    name both stay as they are."""
    from mitsuforest.write.pcd import our_names
    assert our_names(["X", "Y", "Z", "GpsTime", "gpstime_", "ReturnNumber", "returnnumber", "NumberOfReturns",
                      "ScanAngleRank", "scan_angle", "PointSourceId", "Withheld", "Red"]) == \
        ["x", "y", "z", "GpsTime", "gpstime_", "ReturnNumber", "returnnumber", "number_of_returns",
         "scan_angle_rank", "scan_angle", "point_source_id", "withheld", "Red"]
    assert our_names(["x", "y", "z", "Intensity", "intensity"]) == ["x", "y", "z", "Intensity", "intensity"]


PCD_REFUSED = {
    "binary_compressed": ("DATA binary_compressed (LZF) is not supported: re-save the file as binary or ascii PCD "
                          "(pcl_convert_pcd_ascii_binary IN OUT 1, CloudCompare, Open3D)"),
    "ascii cut at a line": "truncated: the header promises 2,000 points, the file holds 1,000",
    "ascii cut in a line": ("ragged: point 1,000 holds 2 values where FIELDS names 10 (a truncated or damaged "
                            "file)"),
    "ascii with a word": "a value does not read as its field's TYPE: could not convert string 'ground' to uint8",
    "ascii of more points than POINTS": ("the header promises 2,000 points, but 2,005 follow: its POINTS does not "
                                         "describe its data (a damaged file)"),
}


@pytest.mark.parametrize("case", sorted(PCD_REFUSED))
def test_a_pcd_that_cannot_be_read_is_refused_in_one_line(case, tmp_path, capsys):
    """binary_compressed (no LZF decoder here) and a short, ragged or wordy ascii body: one line saying so."""
    las = _noisy_las(tmp_path / "other.las")
    path = _foreign_pcd(tmp_path / "bad.pcd", las, data="binary" if case == "binary_compressed" else "ascii")
    raw = path.read_bytes()
    if case == "binary_compressed":
        raw = raw.replace(b"DATA binary", b"DATA binary_compressed")
    else:
        header, _, body = raw.partition(b"DATA ascii\n")
        lines = body.splitlines()
        if case == "ascii cut at a line":
            lines = lines[:1000]
        elif case == "ascii cut in a line":
            lines = lines[:999] + [b" ".join(lines[999].split()[:2])]
        elif case == "ascii of more points than POINTS":
            lines = lines + lines[:5]
        else:
            lines[5] = lines[5].replace(b" 2 ", b" ground ")
        raw = header + b"DATA ascii\n" + b"\n".join(lines)
    path.write_bytes(raw)
    assert main(["compare", str(path), str(las), "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"mitsuforest: {path}: {PCD_REFUSED[case]}"), err


def test_noise_and_withheld_points_are_left_out(tmp_path):
    points = _forest()
    path = _foreign_las(tmp_path / "a.las", points)
    las = laspy.read(str(path))
    las.classification[:3] = 7
    las.classification[3:5] = 18
    las.withheld[10:14] = True
    las.write(str(path))
    cloud = load_cloud(path)
    assert len(cloud) == len(points) - 9
    assert cloud.notes == ["5 noise points (ASPRS classes 7, 18) left out", "4 withheld points left out"]


@pytest.mark.parametrize("damage, offset, value", [("a VLR count of 0", 100, (0).to_bytes(4, "little")),
                                                   ("a header size of 65535", 94, (65535).to_bytes(2, "little"))])
def test_extra_bytes_whose_description_is_not_read_compare_as_the_file_without_them(tmp_path, damage, offset,
                                                                                    value):
    """A foreign LAS with an extra dimension whose header hides its extra-bytes VLR (laspy then reads the
    extra bytes as one unnamed (n, 4) column): compared and read for a twin as the same points without it."""
    from mitsuforest.twin.points import read_scan
    points = _forest()
    pcd = _our_pcd(tmp_path / "ours.pcd", points)
    path = _foreign_las(tmp_path / "other.las", points)
    las = laspy.read(str(path))
    las.add_extra_dim(laspy.ExtraBytesParams(name="treeID", type=np.uint32))
    las.treeID = np.arange(len(points)) % 7
    las.write(str(path))
    raw = bytearray(path.read_bytes())
    raw[offset:offset + len(value)] = value
    path.write_bytes(bytes(raw))
    assert list(laspy.read(str(path)).point_format.dimension_names)[-1] == "ExtraBytes"   # the damage as laspy sees it
    d = compare_files(pcd, path)["distance"]
    assert d["returns_tv"] == 0 and d["ground_share"] == 0 and d["density_ratio"] == 1 and d["height_ks"] == 0
    assert len(read_scan(path)) == len(points)


def test_the_command_writes_table_json_and_figure(tmp_path, capsys):
    points = _forest()
    a = _our_pcd(tmp_path / "a.pcd", points)
    b = _foreign_las(tmp_path / "b.las", _forest(canopy_m=12.0))
    out = tmp_path / "cmp"
    assert main(["compare", str(a), str(b), "-o", str(out)]) == 0
    table = capsys.readouterr().out
    assert "canopy_p95_m +2.00" in table and "height_emd_m 0.80" in table and "A: a.pcd" in table
    saved = json.loads((out / "compare.json").read_text())
    assert set(saved) == {"a", "b", "distance"} and set(saved["distance"]) == DISTANCES
    assert saved["distance"]["canopy_p95_m"] == pytest.approx(2.0)
    png = (out / "compare.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 50_000
    assert sorted(p.name for p in out.iterdir()) == ["compare.json", "compare.png"]   # no temporary left


def test_within_a_measures_b_only_in_a_s_cells(tmp_path, capsys):
    """A: the constructed plot clipped to a disc 6 m across centred at (7, 10) (its 1 m cells whose centres lie
    within it: whole cells, mostly under the canopy of the plot's west half); B: the whole 20 x 20 m plot,
    half canopy. Over all of B the two differ; with --within-a B is measured in A's cells only, which hold
    A's very points: every distance is zero, and B's note says how many of its 2,000 points were measured.
    A B in another frame (georeferenced against A's local one) shares no cell with A and is refused."""
    points = _forest()
    centre = np.hypot(np.floor(points["x"]) + 0.5 - 7, np.floor(points["y"]) + 0.5 - 10) <= 6
    from mitsuforest.write.las import write_las
    a = _our_pcd(tmp_path / "disc.pcd", points[centre])
    b = tmp_path / "plot.las"
    write_las(b, points, offset=[0, 0, 0])
    whole = compare_files(a, b)["distance"]
    assert whole["returns_tv"] > 0.1 and whole["height_ks"] > 0.1 and whole["density_ratio"] < 0.9
    assert main(["compare", str(a), str(b), "--within-a", "-o", str(tmp_path / "cmp")]) == 0
    saved = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    d = saved["distance"]
    assert d["density_ratio"] == 1 and d["returns_tv"] == 0 and d["ground_share"] == 0 and d["height_ks"] == 0
    assert saved["a"]["points"] == saved["b"]["points"] == int(centre.sum()) > 500
    assert f"{int(centre.sum()):,} of 2,000 points" in capsys.readouterr().err
    elsewhere = _foreign_las(tmp_path / "utm.las", points)          # the same plot 470 km east: no common cell
    assert main(["compare", str(a), str(elsewhere), "--within-a", "-o", str(tmp_path / "cmp2")]) == 2
    assert "utm.las: none of its points lies within A (disc.pcd)'s footprint (the 1 m cells holding its points): " \
        "are the two files in one frame?" in capsys.readouterr().err
    assert not (tmp_path / "cmp2").exists()


def test_no_ground_class_is_said_on_stderr(tmp_path, capsys):
    points = _forest()
    a = _foreign_las(tmp_path / "a.las", points, ground=False)
    assert main(["compare", str(a), str(a), "-o", str(tmp_path / "o")]) == 0
    err = capsys.readouterr().err
    assert err.count("no ground points (class 2 (ASPRS ground)): ground from the lowest-point filter") == 2


def test_a_bare_xyz_pcd_compares_with_what_stands_in(tmp_path, capsys):
    """Another tool's PCD with x, y, z only: single-return pulses, the filter's ground, no intensity."""
    points = _forest()
    bare = np.zeros(len(points), [("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    for axis in "xyz":
        bare[axis] = points[axis]
    path = _our_pcd(tmp_path / "bare.pcd", bare)
    assert main(["compare", str(_our_pcd(tmp_path / "ours.pcd", points)), str(path), "-o", str(tmp_path / "o")]) == 0
    err = capsys.readouterr().err
    for said in ("no return numbers: every point taken as a single-return pulse", "no intensity",
                 "no classes: ground from the lowest-point filter"):
        assert f"mitsuforest: bare.pcd: {said}" in err, err
    saved = json.loads((tmp_path / "o" / "compare.json").read_text())
    assert saved["b"]["pulses_by_returns"] == {"1": 1.0} and saved["b"]["intensity"] is None
    assert saved["distance"]["intensity_ks"] is None and saved["distance"]["returns_tv"] == pytest.approx(0.25)
    assert saved["b"]["canopy_height_m"]["p95"] == pytest.approx(10.0)   # the filter's ground is the plane z = 0


def test_return_numbers_left_at_zero_are_said_and_stand_in_as_single_returns(tmp_path, capsys):
    """A LAS whose writer left every return number 0: each point a single-return pulse, said on stderr."""
    points = _forest()
    points["return_number"] = points["number_of_returns"] = 0
    path = _foreign_las(tmp_path / "zero.las", points, point_format=1)
    assert main(["compare", str(path), str(path), "-o", str(tmp_path / "o")]) == 0
    err = capsys.readouterr().err
    assert err.count("mitsuforest: zero.las: return numbers are 0 everywhere: every point taken as a "
                     "single-return pulse") == 2, err
    saved = json.loads((tmp_path / "o" / "compare.json").read_text())
    assert saved["a"]["pulses_by_returns"] == {"1": 1.0} and saved["a"]["pulses"] == len(points)


def test_numbers_of_returns_left_at_zero_are_said_as_such(tmp_path):
    """A LAS whose return numbers are filled but whose numbers of returns are all 0, without GPS times to
    group a pulse's points: the note names the field that is 0 (before, it said the return numbers were,
    which they are not)."""
    points = _forest()
    points["number_of_returns"] = 0
    cloud = load_cloud(_foreign_las(tmp_path / "nr0.las", points))
    assert cloud.notes == ["numbers of returns are 0 everywhere and no GPS time tells one pulse's points apart: "
                           "every point taken as a single-return pulse"]
    assert len(cloud) == 2000 and not (cloud.return_number - 1).any()


def _timed(points, per_stamp=1):
    """``points`` (a :func:`_forest`) with GPS times: each pulse's points one time, ``per_stamp`` pulses a
    stamp (the canopy-and-ground pulses' two points lie at one x, y)."""
    key = np.round(points["x"] * 1000) * 100_000 + np.round(points["y"] * 1000)
    _, pulse = np.unique(key, return_inverse=True)
    points["gps_time"] = 1000.0 + (pulse // per_stamp) * 1e-5
    return points


def test_numbers_of_returns_left_at_zero_are_taken_from_the_points_sharing_a_gps_time(tmp_path):
    """A LAS with return numbers and GPS times but numbers of returns 0 measures as the file that filled
    them: 1,600 pulses, 75 % with one return, 25 % with two (before, every point was a single-return
    pulse: 2,000 pulses, returns_tv 0.25 against the filled file)."""
    filled = _foreign_las(tmp_path / "filled.las", _timed(_forest()))
    points = _timed(_forest())
    points["number_of_returns"] = 0
    cloud = load_cloud(_foreign_las(tmp_path / "nr0.las", points))
    assert cloud.notes == ["numbers of returns are 0 everywhere: taken from the return numbers of the points "
                           "that share a GPS time"]
    assert np.array_equal(cloud.number_of_returns, load_cloud(filled).number_of_returns)
    r = compare_files(filled, tmp_path / "nr0.las")
    assert r["b"]["pulses"] == 1600 and r["b"]["pulses_by_returns"] == {"1": 0.75, "2": 0.25}
    assert r["distance"]["returns_tv"] == 0 and r["distance"]["density_ratio"] == 1


def test_gps_times_coarser_than_the_pulses_do_not_stand_for_numbers_of_returns(tmp_path):
    """Two pulses a GPS stamp: a stamp holds two first returns, so its points are not one pulse's."""
    points = _timed(_forest(), per_stamp=2)
    points["number_of_returns"] = 0
    cloud = load_cloud(_foreign_las(tmp_path / "coarse.las", points))
    assert cloud.notes[0].startswith("numbers of returns are 0 everywhere and no GPS time tells")
    assert not (cloud.number_of_returns - 1).any()


def test_gps_times_that_are_not_numbers_do_not_stand_for_numbers_of_returns(tmp_path):
    """GPS times left NaN (every point's, or some): NaN tells no pulse apart, so a file that left its numbers
    of returns 0 has each point a single-return pulse, in compare and the twin (before, with a
    point_source_id, as every LAS has, each NaN point was a pulse of its own: a first return counted as
    a single-return pulse, its second return as a pulse of two, and the notes said the GPS times told them)."""
    from mitsuforest.twin.points import read_scan
    points = _timed(_forest())
    points["number_of_returns"] = 0
    points["gps_time"] = np.nan
    path = _foreign_las(tmp_path / "nan.las", points)
    cloud = load_cloud(path)
    assert cloud.notes[0].startswith("numbers of returns are 0 everywhere and no GPS time tells")
    assert not (cloud.number_of_returns - 1).any()
    assert not any(note.startswith("numbers of returns are 0") for note in read_scan(path).notes)
    rn, t = np.array([1, 2, 1, 2, 1]), np.array([np.nan, np.nan, 6.0, 6.0, 7.0])
    assert m.numbers_of_returns_by_time(rn, t) is None and m.numbers_of_returns_by_time(rn, t, np.ones(5, int)) is None


def test_numbers_of_returns_by_time_is_the_largest_return_number_of_each_pulse():
    rn = np.array([1, 2, 3, 1, 1, 2])
    t = np.array([5.0, 5.0, 5.0, 6.0, 7.0, 7.0])
    assert m.numbers_of_returns_by_time(rn, t).tolist() == [3, 3, 3, 1, 2, 2]
    source = np.array([1, 1, 1, 1, 1, 2])          # one time, two flight lines: two pulses
    assert m.numbers_of_returns_by_time(np.array([1, 2, 3, 1, 1, 1]), t, source).tolist() == [3, 3, 3, 1, 1, 1]
    assert m.numbers_of_returns_by_time(rn, t, np.ones(6, int)).tolist() == [3, 3, 3, 1, 2, 2]
    assert m.numbers_of_returns_by_time(np.array([1, 1, 2, 1, 1, 2]), t) is None    # two first returns at 5.0


def test_a_file_of_first_returns_only_is_compared_with_the_other_s_first_returns(tmp_path, capsys):
    """The constructed forest's 1,600 first returns alone (each with its pulse's number of returns, every
    return number 1, one GPS time a point) against the whole forest: at distance zero, the whole file
    measured on its first returns and said so (before: density ratio 1.25, ground share 0.6 against 0.5,
    the heights of 400 ground returns more)."""
    whole = _timed(_forest())
    first = whole[whole["return_number"] == 1]
    a, b = _foreign_las(tmp_path / "first.las", first), _foreign_las(tmp_path / "whole.las", whole)
    assert main(["compare", str(a), str(b), "-o", str(tmp_path / "o")]) == 0
    err = capsys.readouterr().err
    assert ("mitsuforest: first.las: first returns only: one point a pulse, each with its pulse's number of returns "
            "(up to 2), every return number 1 and no two points at one GPS time") in err
    assert ("mitsuforest: whole.las: measured on its first returns (1,600 of 2,000 points), as A (first.las) holds "
            "first returns only") in err
    saved = json.loads((tmp_path / "o" / "compare.json").read_text())
    assert saved["distance"] == {**dict.fromkeys(DISTANCES, 0.0), "density_ratio": 1.0}
    assert saved["a"]["pulses_by_returns"] == saved["b"]["pulses_by_returns"] == {"1": 0.75, "2": 0.25}
    assert compare_files(b, a)["distance"] == saved["distance"]         # either way round
    unnumbered = whole.copy()
    unnumbered["return_number"] = 1          # every return kept but none numbered: two points at one time
    assert not load_cloud(_foreign_las(tmp_path / "unnumbered.las", unnumbered)).first_only


def test_a_file_without_first_returns_beside_one_of_first_returns_only_is_refused_in_one_line(tmp_path, capsys):
    """The forest's first returns only against a file of its later returns alone (return numbers 2): there
    are no first returns to measure like for like, said in one line (before, an empty cloud and a traceback
    from numpy, "zero-size array to reduction operation minimum")."""
    whole = _timed(_forest())
    a = _foreign_las(tmp_path / "first.las", whole[whole["return_number"] == 1])
    b = _foreign_las(tmp_path / "later.las", whole[whole["return_number"] == 2])
    assert main(["compare", str(a), str(b)]) == 2
    err = capsys.readouterr().err
    assert err == ("mitsuforest: later.las: none of its 400 points is a first return (return number 1) to measure "
                   "beside A (first.las), which holds first returns only\n")


def test_a_file_of_first_returns_that_left_its_return_numbers_0_is_read_as_the_twin_reads_it(tmp_path):
    """The forest's first returns, one GPS time each, return numbers 0 and numbers of returns kept: compare
    takes them as first returns with their counts, as the twin does (before, compare made every point a
    single-return pulse, returns_tv 0.25 against the file that numbered them, while the twin read it as
    first returns only)."""
    from mitsuforest.twin.points import read_scan
    whole = _timed(_forest())
    first = whole[whole["return_number"] == 1]
    numbered = _foreign_las(tmp_path / "numbered.las", first)
    first["return_number"] = 0
    zero = _foreign_las(tmp_path / "zero.las", first)
    cloud = load_cloud(zero)
    assert cloud.first_only and cloud.notes[0] == "return numbers are 0 everywhere: taken as 1, the file's first returns"
    assert compare_files(numbered, zero)["distance"]["returns_tv"] == 0
    assert read_scan(zero).first_only and read_scan(zero).number_of_returns.tolist() == cloud.number_of_returns.tolist()


def test_pulse_count_is_the_first_returns_or_the_shares_of_unnumbered_returns():
    assert m.pulse_count(np.array([1, 2, 1, 1, 2, 3]), np.array([2, 2, 1, 3, 3, 3])) == 3
    assert m.pulse_count(np.array([1, 2, 1, 1, 2, 3]), np.zeros(6)) == 3    # counts not filled: the first returns
    assert m.pulse_count(np.ones(6), np.array([2, 2, 1, 3, 3, 3])) == pytest.approx(3)   # returns left 1
    assert m.pulse_count(np.ones(6), np.array([2, 2, 1, 3, 3, 3]), first_only=True) == 6    # first returns only


def test_an_output_folder_that_is_a_file_is_refused_first(tmp_path, capsys):
    a = _our_pcd(tmp_path / "a.pcd", _forest())
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["compare", str(a), str(a), "-o", str(blocker)]) == 2
    assert capsys.readouterr().err.strip() == f"mitsuforest: {blocker}: the output folder is a file"


def _empty_pcd(path):
    from mitsuforest.scan import POINT_DTYPE
    return _our_pcd(path, np.zeros(0, POINT_DTYPE))


BAD = {
    "missing": (lambda t: t / "nope.laz", "file not found"),
    "empty": (lambda t: _empty_pcd(t / "empty.pcd"), "the file holds no points"),
    "damaged": (lambda t: _damaged(t / "bad.las"), "cannot read"),
    "header written twice": (lambda t: _header_twice(_our_pcd(t / "twice.pcd", _forest())),
                             "its header is written twice: a second header follows its DATA line"),
    "a folder": (lambda t: t, "is a folder"),
}


def _damaged(path):
    path.write_bytes(bytes(range(256)) * 40)
    return path


def _header_twice(path):
    """Our PCD with its header written a second time after the first (read as the points)."""
    raw = path.read_bytes()
    path.write_bytes(raw[:raw.index(b"DATA binary\n") + 12] + raw)
    return path


def test_a_file_wider_than_its_cells_can_number_is_refused_in_one_line(tmp_path, capsys):
    """Our PCD without ground classes, one point at x = 1e300 m (not left out: our files are not filtered): its
    1 m cells' keys would overflow, and the lowest-point filter's surface found no ground (numpy's warnings, then
    its ValueError); one line."""
    points = _forest()
    points["classification"] = 3
    points["x"][0] = 1e300
    far = _our_pcd(tmp_path / "far.pcd", points)
    out = tmp_path / "out"
    assert main(["compare", str(far), str(_our_pcd(tmp_path / "good.pcd", _forest())), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == ("mitsuforest: far.pcd: its points span 1e+300 m, more than the 1 m cells of a comparison can "
                   "number (2,147,483,647 m): a damaged file, or one of stray coordinates"), err
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.parametrize("case", sorted(BAD))
@pytest.mark.parametrize("side", ["A", "B"])
def test_bad_input_gets_one_line_and_exit_2(case, side, tmp_path, capsys):
    make, message = BAD[case]
    bad = make(tmp_path)
    good = _our_pcd(tmp_path / "good.pcd", _forest())
    args = [bad, good] if side == "A" else [good, bad]
    out = tmp_path / "out"
    assert main(["compare", *map(str, args), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith(f"mitsuforest: {bad}: ") and message in err, err
    assert not out.exists() or not any(out.iterdir())


# The real scans in ../shared/data/real ------------------------------------------------------------------

needs_real = pytest.mark.skipif(not (REAL / "UAS_Clip.laz").is_file() or not (REAL / "MixedConifer.laz").is_file(),
                                reason=f"the real scans are not in {REAL} (GPL data kept beside the project)")


@pytest.fixture(scope="module")
def real_result():
    return compare_clouds(REAL / "UAS_Clip.laz", REAL / "MixedConifer.laz")


@needs_real
def test_the_uas_clip_measures_as_its_readme_says(real_result):
    """README of shared/data/real: points by number_of_returns 141,723 / 143,458 / 75,163 / 24,411 /
    5,272 / 850, as pulses 57.7 % single-return; up to 6 returns; ~559 points/m² over ~700 m²; scan
    angles up to ±70°; ASPRS classes with ground."""
    cloud = load_cloud(REAL / "UAS_Clip.laz")
    assert len(cloud) == 390_877 - 2 and cloud.notes == ["2 noise points (ASPRS classes 7, 18) left out"]
    by_points = np.bincount(cloud.number_of_returns)[1:]
    assert by_points.tolist() == pytest.approx([141_723, 143_458, 75_163, 24_411, 5_272, 850], abs=2)
    s = describe(cloud).summary
    as_pulses = m.shares(by_points / np.arange(1, 7))    # each pulse once: its points over its returns
    assert s["pulses_by_returns"]["1"] == pytest.approx(0.577, abs=0.002)
    assert [s["pulses_by_returns"][str(k)] for k in range(1, 7)] == pytest.approx(as_pulses, abs=0.003)
    assert max(map(int, s["pulses_by_returns"])) == 6
    assert 650 < s["covered_area_m2"] < 760 and 500 < s["density_per_m2"] < 600
    assert s["scan_angle_deg"]["max_abs"] == pytest.approx(70, abs=0.1)
    assert s["ground"]["from"] == "class 2 (ASPRS ground)"
    assert 25 < s["canopy_height_m"]["p99"] < 35                         # canopy up to ~34 m


@needs_real
def test_the_real_scans_compare_with_finite_distances(real_result):
    d = real_result["distance"]
    assert set(d) == DISTANCES and all(isinstance(v, float) and math.isfinite(v) for v in d.values()), d
    assert 0 < d["returns_tv"] < 1 and 0 < d["height_ks"] < 1 and d["height_emd_m"] > 0
    assert d["density_ratio"] == pytest.approx(real_result["b"]["density_per_m2"] / real_result["a"]["density_per_m2"])
    assert real_result["b"]["pulses_by_returns"]["1"] == pytest.approx(26_087 / 37_657)   # every point a first return


@needs_real
def test_mixedconifer_holds_first_returns_only_so_uas_clip_is_measured_on_its_first(real_result):
    """MixedConifer keeps one point a pulse (37,657 points at 37,657 GPS times, every return number 1, its
    points of pulses with 2-4 returns never ground): UAS_Clip beside it is measured on its 246,184 first
    returns, with the same shares of pulses by returns as all its points give."""
    a, b = real_result["a"], real_result["b"]
    assert b["notes"] == ["first returns only: one point a pulse, each with its pulse's number of returns (up to 4), "
                          "every return number 1 and no two points at one GPS time"]
    assert a["points"] == a["pulses"] == 246_184 == int(np.count_nonzero(load_cloud(REAL / "UAS_Clip.laz").return_number == 1))
    assert a["notes"][-1] == ("measured on its first returns (246,184 of 390,875 points), as B (MixedConifer.laz) "
                              "holds first returns only")
    assert a["pulses_by_returns"]["1"] == pytest.approx(0.577, abs=0.002)
    assert b["points"] == b["pulses"] == 37_657


@needs_real
def test_the_lowest_point_filter_finds_the_uas_clips_classified_ground():
    """With its classes ignored, the filter's ground model lies within a few cm of the classified one
    (README, "Comparing scans")."""
    cloud = load_cloud(REAL / "UAS_Clip.laz")
    classified = cloud.classification == 2
    reference = m.ground_model(cloud.x, cloud.y, cloud.x[classified], cloud.y[classified], cloud.z[classified])
    found = m.lowest_point_ground(cloud.x, cloud.y, cloud.z)
    model = m.ground_model(cloud.x, cloud.y, cloud.x[found], cloud.y[found], cloud.z[found])
    gap = np.abs(model.z - reference.z)
    assert np.median(gap) < 0.05 and np.percentile(gap, 90) < 0.12, np.percentile(gap, [50, 90])
    assert np.mean(found[classified]) > 0.95        # the classified ground is found


def test_a_bird_a_multipath_echo_a_stray_point_and_copies_are_left_out(tmp_path, capsys):
    """Another tool's file without ground classes, with a bird 500 m up, a multipath echo 80 m under the
    ground, a point 20 km east and 100 points written twice: each is left out and said, and the file
    measures as the plot does (before, the stray point coarsened the ground model to 10 m cells, the
    copies halved the spacing to 0, and the filter took the echo 80 m down for ground)."""
    points = _forest(slope=0.1)
    extra = points[[0, 1, 2]].copy()
    extra["z"] += [500.0, -80.0, 0.0]
    extra["x"] += [0.0, 0.0, 20_000.0]
    messy = np.concatenate([points, extra, points[::20]])
    clean = compare_files(_foreign_las(tmp_path / "clean.las", points, ground=False),
                          _foreign_las(tmp_path / "messy.las", messy, ground=False))
    assert capsys.readouterr().err == ""
    a, b = clean["a"], clean["b"]
    assert b["notes"][:2] == ["100 repeated points (exact copies) left out",
                              "3 isolated points (fewer than 6 others in the 5 m cubes around them: birds, "
                              "multipath, stray coordinates) left out"]
    assert b["points"] == a["points"] == 2000 and b["covered_area_m2"] == 400
    assert b["spacing_m"] == pytest.approx(STEP)
    assert b["height_m"] == a["height_m"] and b["canopy_height_m"] == a["canopy_height_m"]
    assert a["canopy_height_m"]["p50"] == pytest.approx(10.0, abs=0.02)
    assert b["height_profile"] == a["height_profile"] and b["near_ground_share"] == pytest.approx(0.6)
    assert clean["distance"]["height_ks"] == 0 and clean["distance"]["density_ratio"] == 1


STRAY_NOTE = ("20 points in 2 stray clusters (fewer than 20 points, apart from the scan's 5 m cubes, above or below it "
              "within 20 m or away from it: flocks, multipath, stray coordinates) left out")


def test_a_flock_above_the_canopy_and_multipath_under_the_ground_are_left_out(tmp_path, capsys):
    """Another tool's file of the plot (ground and a 10 m canopy), a flock of 12 birds 60 m over the canopy
    and a cluster of 8 multipath echoes 30 m under the ground, each within 3 m: too many to be isolated
    (11 and 7 others around each point), so before they stayed: the height profile spanned -20 to 72 m
    and the canopy's 99th percentile was 71.5 m, not 10. Now exactly those 20 points are left out, said,
    and the file measures as the plot does."""
    points = _forest()
    rng = np.random.default_rng(7)
    extra = points[np.r_[:12, :8]].copy()
    extra["x"], extra["y"] = 5.0 + rng.uniform(0, 3, 20), 5.0 + rng.uniform(0, 3, 20)
    extra["z"] = np.r_[70.0 + rng.uniform(0, 3, 12), -30.0 - rng.uniform(0, 3, 8)]
    extra["classification"] = 3          # unclassified in a LAS: not ground
    messy = np.concatenate([points, extra])
    cluster = m.stray_clusters(messy["x"], messy["y"], messy["z"])
    assert np.flatnonzero(cluster >= 0).tolist() == list(range(2000, 2020))
    assert sorted(np.bincount(cluster[cluster >= 0]).tolist()) == [8, 12]
    assert not m.isolated_points(messy["x"], messy["y"], messy["z"]).any()      # not for the old rule
    result = compare_files(_foreign_las(tmp_path / "clean.las", points), _foreign_las(tmp_path / "messy.las", messy))
    assert capsys.readouterr().err == ""
    a, b = result["a"], result["b"]
    assert b["notes"] == [STRAY_NOTE] and b["points"] == a["points"] == 2000
    assert b["height_m"] == a["height_m"] and b["canopy_height_m"] == a["canopy_height_m"]
    assert b["height_profile"] == a["height_profile"] and result["distance"]["height_ks"] == 0


def _sparse_stand(tall_tree=True):
    """A 60 × 60 m flat plot sampled as a sparse airborne scan (≈ 4 points/m², a jittered 0.5 m grid), with
    a lone crown (a dome 2 m in radius, 14 to 16 m up, no stem seen: a gap of 14 m over the ground)
    at (15, 15), a small crown (1 m in radius, 12 to 12.5 m up) at (45, 30) and, with ``tall_tree``, a 20 m
    cone of crown 3 m in radius down to the ground at (45, 45), 15 m from the small crown (11 m between
    their edges: apart in 5 m cubes).

    Returns x, y, z (n,) and the (n,) bool points of the lone crown and of the small crown."""
    rng = np.random.default_rng(3)
    g = np.arange(0.25, 60.0, 0.5)
    gx, gy = (v.ravel() + rng.uniform(-0.2, 0.2, v.size) for v in np.meshgrid(g, g, indexing="ij"))
    r_lone, r_small, r_tall = np.hypot(gx - 15, gy - 15), np.hypot(gx - 45, gy - 30), np.hypot(gx - 45, gy - 45)
    lone, small, tall = r_lone < 2, r_small < 1, (r_tall < 3) & tall_tree
    x = np.r_[gx, gx[lone], gx[small], gx[tall]]
    y = np.r_[gy, gy[lone], gy[small], gy[tall]]
    z = np.r_[np.zeros(gx.size), 16 - r_lone[lone] ** 2 / 2, 12.5 - r_small[small] / 2, 20 - r_tall[tall] * 20 / 3]
    part = np.repeat([0, 1, 2, 3], [gx.size, lone.sum(), small.sum(), tall.sum()])
    return x, y, z, part == 1, part == 2


def test_a_sparse_scans_lone_crowns_above_a_gap_are_kept():
    """At ≈ 4 points/m², a lone crown 14 m over the ground (51 points) and a small one 12 m over it (13
    points, as few as a flock) are parts of their own, yet no point is stray: the lone crown has 20 points
    or more, and the small one is not above the top of the scan within 20 m (the tall tree 15 m away). The
    rule's limit: without the tall tree, the small crown over open ground is taken for a flock."""
    x, y, z, lone, small = _sparse_stand()
    part, sizes = m.cube_components(x, y, z)
    assert len(sizes) == 3 and lone.sum() == 51 and small.sum() == 13
    assert sorted(sizes.tolist())[:2] == [13, 51] and len(np.unique(part[lone])) == len(np.unique(part[small])) == 1
    assert not m.isolated_points(x, y, z).any()
    assert (m.stray_clusters(x, y, z) == -1).all()
    x, y, z, lone, small = _sparse_stand(tall_tree=False)
    assert np.flatnonzero(m.stray_clusters(x, y, z) >= 0).tolist() == np.flatnonzero(small).tolist()


@needs_real
@pytest.mark.parametrize("name, points, kept", [("UAS_Clip", 390_877, 390_875), ("MixedConifer", 37_657, 37_657)])
def test_the_real_scans_are_one_part_and_lose_no_point_as_isolated_or_stray(name, points, kept):
    """Both real scans are one connected part in 5 m cubes (UAS_Clip in 224 cubes, MixedConifer, the sparse
    airborne scan, in 1,495), so no cluster is stray and no point isolated: only UAS_Clip's 2 ASPRS noise
    points are left out."""
    from mitsuforest.compare.cloud import usable_points
    from mitsuforest.write.info import load_points
    columns, _, _ = load_points(REAL / f"{name}.laz")
    x, y, z = (np.asarray(columns[a], np.float64) for a in "xyz")
    assert len(x) == points and m.cube_components(x, y, z)[1].tolist() == [points]
    assert (m.stray_clusters(x, y, z) == -1).all() and not m.isolated_points(x, y, z).any()
    usable, notes = usable_points(columns)
    assert len(usable["x"]) == kept
    assert notes == ([] if kept == points else ["2 noise points (ASPRS classes 7, 18) left out"])


def test_a_file_in_feet_is_measured_in_metres_and_one_in_degrees_is_refused(tmp_path, capsys):
    """A state plane in feet (NAD83 / Arizona Central (ft), no vertical CRS: heights in feet too) measures
    as the same plot in metres, said in the notes (before: a 10 m canopy measured 32.8 "m" tall and the
    density per square foot); a file in longitude and latitude is refused in one line."""
    import pyproj
    points = _forest()
    feet = points.copy()
    for axis in "xyz":
        feet[axis] = points[axis] / 0.3048
    path = _foreign_las(tmp_path / "feet.las", feet)
    las = laspy.read(str(path))
    las.header.add_crs(pyproj.CRS.from_epsg(2223))
    las.write(str(path))
    result = compare_files(_foreign_las(tmp_path / "metres.las", points), path)
    b = result["b"]
    assert b["notes"] == ["coordinates in foot (CRS NAD83 / Arizona Central (ft)): converted to metres"]
    assert b["canopy_height_m"]["p95"] == pytest.approx(10.0, abs=1e-3) and b["density_per_m2"] == 5.0
    assert b["spacing_m"] == pytest.approx(STEP, abs=1e-3) and result["distance"]["height_emd_m"] < 1e-3
    las.header.add_crs(pyproj.CRS.from_epsg(4326))
    las.write(str(tmp_path / "degrees.las"))
    assert main(["compare", str(tmp_path / "degrees.las"), str(path)]) == 2
    assert capsys.readouterr().err == (f"mitsuforest: {tmp_path / 'degrees.las'}: its CRS (WGS 84) is geographic: its x "
                                       "and y are in degree; compare measures in metres: reproject the file to a "
                                       "projected CRS (such as its UTM zone) first\n")


def test_a_crs_record_that_cannot_be_read_is_said_in_the_notes(tmp_path):
    """A LAS 1.2 whose GeoTIFF keys name a user-defined projection in feet (ProjectedCSTypeGeoKey 32767,
    ProjLinearUnitsGeoKey 9002), which laspy cannot make a CRS of, is measured in its own units as metres:
    said in its notes (before, silently: a density per square foot read as per m²); a file without any CRS
    record gets no such note."""
    from laspy.vlrs.known import GeoKeyDirectoryVlr, GeoKeyEntryStruct
    path = _foreign_las(tmp_path / "user_defined_feet.las", _forest(), point_format=1)
    las = laspy.read(str(path))
    keys = GeoKeyDirectoryVlr()
    keys.geo_keys = []
    for key, value in ((1024, 1), (3072, 32767), (3076, 9002)):     # projected model; user-defined; feet
        entry = GeoKeyEntryStruct()
        entry.id, entry.tiff_tag_location, entry.count, entry.value_offset = key, 0, 1, value
        keys.geo_keys.append(entry)
    keys.geo_keys_header.number_of_keys = len(keys.geo_keys)
    las.header.vlrs.append(keys)
    las.write(str(path))
    assert laspy.read(str(path)).header.parse_crs() is None
    notes = load_cloud(path).notes
    assert notes[0] == ("its CRS record (GeoTIFF keys) cannot be read: its coordinates are taken as metres; "
                        "give the file a CRS that names its units (such as its EPSG code)")
    assert load_cloud(_foreign_las(tmp_path / "none.las", _forest(), point_format=1)).notes == []


def test_another_tools_label_dimension_is_not_taken_for_our_classes(tmp_path):
    """A foreign LAS with its own extra ``label`` (a segmentation's, here 7 everywhere) keeps its ASPRS
    classes: ground class 2, 1,200 points (before, its labels were read as our classes, none of them our
    ground 1, and the lowest-point filter stood in); our LAS, whose ``label`` says ``mitsuforest class``,
    is still ours."""
    from mitsuforest.write.las import write_las
    points = _forest()
    path = _foreign_las(tmp_path / "labelled.las", points)
    las = laspy.read(str(path))
    las.add_extra_dim(laspy.ExtraBytesParams("label", "u1", "instance label"))
    las.label = np.full(len(las), 7, np.uint8)
    las.write(str(path))
    ours = tmp_path / "ours.las"
    write_las(ours, points, offset=[0, 0, 0])
    result = compare_files(path, ours)
    a, b = result["a"], result["b"]
    assert a["classes"] == "ASPRS" and a["ground"] == {"from": "class 2 (ASPRS ground)", "points": 1200}
    assert b["classes"] == "mitsuforest" and b["ground"] == {"from": "class 1 (our ground)", "points": 1200}
    assert a["notes"] == [] and result["distance"]["height_ks"] == 0


def test_a_file_spanning_kilometres_says_its_ground_model_is_coarse(tmp_path):
    """20 points 5 km from the plot (a block of points with zeroed or shifted coordinates, too many to be
    isolated) make the ground model's cells 2.5 m: said in the notes (before, silently)."""
    points = _forest()
    far = points[:20].copy()
    far["x"] += 5000.0
    cloud = describe(load_cloud(_foreign_las(tmp_path / "far.las", np.concatenate([points, far]))))
    assert cloud.summary["notes"] == ["the points span 5,010 m: the ground model's cells are 2.5 m, not 1 m (at most "
                                      "4,000,000 cells), and heights follow the ground less closely; clip the file "
                                      "to its plot"]


def test_points_without_coordinates_are_left_out_and_said(tmp_path, capsys):
    """A PCD whose empty cells hold NaN (PCL's organized clouds) compares as the same points without them,
    in compare and the twin (before: compare stopped with numpy's "negative dimensions are not allowed",
    the twin refused the file)."""
    from mitsuforest.twin.points import read_scan
    points = _forest()
    bare = np.zeros(len(points) + 3, [("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    for axis in "xyz":
        bare[axis][:len(points)] = points[axis]
    bare["x"][-3:], bare["y"][-2:], bare["z"][-1:] = np.nan, np.nan, np.inf
    clean = _our_pcd(tmp_path / "clean.pcd", bare[:len(points)])
    holed = _our_pcd(tmp_path / "holed.pcd", bare)
    assert main(["compare", str(clean), str(holed), "-o", str(tmp_path / "o")]) == 0
    assert ("mitsuforest: holed.pcd: 3 points without coordinates (NaN or infinite: an organized cloud's empty "
            "cells) left out") in capsys.readouterr().err
    saved = json.loads((tmp_path / "o" / "compare.json").read_text())
    assert saved["distance"] == {**dict.fromkeys(DISTANCES, 0.0), "density_ratio": 1.0, "intensity_ks": None}
    scan = read_scan(holed)
    assert len(scan) == len(points) and scan.notes[0].startswith("3 points without coordinates")
