"""``mitsuforest render SURVEY.xml``: HELIOS++ surveys flown here.

A round trip (export the demo, fly the exported survey, compare with the demo's own render) and a
small survey written the way HELIOS++'s ULS/ALS demos are (relative paths through --assets, an
efilepath, templates, a y-up OBJ with scale, rotation and translation, materials without our classes),
checked against the box's analytic surfaces; anything unsupported is one line naming the element.
"""

import re
import textwrap

import numpy as np
import pytest

from mitsuforest.cli import main
from mitsuforest.errors import ConfigError
from mitsuforest.helios.render import render_survey
from mitsuforest.pipeline import render
from mitsuforest.trees import build_models
from mitsuforest.write import read_pcd
from mitsuforest.helios.export import export_scene

QUIET = {"write": False, "progress": False, "log": lambda *_: None}


@pytest.mark.slow
def test_exported_survey_flown_here_gives_the_demo_points(tmp_path, demo_result, variant):
    """``mitsuforest render EXPORT/demo_helios_survey.xml`` against the demo's own render (one leg),
    with the sensor's ranging noise constant (HELIOS++ takes one accuracy; the export says so)."""
    notes = []
    export_scene(demo_result.scene, demo_result.plan, build_models(demo_result.plan), tmp_path / "noted",
                 log=notes.append)
    assert [n for n in notes if n.startswith("note:")] == [
        "note: HELIOS++ takes one ranging accuracy: accuracy_m is range_precision (0.005 m), without its growth "
        "with range and incidence"]
    scene = demo_result.scene.with_({"sensor.footprint_range_noise": 0.0})
    plan = demo_result.plan
    export_scene(scene, plan, build_models(plan), tmp_path / "export", log=lambda *_: None)
    native = render(scene, **QUIET).points
    assert main(["render", str(tmp_path / "export" / "demo_helios_survey.xml"), "-o", str(tmp_path / "flown"),
                 "--variant", variant, "--quiet"]) == 0                  # the survey carries the seed
    flown = read_pcd(tmp_path / "flown" / "demo.pcd")
    assert abs(len(flown) - len(native)) <= 1e-3 * len(native)
    for field in ("classification", "return_number"):
        a, b = (np.bincount(p[field], minlength=16) for p in (native, flown))
        assert np.abs(a - b).max() <= max(3, 1e-3 * len(native)), field
    key = lambda p: p["pulse_id"].astype(np.int64) * 64 + p["return_number"]   # noqa: E731
    common, i, j = np.intersect1d(key(native), key(flown), return_indices=True)
    assert len(common) >= 0.999 * len(native)
    a, b = native[i], flown[j]
    gap = np.sqrt(sum((a[c] - b[c]) ** 2 for c in "xyz"))
    assert np.mean(gap < 1e-3) >= 0.999
    assert np.mean(a["object_id"] == b["object_id"]) >= 0.999      # each part's id is our object_id
    assert np.mean(a["classification"] == b["classification"]) >= 0.999


CUBE = "".join(f"v {x} {y} {z}\n" for x in (0, 1) for y in (0, 1) for z in (0, 1)) + textwrap.dedent("""\
    f 1 3 7
    f 1 7 5
    f 2 6 8
    f 2 8 4
    f 1 5 6
    f 1 6 2
    f 3 4 8
    f 3 8 7
    f 1 2 4
    f 1 4 3
    f 5 7 8
    f 5 8 6
    """)


