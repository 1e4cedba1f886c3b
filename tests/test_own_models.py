"""Imported trees (forest.models): meshes and QSMs, repaired, labelled, with exact wood volume."""

import numpy as np
import pytest
from helpers import ROOT, scene_file, write_obj

from mitsuforest.cli import main
from mitsuforest.classes import TREE_LEAVES, TREE_WOOD
from mitsuforest.config import load_scene
from mitsuforest.trees.cache import cache_dir
from mitsuforest.trees.imported import imported_model, mesh_tree_model, qsm_tree_model
from mitsuforest.specs.sources import MeshTree, ModelFileError, QsmTree
from mitsuforest.trees.tubes import tube


def cylinder(start, end, radius, sides=32):
    """A closed n-gon prism whose volume is exactly π r² h (radii area-corrected, see trees/tubes.py)."""
    return tube(np.array([start, end], float), np.array([radius, radius]), sides)


def without_end_cap(mesh, sides=32):
    v, f = mesh
    return v[:-1], f[:-sides]   # the end cap is the last `sides` faces around the last vertex


def leaf_sheet(z, size=3.0, centre=(0.0, 0.0)):
    (x, y), h = centre, size / 2
    v = np.array([[x - h, y - h, z], [x + h, y - h, z], [x + h, y + h, z], [x - h, y + h, z]])
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def test_cylinder_with_a_missing_cap_repairs_to_its_exact_volume(tmp_path):
    start, end, r = np.array([1e5, -2e5, 30.0]), np.array([1e5 + 0.4, -2e5 - 0.3, 33.0]), 0.15
    path = write_obj(tmp_path / "open.obj", {"stem": (*without_end_cap(cylinder(start, end, r)), "bark")})
    model = mesh_tree_model(MeshTree(mesh=str(path), leaves=()), "t")
    exact = np.pi * r * r * np.linalg.norm(end - start)
    assert model.volume.union == pytest.approx(exact, rel=1e-6)
    assert model.volume.naive == pytest.approx(exact, rel=1e-6)
    (report,) = model.meta["repair"]
    assert report["action"] == "repaired" and report["holes"] == 1 and report["faces_removed"] == 0
    assert report["faces_after"] - report["faces_before"] == report["faces_added"] > 0
    assert np.isnan(report["volume_before"]) and report["volume_after"] == pytest.approx(exact, rel=1e-6)
    assert model.volume.repaired == 1 and model.volume.skipped == 0


def test_crossing_cylinders_union_to_the_steinmetz_value(tmp_path):
    """Two loose parts, cylinders of radius r crossing at right angles: the union loses 16 r³/3."""
    r, half = 0.1, 1.0
    a = cylinder([0, 0, 0], [0, 0, 2 * half], r, 128)
    b = cylinder([-half, 0, half], [half, 0, half], r, 128)
    path = write_obj(tmp_path / "cross.obj", {"a": (*a, "bark"), "b": (*b, "bark")})
    model = mesh_tree_model(MeshTree(mesh=str(path), leaves=()), "t")
    steinmetz = 16 * r ** 3 / 3
    assert model.volume.parts == 2 and model.meta["repair"] == []
    assert model.volume.naive == pytest.approx(2 * np.pi * r * r * 2 * half, rel=1e-12)
    # 128-gons, not circles: the intersection is within 0.1 % of the round one
    assert model.volume.naive - model.volume.union == pytest.approx(steinmetz, rel=1e-3)


def test_inward_facing_part_is_turned_round_not_subtracted(tmp_path):
    v, f = cylinder([0, 0, 0], [0, 0, 3], 0.2)
    bv, bf = cylinder([0.5, 0, 1], [1.5, 0, 2], 0.05)
    path = write_obj(tmp_path / "flip.obj", {"stem": (v, f, "bark"), "branch": (bv, bf[:, ::-1], "bark")})
    model = mesh_tree_model(MeshTree(mesh=str(path), leaves=()), "t")
    exact = np.pi * (0.04 * 3 + 0.0025 * np.sqrt(2))
    assert model.volume.union == pytest.approx(exact, rel=1e-9)
    (report,) = model.meta["repair"]
    assert report["action"] == "reoriented" and report["volume_before"] < 0 < report["volume_after"]


def qsm_text(rows, sep="\t"):
    header = ["radius (m)", "length (m)", "start_point", "", "", "axis_direction", "", "", "parent", "extension",
              "branch", "branch_order"]
    lines = [sep.join(header)] + [sep.join(f"{x:.17g}" for x in row) for row in rows]
    return "\n".join(lines) + "\n"


