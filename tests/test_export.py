"""``mitsuforest export``: meshes, tables and a HELIOS++ survey that reproduce the planned scene.

The written XML is parsed here with ElementTree alone (not with our reader) and checked against the
scene: every file it names exists and is named by an absolute path (HELIOS++ then loads each one
once, whatever its working folder and --assets), every part is one component of one object at its
place, and the survey flies our legs with our sensor settings.
"""

import csv
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import trimesh
from helpers import ROOT

from mitsuforest.classes import CLASS_NAMES, GROUND, TREE_LEAVES
from mitsuforest.cli import main
from mitsuforest.config import load_scene
from mitsuforest.helios.documents import beam_sample_quality, sub_rays
from mitsuforest.survey import make_plan
from mitsuforest.plan.transforms import apply
from mitsuforest.scan.radiometry import reflectance_table
from mitsuforest.trees import build_models
from mitsuforest.helios.export import component_meshes


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    folder = tmp_path_factory.mktemp("export")
    assert main(["export", str(ROOT / "scenes" / "demo.yaml"), "-o", str(folder)]) == 0
    scene = load_scene(ROOT / "scenes" / "demo.yaml")
    plan = make_plan(scene)
    return folder, scene, plan, build_models(plan)


def _rows(path):
    with open(path) as f:
        return list(csv.DictReader(line for line in f if not line.startswith("#")))


def _rotation(axis, degrees):
    a = math.radians(degrees)
    c, s = math.cos(a), math.sin(a)
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]), "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


@pytest.mark.slow
def test_every_part_is_one_component_in_place_with_its_object_id(exported):
    folder, scene, plan, models = exported
    doc = ET.parse(folder / "demo_helios_scene.xml").getroot()
    parts = {int(p.get("id")): p for p in doc.iter("part")}
    expected = {plan.ground_object_id: None}
    for obj in plan.objects:
        for k in component_meshes(models[obj.model]):
            expected[obj.object_id + k] = (obj, k)
    assert sorted(parts) == sorted(expected)
    for part_id, part in parts.items():
        (path,) = [p.get("value") for p in part.iter("param") if p.get("key") in ("filepath", "efilepath")]
        assert [p.get("key") for p in part.iter("param") if "filepath" in p.get("key")] == ["filepath"]
        assert Path(path).is_absolute() and Path(path).is_file()
        mesh = trimesh.load(path, process=False, maintain_order=True)
        rotation = np.eye(3)
        for rot in part.iter("rot"):   # HELIOS++ applies a rotation's <rot> list in order
            rotation = _rotation(rot.get("axis"), float(rot.get("angle_deg"))) @ rotation
        offsets = [p.get("value") for p in part.iter("param") if p.get("key") == "offset"]
        offset = np.array([float(v) for v in offsets[0].split(";")]) if offsets else np.zeros(3)
        world = mesh.vertices @ rotation.T + offset
        if expected[part_id] is None:
            truth = plan.terrain.mesh()[0]
        else:
            obj, k = expected[part_id]
            truth = apply(obj.matrix, component_meshes(models[obj.model])[k][0])
        assert world.shape == truth.shape
        assert np.abs(world - truth).max() < 1e-6


def test_materials_carry_our_reflectance_and_class(exported):
    folder, scene, plan, models = exported
    table = reflectance_table(scene.sensor.wavelength)
    mtl = trimesh.exchange.obj.parse_mtl((folder / "demo_models" / "materials.mtl").read_bytes())
    for code, name in CLASS_NAMES.items():
        assert float(mtl[name]["helios_reflectance"][0]) == pytest.approx(table[code])
        assert int(mtl[name]["helios_classification"][0]) == code
        assert (mtl[name]["helios_isground"][0] == "true") == (code == GROUND)
    assert float(mtl["tree_leaves"]["helios_reflectance"][0]) == 0.25   # leaves at 1550 nm (radiometry.py)
    for obj_path in (folder / "demo_models").glob("*.obj"):
        head = obj_path.read_text().splitlines()[:2]
        assert head[0] == "mtllib materials.mtl" and head[1].removeprefix("usemtl ") in mtl


def test_the_parts_table_maps_every_part(exported):
    folder, scene, plan, models = exported
    rows = {int(r["part_id"]): r for r in _rows(folder / "demo_helios_parts.csv")}
    ids = {int(p.get("id")) for p in ET.parse(folder / "demo_helios_scene.xml").getroot().iter("part")}
    assert set(rows) == ids
    assert rows[plan.ground_object_id]["class"] == "ground"
    for obj in plan.objects:
        for k, comp in enumerate(models[obj.model].components):
            row = rows[obj.object_id + k]
            assert (int(row["object_id"]), int(row["instance"]), int(row["classification"]), row["model"]) == \
                (obj.object_id + k, obj.instance, comp.classification, obj.model)
            wood_or_leaves = obj.kind == "tree"
            assert int(row["treeid"]) == (obj.treeid if wood_or_leaves or obj.kind == "deadwood" else 0)
            assert (folder / row["file"]).is_file()
    assert any(int(r["classification"]) == TREE_LEAVES for r in rows.values())


