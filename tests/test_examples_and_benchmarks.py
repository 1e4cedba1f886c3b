"""Every example and benchmark runs (quick versions, no timing assertions), so none can rot."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from helpers import ROOT

EXAMPLES = ["leaf_wood.py", "instances.py", "wood_volume.py", "sensors.py", "python_api.py", "own_models.py"]


def _run(args, cwd):
    proc = subprocess.run([sys.executable, *args], cwd=cwd, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-4000:]
    return proc.stdout


@pytest.fixture(scope="module")
def shared_render(tmp_path_factory):
    """One quick demo render shared by the examples that only read points."""
    return tmp_path_factory.mktemp("examples")


@pytest.mark.slow
@pytest.mark.parametrize("name", EXAMPLES)
def test_example_runs(name, shared_render):
    out = shared_render / name.removesuffix(".py")
    stdout = _run([str(ROOT / "examples" / name), "--quick", "--out", str(out)], ROOT)
    expected = {"leaf_wood.py": "confusion_matrix.csv", "instances.py": "instances_side.png",
                "wood_volume.py": "training_table.csv", "sensors.py": "sensors.md", "python_api.py": None,
                "own_models.py": "render-quick/own_models_manifest.json"}[name]
    if expected:
        assert (out / expected).exists(), stdout
    if name == "leaf_wood.py":
        assert "accuracy" in stdout and "IoU wood" in stdout
    if name == "own_models.py":
        assert "reoriented" in stdout and stdout.count("repaired ") == 4 and "treeid 4:" in stdout
    if name == "sensors.py":
        assert stdout.count("| RIEGL") == 3 and "Livox" in stdout and "ideal" in stdout
        assert "| Leica ALS50-II | 300 m |" in stdout


def test_an_example_does_not_reuse_the_render_of_the_other_mode(tmp_path, monkeypatch):
    """``--quick`` renders one leg at 100 kHz and 7 sub-rays: a full run into the same ``--out`` renders
    the demo again rather than reading the quick render's points (and a quick run after a full one)."""
    import importlib.util
    from pathlib import Path
    import mitsuforest as mf
    spec = importlib.util.spec_from_file_location("examples_common", ROOT / "examples" / "common.py")
    common = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(common)
    rendered = []

    def render(scene, **_):
        folder = Path(scene.output.dir)
        folder.mkdir(parents=True, exist_ok=True)
        (folder / f"{scene.name}_manifest.json").write_text("{}")
        rendered.append((folder, scene.simulation.beam_samples))

    monkeypatch.setattr(mf, "render", render)
    monkeypatch.setattr(mf, "read_pcd", lambda path: path)
    for quick in (True, False, True, False):                # the second of each mode reads its own render
        common.load_render(ROOT / "scenes" / "demo.yaml", tmp_path, quick)
    assert [samples for _, samples in rendered] == [7, 19]
    assert rendered[0][0] != rendered[1][0]


def test_the_instances_example_keeps_trees_numbered_past_ten(tmp_path):
    """examples/instances.py measures every tree: a tree's points are its wood and leaves, whatever its
    treeid. Trees are numbered past ten (unique trees, a tree list: deadwood then one past the last), and
    selecting treeid 1-10 dropped tree 12 here. The render it reads is a hand-made PCD in the quick
    render's folder: ground at z 0, tree 1 (treeid 3) 10 points up to 9 m, tree 2 (treeid 12) 10 points
    up to 5.5 m, deadwood (treeid 13) 10 points."""
    from mitsuforest.fields import RECORD_DTYPE, pcd_dtype
    from mitsuforest.write.pcd import pcd_header
    points = np.zeros(40, pcd_dtype(RECORD_DTYPE, local=True))
    points["classification"] = [1] * 10 + [2] * 5 + [3] * 5 + [3] * 10 + [4] * 10
    points["instance"] = [0] * 10 + [1] * 10 + [2] * 10 + [3] * 10
    points["treeid"] = [0] * 10 + [3] * 10 + [12] * 10 + [13] * 10
    points["x"] = np.tile(np.arange(10.0), 4)
    points["z"] = np.concatenate([np.zeros(10), np.arange(10.0), np.arange(10.0) / 2 + 1, np.full(10, 0.2)])
    folder = tmp_path / "render-quick"
    folder.mkdir()
    (folder / "demo.pcd").write_bytes(pcd_header(points.dtype, len(points)).encode() + points.tobytes())
    (folder / "demo_manifest.json").write_text("{}")
    _run([str(ROOT / "examples" / "instances.py"), "--out", str(tmp_path), "--quick"], ROOT)
    rows = (tmp_path / "trees.csv").read_text().splitlines()
    assert rows[0] == "instance,treeid,points,height_m,crown_diameter_m"
    assert [r.split(",")[:4] for r in rows[1:]] == [["1", "3", "10", "9.00"], ["2", "12", "10", "5.50"]]


