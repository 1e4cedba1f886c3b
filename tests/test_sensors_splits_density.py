"""What a new user met: built-in sensors named without a path (so a copied example scene renders), a
clear message for a missing relative sensor path, densities that say what they are over, and the example
dataset's splits each holding a plot."""

import shutil

import numpy as np
import pytest

from conftest import ROOT

SENSORS = sorted(p.stem for p in (ROOT / "sensors").glob("*.yaml"))


def _scene(folder, sensor: str, pulse_frequency: int | None = 100_000):
    """A 12 m plot scanned by ``sensor`` at ``pulse_frequency`` (``None``: the sensor's own default)."""
    path = folder / "scene.yaml"
    rate = "" if pulse_frequency is None else f"pulse_frequency: {pulse_frequency}, "
    path.write_text(f"name: tiny\nseed: 3\narea: {{size: [12, 12]}}\nforest: {{type: open, trees: 1}}\n"
                    f"understory: {{bushes: 0, rocks: 0, deadwood: 0, stumps: 0}}\nsensor: {sensor}\n"
                    f"survey: {{altitude: 30, speed: 20, {rate}line_spacing: 6, margin: 2}}\n"
                    "simulation: {beam_samples: 1, beam_pattern: fixed}\noutput: {formats: [laz]}\n")
    return path


def test_the_package_ships_every_sensor_of_sensors_folder():
    from mitsuforest.config import BUILTIN_SENSORS, builtin_sensors
    assert builtin_sensors() == SENSORS and len(SENSORS) >= 5
    assert BUILTIN_SENSORS.is_relative_to(ROOT / "mitsuforest")


@pytest.mark.parametrize("name", SENSORS)
def test_a_builtin_sensor_is_named_without_a_path(tmp_path, name):
    from mitsuforest.config import load_scene, load_sensor
    scene = load_scene(_scene(tmp_path, name, pulse_frequency=None))
    assert scene.sensor == load_sensor(ROOT / "sensors" / f"{name}.yaml")
    assert scene.sensor.file == str((ROOT / "sensors" / f"{name}.yaml").resolve())


def test_an_unknown_sensor_name_lists_the_builtin_ones(tmp_path, capsys):
    from mitsuforest.cli import main
    path = _scene(tmp_path, "livox_avia")
    assert main(["plan", str(path), "-o", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"mitsuforest: {path}: sensor: unknown built-in sensor 'livox_avia'; built-in sensors: "
        f"{', '.join(SENSORS)} (or give a sensor file's path)"]
    assert not (tmp_path / "out").exists()


def test_a_missing_relative_path_to_a_builtin_sensor_says_to_name_it(tmp_path, capsys):
    from mitsuforest.cli import main
    path = _scene(tmp_path, "../sensors/riegl_minivux-1uav.yaml")
    assert main(["plan", str(path), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    missing = tmp_path.parent / "sensors" / "riegl_minivux-1uav.yaml"
    assert err == [f"mitsuforest: {path}: sensor: file not found: {missing} "
                   "(relative paths are read from the scene file's folder); the built-in sensor of that name is "
                   "named without a path: sensor: riegl_minivux-1uav"]


def test_a_copied_example_scene_loads(tmp_path):
    """examples/custom_scene.yaml copied elsewhere (its sensor was ../sensors/..., relative to the copy)."""
    from mitsuforest.config import load_scene
    copy = tmp_path / "mine.yaml"
    shutil.copy(ROOT / "examples" / "custom_scene.yaml", copy)
    assert load_scene(copy).sensor.name == load_scene(ROOT / "examples" / "custom_scene.yaml").sensor.name


def test_the_example_dataset_gives_every_split_a_plot():
    """8 plots at 0.75 / 0.125 / 0.125: 6 / 1 / 1 (validation was empty)."""
    from mitsuforest.dataset import load_dataset
    from mitsuforest.dataset.files import assign_splits
    dataset = load_dataset(ROOT / "examples" / "dataset.yaml")
    splits = assign_splits([p.name for p in dataset.plots], dataset.splits, dataset.seed)
    assert {k: len(v) for k, v in splits.items()} == {k: round(r * len(dataset.plots))
                                                      for k, r in dataset.splits.items()} == \
        {"train": 6, "validation": 1, "test": 1}


@pytest.mark.parametrize("ratios", [{"train": 0.75, "validation": 0.125, "test": 0.125},
                                    {"train": 0.8, "validation": 0.1, "test": 0.1},
                                    {"train": 0.6, "validation": 0.3, "test": 0.1}])
def test_the_first_plots_hold_every_split(ratios):
    """From as many plots as splits on, every split with a place in the first block of 10 has a plot, for
    every seed."""
    from mitsuforest.dataset.files import assign_splits
    names = [f"plot_{i:04d}" for i in range(10)]
    for seed in range(50):
        for n in range(len(ratios), 11):
            assert all(assign_splits(names[:n], ratios, seed).values()), (seed, n)


def test_a_split_left_empty_is_explained(tmp_path):
    from mitsuforest.dataset import load_dataset
    from mitsuforest.dataset.runner import _empty_splits
    (tmp_path / "set.yaml").write_text(f"base: {ROOT}/scenes/demo.yaml\nplots: 3\n"
                                       "splits: {train: 0.9, validation: 0.05, test: 0.05}\n")
    dataset = load_dataset(tmp_path / "set.yaml")
    from mitsuforest.dataset.files import assign_splits
    splits = assign_splits([p.name for p in dataset.plots], dataset.splits, dataset.seed)
    empty = [k for k, v in splits.items() if not v]
    assert empty and _empty_splits(splits, dataset) == [
        f"split '{k}' (5.0%) holds none of the 3 plots: 3 plots at 5.0% make 0.15 of one (each block of 10 plots "
        "gets its share, rounded)" for k in empty]


def test_render_and_info_say_what_their_densities_are_over(tmp_path):
    """The render's density is over the plot (144 m²), `info`'s over the points' bounding box, which the
    swaths overrun: both say so, and each number is its count over its area."""
    from mitsuforest.pipeline import render
    from mitsuforest.write.info import summary
    lines = []
    result = render(_scene(tmp_path, "riegl_vux-1uav22"), output_dir=tmp_path / "out", progress=False,
                    log=lines.append)
    points = result.manifest["points"]
    scan_line = next(line for line in lines if line.startswith("scan:"))
    assert scan_line.endswith(f", {points / 144:.0f} points/m2 over the plot (12 x 12 m)")
    info = summary(tmp_path / "out" / "tiny.laz").splitlines()
    bounds = dict(zip("xyz", [tuple(map(float, part.split()[1::2])) for part in info[2][8:].split("  ")]))
    area = (bounds["x"][1] - bounds["x"][0]) * (bounds["y"][1] - bounds["y"][0])
    assert area > 144
    density = next(line for line in info if line.startswith("density:"))
    assert density.startswith(f"density: {points / area:.1f} points/m2 over the x-y bounding box ({area:.1f} m2; "
                              "a render reports its density over its plot")
    assert np.isclose(result.manifest["density_per_m2"], points / 144)
