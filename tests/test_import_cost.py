"""What reading point files imports. ``mitsuforest info`` and ``compare`` import write and compare, and
write reads scan.radiometry, so the scan package is imported too; the modules that run Dr.Jit import
``drjit`` and ``mitsuba`` at the top, so the scan package loads them (Platform, PulseTracer) on first
use, and reading point files loads neither Mitsuba nor Dr.Jit."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

LOADED = "sorted(m for m in ('mitsuba', 'drjit') if m in sys.modules)"


def test_reading_point_files_loads_no_mitsuba_and_the_scan_side_loads_on_first_use():
    code = ("import sys\n"
            "import mitsuforest.compare, mitsuforest.scan, mitsuforest.write, mitsuforest.write.info\n"
            f"print({LOADED})\n"
            "from mitsuforest.scan import POINT_DTYPE, Platform, PulseTracer\n"
            "from mitsuforest.scan.tracer import POINT_DTYPE as TRACER_DTYPE\n"
            f"print({LOADED}, Platform.__module__, PulseTracer.__module__, POINT_DTYPE is TRACER_DTYPE)\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.splitlines() == ["[]", "['drjit', 'mitsuba'] mitsuforest.scan.platform mitsuforest.scan.tracer True"]


def test_a_render_of_cached_models_imports_no_trimesh():
    """trimesh (0.45 s to import, with scipy.ndimage) reads meshes and repairs imported wood: a render,
    a dataset worker or the command line whose models are cached never needs it, so none of them loads
    it until a model is built or a mesh is read."""
    code = ("import sys\n"
            "import mitsuforest.cli, mitsuforest.pipeline, mitsuforest.dataset.tasks\n"
            "print('trimesh' in sys.modules)\n"
            "from mitsuforest.trees.repair import boundary_loops\n"
            "import numpy as np\n"
            "print(boundary_loops(np.array([[0, 1, 2]])), 'trimesh' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.splitlines() == ["False", "1 True"]


def test_the_writers_worker_processes_load_neither_the_plan_nor_scipy():
    """A writer's worker process imports ``write.processes`` (0.25 s on a 2-core Xeon): the scan package's
    navigation (which reads the plan package's frames, and so scipy's qhull) loads on first use, not
    through the radiometry that the LAS records read."""
    modules = "sorted(m for m in ('mitsuforest.plan', 'scipy', 'mitsuba', 'drjit') if m in sys.modules)"
    code = ("import sys\n"
            "import mitsuforest.write.processes\n"
            f"print({modules})\n"
            "from mitsuforest.scan import NavigationModel\n"
            "print(NavigationModel.__module__)\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.splitlines() == ["[]", "mitsuforest.scan.navigation"]