def _demo_like_survey(tmp_path, scene_extra="", scanner_optics="rotating") -> None:
    """A survey laid out like HELIOS++'s data/: a copter over a ground plane and a box."""
    assets = tmp_path / "assets"
    (assets / "parts").mkdir(parents=True)
    (assets / "parts" / "ground.mtl").write_text("newmtl soil\nKd 0.2 0.5 0.2\nhelios_isGround true\n")
    (assets / "parts" / "ground.obj").write_text(
        "mtllib ground.mtl\nusemtl soil\nv -20 -20 0\nv 40 -20 0\nv 40 40 0\nv -20 40 0\nf 1 2 3\nf 1 3 4\n")
    (assets / "parts" / "box.mtl").write_text("newmtl brick\nKd 0.6 0.6 0.6\nhelios_reflectance 0.5\n")
    (assets / "parts" / "box.obj").write_text("mtllib box.mtl\nusemtl brick\n" + CUBE)
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "platforms.xml").write_text("""<document>
      <platform id="copter_linearpath" name="Quadrocopter UAV" type="linearpath">
        <scannerMount x="0" y="0" z="0.2"><rot axis="x" angle_deg="180"/></scannerMount>
      </platform></document>""")
    (tmp_path / "data" / "scanners.xml").write_text(f"""<document>
      <scanner id="vux" name="VUX-like" optics="{scanner_optics}" accuracy_m="0" beamDivergence_rad="0.0005"
               pulseFreqs_Hz="100000,200000" pulseLength_ns="4" rangeMin_m="3" scanAngleMax_deg="180"
               scanAngleEffectiveMax_deg="180" scanFreqMin_Hz="10" scanFreqMax_Hz="200" wavelength_nm="1550">
        <beamOrigin x="0" y="0.085" z="0.06"><rot axis="x" angle_deg="90"/><rot axis="z" angle_deg="90"/></beamOrigin>
        <headRotateAxis x="0" y="0" z="1"/>
      </scanner></document>""")
    (tmp_path / "data" / "scene.xml").write_text(f"""<document><scene id="toy" name="Toy">
      <part id="1"><filter type="objloader"><param type="string" key="filepath" value="parts/ground.obj"/></filter></part>
      <part id="7">
        <filter type="objloader"><param type="string" key="efilepath" value="parts/box\\.obj"/>
          <param type="string" key="up" value="y"/></filter>
        <filter type="rotate"><param key="rotation" type="rotation"><rot axis="z" angle_deg="90"/></param></filter>
        <filter type="scale"><param type="double" key="scale" value="2"/></filter>
        <filter type="translate"><param type="vec3" key="offset" value="10;10;0"/></filter>
      </part>{scene_extra}
    </scene></document>""")
    (tmp_path / "data" / "survey.xml").write_text("""<?xml version="1.0"?><document>
      <platformSettings id="p1" movePerSec_m="5" z="30"/>
      <scannerSettings id="s1" active="true" pulseFreq_hz="100000" scanFreq_hz="50" scanAngle_deg="60"/>
      <survey name="toy" platform="data/platforms.xml#copter_linearpath" scanner="data/scanners.xml#vux"
              scene="data/scene.xml#toy">
        <FWFSettings beamSampleQuality="2"/>
        <leg><platformSettings x="11" y="2" template="p1"/><scannerSettings template="s1"/></leg>
        <leg><platformSettings x="11" y="20" template="p1"/><scannerSettings template="s1" active="false"/></leg>
      </survey></document>""")


def test_a_demo_style_survey_lands_on_its_parts(tmp_path, monkeypatch, variant):
    """With points on the surface (point_position: surface), every point lies on its part. (On the
    beam axis, the default, an echo mixing the box's wall and the ground lies between them.)"""
    from mitsuforest.helios import render as helios_render
    _demo_like_survey(tmp_path)
    monkeypatch.chdir(tmp_path)   # HELIOS++ demos are run from HELIOS++'s folder
    survey_scene = helios_render.survey_scene

    def on_surface(*args, **kwargs):
        scene, *rest = survey_scene(*args, **kwargs)
        return (scene.with_({"simulation.point_position": "surface"}), *rest)
    monkeypatch.setattr(helios_render, "survey_scene", on_surface)
    result = render_survey("data/survey.xml", assets=["assets"], variant=variant, **QUIET)
    pts = result.points
    assert [leg.start for leg in result.plan.legs] == [(11.0, 2.0, 30.0)]
    assert result.plan.legs[0].t1 == pytest.approx(18 / 5)          # 18 m at 5 m/s
    assert result.scene.sensor.field_of_view == 120                 # scanAngle_deg is half of it
    assert result.scene.simulation.beam_samples == 7                # beamSampleQuality 2
    box, ground = pts[pts["object_id"] == 7], pts[pts["object_id"] == 1]
    assert len(box) > 300 and len(ground) > 1000 and len(box) + len(ground) == len(pts)
    assert np.abs(ground["z"]).max() < 1e-3
    assert set(ground["classification"]) == {1} and set(box["classification"]) == {0}
    # The y-up unit cube, scaled by 2, turned 90° about z and moved to (10, 10, 0): [10, 12]² x [0, 2].
    xyz = np.column_stack([box["x"], box["y"], box["z"]])
    assert (xyz.min(0) > [10 - 1e-3, 10 - 1e-3, -1e-3]).all() and (xyz.max(0) < [12 + 1e-3, 12 + 1e-3, 2 + 1e-3]).all()
    outside = np.minimum.reduce([np.abs(xyz[:, 0] - 10), np.abs(xyz[:, 0] - 12), np.abs(xyz[:, 1] - 10),
                                 np.abs(xyz[:, 1] - 12), np.abs(xyz[:, 2] - 2)])
    assert outside.max() < 1e-3                                      # every box point on a face
    assert np.mean(np.abs(xyz[:, 2] - 2) < 1e-3) > 0.5               # seen from above: mostly the top


