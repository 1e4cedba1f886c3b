"""The point schema (mitsuforest/fields.py): every file's header and every reader list exactly its
fields, the written headers match a golden description, and each field comes back from our LAS files
as it was written."""

import importlib.util
import re

import laspy
import numpy as np
import pytest
from conftest import ROOT

from mitsuforest import fields
from mitsuforest.fields import FIELDS, LAS_FIELDS, POINT_DTYPE, RECORD_DTYPE
from mitsuforest.write import PointWriter, Staging, read_pcd
from mitsuforest.write.las import read_las_points, write_las

OFFSET = (500000.0, 6100000.0, 10.0)
HAS_COPC = importlib.util.find_spec("copclib") is not None

# The golden description: what the files held when the schema was made (commit 33a1831), written out.
GOLDEN_PCD = {
    "FIELDS": "treeid x y z classification instance object_id number_of_returns return_number intensity gps_time "
              "scan_angle pulse_id range species reflectance point_source_id height_above_ground",
    "SIZE": "2 4 4 4 1 4 4 1 1 4 8 4 8 4 1 4 2 4",            # x, y, z float32 in the local frame
    "TYPE": "U F F F U U U U U F F F U F U F U F",
}
GOLDEN_PCD_GEOREFERENCED_SIZE = "2 8 8 8 1 4 4 1 1 4 8 4 8 4 1 4 2 4"
GOLDEN_LAS_EXTRA = [                                        # name, type, description, in file order
    ("label", "u1", "mitsuforest class 1-8"),
    ("treeid", "<u2", "tree model; deadwood max(11,N+1)"),   # "archetype 1-10, deadwood 11" until the audit
    ("instance", "<u4", "object instance id"),
    ("object_id", "<u4", "component id"),
    ("amplitude", "<f4", "echo amplitude (white at 1 m=1)"),
    ("species", "u1", "tree family code, 0 none"),
    ("reflectance", "<f4", "dB: amplitude/white target's"),
    ("height_above_ground", "<f4", "m above the terrain"),
]
GOLDEN_PCD_ONLY = {"pulse_id", "range"}                     # fields our LAS files do not hold


def _points(n=3000, seed=5) -> np.ndarray:
    """Scan points over the demo's plot with every field varied (returns above 15 included)."""
    rng = np.random.default_rng(seed)
    p = np.zeros(n, POINT_DTYPE)
    for f in fields.SCAN_FIELDS:
        p[f.name] = rng.integers(0, 200, n)
    p["x"], p["y"], p["z"] = rng.uniform(0, 20, n), rng.uniform(0, 20, n), rng.uniform(0, 25, n)
    p["classification"] = rng.integers(1, 9, n)
    p["number_of_returns"] = rng.integers(1, 20, n)
    p["return_number"] = np.minimum(rng.integers(1, 20, n), p["number_of_returns"])
    p["intensity"], p["reflectance"] = rng.uniform(0, 0.08, n), rng.uniform(-30, 5, n)
    p["gps_time"], p["scan_angle"], p["range"] = np.sort(rng.uniform(0, 60, n)), rng.uniform(-60, 60, n), 30.0
    return p


def _write(tmp_path, offset, formats=("pcd", "las", "laz")) -> dict:
    from mitsuforest.config import load_scene
    scene = load_scene(ROOT / "scenes" / "demo.yaml").with_({"origin.offset": list(offset),
                                                            "output.formats": list(formats)})
    staging = Staging(tmp_path, scene.name)
    writer = PointWriter(staging, scene, keep=True, threads=1)
    writer.add(_points())
    writer.close()
    return {p.name.removeprefix(scene.name): p for p in staging.path.iterdir()}


def _pcd_header(path) -> dict:
    lines = path.read_bytes().split(b"DATA binary")[0].decode("ascii").splitlines()
    return {line.split()[0]: " ".join(line.split()[1:]) for line in lines if line and not line.startswith("#")}


def _las_extra(path) -> list[tuple]:
    with laspy.open(str(path)) as f:
        structs = f.header.vlrs.get("ExtraBytesVlr")[0].extra_bytes_structs
        dims = [f.header.point_format.dimension_by_name(s.name.rstrip(b"\0").decode()) for s in structs]
        return [(d.name, np.dtype(d.dtype).str.replace("|", ""), s.description.rstrip(b"\0").decode())
                for d, s in zip(dims, structs)]