def test_qsm_gives_its_cylinder_sum_and_exact_union(tmp_path):
    """TreeQSM's layout: a stem of two stacked cylinders (touching: union = sum), a thinner leader that
    starts 0.5 m inside the stem's top (overlap π r² 0.5), and a branch off the side (no overlap)."""
    R, r, rb = 0.2, 0.08, 0.03
    rows = [[R, 2.0, 500000, 6000000, 10, 0, 0, 1, 0, 2, 1, 0],
            [R, 2.0, 500000, 6000000, 12, 0, 0, 1, 1, 3, 1, 0],
            [r, 3.0, 500000, 6000000, 13.5, 0, 0, 1, 2, 0, 2, 1],
            [rb, 1.0, 500000 + 0.5, 6000000, 15, 1, 0, 0, 3, 0, 3, 2]]
    path = tmp_path / "tree.txt"
    path.write_text(qsm_text(rows))
    model = qsm_tree_model(QsmTree(qsm=str(path), leaf_area=2.0), "q")
    cylinder_sum = np.pi * (R * R * 4.0 + r * r * 3.0 + rb * rb * 1.0)
    assert model.volume.analytic == pytest.approx(cylinder_sum, rel=1e-12)
    assert model.volume.naive == pytest.approx(cylinder_sum, rel=1e-12)
    assert model.volume.union == pytest.approx(cylinder_sum - np.pi * r * r * 0.5, rel=1e-9)
    assert [c.kind for c in model.components] == ["stem", "branch", "branch", "leaves"]
    assert model.meta["height"] == pytest.approx(6.5)   # the base moved to the origin
    wood, leaves = model.parts
    assert set(np.unique(wood.component)) == {0, 1, 2} and set(np.unique(leaves.component)) == {3}
    assert 2.0 / (0.5 * 0.13 * 0.025) == pytest.approx(len(leaves.faces) / 2, abs=1)   # the leaf area
    tips = leaves.vertices[:, 2]
    assert tips.min() > 4.0   # leaves hang on the terminal branches (leader and side branch)


def test_qsm_csv_with_end_points_and_ids(tmp_path):
    path = tmp_path / "q.csv"
    path.write_text("ID,ParentID,Radius,StartX,StartY,StartZ,EndX,EndY,EndZ\n"
                    "7,0,0.1,0,0,0,0,0,2\n8,7,0.05,0,0,2,1,0,2\n")
    model = qsm_tree_model(QsmTree(qsm=str(path), leaf_area=0), "q")
    assert model.volume.analytic == pytest.approx(np.pi * (0.01 * 2 + 0.0025), rel=1e-12)
    assert len(model.parts) == 1 and [c.kind for c in model.components] == ["stem"]


QSM_UNITS = {   # a header naming its columns' units, the entry's units, and the cylinders in metres: a 1.2 m
    # sapling of radius 2 cm and a 0.4 m branch of radius 1 cm clear of it (union = cylinder sum)
    "all in cm": ("radius (cm),start_x (cm),start_y (cm),start_z (cm),end_x (cm),end_y (cm),end_z (cm)\n"
                  "2,0,0,0,0,0,120\n1,5,0,60,45,0,60\n", "m"),
    "radius in cm, points in m": ("Radius [cm],StartX,StartY,StartZ,EndX,EndY,EndZ\n2,0,0,0,0,0,1.2\n"
                                  "1,0.05,0,0.6,0.45,0,0.6\n", "m"),
    "TreeQSM's (m), units m": ("radius (m)\tlength (m)\tstart_point\t\t\taxis_direction\t\t\n"
                               "0.02\t1.2\t0\t0\t0\t0\t0\t1\n0.01\t0.4\t0.05\t0\t0.6\t1\t0\t0\n", "m"),
    "no unit named: units": ("radius,start_x,start_y,start_z,end_x,end_y,end_z\n20,0,0,0,0,0,1200\n"
                             "10,50,0,600,450,0,600\n", "mm"),
}


@pytest.mark.parametrize("case", QSM_UNITS)
def test_qsm_columns_are_read_in_the_unit_their_header_names(tmp_path, case):
    """A header cell's unit, (cm) or [mm], is that column's unit; ``units`` is that of the columns naming none.
    Before, the unit was dropped with the rest of the suffix: a sapling in cm stood 120 m tall with 2 m radii
    (within the height and radius checks), 10⁶ times its wood, silently."""
    text, units = QSM_UNITS[case]
    path = tmp_path / "q.txt"
    path.write_text(text)
    model = qsm_tree_model(QsmTree(qsm=str(path), units=units, leaf_area=0), "q")
    assert model.meta["height"] == pytest.approx(1.2, rel=1e-12)
    assert model.volume.analytic == pytest.approx(np.pi * (0.02 ** 2 * 1.2 + 0.01 ** 2 * 0.4), rel=1e-12)
    assert model.volume.union == pytest.approx(model.volume.analytic, rel=1e-9)


def test_qsm_units_that_contradict_the_header_are_refused(tmp_path):
    """TreeQSM names metres on its radius and length but not on its start point: with units: cm these were
    read in cm (start points, 100 times too close) and in m, a tree of mixed units."""
    path = tmp_path / "q.txt"
    path.write_text(QSM_UNITS["TreeQSM's (m), units m"][0])
    with pytest.raises(ModelFileError, match=r"q\.txt: units: the header gives radius in m, length in m, but units: "
                                             r"cm; .*drop units, or the header's unit"):
        qsm_tree_model(QsmTree(qsm=str(path), units="cm", leaf_area=0), "q")


