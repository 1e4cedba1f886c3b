"""Bad input as a new user would give it: one clear line naming file and key, exit 2, nothing written."""

import dataclasses
import re

import numpy as np
import pytest
import yaml
from helpers import ROOT, SENSORS

from mitsuforest.cli import main
from mitsuforest.config import ConfigError, _CheckedLoader, _parse_yaml, load_scene, load_sensor, read_yaml
from mitsuforest.survey import make_plan
from mitsuforest.pipeline import render

GOOD = f"""
name: t
area: {{size: [10, 10]}}
forest: {{trees: 1}}
understory: {{bushes: 0, rocks: 0, deadwood: 0, stumps: 0}}
sensor: {SENSORS / 'riegl_vux-1uav22.yaml'}
survey: {{altitude: 30, pulse_frequency: 200000}}
"""

CASES = {
    "empty name": (GOOD.replace("name: t", 'name: ""'), "name: must not be empty"),
    "name leaving the folder": (GOOD.replace("name: t", "name: ../escape"),
                                "name: must be a plain file name, without / or \\, got '../escape'"),
    "name with a folder": (GOOD.replace("name: t", "name: a/b"), "name: must be a plain file name"),
    "name with a backslash": (GOOD.replace("name: t", "name: 'a\\b'"), "name: must be a plain file name"),
    "name dot": (GOOD.replace("name: t", "name: ."), "name: must not start with a dot"),
    "name dot dot": (GOOD.replace("name: t", "name: .."), "name: must not start with a dot"),
    "name with a newline": (GOOD.replace("name: t", 'name: "a\\nb"'), "name: must not hold control characters, got 'a\\nb'"),
    "name with an escape code": (GOOD.replace("name: t", 'name: "t\\e[31mred"'),
                                 "name: must not hold control characters, got 't\\x1b[31mred'"),
    "hidden name": (GOOD.replace("name: t", "name: .t"), "name: must not start with a dot"),
    "wrong type": (GOOD.replace("altitude: 30", "altitude: high"), "survey.altitude: must be a number, got 'high'"),
    "negative altitude": (GOOD.replace("altitude: 30", "altitude: -30"), "survey.altitude: must be > 0, got -30"),
    "unknown key": (GOOD.replace("altitude: 30", "altitud: 30"),
                    "survey.altitud: unknown key (did you mean 'altitude'?)"),
    "pulse frequency": (GOOD.replace("pulse_frequency: 200000", "pulse_frequency: 150000"),
                        "survey.pulse_frequency: 150000 Hz is not one of the sensor's pulse frequencies"),
    "sensor missing": (GOOD.replace("riegl_vux-1uav22.yaml", "nope.yaml"), "sensor: file not found"),
    "sensor a folder": (GOOD.replace(f"{SENSORS / 'riegl_vux-1uav22.yaml'}", f"{SENSORS}"),
                        f"sensor: not a file (a folder): {SENSORS}"),
    "model a folder": (GOOD.replace("trees: 1", "trees: 1, models: [{qsm: .}]"),
                       "forest.models[0].qsm: not a file (a folder): "),
    "model a device": (GOOD.replace("trees: 1", "trees: 1, models: [{qsm: /dev/null}]"),
                       "forest.models[0].qsm: not a file (a device, pipe or socket): /dev/null"),
    "model empty path": (GOOD.replace("trees: 1", "trees: 1, models: [{qsm: ''}]"),
                         "forest.models[0].qsm: must name a file, got an empty path"),
    "syntax": (GOOD + "forest: [1,\n", "YAML syntax error: line"),
    "format twice": (GOOD + "output: {formats: [pcd, laz, pcd]}\n",
                     "output.formats[2]: 'pcd' is given twice (also output.formats[0])"),
    "cover band": (GOOD.replace("trees: 1", "type: closed, canopy_cover: 0.5"),
                   "forest.canopy_cover: 0.5 is outside the closed band 0.8-1"),
    "both tree targets": (GOOD.replace("trees: 1", "trees: 1, canopy_cover: 0.6"),
                          "forest.trees: give either forest.canopy_cover or forest.trees, not both"),
    "archetype key": (GOOD.replace("trees: 1", "trees: 1, archetypes: [{base: 2, hieght: 20}]"),
                      "forest.archetypes[0].hieght: unknown key (did you mean 'height'?)"),
    "scan frequency": (GOOD.replace("altitude: 30", "scan_frequency: 500"),
                       "survey.scan_frequency: 500 Hz is outside the sensor's range 10-200 Hz"),
    "fractional seed": ("seed: 1.5\n" + GOOD, "seed: must be an integer, got 1.5"),
    "plot under a metre": (GOOD.replace("size: [10, 10]", "size: [0.1, 10]"), "area.size[0]: must be >= 1, got 0.1"),
    "offset beyond any map": (GOOD + "origin: {offset: [0, -1e300, 0]}\n",
                              "origin.offset[1]: -1e+300 m is no map coordinate: projected CRSs stay within ±1e+09 m"),
    "ground above the flight": (GOOD + "terrain: {type: noise, amplitude: 80}\n",
                                "terrain.amplitude: the ground rises 53.9 m above its mean height, higher than the flight at "
                                "survey.altitude 30 m less the sensor's minimum range 3 m"),
    "nested 1,000 deep": (GOOD + "deep: " + "[" * 1000 + "]" * 1000 + "\n",
                          "scene.yaml: line 8, column 106: nested deeper than 100 levels"),
    "nested 1,000 deep in blocks": (GOOD + "".join(f"{'  ' * i}k:\n" for i in range(1000)),
                                    "scene.yaml: line 107, column 199: nested deeper than 100 levels"),
    "point position": (GOOD + "simulation: {point_position: axis}\n",
                       "simulation.point_position: must be one of beam_axis, surface, got 'axis'"),
    "saved as Windows-1252": (("# Fläche\n" + GOOD).encode("cp1252"),
                              "not UTF-8 text (line 1 holds the byte 0xe4, as Windows-1252 or Latin-1 would write an "
                              "accented letter); save the file as UTF-8"),
    "binary": (b"\x00\x01\xff" + GOOD.encode(), "scene.yaml: not a text file"),
    # Values that passed the schema and then hung the plan, ended in a traceback, printed a number of 300
    # digits or rendered an empty scan:
    "line spacing of a micrometre": (GOOD.replace("altitude: 30", "altitude: 30, line_spacing: 1e-6"),
                                     "survey.line_spacing: 1e-06 m apart, 10,000,001 flight lines cross the plot, "
                                     "more than the 65,535"),
    "line spacing below float64s normal range": (GOOD.replace("altitude: 30", "altitude: 30, line_spacing: 1e-320"),
                               "m apart, inf flight lines cross the plot"),
    "margin of 1e300 m": (GOOD.replace("altitude: 30", "altitude: 30, margin: 1e300"),
                          "survey.margin: must be <= 1e+09, got 1e+300"),
    "leg of 1e300 m": (GOOD.replace("altitude: 30", "altitude: 30, lines: [[[5, -1e300], [5, 1e300]]]"),
                       "survey.lines[0][0][1]: must be >= -1e+09, got -1e+300"),
    "speed of 1e-300 m/s": (GOOD.replace("altitude: 30", "altitude: 30, speed: 1e-300"),
                            "survey.speed: leg 1 lasts 3e+301 s: 6e+306 pulses, more than the 4,294,967,296"),
    "speed of 1e300 m/s": (GOOD.replace("altitude: 30", "altitude: 30, speed: 1e300"), "survey: fires no pulse"),
    "flight under the sensor's minimum range": (GOOD.replace("altitude: 30", "altitude: 2"),
                                                "survey.altitude: 2 m is under the sensor's minimum range 3 m (RIEGL "
                                                "VUX-1UAV22): it would see nothing; fly at least that high"),
    "flight beyond the sensor's range": (GOOD.replace("altitude: 30", "altitude: 2000"),
                                         "survey.altitude: the plot's ground, and anything 150 m tall on it, lies "
                                         "1,850.0 m from leg 1 at the nearest, beyond the sensor's range_max of 1,000 m"),
    "a line across the plot beyond the sensor's range": (
        GOOD.replace("altitude: 30", "altitude: 2000, lines: [[[5, -5], [5, 15]]]"),
        "survey.altitude: the plot's ground, and anything 150 m tall on it, lies 1,850.0 m from leg 1"),
    "a billion trees without spacing": (GOOD.replace("trees: 1", "trees: 1000000000, min_spacing: 0"),
                                        "forest.trees: 1000000000 trees in a 10 x 10 m plot is more than 10 a square metre"),
    "spacing of 1e300 m": (GOOD.replace("trees: 1", "trees: 2, min_spacing: 1e300"),
                           "forest.trees: 2 trees at min_spacing 1e+300 m do not fit"),
    # Found by fuzzing: a traceback (OverflowError, TypeError, ValueError, ZeroDivisionError), exit 1 or two lines
    "an integer of 400 digits": (GOOD.replace("altitude: 30", "altitude: " + "9" * 400),
                                 "survey.altitude: must be within ±1.8e+308 (float64), got an integer of about 401 digits"),
    "a count of 400 digits": (GOOD.replace("bushes: 0", "bushes: " + "9" * 400), "understory.bushes: must be within"),
    "an integer of 5,000 digits": ("seed: " + "9" * 5000 + "\n" + GOOD,
                                   "YAML syntax error: line 1, column 7: an integer of 5,000 digits is too long"),
    "a list as a key": (GOOD + "? [a, b]\n: 1\n", "YAML syntax error: line 8, column 3: found unhashable key"),
    "a mapping as a key": (GOOD.replace("survey: {", "survey: {? {a: 1}: 2, "), "found unhashable key"),
    "a NUL byte": (GOOD.replace("name: t", "name: t\0"),
                   "YAML syntax error: line 2: unacceptable character #x0000: special characters are not allowed"),
    "UTF-16 without a byte order mark": (GOOD.encode("utf-16-le"), "scene.yaml: YAML syntax error: line 2: "
                                         "unacceptable character #x0000"),
    "spacing under 1e-160 m": (GOOD.replace("trees: 1", "trees: 2000, min_spacing: 1e-320"),
                               "forest.trees: 2000 trees in a 10 x 10 m plot is more than 10 a square metre"),
    "a model path too long for the file system": (GOOD.replace("trees: 1", "trees: 1, models: [{qsm: " + "x" * 5000 + "}]"),
                                                  "forest.models[0].qsm: cannot be read (File name too long): "),
    "GNSS error of 1e300 m": (GOOD.replace("altitude: 30", "altitude: 30, navigation_errors: {gnss_sigma_m: 1e300}"),
                              "survey.navigation_errors.gnss_sigma_m: must be <= 100, got 1e+300"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_scene_gives_one_line_and_exit_2(case, tmp_path, monkeypatch, capsys):
    text, message = CASES[case]
    monkeypatch.chdir(tmp_path)
    (tmp_path / "scene.yaml").write_bytes(text if isinstance(text, bytes) else text.encode())
    code = main(["render", "scene.yaml", "-o", "out"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert err.count("\n") == 0 and "Traceback" not in err
    assert err.startswith("mitsuforest: scene.yaml: ")
    assert message in err
    assert not (tmp_path / "out").exists()


def test_a_seed_of_any_size_is_an_integer(tmp_path):
    """Seeds are hashed (keys) or given to numpy whole: one beyond float64's 2**53 must stay exact."""
    big = 99999999999999999999999
    path = tmp_path / "scene.yaml"
    path.write_text(f"seed: {big}\n" + GOOD)
    assert load_scene(path).seed == big
    assert load_scene(path, seed=2**53 + 1).seed == 2**53 + 1


@pytest.mark.parametrize("path", sorted([*ROOT.glob("scenes/*.yaml"), *ROOT.glob("sensors/*.yaml"),
                                          *ROOT.glob("examples/**/*.yaml")]), ids=lambda p: p.name)
def test_libyaml_reads_each_shipped_file_as_the_python_parser_does(path):
    text = path.read_text()
    assert _parse_yaml(text) == yaml.load(text, Loader=_CheckedLoader)


@pytest.mark.parametrize(("text", "message"), [
    ("a: 1\nb: 2\na: 3\n", "line 3, column 1: duplicate key 'a'"),
    ("x: " + "[" * 98 + "&d [[[[1]]]]" + "]" * 98 + "\ny: *d\n", "line 1, column 106: nested deeper than 100 levels"),
    ("x: [\n", "YAML syntax error: line 2, column 1"),
])
def test_what_libyaml_refuses_or_passes_too_deep_is_told_as_the_python_parser_tells_it(text, message, tmp_path):
    """A duplicate key, an anchor nested too deep that a shallow alias names later (libyaml's walk
    reaches it there first) and a syntax error: each with the Python parser's line and column."""
    path = tmp_path / "s.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=re.escape(message)):
        read_yaml(path)


def test_a_thousand_aliases_of_aliases_are_read_at_once(tmp_path):
    """Ten references a level, nine levels (a billion leaves if expanded): the depth walk takes each
    node once a level, and the values are shared, not copied."""
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x, x]"]
    lines += [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]" for i in range(1, 10)]
    path = tmp_path / "s.yaml"
    path.write_text("\n".join(lines) + "\n")
    data, _ = read_yaml(path)
    assert data["a9"][0][0][0][0][0][0][0][0][0][0] == "x"
    assert data["a9"][0] is data["a8"]


def test_missing_scene_file(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["render", "missing.yaml"]) == 2
    assert capsys.readouterr().err.strip() == "mitsuforest: missing.yaml: file not found"


def test_a_sensor_files_syntax_error_names_it_as_the_scene_names_it(tmp_path, monkeypatch, capsys):
    """Relative to the working folder, as every other error names a file (it printed the absolute path)."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "s.yaml").write_text("name: x\nbeam_divergence: [1,\n")
    (tmp_path / "scene.yaml").write_text(GOOD.replace(str(SENSORS / "riegl_vux-1uav22.yaml"), "s.yaml"))
    assert main(["plan", "scene.yaml"]) == 2
    assert capsys.readouterr().err.startswith("mitsuforest: s.yaml: YAML syntax error: line 3")


def test_errors_inside_a_sensor_file_name_that_file(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "s.yaml").write_text("name: x\nbeam_divergence: -1\npulse_frequencies: [1000]\n")
    (tmp_path / "scene.yaml").write_text(GOOD.replace(str(SENSORS / "riegl_vux-1uav22.yaml"), "s.yaml"))
    assert main(["plan", "scene.yaml"]) == 2
    assert capsys.readouterr().err.strip() == "mitsuforest: s.yaml: beam_divergence: must be >= 0, got -1"


@pytest.mark.parametrize(("line", "message"), [
    ("speckle_looks: 65", "speckle_looks: must be <= 64, got 65"),
    ("speckle_looks: 1.5", "speckle_looks: must be an integer, got 1.5"),
    ("footprint_range_noise: -1", "footprint_range_noise: must be >= 0, got -1"),
    ("range_precision_per_metre: x", "range_precision_per_metre: must be a number, got 'x'"),
    ("intensity: {saturation: 70000}", "intensity.saturation: must be <= 65535, got 70000"),
    ("intensity: {gain: 0}", "intensity.gain: must be > 0, got 0"),
    ("intensity: {source: counts}", "intensity.source: must be one of amplitude, reflectance, reflectance_db, got 'counts'"),
    ("intensity: {scale: 2}", "intensity.scale: unknown key"),
    ("wavelength: 905", "wavelength: must be <= 2e-05, got 905 (metres: 905 nm is 905e-9)"),
    ("wavelength: 1e-9", "wavelength: must be >= 2e-07, got 1e-09"),
    ("pulse_length: 4", "pulse_length: must be <= 1e-06, got 4 (seconds: 4 ns is 4e-9)"),
    ("beam_divergence: [0.5, 0.5]", "beam_divergence[0]: must be <= 0.3, got 0.5 (radians, full angle: 0.5 mrad is 0.5e-3)"),
    # each of these passed and then ended the render in a traceback, or rendered no point, saying nothing:
    ("range_precision: 1e300", "range_precision: must be <= 10, got 1e+300"),
    ("range_precision_per_metre: 1e300", "range_precision_per_metre: must be <= 0.1, got 1e+300"),
    ("footprint_range_noise: 1e300", "footprint_range_noise: must be <= 10, got 1e+300"),
    ("range_max: 1e300", "range_max: must be <= 100000, got 1e+300"),
    ("waveform: {bin_size: 1e-300}", "waveform.bin_size: must be >= 1e-11, got 1e-300"),
    ("pulse_length: 1e-300", "pulse_length: must be >= 1e-11, got 1e-300"),
    ("echo_separation: 1e-300", "echo_separation: must be >= 0.0001, got 1e-300"),
    ("mount: {lever_arm: [1e6, 0, 0]}", "mount.lever_arm[0]: must be <= 100, got 1e+06"),
    ("scan_frequency_range: [0, 0]", "scan_frequency_range: a rotating deflector needs a scan frequency above 0"),
    ("scan_frequency_range: [1e300, 1e300]", "scan_frequency_range[0]: must be <= 10000, got 1e+300"),
    ("risley: {prism_rates: [1e300, 1]}", "risley.prism_rates[0]: must be <= 10000, got 1e+300"),
])
def test_bad_noise_and_intensity_keys_of_a_sensor_file(tmp_path, monkeypatch, capsys, line, message):
    monkeypatch.chdir(tmp_path)
    divergence = "" if line.startswith("beam_divergence") else "beam_divergence: [1.0e-3, 0.5e-3]\n"
    (tmp_path / "s.yaml").write_text(f"name: x\n{divergence}pulse_frequencies: [200000]\n{line}\n")
    (tmp_path / "scene.yaml").write_text(GOOD.replace(str(SENSORS / "riegl_vux-1uav22.yaml"), "s.yaml"))
    assert main(["plan", "scene.yaml"]) == 2
    assert capsys.readouterr().err.strip().startswith(f"mitsuforest: s.yaml: {message}")


def test_sensor_noise_and_intensity_defaults_keep_the_old_behaviour(tmp_path):
    (tmp_path / "s.yaml").write_text("name: x\nbeam_divergence: 1.0e-3\npulse_frequencies: [200000]\n")
    sensor = load_sensor(tmp_path / "s.yaml")
    assert (sensor.range_precision_per_metre, sensor.footprint_range_noise, sensor.speckle_looks) == (0, 0, 0)
    assert (sensor.intensity.source, sensor.intensity.gain, sensor.intensity.offset, sensor.intensity.saturation) == \
        ("amplitude", 1e6, 0, 65535)
    livox = load_sensor(SENSORS / "livox_mid-70.yaml")
    assert livox.beam_divergence == pytest.approx((np.deg2rad(0.03), np.deg2rad(0.28)), rel=0.01)
    assert livox.intensity.source == "reflectance" and livox.intensity.saturation == 255 * 256


def test_defaults_and_relative_paths(tmp_path):
    (tmp_path / "scene.yaml").write_text(GOOD)
    scene = load_scene(tmp_path / "scene.yaml")
    assert scene.simulation.beam_samples == 19 and scene.simulation.beam_pattern == "stratified"
    assert scene.simulation.point_position == "beam_axis"
    assert scene.output.formats == ("pcd", "laz")
    assert scene.survey.scan_frequency is None and scene.scan_frequency == 50
    assert scene.sensor.beam_divergence == (0.5e-3, 0.5e-3)
    assert scene.forest.archetypes[0].height > 0 and len(scene.forest.archetypes) == 10
    demo = load_scene(ROOT / "scenes" / "demo.yaml")
    assert demo.sensor.file == str(SENSORS / "riegl_vux-1uav22.yaml")
    assert demo.output.dir == str(ROOT / "out" / "demo")


def test_every_shipped_file_loads():
    from mitsuforest.dataset import load_dataset
    for path in sorted((ROOT / "scenes").glob("*.yaml")) + sorted((ROOT / "examples").glob("*.yaml")):
        if path.name == "dataset.yaml":                  # a dataset file: a base scene and what varies
            assert len(load_dataset(path).plots) == 8
        else:
            assert load_scene(path).name


def test_derived_values_follow_edits(tmp_path):
    """A notebook user replaces the sensor or the altitude: every derived value follows."""
    (tmp_path / "scene.yaml").write_text(GOOD.replace("pulse_frequency: 200000", "scan_frequency: 100"))
    scene = load_scene(tmp_path / "scene.yaml")
    assert scene.pulse_frequency == 200000 and scene.scan_frequency == 100
    assert scene.sensor.detection_threshold == 2e-7               # the sensor file's own value
    near = scene.with_({"sensor.detection_threshold": None, "sensor.range_max": 200})
    assert near.sensor.detection_threshold == pytest.approx(0.2 / 200 ** 2)
    assert near.sensor.file is None and scene.sensor.file             # an edited sensor is no longer its file
    mini = scene.with_(sensor=load_sensor(SENSORS / "riegl_minivux-1uav.yaml"), survey={"scan_frequency": None})
    assert mini.pulse_frequency == 100000 and mini.scan_frequency == 50
    assert mini.sensor.resolving_distance == pytest.approx(299_792_458.0 * mini.sensor.pulse_length / 2)
    assert mini.sensor.half_fov == pytest.approx(np.pi)
    high = dataclasses.replace(scene, survey=dataclasses.replace(scene.survey, altitude=60))
    assert make_plan(high).legs[0].start[2] == 60
    cover = scene.with_(forest={"trees": None, "type": "closed"})
    assert cover.forest.target_cover == pytest.approx(0.9)


BAD_EDITS = {
    "beam samples": ({"simulation.beam_samples": 0}, "scene.yaml: simulation.beam_samples: must be >= 1, got 0"),
    "beam samples cap": ({"simulation.beam_samples": 62}, "simulation.beam_samples: must be <= 61, got 62"),
    "altitude": ({"survey.altitude": -5}, "scene.yaml: survey.altitude: must be > 0, got -5"),
    "sensor value": ({"sensor.range_max": -1}, "scene.yaml: sensor.range_max: must be > 0, got -1"),
    "unknown key": ({"survey.altitud": 30}, "scene.yaml: survey.altitud: unknown key (did you mean 'altitude'?)"),
    "unknown section": ({"surve.altitude": 30}, "scene.yaml: surve: unknown key (did you mean 'survey'?)"),
    "not a section": ({"seed.x": 1}, "scene.yaml: seed.x: seed is not a section"),
    "pulse rate": ({"survey.pulse_frequency": 150000},
                   "survey.pulse_frequency: 150000 Hz is not one of the sensor's pulse frequencies"),
    "variant": ({"simulation.variant": "scalar_rgb"}, "simulation.variant: must be auto or a Mitsuba llvm_*"),
    "nan": ({"forest.trees": float("nan")}, "forest.trees: must be finite, got nan"),
    "crs": ({"origin.crs": "EPSG:999999"}, "scene.yaml: origin.crs: 'EPSG:999999' is not a coordinate reference system"),
    "crs in degrees": ({"origin.crs": "EPSG:4326"}, "scene.yaml: origin.crs: 'EPSG:4326' (WGS 84) is geographic, in degrees"),
}


@pytest.mark.parametrize("case", sorted(BAD_EDITS))
def test_bad_edits_are_refused_like_the_yaml(case, tmp_path):
    (tmp_path / "scene.yaml").write_text(GOOD)
    scene = load_scene(tmp_path / "scene.yaml")
    change, message = BAD_EDITS[case]
    with pytest.raises(ConfigError) as e:
        scene.with_(change)
    assert message in str(e.value)


def test_replace_is_validated_and_render_validates_mappings(tmp_path):
    (tmp_path / "scene.yaml").write_text(GOOD)
    scene = load_scene(tmp_path / "scene.yaml")
    with pytest.raises(ConfigError, match="survey.speed: must be > 0, got 0"):
        dataclasses.replace(scene, survey=dataclasses.replace(scene.survey, speed=0))
    data = yaml.safe_load(GOOD)
    data["simulation"] = {"beam_samples": 0}
    with pytest.raises(ConfigError, match="<scene>: simulation.beam_samples: must be >= 1, got 0"):
        render(data, write=False)


def test_version(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.startswith("mitsuforest 0.")


def test_a_flight_whose_ground_is_out_of_range_but_a_tall_tree_is_not_plans(tmp_path):
    """From 1,100 m the VUX-1UAV22 (range_max 1,000 m) cannot reach the ground, but would reach the top of
    a tree 100 m tall or more: not refused (from 1,200 m nothing 150 m tall is in reach, above)."""
    (tmp_path / "scene.yaml").write_text(GOOD.replace("altitude: 30", "altitude: 1100"))
    assert make_plan(load_scene(tmp_path / "scene.yaml")).legs
    (tmp_path / "scene.yaml").write_text(GOOD.replace("altitude: 30", "altitude: 1200"))
    with pytest.raises(ConfigError, match="lies 1,050.0 m from leg 1"):
        make_plan(load_scene(tmp_path / "scene.yaml"))
