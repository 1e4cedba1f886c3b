"""Every example and benchmark runs (quick versions, no timing assertions), so none can rot."""

import subprocess
import sys

import pytest
from helpers import ROOT

EXAMPLES = ["leaf_wood.py", "instances.py", "wood_volume.py", "sensors.py", "python_api.py"]


def _run(args, cwd):
    proc = subprocess.run([sys.executable, *args], cwd=cwd, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-4000:]
    return proc.stdout


@pytest.fixture(scope="module")
def shared_render(tmp_path_factory):
    """One quick demo render shared by the examples that only read points."""
    return tmp_path_factory.mktemp("examples")


@pytest.mark.parametrize("name", EXAMPLES)
def test_example_runs(name, shared_render):
    out = shared_render / name.removesuffix(".py")
    stdout = _run([str(ROOT / "examples" / name), "--quick", "--out", str(out)], ROOT)
    expected = {"leaf_wood.py": "confusion_matrix.csv", "instances.py": "instances_side.png",
                "wood_volume.py": "training_table.csv", "sensors.py": "sensors.md", "python_api.py": None}[name]
    if expected:
        assert (out / expected).exists(), stdout
    if name == "leaf_wood.py":
        assert "accuracy" in stdout and "IoU wood" in stdout
    if name == "sensors.py":
        assert stdout.count("| RIEGL") == 3 and "Livox" in stdout and "ideal" in stdout


def test_custom_scene_plans(tmp_path):
    from mitsuforest.cli import main
    assert main(["plan", str(ROOT / "examples" / "custom_scene.yaml"), "-o", str(tmp_path)]) == 0


def test_stability_benchmark_quick():
    """The figures only (tests/test_stability.py checks the cases)."""
    stdout = _run([str(ROOT / "benchmarks" / "stability.py"), "--quick"], ROOT)
    assert "chains_vs_maxima" in stdout and "too_many_returns" in stdout


def test_speed_vs_error_benchmark_quick(tmp_path):
    stdout = _run([str(ROOT / "benchmarks" / "speed_vs_error.py"), "--quick", "--out", str(tmp_path)], ROOT)
    assert "7 fixed" in stdout and "7 stratified" in stdout and "chains_not_maxima" in stdout and (tmp_path / "speed_vs_error.json").exists()


def test_full_scenes_benchmark_quick(tmp_path):
    stdout = _run([str(ROOT / "benchmarks" / "full_scenes.py", ), "open", "--quick", "--out", str(tmp_path)], ROOT)
    assert "pts/m2 (paper 3593)" in stdout


def test_profile_leg_benchmark():
    stdout = _run([str(ROOT / "benchmarks" / "profile_leg.py"), "--scene", str(ROOT / "scenes" / "demo.yaml"),
                   "--leg", "1"], ROOT)
    assert "rays and labels" in stdout and "points/s" in stdout