@pytest.mark.parametrize("encoding", ["cp1252", "utf-16", "utf-8-sig"])
def test_qsm_table_saved_by_windows_tools_reads_as_utf8(tmp_path, encoding):
    """A MATLAB or spreadsheet export on Windows: single-byte text with an accented comment, UTF-16 with
    its byte order mark, or UTF-8 with one, CRLF line ends: the same cylinders as plain UTF-8."""
    path = tmp_path / "q.csv"
    path.write_bytes("# Kiefer, gemessen im März\r\nradius,start_x,start_y,start_z,end_x,end_y,end_z\r\n"
                     "0.1,0,0,0,0,0,2\r\n".encode(encoding))
    model = qsm_tree_model(QsmTree(qsm=str(path), leaf_area=0), "q")
    assert model.volume.analytic == pytest.approx(np.pi * 0.01 * 2, rel=1e-12)


BAD_TABLES = {   # the file's text, and the error: its real line (comments and blank lines counted)
    "negative length": ("# exported by hand\n\nradius,length,start_x,start_y,start_z,axis_x,axis_y,axis_z\n"
                        "0.1,2,0,0,0,0,0,1\n\n0.05,-1,0,0,2,0,0,1\n", "line 6: length -1 is not positive"),
    "zero radii": ("radius,start_x,start_y,start_z,end_x,end_y,end_z\n# stem\n0,0,0,0,0,0,1\n0,0,0,1,0,0,2\n",
                   "line 3: radius 0 is not positive (1 more cylinders like it)"),
    "one zero radius": ("radius,start_x,start_y,start_z,end_x,end_y,end_z\n0.1,0,0,0,0,0,1\n0,0,0,1,0,0,2\n",
                        "line 3: radius 0 is not positive"),
    "no header": ("# TreeQSM cylinder export\n# in metres\n0.1 2 0 0 0 0 0 1 0 0 1 0 9 9\n"
                  "0.1 2 0 0 2 0 0 x 1 0 1 0\n", "line 4: not a number in '0.1 2 0 0 2 0 0 x 1 0 1 0'"),
    "nan radius": ("# by hand\nradius,length,start_x,start_y,start_z,axis_x,axis_y,axis_z\n0.1,2,0,0,0,0,0,1\n\n"
                   "nan,1,0,0,2,0,0,1\n", "line 5: a value is not finite"),
    "inf axis": ("radius start_x start_y start_z end_x end_y end_z\n# stem\n0.1 0 0 0 0 0 inf\n",
                 "line 3: a value is not finite"),
    "a coordinate of 1e308": ("radius,start_x,start_y,start_z,end_x,end_y,end_z\n0.1,0,0,0,0,0,1\n0.1,0,1e308,1,0,0,2\n",
                              "line 3: start_y 1e+308 is beyond ±1e+09: no tree's size or coordinate (even in millimetres on a "
                              "map grid)"),   # was numpy's overflow warnings, then "the tree is 1e+308 m tall"
    "long row": ("radius,start_x,start_y,start_z,end_x,end_y,end_z\n0.1,0,0,0,0,0,1,7\n",
                 "line 2: 8 values, the header names 7 columns"),
    "binary": (b"MATLAB 5.0 MAT-file\x00\xff\xfe\x80", "not a text table (a binary file; TreeQSM's .mat models"),
    "a quantity twice": ("radius,start_x,start_y,start_z,end_x,end_y,end_z,r\n0.1,0,0,0,0,0,2,0.3\n",
                         "columns 1 and 8 both give radius; keep one"),
    "semicolons": ("radius;start_x;start_y;start_z;end_x;end_y;end_z\n0,1;0;0;0;0;0;2\n",
                   "the cylinder table is separated by ';' (a spreadsheet set to decimal commas)"),
    "absurd radius": ("radius,start_x,start_y,start_z,end_x,end_y,end_z\n0.1,0,0,0,0,0,1\n# top\n1e9,0,0,1,0,0,2\n",
                      "line 4: radius 1e+09 m with units: m is wider than any tree (at most 10 m); check units"),
    "fractional branch": ("radius,start_x,start_y,start_z,end_x,end_y,end_z,branch\n0.2,0,0,0,0,0,3,1\n"
                          "0.1,0,0,3,0,0,6,1.5\n", "line 3: branch 1.5 is not a whole number"),
    "huge parent": ("radius,start_x,start_y,start_z,end_x,end_y,end_z,parent\n0.2,0,0,0,0,0,3,1e30\n",
                    "line 2: parent 1e+30 is not a whole number"),
    "own parent": ("radius,start_x,start_y,start_z,end_x,end_y,end_z,id,parent\n0.2,0,0,0,0,0,3,1,0\n"
                   "# top\n0.1,0,0,3,0,0,6,2,2\n", "line 4: the cylinder is its own ancestor (the parent ids go round "
                   "in a loop); check the parent and id columns"),
    "parent loop": ("radius,start_x,start_y,start_z,end_x,end_y,end_z,id,parent\n0.2,0,0,0,0,0,3,1,0\n"
                    "0.1,0,0,3,0,0,6,2,4\n0.1,0,0,6,0,0,7,3,2\n0.1,0,0,7,0,0,8,4,3\n",
                    "line 4: the cylinder is its own ancestor (the parent ids go round in a loop); check the parent "
                    "and id columns"),
}