def test_custom_scene_plans(tmp_path):
    from mitsuforest.cli import main
    assert main(["plan", str(ROOT / "examples" / "custom_scene.yaml"), "-o", str(tmp_path)]) == 0
    assert main(["plan", str(ROOT / "examples" / "own_models.yaml"), "-o", str(tmp_path)]) == 0
    assert main(["plan", str(ROOT / "examples" / "flight.yaml"), "-o", str(tmp_path)]) == 0


def test_flight_data_is_what_the_example_writes(tmp_path):
    import importlib.util
    spec = importlib.util.spec_from_file_location("make_flight", ROOT / "examples" / "data" / "make_flight.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.main(tmp_path / "flight.csv").read_bytes() == (ROOT / "examples" / "data" / "flight.csv").read_bytes()


def test_own_models_data_is_what_the_example_writes(tmp_path):
    import importlib.util
    sys.path.insert(0, str(ROOT / "examples"))
    spec = importlib.util.spec_from_file_location("own_models", ROOT / "examples" / "own_models.py")
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    example.write_mesh_tree(tmp_path / "sapling_tree.obj")
    example.write_qsm(tmp_path / "small_qsm.txt")
    for name in ("sapling_tree.obj", "sapling_tree.mtl", "small_qsm.txt"):
        assert (tmp_path / name).read_bytes() == (ROOT / "examples" / "data" / name).read_bytes(), name


@pytest.mark.slow
def test_stability_benchmark_quick():
    """The figures only (tests/test_stability.py checks the cases)."""
    stdout = _run([str(ROOT / "benchmarks" / "stability.py"), "--quick"], ROOT)
    assert "chains_vs_maxima" in stdout and "too_many_returns" in stdout


@pytest.mark.slow
def test_label_purity_benchmark_quick():
    stdout = _run([str(ROOT / "benchmarks" / "label_purity.py"), "--quick"], ROOT)
    assert "beam_axis: 5,000 of" in stdout and "surface: 5,000 of" in stdout


def test_point_to_triangle_distance_of_the_label_purity_benchmark():
    """The exact distance against points placed in each Voronoi region of one triangle."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from label_purity import point_triangle_distance, within
    import numpy as np
    a, b, c = np.array([0.0, 0, 0]), np.array([1.0, 0, 0]), np.array([0.0, 1, 0])
    p = np.array([[0.2, 0.2, 0.5], [-1, -1, 0], [2, 0, 0], [0, 3, 0], [0.5, -2, 0], [-2, 0.5, 0], [1, 1, 0]])
    expected = [0.5, np.sqrt(2), 1, 2, 2, 2, np.sqrt(0.5)]
    got = point_triangle_distance(p, *(np.tile(v, (len(p), 1)) for v in (a, b, c)))
    assert np.allclose(got, expected, atol=1e-12)
    assert within(p, np.array([[a, b, c]]), 1.0).tolist() == [True, False, True, False, False, False, True]


@pytest.mark.slow
def test_speed_vs_error_benchmark_quick(tmp_path):
    stdout = _run([str(ROOT / "benchmarks" / "speed_vs_error.py"), "--quick", "--out", str(tmp_path)], ROOT)
    assert "7 fixed" in stdout and "7 stratified" in stdout and "chains_not_maxima" in stdout and (tmp_path / "speed_vs_error.json").exists()


@pytest.mark.slow
def test_full_scenes_benchmark_quick(tmp_path):
    stdout = _run([str(ROOT / "benchmarks" / "full_scenes.py", ), "open", "--quick", "--out", str(tmp_path)], ROOT)
    assert "pts/m2 (paper 3593)" in stdout
    import json
    run = json.loads((tmp_path / "full_scenes.json").read_text())[0]
    points, returns = run["points"], run["returns_histogram"]
    assert run["scene"] == "open" and run["beam_samples"] == 19 and points > 50_000
    assert points == sum(int(n) * count for n, count in returns.items())   # a pulse of n returns gives n points
    assert points == sum(run["classes"].values())
    assert run["density_per_m2"] * 400 == pytest.approx(points)            # the quick plot is 20 m x 20 m
    assert sum(returns.values()) <= run["pulses_cast"]


@pytest.mark.slow
def test_profile_leg_benchmark():
    stdout = _run([str(ROOT / "benchmarks" / "profile_leg.py"), "--scene", str(ROOT / "scenes" / "demo.yaml")], ROOT)
    assert "demo.yaml, leg 1: 3,000,000 time slots" in stdout, stdout      # the middle of its three legs
    assert "rays and hit lookup" in stdout and "labels" in stdout and "points/s" in stdout


def test_helios_compare_without_helios_says_so(tmp_path):
    env = {**os.environ, "PATH": str(tmp_path)}   # no helios++ on it
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "helios_compare.py")], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0 and "helios++ not found (not on PATH and no --helios)" in proc.stdout, proc.stderr
    missing = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "helios_compare.py"), "--helios",
                              str(tmp_path / "none")], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert missing.returncode == 2 and missing.stderr == f"--helios {tmp_path / 'none'}: no such executable\n"


FAILING_HELIOS = '''
import sys
print("arguments:", " ".join(sys.argv[3:]))
print("ERROR: the kd-tree does not fit in memory", file=sys.stderr)
sys.exit(3)
'''


@pytest.mark.slow
def test_helios_compare_keeps_the_helios_log_and_passes_its_flags(tmp_path):
    """HELIOS++'s output (stdout and stderr) is kept in WORK/logs/helios.log, a failing run prints its
    tail and the log's path, and --helios-args reach the helios++ command."""
    fake = tmp_path / "helios++"
    fake.write_text(f"#!{sys.executable}\n" + FAILING_HELIOS)
    fake.chmod(0o755)
    from test_config import GOOD
    (tmp_path / "small.yaml").write_text(GOOD)   # one tree, no understory: a quick export
    work = tmp_path / "work"
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "helios_compare.py"), "--helios", str(fake),
                           "--scene", str(tmp_path / "small.yaml"), "--quick", "--work", str(work),
                           "--helios-args", "--kdtJobs 1 --nthreads 2"],
                          cwd=ROOT, capture_output=True, text=True, timeout=600)
    log = work / "logs" / "helios.log"
    assert proc.returncode == 1, proc.stderr
    assert set(log.read_text().splitlines()) == {f"arguments: {work / 'helios_out'} --kdtJobs 1 --nthreads 2",
                                                 "ERROR: the kd-tree does not fit in memory"}
    assert f"failed (3); its log, {log}, ends:" in proc.stderr and "ERROR: the kd-tree" in proc.stderr


