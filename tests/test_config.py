"""Bad input as a new user would give it: one clear line naming file and key, exit 2, nothing written."""

import pytest
from helpers import ROOT, SENSORS

from mitsuforest.cli import main
from mitsuforest.config import load_scene

GOOD = f"""
name: t
area: {{size: [10, 10]}}
forest: {{trees: 1}}
understory: {{bushes: 0, rocks: 0, deadwood: 0, stumps: 0}}
sensor: {SENSORS / 'riegl_vux-1uav22.yaml'}
survey: {{altitude: 30, pulse_frequency: 200000}}
"""

CASES = {
    "wrong type": (GOOD.replace("altitude: 30", "altitude: high"), "survey.altitude: must be a number, got 'high'"),
    "negative altitude": (GOOD.replace("altitude: 30", "altitude: -30"), "survey.altitude: must be > 0, got -30"),
    "unknown key": (GOOD.replace("altitude: 30", "altitud: 30"),
                    "survey.altitud: unknown key (did you mean 'altitude'?)"),
    "pulse frequency": (GOOD.replace("pulse_frequency: 200000", "pulse_frequency: 150000"),
                        "survey.pulse_frequency: 150000 Hz is not one of the sensor's pulse frequencies"),
    "sensor missing": (GOOD.replace("riegl_vux-1uav22.yaml", "nope.yaml"), "sensor: file not found"),
    "syntax": (GOOD + "forest: [1,\n", "YAML syntax error: line"),
    "cover band": (GOOD.replace("trees: 1", "type: closed, canopy_cover: 0.5"),
                   "forest.canopy_cover: 0.5 is outside the closed band 0.8-1"),
    "both tree targets": (GOOD.replace("trees: 1", "trees: 1, canopy_cover: 0.6"),
                          "forest.trees: give either forest.canopy_cover or forest.trees, not both"),
    "archetype key": (GOOD.replace("trees: 1", "trees: 1, archetypes: [{base: 2, hieght: 20}]"),
                      "forest.archetypes[0].hieght: unknown key (did you mean 'height'?)"),
    "scan frequency": (GOOD.replace("altitude: 30", "scan_frequency: 500"),
                       "survey.scan_frequency: 500 Hz is outside the sensor's range 10-200 Hz"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_scene_gives_one_line_and_exit_2(case, tmp_path, monkeypatch, capsys):
    text, message = CASES[case]
    monkeypatch.chdir(tmp_path)
    (tmp_path / "scene.yaml").write_text(text)
    code = main(["render", "scene.yaml", "-o", "out"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert err.count("\n") == 0 and "Traceback" not in err
    assert err.startswith("mitsuforest: scene.yaml: ")
    assert message in err
    assert not (tmp_path / "out").exists()


def test_missing_scene_file(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["render", "missing.yaml"]) == 2
    assert capsys.readouterr().err.strip() == "mitsuforest: missing.yaml: file not found"


def test_errors_inside_a_sensor_file_name_that_file(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "s.yaml").write_text("name: x\nbeam_divergence: -1\npulse_frequencies: [1000]\n")
    (tmp_path / "scene.yaml").write_text(GOOD.replace(str(SENSORS / "riegl_vux-1uav22.yaml"), "s.yaml"))
    assert main(["plan", "scene.yaml"]) == 2
    assert capsys.readouterr().err.strip() == "mitsuforest: s.yaml: beam_divergence: must be >= 0, got -1"


def test_defaults_and_relative_paths(tmp_path):
    (tmp_path / "scene.yaml").write_text(GOOD)
    scene = load_scene(tmp_path / "scene.yaml")
    assert scene["simulation"]["beam_samples"] == 7
    assert scene["survey"]["scan_frequency"] == 50
    assert scene["sensor"]["beam_divergence"] == [0.5e-3, 0.5e-3]
    assert scene["forest"]["archetypes"][0]["height"] > 0 and len(scene["forest"]["archetypes"]) == 10
    demo = load_scene(ROOT / "scenes" / "demo.yaml")
    assert demo["sensor"]["file"] == str(SENSORS / "riegl_vux-1uav22.yaml")
    assert demo["output"]["dir"] == str(ROOT / "out" / "demo")


def test_every_shipped_file_loads():
    for path in sorted((ROOT / "scenes").glob("*.yaml")) + sorted((ROOT / "examples").glob("*.yaml")):
        assert load_scene(path)["name"]


def test_version(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.startswith("mitsuforest 0.")