@pytest.mark.parametrize("case", sorted(BAD_TABLES))
def test_bad_qsm_table_names_its_real_line(case, tmp_path):
    text, message = BAD_TABLES[case]
    path = tmp_path / "q.csv"
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    with pytest.raises(ModelFileError) as e:
        qsm_tree_model(QsmTree(qsm=str(path), leaf_area=0), "q")
    if message.startswith("line"):
        assert f"{e.value.key}: {e.value.reason}" == message
    else:
        assert e.value.reason.startswith(message)


def test_qsm_whose_branches_all_grow_from_each_other_is_refused_for_leaves(tmp_path):
    """Cylinder 2 (branch 1) grows from cylinder 3 (branch 2), which grows from the stem (branch 1): a tree of
    cylinders, but no branch is a tip; the leaves had no twig (a ValueError from numpy)."""
    path = tmp_path / "q.csv"
    path.write_text("radius,start_x,start_y,start_z,end_x,end_y,end_z,id,parent,branch\n0.2,0,0,0,0,0,3,1,0,1\n"
                    "0.1,0,0,3,0,0,6,2,3,1\n0.1,0,0,3,1,0,4,3,1,2\n")
    with pytest.raises(ModelFileError) as e:
        qsm_tree_model(QsmTree(qsm=str(path)), "q")
    assert f"{e.value.key}: {e.value.reason}" == ("branch: every branch grows from another, so no branch ends in a tip "
                                                  "to carry leaves; check the branch column, or give leaf_area: 0")
    assert len(qsm_tree_model(QsmTree(qsm=str(path), leaf_area=0), "q").parts) == 1


def test_qsm_listed_top_down_stands_on_the_ground(tmp_path):
    """A stem whose cylinders run from top to bottom: the base is the lowest end, not the lowest start."""
    down = tmp_path / "down.csv"
    down.write_text("radius,start_x,start_y,start_z,end_x,end_y,end_z\n0.1,5,5,14,5,5,12\n0.15,5,5,12,5,5,10\n")
    up = tmp_path / "up.csv"
    up.write_text("radius,start_x,start_y,start_z,end_x,end_y,end_z\n0.15,5,5,10,5,5,12\n0.1,5,5,12,5,5,14\n")
    for path in (down, up):
        model = qsm_tree_model(QsmTree(qsm=str(path), leaf_area=0), "q")
        wood = model.parts[0].vertices
        assert wood[:, 2].min() == pytest.approx(0.0, abs=1e-9) and wood[:, 2].max() == pytest.approx(4.0)
        assert np.abs(wood[:, :2]).max() <= 0.15 * 1.1   # centred on the stem axis
        assert model.meta["height"] == pytest.approx(4.0)
        assert model.volume.analytic == pytest.approx(np.pi * (0.01 + 0.0225) * 2, rel=1e-12)


def test_y_up_obj_in_centimetres_stands_upright_at_its_height(tmp_path):
    stem = cylinder([0, 0, 0], [0, 0, 12.0], 0.25)
    branch = cylinder([0, 0, 6.0], [3.0, 0, 9.0], 0.05)
    crown = leaf_sheet(11.0)
    path = write_obj(tmp_path / "yup.obj", {"trunk": (*stem, "Bark"), "branch": (*branch, "Bark"),
                                           "crown": (*crown, "Leaf")}, scale=100, y_up=True)
    model = mesh_tree_model(MeshTree(mesh=str(path), units="cm", up="y"), "t")
    wood, leaves = model.parts
    assert model.meta["height"] == pytest.approx(12.0, rel=1e-12)
    assert wood.vertices[:, 2].min() == pytest.approx(0.0, abs=1e-12)
    top = wood.vertices[wood.vertices[:, 2] > 12.0 - 1e-9]
    assert np.abs(top[:, :2]).max() < 0.3    # the stem's top is above its base
    assert leaves.vertices[:, 2] == pytest.approx(np.full(4, 11.0))
    assert model.volume.union == pytest.approx(np.pi * (0.0625 * 12 + 0.0025 * np.sqrt(18)) - _inside(0.25, 0.05),
                                               rel=1e-3)
    with pytest.raises(ModelFileError, match="1,200 m tall with units: m and up: y.*check units"):
        mesh_tree_model(MeshTree(mesh=str(path), units="m", up="y"), "t")