FAKE_HELIOS = '''
import sys
from pathlib import Path

import numpy as np

from mitsuforest.helios.render import render_survey

survey, out = sys.argv[1], Path(sys.argv[sys.argv.index("--output") + 1])
pts = render_survey(survey, write=False, progress=False, log=lambda *_: None).points   # the survey's seed
folder = out / "survey" / "2026-01-01_00-00-00"
folder.mkdir(parents=True)
columns = [pts["x"], pts["y"], pts["z"], pts["intensity"], np.zeros(len(pts)), pts["return_number"],
           pts["number_of_returns"], np.zeros(len(pts)), pts["object_id"], pts["classification"], pts["gps_time"]]
np.savetxt(folder / "leg000_points.xyz", np.column_stack(columns), fmt="%.4f")
'''


@pytest.mark.slow
def test_helios_compare_runs_against_a_stand_in(tmp_path):
    """A stand-in for helios++ that flies the exported survey with ``render SURVEY.xml`` and writes
    HELIOS++'s .xyz columns: the comparison's plumbing, and trees in place on both sides."""
    fake = tmp_path / "helios++"
    fake.write_text(f"#!{sys.executable}\n" + FAKE_HELIOS)
    fake.chmod(0o755)
    stdout = _run([str(ROOT / "benchmarks" / "helios_compare.py"), "--helios", str(fake), "--quick",
                   "--work", str(tmp_path / "work")], ROOT)
    assert "peak memory (GB)" in stdout and "share tree_leaves" in stdout
    offsets = [float(line.split()[1]) for line in stdout.splitlines()[1:]
               if line.split() and line.split()[0].isdigit() and line.split()[1] != "-"]
    assert offsets and max(offsets) < 0.001, stdout   # the same seed: the same points