def test_the_schema_is_the_golden_description():
    assert " ".join(f.name for f in FIELDS) == GOLDEN_PCD["FIELDS"]
    assert " ".join(str(fields.pcd_type(f.pcd_local or f.dtype)[1]) for f in FIELDS) == GOLDEN_PCD["SIZE"]
    assert " ".join(fields.pcd_type(f.dtype)[0] for f in FIELDS) == GOLDEN_PCD["TYPE"]
    assert [(d.name, np.dtype(d.dtype).str.replace("|", ""), d.description)
            for d in fields.LAS_EXTRA_DIMENSIONS] == GOLDEN_LAS_EXTRA
    assert {f.name for f in FIELDS} - {f.name for f in LAS_FIELDS} == GOLDEN_PCD_ONLY
    assert [f.name for f in fields.WRITER_FIELDS] == ["height_above_ground"]
    assert POINT_DTYPE.names == RECORD_DTYPE.names[:-1]            # the scan's fields, then the writer's
    assert [d.slot for d in fields.LAS_EXTRA_DIMENSIONS] == list(range(len(GOLDEN_LAS_EXTRA)))
    assert all(len(d.description) <= 32 and d.description.isascii() for d in fields.LAS_EXTRA_DIMENSIONS)


def test_the_las_treeid_description_states_deadwood_s_id_past_ten_tree_models():
    """The treeid dimension's description in every LAS file must hold for any scene. Deadwood is 11 only
    up to ten tree models: with twelve (unique trees, a tree list, forest.models) the trees are 1-12 and
    deadwood 13, so "archetype 1-10, deadwood 11" named tree 11's points deadwood (a 12-unique-tree demo:
    30,072 wood and leaf points with treeid 11, deadwood 13)."""
    from mitsuforest.plan import _deadwood_treeid
    description = fields.FIELD["treeid"].las[0].description
    rule = re.fullmatch(r"tree model; deadwood max\((\d+),N\+1\)", description)
    assert rule, description
    models = (0, 5, 10, 11, 12, 65_534)
    assert [max(int(rule[1]), n + 1) for n in models] == [_deadwood_treeid(n) for n in models] \
        == [11, 11, 11, 12, 13, 65_535]


@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), OFFSET])
def test_written_headers_list_exactly_the_schema_fields(tmp_path, offset):
    formats = ("pcd", "las", "laz", "copc") if HAS_COPC else ("pcd", "las", "laz")
    files = _write(tmp_path, offset, formats)
    header = _pcd_header(files[".pcd"])
    size = GOLDEN_PCD["SIZE"] if not any(offset) else GOLDEN_PCD_GEOREFERENCED_SIZE
    assert (header["FIELDS"], header["SIZE"], header["TYPE"]) == (GOLDEN_PCD["FIELDS"], size, GOLDEN_PCD["TYPE"])
    assert read_pcd(files[".pcd"]).dtype.names == RECORD_DTYPE.names
    for suffix in (".las", ".laz", ".copc.laz")[:3 if HAS_COPC else 2]:
        assert _las_extra(files[suffix]) == GOLDEN_LAS_EXTRA, suffix
        with laspy.open(str(files[suffix])) as f:
            held = set(f.header.point_format.dimension_names)
        assert held == set(laspy.PointFormat(6).dimension_names) | {name for name, _, _ in GOLDEN_LAS_EXTRA}
        assert {d.name for f in LAS_FIELDS for d in f.las} <= held
        assert read_las_points(files[suffix]).dtype.names == tuple(f.name for f in LAS_FIELDS)


@pytest.mark.parametrize("suffix", [".las", ".pcd"])
def test_tiles_cut_from_a_plot_keep_the_schema_fields(tmp_path, suffix):
    """A tile's file (dataset/files.py) holds the fields of the plot's file it was cut from."""
    from mitsuforest.dataset.files import read_plot_points
    from mitsuforest.write.formats import write_points
    files = _write(tmp_path / "plot", OFFSET, ("pcd", "las"))
    fmt = suffix.lstrip(".")
    points = read_plot_points(files[suffix].parent, files[suffix].stem, [fmt])
    tile = tmp_path / f"tile{suffix}"
    write_points(tile, points[::3], OFFSET, None, None)
    if suffix == ".pcd":
        assert read_pcd(tile).dtype.names == RECORD_DTYPE.names
    else:
        assert _las_extra(tile) == GOLDEN_LAS_EXTRA
        assert read_las_points(tile).dtype.names == tuple(f.name for f in LAS_FIELDS)