def test_a_tree_read_with_the_wrong_up_axis_is_warned_of_as_lying_on_its_side(tmp_path, caplog):
    """The stem leans 0° read with its file's up axis and 90° with the other: the second is warned of
    once, naming the file and the up axis it was given."""
    import logging
    stem = cylinder([0, 0, 0], [0, 0, 12.0], 0.25)
    branch = cylinder([0, 0, 6.0], [3.0, 0, 9.0], 0.05)
    path = write_obj(tmp_path / "yup.obj", {"trunk": (*stem, "Bark"), "branch": (*branch, "Bark")}, scale=100,
                     y_up=True)
    upright = imported_model(MeshTree(mesh=str(path), units="cm", up="y", leaves=()), "t")
    assert upright.meta["stem_lean_deg"] < 1.0 and "lie on its side" not in caplog.text
    with caplog.at_level(logging.WARNING):
        lying = imported_model(MeshTree(mesh=str(path), units="cm", up="z", leaves=()), "t")
        imported_model(MeshTree(mesh=str(path), units="cm", up="z", leaves=()), "t")
    assert lying.meta["stem_lean_deg"] > 89.0
    assert caplog.text.count("yup.obj: the wood's lowest quarter runs 90° from up: does the tree lie on its side? "
                             "Check up (z or y; it is z)") == 1


def test_a_stem_given_twice_in_the_file_is_one_closed_part(tmp_path):
    """An exporter's duplicate of a closed stem (same vertices, same faces) made one non-manifold part
    after merging vertices, refused as 'a flat sheet such as a leaf'; the copy's faces are dropped."""
    stem = cylinder([0, 0, 0], [0, 0, 6.0], 0.2)
    path = write_obj(tmp_path / "twice.obj", {"trunk": (*stem, "Bark"), "trunk_copy": (*stem, "Bark")})
    model = mesh_tree_model(MeshTree(mesh=str(path), leaves=()), "t")
    assert model.volume.parts == 1 and model.volume.repaired == 0
    assert model.volume.union == pytest.approx(np.pi * 0.04 * 6.0, rel=1e-9)


def _inside(R, r):
    """Volume of a thin branch leaving a stem's axis at 45° that lies inside the stem (to first order)."""
    return np.pi * r * r * R * np.sqrt(2)


def test_unrepairable_part_is_an_error_or_skipped(tmp_path, caplog):
    stem = cylinder([0, 0, 0], [0, 0, 5.0], 0.2)
    sheet = leaf_sheet(3.0, 0.5, (2.0, 0.0))
    path = write_obj(tmp_path / "t.obj", {"stem": (*stem, "bark"), "flat": (*sheet, "bark")})
    with pytest.raises(ModelFileError, match=r"t\.obj: part 2: 2 faces, 1 hole: .*repair: skip"):
        mesh_tree_model(MeshTree(mesh=str(path), leaves=()), "t")
    model = imported_model(MeshTree(mesh=str(path), leaves=(), repair="skip"), "t")
    assert model.volume.union == pytest.approx(np.pi * 0.04 * 5, rel=1e-9)
    assert model.volume.skipped == 1 and model.volume.parts == 1
    (report,) = model.meta["repair"]
    assert report["action"] == "skipped" and report["part"] == 2
    assert "part 2" in caplog.text and "repair: skip" in caplog.text
    assert len(model.components) == 2    # a skipped part is still scanned, with its own object id


def test_import_report_gives_none_for_undefined_volumes(tmp_path):
    """A mesh has no cylinder sum and a skipped open part no volume: the manifest's report (also the
    ``result.manifest`` a caller gets) says None, not nan, so it is JSON as it stands."""
    import json
    from types import SimpleNamespace

    from mitsuforest.write.manifest import import_report
    path = write_obj(tmp_path / "t.obj", {"stem": (*cylinder([0, 0, 0], [0, 0, 5.0], 0.2), "bark"),
                                          "flat": (*leaf_sheet(3.0, 0.5, (2.0, 0.0)), "bark")})
    entry = MeshTree(mesh=str(path), leaves=(), repair="skip")
    plan = SimpleNamespace(models={"tree01": SimpleNamespace(source=entry)})
    report = import_report(plan, {"tree01": imported_model(entry, "tree01")})["tree01"]
    assert report["volume_m3"]["analytic"] is None
    assert report["volume_m3"]["union"] == pytest.approx(np.pi * 0.04 * 5, rel=1e-9)
    (repair,) = report["repair"]
    assert repair["action"] == "skipped" and repair["volume_before"] is None and repair["volume_after"] is None
    json.dumps(report, allow_nan=False)


def test_cache_is_keyed_on_the_file_content(tmp_path):
    stem = cylinder([0, 0, 0], [0, 0, 5.0], 0.2)
    path = write_obj(tmp_path / "c.obj", {"stem": (*stem, "bark"), "leaves": (*leaf_sheet(4.0), "leaf")})
    entries = lambda: set(cache_dir().glob("mesh_tree-*.npz"))  # noqa: E731
    before = entries()
    first = imported_model(MeshTree(mesh=str(path)), "a")
    added = entries() - before
    assert len(added) == 1
    moved = tmp_path / "elsewhere.obj"
    moved.write_bytes(path.read_bytes())
    (tmp_path / "elsewhere.mtl").write_bytes(path.with_suffix(".mtl").read_bytes())
    again = imported_model(MeshTree(mesh=str(moved)), "b")
    assert entries() - before == added and again.volume.union == first.volume.union
    assert (first.meta["source"], again.meta["source"]) == ("c.obj", "elsewhere.obj")   # each its own file
    mtl = path.with_suffix(".mtl")
    mtl.write_text(mtl.read_text().replace("newmtl leaf", "newmtl foliage"))   # material names pick leaves
    imported_model(MeshTree(mesh=str(path)), "a")
    assert len(entries() - before) == 2                                           # so an edit is a new model
    write_obj(path, {"stem": (*cylinder([0, 0, 0], [0, 0, 6.0], 0.2), "bark"), "leaves": (*leaf_sheet(4.0), "leaf")})
    changed = imported_model(MeshTree(mesh=str(path)), "a")
    assert len(entries() - before) == 3
    assert changed.volume.union == pytest.approx(np.pi * 0.04 * 6, rel=1e-9)