def test_the_survey_flies_our_legs_with_our_sensor(exported):
    folder, scene, plan, models = exported
    survey = ET.parse(folder / "demo_helios_survey.xml").getroot().find("survey")
    assert survey.get("seed") == str(scene.seed) == "7"
    for key, tag in (("platform", "platform"), ("scanner", "scanner"), ("scene", "scene")):
        path, ident = survey.get(key).split("#")
        assert Path(path).is_absolute() and Path(path).is_file()
        assert [n for n in ET.parse(path).getroot().iter(tag) if n.get("id") == ident]
    legs = survey.findall("leg")
    assert len(legs) == 2 * len(plan.legs)
    for i, leg in enumerate(plan.legs):
        for node, point, active in ((legs[2 * i], leg.start, "true"), (legs[2 * i + 1], leg.end, "false")):
            p, s = node.find("platformSettings"), node.find("scannerSettings")
            assert [float(p.get(k)) for k in "xyz"] == pytest.approx(point, abs=1e-9)
            assert p.get("onGround") == "false"
            assert float(p.get("movePerSec_m")) == pytest.approx(scene.survey.speed)
            assert s.get("active") == active
            assert float(s.get("pulseFreq_hz")) == scene.pulse_frequency == 200000
            assert float(s.get("scanFreq_hz")) == scene.scan_frequency == 50
            assert float(s.get("scanAngle_deg")) == scene.sensor.field_of_view / 2 == 180
            assert float(s.get("headRotatePerSec_deg")) == 0
    assert legs[0].find("platformSettings").get("z") == "30"   # altitude over flat ground at 0
    quality = int(survey.find("FWFSettings").get("beamSampleQuality"))
    assert sub_rays(quality) == scene.simulation.beam_samples == 19
    scanner = ET.parse(folder / "demo_helios_scanner.xml").getroot().find("scanner")
    assert float(scanner.get("pulseLength_ns")) == pytest.approx(4.0)
    assert float(scanner.get("beamDivergence_rad")) == pytest.approx(0.5e-3)
    assert int(scanner.get("wavelength_nm")) == 1550
    assert float(scanner.get("scanAngleMax_deg")) == 180
    assert "200000" in scanner.get("pulseFreqs_Hz").split(",")
    assert int(scanner.get("maxNOR")) == scene.sensor.max_returns
    assert float(scanner.get("accuracy_m")) == scene.sensor.range_precision


def test_beam_sample_quality_matches_helios_sub_ray_counts():
    assert [sub_rays(q) for q in range(1, 6)] == [1, 7, 19, 37, 62]
    assert [beam_sample_quality(n) for n in (1, 7, 19, 37, 61)] == [1, 2, 3, 4, 5]


def test_a_risley_sensor_is_refused_before_anything_is_written(tmp_path, capsys):
    from helpers import scene_file
    path = scene_file(tmp_path, sensor="livox_mid-70.yaml")
    assert main(["export", str(path), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "sensor.deflector: risley" in err
    assert not (tmp_path / "out").exists()


def test_a_folder_helios_cannot_name_is_refused_before_anything_is_written(tmp_path, capsys):
    out = tmp_path / "a#b"
    assert main(["export", str(ROOT / "scenes" / "demo.yaml"), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "HELIOS++ cannot name a file whose path holds '#'" in err
    assert not out.exists()


@pytest.mark.slow
def test_two_scenes_exported_into_one_folder_keep_their_own_meshes(tmp_path):
    """Both scenes have a deadwood001 (drawn from the scene's seed) and a ground: each survey must
    fly its own, so each scene's meshes go into its own folder."""
    import yaml
    data = yaml.safe_load((ROOT / "scenes" / "demo.yaml").read_text())
    data.update(name="other", seed=data["seed"] + 1, sensor=str(ROOT / "scenes" / data["sensor"]))
    data["terrain"] = {"type": "noise"}
    (tmp_path / "other.yaml").write_text(yaml.safe_dump(data))
    for path in (ROOT / "scenes" / "demo.yaml", tmp_path / "other.yaml"):
        assert main(["export", str(path), "-o", str(tmp_path / "out")]) == 0
    for name in ("demo", "other"):
        doc = ET.parse(tmp_path / "out" / f"{name}_helios_scene.xml").getroot()
        files = {Path(f.get("value")).parent for f in doc.iter("param") if f.get("key") == "filepath"}
        assert files == {tmp_path / "out" / f"{name}_models"}
    for mesh in ("deadwood001_c000_deadwood.obj", "ground.obj"):
        assert ((tmp_path / "out" / "demo_models" / mesh).read_bytes()
                != (tmp_path / "out" / "other_models" / mesh).read_bytes())


def test_a_rotating_mirror_is_exported_as_a_full_turn_per_scan_line(tmp_path):
    """HELIOS++'s rotating mirror sweeps 2 x scanAngleMax_deg each scan line and fires within
    scanAngleEffectiveMax_deg (its own VUX-1UAV: 180 and 165); ours turns 360° a line. A 330° sensor
    exported with scanAngleMax_deg 165 had HELIOS++ sweep 330° a line, pulses 8 % closer and all fired."""
    from helpers import scene_file
    path = scene_file(tmp_path, sensor="riegl_vux-1uav.yaml")
    assert main(["export", str(path), "-o", str(tmp_path / "out")]) == 0
    scanner = ET.parse(tmp_path / "out" / "test_helios_scanner.xml").getroot().find("scanner")
    assert scanner.get("optics") == "rotating"
    assert float(scanner.get("scanAngleMax_deg")) == 180
    assert float(scanner.get("scanAngleEffectiveMax_deg")) == 165
    legs = ET.parse(tmp_path / "out" / "test_helios_survey.xml").getroot().iter("scannerSettings")
    assert {float(s.get("scanAngle_deg")) for s in legs} == {165}