@pytest.mark.slow
def test_dataset_benchmark_quick(tmp_path):
    stdout = _run([str(ROOT / "benchmarks" / "dataset.py"), "--quick", "--out", str(tmp_path)], ROOT)
    assert "| 2 |" in stdout and "leg tasks" in stdout and "merge" in stdout


@pytest.mark.slow
def test_own_models_benchmark_quick():
    stdout = _run([str(ROOT / "benchmarks" / "own_models.py"), "--quick"], ROOT)
    assert "load + split + repair + union" in stdout and "scene with 3 placed copies" in stdout



@pytest.mark.slow
def test_terrain_benchmark_quick():
    stdout = _run([str(ROOT / "benchmarks" / "terrain.py"), "--quick"], ROOT)
    assert "dem: 200 x 200 cells" in stdout and "mesh: 20,000 triangles" in stdout


@pytest.mark.slow
def test_strips_benchmark_quick(tmp_path):
    stdout = _run([str(ROOT / "benchmarks" / "strips.py"), "--quick", "--out", str(tmp_path / "strips.png")], ROOT)
    assert "true trajectory:" in stdout and "with navigation errors:" in stdout and (tmp_path / "strips.png").exists()


@pytest.mark.slow
def test_pictures_benchmark_quick():
    stdout = _run([str(ROOT / "benchmarks" / "pictures.py"), "--quick"], ROOT)
    assert "points: 2,000,000" in stdout and "pictures in all" in stdout


@pytest.mark.slow
def test_warm_render_benchmark_renders_a_scene_cold_then_warm(tmp_path):
    from helpers import tiny_scene
    path = tmp_path / "tiny.yaml"
    path.write_text(tiny_scene(1, 1, 0, 0, 0))
    stdout = _run([str(ROOT / "benchmarks" / "warm_render.py"), str(path), "--beam-samples", "3",
                   "--manifest", str(tmp_path / "manifest.json")], ROOT)
    runs = [line.split(":")[0] for line in stdout.splitlines()]
    points = {line.split(" CPU, ")[1].split(" points")[0] for line in stdout.splitlines()}
    assert runs == ["cold", "warm"] and len(points) == 1, stdout          # the same points both times
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert f"{manifest['points']:,}" in points and manifest["scene"]["simulation"]["beam_samples"] == 3


@pytest.mark.slow
def test_writer_benchmark_quick():
    stdout = _run([str(ROOT / "benchmarks" / "writer.py"), "--quick"], ROOT)
    rows = [line.split() for line in stdout.splitlines() if line.split() and line.split()[0].isdigit()]
    assert [r[0] for r in rows] == ["1", "2"] and rows[0][-2:] == rows[1][-2:], stdout   # same hashes


@pytest.mark.slow
def test_writer_benchmark_parts_adds_up_its_steps():
    stdout = _run([str(ROOT / "benchmarks" / "writer.py"), "--parts"], ROOT)
    steps = {line.rsplit(None, 4)[0].strip(): line.split()[-4] for line in stdout.splitlines()
             if line.endswith(" ns a point")}
    total = float(stdout.split(" sum ")[1].split()[0])
    assert len(steps) == 7 and "LAZ chunks compressed" in steps, stdout
    assert all(float(ns) > 0 for ns in steps.values()), stdout
    assert total == pytest.approx(sum(float(ns) for ns in steps.values()), abs=0.5), stdout
    assert float(steps["LAZ chunks compressed"]) > float(steps["header summary"]), stdout   # lazrs' arithmetic coder


@pytest.mark.slow
def test_copc_benchmark_small():
    pytest.importorskip("copclib", reason="copclib (the test extra) writes COPC")
    stdout = _run([str(ROOT / "benchmarks" / "copc_write.py"), "200000"], ROOT)
    assert "200,000 points: spool" in stdout and "after the octree" in stdout


@pytest.mark.slow
def test_readme_python_block_runs():
    """README's "From Python" block, run as written (from the repository root), gives the values its
    comments state and points with labels."""
    text = (ROOT / "README.md").read_text()
    block = text.split("From Python:\n\n```python\n", 1)[1].split("```", 1)[0]
    script = block + ("assert scene.pulse_frequency == 100000 and abs(scene.sensor.detection_threshold - 9.6e-06) < 1e-12\n"
                      "assert len(result.points) > 10000 and set(result.points['classification']) >= {1, 2, 3}\n")
    _run(["-c", script], ROOT)