def _tree_scene(tmp_path, model, **forest):
    return scene_file(tmp_path, area={"size": [4, 4]},
                      forest={"trees": 1, "archetypes": [], "models": [model], "min_spacing": 0, "tilt": 0, **forest},
                      survey={"altitude": 30, "speed": 4, "pulse_frequency": 100000, "lines": [[[2, -6], [2, 10]]]})


def test_bark_and_leaf_materials_become_wood_and_leaf_points_with_the_tree_ids(tmp_path):
    from mitsuforest.pipeline import render
    stem = cylinder([0, 0, 0], [0, 0, 10.0], 0.3)
    branch = cylinder([0, 0, 5.0], [1.2, 0, 7.0], 0.08)
    write_obj(tmp_path / "tree.obj", {"stem": (*stem, "bark"), "limb": (*branch, "bark"),
                                  "canopy": (*leaf_sheet(8.0, 2.0, (-1.0, 0)), "leaf")})
    scene = load_scene(_tree_scene(tmp_path, {"mesh": "tree.obj", "leaves": ["leaf"]}))
    result = render(scene, write=True, keep_points=True, progress=False, log=lambda *_: None)
    (tree,) = result.plan.trees
    assert tree.treeid == 1 and tree.components == 3   # stem, limb, leaves
    p = result.points
    on_tree = p["instance"] == tree.instance
    assert set(np.unique(p["classification"][on_tree])) == {TREE_WOOD, TREE_LEAVES}
    assert np.all(p["treeid"][on_tree] == 1) and np.all(p["treeid"][~on_tree] == 0)
    wood, leaves = on_tree & (p["classification"] == TREE_WOOD), on_tree & (p["classification"] == TREE_LEAVES)
    assert set(np.unique(p["object_id"][wood])) <= {tree.object_id, tree.object_id + 1}
    assert tree.object_id in p["object_id"][wood]
    assert np.all(p["object_id"][leaves] == tree.object_id + 2)
    assert np.allclose(p["z"][leaves] - result.plan.terrain.height(*tree.position[:2]), 8.0 - 0.05, atol=0.01)
    out = result.scene.output.dir
    ids = (tmp_path / "out" / "test_ids.csv").read_text().splitlines()
    assert ids[0].endswith(",source") and sum(r.endswith(",tree.obj") for r in ids) == 3
    assert any(r.startswith(f"{tree.object_id + 2},{tree.instance},1,{TREE_LEAVES},leaves,tree01,") for r in ids)
    volumes = (tmp_path / "out" / "test_volumes.csv").read_text().splitlines()
    assert volumes[0].endswith(",source,parts_repaired,parts_skipped") and out
    row = next(r.split(",") for r in volumes if r.startswith("tree,"))
    assert row[4] == "" and row[-3:] == ["tree.obj", "0", "0"]   # no analytic volume for a mesh
    limb, sine = np.hypot(1.2, 2.0), 1.2 / np.hypot(1.2, 2.0)    # the limb's first 0.3 / sine m are inside the stem
    assert float(row[3]) == pytest.approx(np.pi * (0.09 * 10 + 0.0064 * (limb - 0.3 / sine)), rel=1e-3)
    import json

    def refuse(constant):
        raise ValueError(f"{constant} is not JSON")
    manifest = json.loads((tmp_path / "out" / "test_manifest.json").read_text(), parse_constant=refuse)
    report = manifest["imported_trees"]["tree01"]["volume_m3"]
    assert report["analytic"] is None and report["union"] == pytest.approx(float(row[3]), rel=1e-6)


def test_models_come_after_the_archetypes_in_treeid_and_deadwood_moves_past_them(tmp_path):
    from mitsuforest.survey import make_plan
    stem = cylinder([0, 0, 0], [0, 0, 8.0], 0.2)
    write_obj(tmp_path / "a.obj", {"stem": (*stem, "bark"), "leaves": (*leaf_sheet(7.0), "leaf")})
    models = [{"mesh": "a.obj", "weight": 5}] * 2
    path = scene_file(tmp_path, area={"size": [30, 30]}, forest={"trees": 12, "min_spacing": 2, "models": models},
                      understory={"deadwood": 2, "bushes": 0, "rocks": 0, "stumps": 0})
    plan = make_plan(load_scene(path))
    assert sorted(n for n in plan.models if n.startswith("tree")) == [f"tree{i:02d}" for i in range(1, 13)]
    assert plan.models["tree11"].source.mesh == str(tmp_path / "a.obj") and plan.models["tree10"].source is None
    assert {o.treeid for o in plan.trees if o.model in ("tree11", "tree12")} == {11, 12}
    assert all(o.treeid == int(o.model[4:]) for o in plan.trees)
    assert {o.treeid for o in plan.objects if o.kind == "deadwood"} == {13}


