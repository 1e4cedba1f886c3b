"""The realism table: area indices from the meshes, gap fraction, class shares and profile from the points."""

import numpy as np
import trimesh
from helpers import ROOT, analytic_scene, plane_model, scene_file

from mitsuforest.classes import GROUND, TREE_LEAVES, TREE_WOOD
from mitsuforest.config import load_scene
from mitsuforest.survey import make_plan
from mitsuforest.realism import REFERENCE, area_indices
from mitsuforest.trees import build_models


def test_lai_is_the_leaf_area_placed_over_the_plot_area():
    plan = make_plan(load_scene(ROOT / "scenes" / "demo.yaml"))
    models = build_models(plan)
    leaf_area = sum(trimesh.Trimesh(p.vertices, p.faces, process=False).area
                    for o in plan.trees for p in models[o.model].parts if p.name == "leaves")
    got = area_indices(plan, models)
    assert got["plot_area_m2"] == 400.0
    assert abs(got["leaf_area_index"] - leaf_area / 400.0) < 1e-9
    # Blades are drawn 0.8-1.2 times their nominal size, so the meshes hold the archetypes' leaf area
    # to a few per cent.
    nominal = sum(plan.models[o.model].archetype.leaf_area for o in plan.trees) / 400.0
    assert abs(got["leaf_area_index"] / nominal - 1) < 0.03


def test_area_indices_of_known_squares(tmp_path):
    """Three 2 m leaf squares and one 3 m bark square on a 40 m plot: LAI 12/1600, WAI 9/2/1600."""
    leaf, bark = plane_model("leaf", 2.0, TREE_LEAVES, "leaves"), plane_model("bark", 3.0, TREE_WOOD, "wood")
    objects = [(leaf, (x, 10.0, 5.0), 30.0, (0, 20), 1) for x in (5.0, 15.0, 25.0)]
    _, plan, models, _ = analytic_scene(scene_file(tmp_path), objects + [(bark, (20.0, 30.0, 2.0), 0, (0, 0), 1)])
    got = area_indices(plan, models)
    assert abs(got["leaf_area_index"] - 12 / 1600) < 1e-12
    assert abs(got["wood_area_index"] - 4.5 / 1600) < 1e-12


def test_realism_table_of_a_render(demo_result):
    realism, pts = demo_result.manifest["realism"], demo_result.points
    first = pts[pts["return_number"] == 1]
    assert realism["first_return_ground_share"] == np.mean(first["classification"] == GROUND)
    shares = realism["class_shares"]
    assert abs(shares["ground"] - np.mean(pts["classification"] == GROUND)) < 1e-12
    assert abs(sum(shares.values()) - 1) < 1e-12
    profile = realism["vertical_profile"]
    assert sum(sum(v) for v in profile["returns"].values()) == len(pts)
    edges = np.array(profile["height_above_ground_m"])
    leaves = pts["z"][pts["classification"] == TREE_LEAVES]     # flat demo ground: height is z
    counts = np.histogram(np.clip(leaves, edges[0], edges[-1] - 1e-6), edges)[0]
    assert counts.tolist() == profile["returns"]["tree_leaves"]
    assert realism["reference"]["forest_type"] == "open"
    assert realism["reference"]["gap_fraction"]["low"] == REFERENCE["open"]["gap_fraction"][0]


def test_bare_ground_has_a_gap_fraction_of_one(tmp_path):
    from mitsuforest.pipeline import render
    path = scene_file(tmp_path, survey={"altitude": 30, "pulse_frequency": 100000, "scan_frequency": 50,
                                        "speed": 20, "lines": [[[20.0, 0.0], [20.0, 40.0]]]})
    realism = render(path, write=False, progress=False, log=lambda *_: None).manifest["realism"]
    assert realism["first_return_ground_share"] == 1.0
    assert realism["leaf_area_index"] == 0 and realism["class_shares"] == {"ground": 1.0}
