"""``mitsuforest export``: meshes, transforms and a HELIOS++ scene that reproduce the planned scene."""

import xml.etree.ElementTree as ET

import numpy as np
import trimesh
from helpers import ROOT

from mitsuforest.cli import main
from mitsuforest.config import load_scene
from mitsuforest.plan import make_plan
from mitsuforest.plan.transforms import apply
from mitsuforest.trees import build_models


def test_export_reproduces_the_planned_scene(tmp_path):
    assert main(["export", str(ROOT / "scenes" / "demo.yaml"), "-o", str(tmp_path)]) == 0
    scene = load_scene(ROOT / "scenes" / "demo.yaml")
    plan = make_plan(scene)
    models = build_models(plan)
    rows = np.genfromtxt(tmp_path / "demo_transforms.csv", delimiter=",", skip_header=2, dtype=None, encoding=None)
    assert len(rows) == len(plan.objects)
    for row, obj in zip(rows, plan.objects):
        assert (row[0], row[1], row[4]) == (obj.instance, obj.object_id, obj.model)
        m = np.array(list(row)[6:18], float).reshape(3, 4)
        parts = [trimesh.load(tmp_path / "models" / f"{obj.model}_{p.name}.obj", process=False)
                 for p in models[obj.model].parts]
        v = np.vstack([p.vertices for p in parts])
        assert np.abs(v @ m[:, :3].T + m[:, 3] - apply(obj.matrix, models[obj.model].vertices())).max() < 1e-6
    doc = ET.parse(tmp_path / "demo_helios_scene.xml").getroot()
    ids = [p.get("id") for p in doc.iter("part")]
    assert ids == ["0"] + [str(o.instance) for o in plan.objects]