@pytest.mark.parametrize("case, model, message", [
    ("missing", {"mesh": "nowhere.obj"}, "forest.models[0].mesh: file not found"),
    ("unreadable", {"mesh": "junk.glb"}, "junk.glb: cannot read the mesh"),
    ("no leaves", {"mesh": "tree.obj", "leaves": ["*needle*"]}, "tree.obj: leaves: the patterns ['*needle*'] match no piece"),
    ("all leaves", {"mesh": "tree.obj", "leaves": ["*"]}, "tree.obj: leaves: the patterns ['*'] match every piece"),
    ("three km", {"mesh": "tree.obj", "units": "m", "up": "y"}, "tree.obj: units: the tree is 1,000 m tall"),
    ("columns", {"qsm": "cols.csv"}, "cols.csv: no start_x, start_y, start_z column"),
    ("radius", {"qsm": "neg.csv"}, "neg.csv: line 3: radius -0.05 is not positive"),
    ("two kinds", {"mesh": "tree.obj", "qsm": "neg.csv"}, "forest.models[0]: give exactly one of mesh:"),
    ("bad units", {"mesh": "tree.obj", "units": "ft"}, "forest.models[0].units: must be one of m, cm, mm"),
    ("nan vertex", {"mesh": "nan.obj"}, "nan.obj: piece 'stem': a vertex is not finite, the first at (0, 1, nan)"),
    ("a folder", {"mesh": "."}, "forest.models[0].mesh: not a file (a folder): "),
    ("JSON, not glTF", {"mesh": "list.gltf"}, "list.gltf: cannot read the mesh"),
    ("glTF buffer uri not text", {"mesh": "uri.gltf"}, "uri.gltf: cannot read the mesh"),
    ("no mtl", {"mesh": "nomtl.obj"}, "match no piece (pieces and materials: crown_crown, stem_stem); the material "
                                      "file nomtl.mtl is missing, so material names are unknown"),
])
def test_bad_model_input_is_one_line_exit_2_and_nothing_written(tmp_path, capsys, case, model, message):
    write_obj(tmp_path / "tree.obj", {"stem": (*cylinder([0, 0, 0], [0, 0, 10.0], 0.2), "bark"),
                                      "leaves": (*leaf_sheet(9.0), "leaf")}, scale=100, y_up=True)
    (tmp_path / "junk.glb").write_bytes(b"glTF not really")
    (tmp_path / "list.gltf").write_text("[1, 2]")   # read for its buffers' names before the mesh reader sees it
    (tmp_path / "uri.gltf").write_text('{"buffers": [{"uri": 5}]}')
    write_obj(tmp_path / "nomtl.obj", {"stem": (*cylinder([0, 0, 0], [0, 0, 10.0], 0.2), "bark"),
                                       "crown": (*leaf_sheet(9.0), "leaf")}, scale=100, y_up=True)
    (tmp_path / "nomtl.mtl").unlink()
    (tmp_path / "nan.obj").write_text("o stem\nv 0 0 0\nv 1 0 0\nv 0 1 nan\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    (tmp_path / "cols.csv").write_text("radius,length\n0.1,2\n")
    (tmp_path / "neg.csv").write_text("radius,start_x,start_y,start_z,end_x,end_y,end_z\n"
                                      "0.1,0,0,0,0,0,1\n-0.05,0,0,1,0,0,2\n")
    model = {"units": "cm", "up": "y", **model} if "mesh" in model else model
    path = _tree_scene(tmp_path, model)
    out = tmp_path / "result"
    assert main(["render", str(path), "-o", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and message in err and "Traceback" not in err, err
    assert not out.exists()


def test_trees_command_shows_imported_models(tmp_path):
    write_obj(tmp_path / "tree.obj", {"stem": (*without_end_cap(cylinder([0, 0, 0], [0, 0, 6.0], 0.2)), "bark"),
                                      "leaves": (*leaf_sheet(5.0), "leaf")})
    path = _tree_scene(tmp_path, {"mesh": "tree.obj"}, archetypes=[{"base": 4}])
    assert main(["trees", "--scene", str(path), "-o", str(tmp_path / "g")]) == 0
    names = sorted(p.name for p in (tmp_path / "g").iterdir())
    assert names == ["repairs.csv", "tree01_leaves.ply", "tree01_wood.ply", "tree02_leaves.ply", "tree02_wood.ply",
                     "trees.png", "volumes.csv"]
    rows = (tmp_path / "g" / "volumes.csv").read_text().splitlines()
    assert rows[2].startswith("tree02,6,,") and rows[2].endswith(",tree.obj,1,0")
    repairs = (tmp_path / "g" / "repairs.csv").read_text().splitlines()
    assert repairs[1].startswith("tree02,tree.obj,1,stem_stem_bark,repaired,96,126,1,0,30,,0.75398")
    before = {p.name: p.read_bytes() for p in (tmp_path / "g").iterdir()}
    (tmp_path / "bad.csv").write_text("radius,start_x,start_y,start_z,end_x,end_y,end_z\n-1,0,0,0,0,0,1\n")
    bad = _tree_scene(tmp_path, {"qsm": "bad.csv"}, archetypes=[{"base": 4}])
    for folder in ("g", "fresh"):   # a model that cannot be built writes nothing, not even the folder
        assert main(["trees", "--scene", str(bad), "-o", str(tmp_path / folder)]) == 2
    assert {p.name: p.read_bytes() for p in (tmp_path / "g").iterdir()} == before
    assert not (tmp_path / "fresh").exists()
    one = scene_file(tmp_path, forest={"trees": 1, "archetypes": [{"base": 2}]})
    assert main(["trees", "--scene", str(one), "-o", str(tmp_path / "g")]) == 0
    assert sorted(p.name for p in (tmp_path / "g").iterdir()) == [   # the earlier gallery's files are gone
        "tree01_leaves.ply", "tree01_wood.ply", "trees.png", "volumes.csv"]


def test_scene_edits_keep_the_models(tmp_path):
    write_obj(tmp_path / "tree.obj", {"stem": (*cylinder([0, 0, 0], [0, 0, 6.0], 0.2), "bark")})
    scene = load_scene(_tree_scene(tmp_path, {"wood": "tree.obj", "weight": 2}))
    edited = scene.with_({"survey.altitude": 40})
    assert edited.forest.models == scene.forest.models == (MeshTree(wood=str(tmp_path / "tree.obj"), leaves=None,
                                                                     weight=2.0),)
    assert scene.describe()["forest"]["models"][0]["wood"] == str(tmp_path / "tree.obj")
    with pytest.raises(Exception, match="at least one archetype or model needs weight > 0"):
        scene.with_({"forest.models": [], "forest.archetypes": []})


def test_examples_data_qsm_reads(tmp_path):
    model = qsm_tree_model(QsmTree(qsm=str(ROOT / "examples" / "data" / "small_qsm.txt")), "q")
    assert 0 < model.volume.union <= model.volume.analytic


def test_glb_pieces_split_by_material_name(tmp_path):
    import trimesh
    from trimesh.visual.material import PBRMaterial
    stem = trimesh.creation.cylinder(radius=0.2, height=5.0, sections=32)
    stem.apply_translation([3.0, -2.0, 7.5])
    crown = trimesh.creation.box([2.0, 2.0, 0.01])
    crown.apply_translation([3.0, -2.0, 9.0])
    stem.visual = trimesh.visual.TextureVisuals(material=PBRMaterial(name="Bark"))
    crown.visual = trimesh.visual.TextureVisuals(material=PBRMaterial(name="Leaf"))
    scene = trimesh.Scene()
    scene.add_geometry(stem, geom_name="trunk")
    scene.add_geometry(crown, geom_name="crown")
    scene.export(tmp_path / "t.glb")
    model = mesh_tree_model(MeshTree(mesh=str(tmp_path / "t.glb"), leaves=("leaf",)), "g")
    prism = 32 / 2 * 0.2 ** 2 * np.sin(2 * np.pi / 32) * 5.0
    assert model.volume.union == pytest.approx(prism, rel=1e-6)   # glTF stores float32 positions
    assert [c.kind for c in model.components] == ["stem", "leaves"]
    assert model.parts[1].vertices[:, 2].min() == pytest.approx(9.0 - 0.005 - 5.0, abs=1e-6)


def test_the_cache_key_covers_the_files_a_mesh_reads(tmp_path):
    """A glTF's buffers and an OBJ's material libraries change the key; a missing one too, so a warm cache
    cannot accept what a cold one refuses; so does the file's kind (suffix)."""
    import json

    from mitsuforest.specs.sources import companion_files, content_hash
    gltf = tmp_path / "t.gltf"
    gltf.write_text(json.dumps({"buffers": [{"uri": "geo%20metry.bin"}, {"uri": "data:application/octet-stream;base64,AA=="}]}))
    (tmp_path / "geo metry.bin").write_bytes(b"\0" * 8)
    assert companion_files(gltf) == [tmp_path / "geo metry.bin"]
    key = content_hash([gltf])
    (tmp_path / "geo metry.bin").write_bytes(b"\1" * 8)
    edited = content_hash([gltf])
    (tmp_path / "geo metry.bin").unlink()
    assert len({key, edited, content_hash([gltf])}) == 3
    obj = write_obj(tmp_path / "c.obj", {"stem": (*cylinder([0, 0, 0], [0, 0, 5.0], 0.2), "bark")})
    with_mtl = content_hash([obj])
    obj.with_suffix(".mtl").unlink()
    without_mtl = content_hash([obj])
    as_stl = content_hash([obj.rename(tmp_path / "c.stl")])
    assert len({with_mtl, without_mtl, as_stl}) == 3