@pytest.mark.parametrize("extra, optics, element", [
    ('<part id="9"><filter type="geotiffloader"><param type="string" key="filepath" value="x.tif"/></filter></part>',
     "rotating", "scene.part[2].filter[0]: filter type 'geotiffloader' is not supported"),
    ('<part id="9"><filter type="objloader"><param type="string" key="filepath" value="parts/box.obj"/></filter>'
     '<filter type="translate"><param type="integer" key="onGround" value="-1"/></filter></part>',
     "rotating", "scene.part[2].filter[1].onGround"),
    ("", "conic", "scanner[vux].optics: 'conic' is not supported"),
    ('<part id="9"><filter type="objloader"><param type="string" key="filepath" value="nowhere/box.obj"/></filter></part>',
     "rotating", "scene.part[2].filter[0]: nowhere/box.obj is in no assets folder (assets, ., assets)"),
])
def test_unsupported_elements_are_named_in_one_line(tmp_path, monkeypatch, capsys, extra, optics, element):
    _demo_like_survey(tmp_path, extra, optics)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError, match=re.escape(element)):
        render_survey("data/survey.xml", assets=["assets"], **QUIET)
    assert main(["render", "data/survey.xml", "--assets", "assets", "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("mitsuforest: data/survey.xml: ") and element in err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("name, reason", [("../escape", "must be a plain file name"), (".hidden", "must not start")])
def test_a_survey_name_that_is_no_file_name_is_refused(tmp_path, monkeypatch, capsys, name, reason):
    """The survey's name prefixes the output files: one that would leave the folder or hide them is
    refused in one line, before any part is read, nothing written."""
    _demo_like_survey(tmp_path)
    survey = tmp_path / "data" / "survey.xml"
    survey.write_text(survey.read_text().replace('name="toy"', f'name="{name}"'))
    monkeypatch.chdir(tmp_path)
    assert main(["render", "data/survey.xml", "--assets", "assets", "-o", "out"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("mitsuforest: data/survey.xml: survey.name: " + reason), err
    assert not (tmp_path / "out").exists()


HOSTILE_SURVEYS = {   # file in data/, its text, the text to put instead, and the one-line message
    "huge beam quality": ("survey.xml", 'beamSampleQuality="2"', 'beamSampleQuality="1e12"',
                          "survey.FWFSettings.beamSampleQuality: must be a whole number from 1 to 100, got 1e12"),
    "zero beam quality": ("survey.xml", 'beamSampleQuality="2"', 'beamSampleQuality="0"',
                          "survey.FWFSettings.beamSampleQuality: must be a whole number from 1 to 100, got 0"),
    "fractional beam quality": ("survey.xml", 'beamSampleQuality="2"', 'beamSampleQuality="2.5"',
                                "survey.FWFSettings.beamSampleQuality: must be a whole number from 1 to 100, got 2.5"),
    "pulses past the leg counter": ("survey.xml", 'pulseFreq_hz="100000"', 'pulseFreq_hz="1e15"',
                                    "survey.leg[0].scannerSettings.pulseFreq_hz: 1e+15 Hz over the leg's 3.6 s is "
                                    "3,600,000,000,000,000 pulses, more than the 4,294,967,296 a leg can number"),
    "template cycle": ("survey.xml", '<platformSettings id="p1" ', '<platformSettings id="p1" template="p1" ',
                       "survey.leg[0].platformSettings.template.template: 'p1' leads back to itself"),
    "fractional maxNOR": ("scanners.xml", "optics=", 'maxNOR="2.7" optics=',
                          "scanner[vux].maxNOR: must be a whole number >= 0, got 2.7"),
    "part id past 32 bits": ("scene.xml", '<part id="7">', '<part id="4294967296">',
                             "scene.part[1].id: must be a whole number from 0 to 4294967295"),
    "negative divergence": ("scanners.xml", 'beamDivergence_rad="0.0005"', 'beamDivergence_rad="-1"',
                            "scanner[vux].beamDivergence_rad: must be >= 0, got -1 (checked as our "
                            "sensor.beam_divergence)"),
    "zero pulse length": ("scanners.xml", 'pulseLength_ns="4"', 'pulseLength_ns="0"',
                          "scanner[vux].pulseLength_ns: must be >= 1e-11, got 0 (checked as our sensor.pulse_length)"),
}


@pytest.mark.parametrize("case", sorted(HOSTILE_SURVEYS))
def test_hostile_survey_value_is_refused_in_one_line(case, tmp_path, monkeypatch, capsys):
    """Values that used to hang (a quality of 1e12 sums 10^12 rings), fill the disk (10^15 pulses), recurse
    without end (a template naming itself), end in a traceback (an id past 32 bits) or were silently
    coerced (0, 2.5, maxNOR 2.7) are refused, and values checked after conversion are named by the
    survey's own attribute, not by our key: exit 2, one line, nothing written."""
    file, old, new, message = HOSTILE_SURVEYS[case]
    _demo_like_survey(tmp_path)
    path = tmp_path / "data" / file
    assert old in path.read_text()
    path.write_text(path.read_text().replace(old, new, 1))
    monkeypatch.chdir(tmp_path)
    assert main(["render", "data/survey.xml", "--assets", "assets", "-o", "out"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("mitsuforest: data/survey.xml: " + message), err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("survey, message", [
    ("folder.xml", "folder.xml: a folder, not a file"),
    ("broken.xml", "broken.xml: not valid XML (unclosed token: line 1, column 0)"),
    ("nowhere.xml", "nowhere.xml: file not found"),
])
def test_a_survey_that_cannot_be_read_is_named_once(survey, message, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "folder.xml").mkdir()
    (tmp_path / "broken.xml").write_text("<doc")
    assert main(["render", survey, "-o", "out"]) == 2
    assert capsys.readouterr().err == f"mitsuforest: {message}\n"


def test_an_unreadable_survey_is_bad_input(tmp_path, monkeypatch, capsys):
    """A survey this user cannot read (chmod 000 does not stop root, who runs the tests): exit 2, not a
    failing write's exit 1."""
    from mitsuforest.helios import survey
    (tmp_path / "survey.xml").write_text("<document/>")
    def denied(path, *args, **kwargs):
        raise PermissionError(13, "Permission denied", str(path))
    monkeypatch.setattr(survey.ET, "parse", denied)
    monkeypatch.chdir(tmp_path)
    assert main(["render", "survey.xml", "-o", "out"]) == 2
    assert capsys.readouterr().err == "mitsuforest: survey.xml: cannot be read (Permission denied)\n"
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("text", ["", "not a mesh\n"])
def test_a_part_without_triangles_is_named_with_the_survey(tmp_path, monkeypatch, capsys, text):
    """An empty or unreadable part OBJ named only itself: the survey file and its part come first."""
    _demo_like_survey(tmp_path)
    (tmp_path / "assets" / "parts" / "box.obj").write_text(text)
    monkeypatch.chdir(tmp_path)
    assert main(["render", "data/survey.xml", "--assets", "assets", "-o", "out"]) == 2
    assert capsys.readouterr().err == (f"mitsuforest: data/survey.xml: scene.part[1]: "
                                       f"{tmp_path / 'assets/parts/box.obj'}: the OBJ file holds no triangles\n")
    assert not (tmp_path / "out").exists()


def test_a_part_path_naming_a_folder_says_so(tmp_path, monkeypatch, capsys):
    _demo_like_survey(tmp_path)
    scene = tmp_path / "data" / "scene.xml"
    scene.write_text(scene.read_text().replace('value="parts/ground.obj"', f'value="{tmp_path / "assets"}"'))
    monkeypatch.chdir(tmp_path)
    assert main(["render", "data/survey.xml", "--assets", "assets", "-o", "out"]) == 2
    assert capsys.readouterr().err == (f"mitsuforest: data/survey.xml: scene.part[0].filter[0]: a folder, not a file: "
                                       f"{tmp_path / 'assets'}\n")


def test_a_missing_material_file_is_named(tmp_path, monkeypatch, capsys):
    """Without its .mtl the ground part has no helios_isGround: the refusal says why."""
    _demo_like_survey(tmp_path)
    (tmp_path / "assets" / "parts" / "ground.mtl").unlink()
    monkeypatch.chdir(tmp_path)
    assert main(["render", "data/survey.xml", "--assets", "assets", "-o", "out"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "scene: no part is ground" in err, err
    assert err.rstrip().endswith(f"material file not found, faces unclassified: {tmp_path / 'assets/parts/ground.mtl'}")


def _read_toy(tmp_path, monkeypatch, *changes):
    """The demo-like survey with ``(file in data/, old text, new text)`` changes, read and converted
    (not flown)."""
    from mitsuforest.helios.render import survey_scene
    from mitsuforest.helios.survey import read_survey
    _demo_like_survey(tmp_path)
    for file, old, new in changes:
        path = tmp_path / "data" / file
        assert old in path.read_text()
        path.write_text(path.read_text().replace(old, new, 1))
    monkeypatch.chdir(tmp_path)
    return survey_scene(read_survey("data/survey.xml", assets=["assets"]))


@pytest.mark.parametrize("effective, scan_angle, fov", [("165", "180", 330), ("165", "60", 120), ("180", "180", 360)])
def test_a_rotating_mirror_fires_within_its_effective_scan_angle(tmp_path, monkeypatch, effective, scan_angle, fov):
    """HELIOS++'s rotating mirror (PolygonMirrorBeamDeflector) fires within the smaller of the scanner's
    scanAngleEffectiveMax_deg and the leg's scanAngle_deg; its VUX-1UAV (180, 165) flown at 180 scans
    330°, not 360°."""
    scene, *_ = _read_toy(tmp_path, monkeypatch,
                          ("scanners.xml", 'scanAngleEffectiveMax_deg="180"', f'scanAngleEffectiveMax_deg="{effective}"'),
                          ("survey.xml", 'scanAngle_deg="60"', f'scanAngle_deg="{scan_angle}"'))
    assert scene.sensor.field_of_view == fov


@pytest.mark.parametrize("old, new, message", [
    ('scanAngleMax_deg="180"', 'scanAngleMax_deg="45"',
     "scanner[vux].scanAngleMax_deg: a rotating mirror sweeping 90° a scan line is not supported"),
    ('scanAngleEffectiveMax_deg="180"', "", "scanner[vux].scanAngleEffectiveMax_deg: is required"),
])
def test_a_rotating_mirror_we_cannot_fly_is_refused(tmp_path, monkeypatch, old, new, message):
    """Our rotating mirror turns 360° a scan line: HELIOS++'s LMS-Q560 (scanAngleMax_deg 45: 90° a line,
    four times our pulses per degree) is refused, and so is a rotating scanner without
    scanAngleEffectiveMax_deg (HELIOS++ fires none of its pulses)."""
    with pytest.raises(ConfigError, match=re.escape(message)):
        _read_toy(tmp_path, monkeypatch, ("scanners.xml", old, new))


def test_the_survey_full_waveform_settings_helios_reads_are_taken_or_ignored(tmp_path, monkeypatch):
    """HELIOS++ reads FWFSettings binSize_ns, beamSampleQuality, winSize_ns, maxFullwaveRange_ns and
    apertureDiameter_m (XmlAssetsLoader::createFWFSettingsFromXml); the energy model's aperture changes
    no hit here, so it is ignored, not refused."""
    scene, *_ = _read_toy(tmp_path, monkeypatch, ("survey.xml", '<FWFSettings beamSampleQuality="2"/>',
                                                  '<FWFSettings beamSampleQuality="2" binSize_ns="0.25" winSize_ns="1" '
                                                  'maxFullwaveRange_ns="0" apertureDiameter_m="0.1"/>'))
    assert scene.simulation.beam_samples == 7


def test_a_part_without_an_id_loading_several_files_is_one_part_a_file(tmp_path, monkeypatch):
    """HELIOS++ numbers a part without an id by its index and splits one whose objloader loads several
    files into one part a file, numbered on from that index; later parts without an id move on with
    them (XmlSceneLoader, ScenePart::splitSubparts). Two boxes matched by one efilepath (the third part),
    then a ground without an id: ids 2 and 3 for the boxes, 4 for the ground (HELIOS++'s hitObjectId)."""
    from mitsuforest.helios.survey import read_survey
    _demo_like_survey(tmp_path, '<part><filter type="objloader"><param type="string" key="efilepath" '
                                'value="parts/bo.\\.obj"/></filter></part>'
                                '<part><filter type="objloader"><param type="string" key="filepath" '
                                'value="parts/ground.obj"/></filter></part>')
    parts = tmp_path / "assets" / "parts"
    (parts / "box.obj").rename(parts / "boa.obj")
    (parts / "bob.obj").write_text((parts / "boa.obj").read_text())
    scene = tmp_path / "data" / "scene.xml"
    scene.write_text(scene.read_text().replace("parts/box\\.obj", "parts/boa\\.obj"))
    monkeypatch.chdir(tmp_path)
    survey = read_survey("data/survey.xml", assets=["assets"])
    assert [(p.part_id, [f.name for f in p.files]) for p in survey.parts] == [
        (1, ["ground.obj"]), (7, ["boa.obj"]), (2, ["boa.obj"]), (3, ["bob.obj"]), (4, ["ground.obj"])]