@pytest.mark.slow
def test_learning_curve_benchmark_smallest():
    """Two training plots and one test plot per condition: the table has its rows, and the classifier
    tells wood from leaves on trees it never saw far better than chance (0.5)."""
    stdout = _run([str(ROOT / "benchmarks" / "learning_curve.py"), "--plots", "2", "--test-plots", "1",
                   "--tree-points", "3000", "--no-figure", "--no-real"], ROOT)
    rows = [line.split("|")[1:-1] for line in stdout.splitlines() if line.startswith("| 1 |") or line.startswith("| 2 |")]
    assert [r[0].strip() for r in rows] == ["1", "2"]
    scores = np.array([[float(x) for x in r[1:]] for r in rows])   # balanced accuracy, wood F1, per condition
    assert scores.shape == (2, 4) and scores[:, [0, 2]].min() > 0.7 and scores.max() <= 1


@pytest.mark.slow
def test_fixed_costs_benchmark_quick():
    stdout = _run([str(ROOT / "benchmarks" / "fixed_costs.py"), "--quick", "--profile", "3", "--against", str(ROOT)], ROOT)
    assert stdout.count("| plot_0001 |") == 2 and "| fixed costs |" in stdout and "function calls" in stdout, stdout


def test_gpu_check_script_parses_and_refuses_an_unknown_step():
    """The GPU check runs only where a GPU is lent: here its syntax, and its usage on a wrong step."""
    script = ROOT / "benchmarks" / "gpu_check.sh"
    assert subprocess.run(["bash", "-n", str(script)], capture_output=True).returncode == 0
    wrong = subprocess.run(["bash", str(script), "fly"], capture_output=True, text=True)
    assert wrong.returncode == 2 and "usage:" in wrong.stderr


def test_agreement_benchmark_gives_each_counts_relative_difference(tmp_path):
    """Two manifests 1 % apart in points, 2.5 % in leaves, a class and a returns count one of them lacks."""
    a = {"variant": "llvm_ad_mono", "points": 1000, "classes": {"1": 600, "3": 400},
         "returns_histogram": {"1": 700, "2": 100}}
    b = {"variant": "cuda_ad_mono", "points": 1010, "classes": {"1": 600, "3": 410},
         "returns_histogram": {"1": 700, "2": 105, "3": 1}}
    for name, manifest in (("a", a), ("b", b)):
        (tmp_path / f"{name}.json").write_text(json.dumps(manifest))
    stdout = _run([str(ROOT / "benchmarks" / "agreement.py"), str(tmp_path / "a.json"), str(tmp_path / "b.json")], ROOT)
    assert stdout.splitlines() == [
        "| | llvm_ad_mono | cuda_ad_mono | difference |", "| --- | --- | --- | --- |",
        "| points | 1,000 | 1,010 | +1.0000% |", "| ground | 600 | 600 | +0.0000% |",
        "| tree_leaves | 400 | 410 | +2.5000% |", "| pulses with 1 returns | 700 | 700 | +0.0000% |",
        "| pulses with 2 returns | 100 | 105 | +5.0000% |", "| pulses with 3 returns | 0 | 1 | – |"]


@pytest.mark.parametrize("args, said", [(["--plots", "0"], "argument --plots: must be a whole number >= 1, got '0'"),
                                        (["--tree-points", "-5"], "argument --tree-points: must be a whole number >= 1"),
                                        (["--figure", "/no/such/folder/c.png"], "--figure: no folder /no/such/folder")])
def test_learning_curve_benchmark_refuses_bad_arguments_before_any_render(args, said):
    """Before, ``--plots 0`` trained on one plot and wrote over docs/learning_curve.png, and a bad
    ``--tree-points`` or ``--figure`` failed only after every render."""
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "learning_curve.py"), *args],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and said in proc.stderr.strip().splitlines()[-1], proc.stderr


def test_tree_list_benchmark_quick():
    """Both runs plan the twelve listed trees to the same bytes, one process and two workers."""
    stdout = _run([str(ROOT / "benchmarks" / "tree_list.py"), "--quick", "--processes", "0", "2"], ROOT)
    assert "processes 0" in stdout and "processes 2" in stdout and "plans: the same bytes" in stdout, stdout