def test_each_field_comes_back_from_the_las_file_as_written(tmp_path):
    """Both ways of every LAS mapping: coordinates to the 0.1 mm grid, scan angles to 0.006°,
    return numbers above 15 as 15, the rest exact; a field the points lack reads its ``missing``."""
    points = _points()
    for axis, o in zip("xyz", OFFSET):
        points[axis] += o
    write_las(tmp_path / "p.laz", points, OFFSET)
    read = read_las_points(tmp_path / "p.laz")
    tolerance = {"x": 5e-5 + 1e-9, "y": 5e-5 + 1e-9, "z": 5e-5 + 1e-9, "scan_angle": 0.003 + 1e-6}
    for f in LAS_FIELDS:
        if f.name == "height_above_ground":
            assert np.isnan(read[f.name]).all() and np.isnan(f.missing)     # points without one
            continue
        expected = points[f.name]
        if f.name in ("return_number", "number_of_returns"):
            expected = np.minimum(expected, 15)
        assert np.abs(read[f.name].astype(float) - expected.astype(float)).max() <= tolerance.get(f.name, 0), f.name
    assert (points["number_of_returns"] > 15).any()                   # the clip was exercised
    with laspy.open(str(tmp_path / "p.laz")) as f:
        las = f.read()
    from mitsuforest.write.las import ASPRS_CODE
    assert np.array_equal(las.classification, [ASPRS_CODE[c] for c in points["classification"]])


NEW_FIELD = '''    Field("echo_width", "<f4", "ns, the echo's width", las=(extra("echo_width", "<f4", "ns, echo width", 8),)),
'''
ADD_A_FIELD = '''
import importlib.util, json, sys
spec = importlib.util.spec_from_file_location("mitsuforest.fields", sys.argv[1])
sys.modules["mitsuforest.fields"] = fields = importlib.util.module_from_spec(spec)
spec.loader.exec_module(fields)
import numpy as np
from pathlib import Path
from mitsuforest.config import load_scene
from mitsuforest.write import PointWriter, Staging, read_pcd
from mitsuforest.write.las import read_las_points
scene = load_scene(Path("scenes/demo.yaml")).with_({"output.formats": ["pcd", "las"]})
points = np.zeros(100, fields.POINT_DTYPE)
points["x"], points["number_of_returns"], points["echo_width"] = 5.0, 1, np.arange(100) / 8
staging = Staging(Path(sys.argv[2]), "demo")
writer = PointWriter(staging, scene, threads=1)
writer.add(points)
writer.close()
pcd = read_pcd(staging.path / "demo.pcd")
las = read_las_points(staging.path / "demo.las")
print(json.dumps({"pcd": pcd.dtype.names, "las": las.dtype.names,
                  "pcd_values": pcd["echo_width"].tolist(), "las_values": las["echo_width"].tolist()}))
'''


def test_a_new_field_is_one_entry(tmp_path):
    """One line added to FIELDS (a scan field with an extra-bytes dimension) and nothing else: the scan's
    POINT_DTYPE, the PCD, the LAS file and its reader all carry it, with its values."""
    import json
    import subprocess
    import sys
    source = (ROOT / "mitsuforest" / "fields.py").read_text()
    anchor = '    Field("height_above_ground"'
    assert source.count(anchor) == 1
    patched = tmp_path / "fields.py"
    patched.write_text(source.replace(anchor, NEW_FIELD + anchor))
    run = subprocess.run([sys.executable, "-c", ADD_A_FIELD, str(patched), str(tmp_path / "out")], cwd=ROOT,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout.splitlines()[-1])
    names = GOLDEN_PCD["FIELDS"].split()
    assert out["pcd"] == [*names[:-1], "echo_width", names[-1]]
    assert out["las"] == [n for n in out["pcd"] if n not in GOLDEN_PCD_ONLY]
    assert out["pcd_values"] == out["las_values"] == [i / 8 for i in range(100)]


def test_the_schema_imports_no_pipeline_stage():
    """scan/ builds its points from the schema and write/ reads it: it imports neither (nor any stage)."""
    import ast
    tree = ast.parse((ROOT / "mitsuforest" / "fields.py").read_text())
    imported = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    imported |= {n.module or "." for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    assert imported == {"__future__", "dataclasses", "numpy"}
