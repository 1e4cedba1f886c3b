import os
import signal
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).parent))

from mitsuforest.scene.variant import available_variants  # noqa: E402

# A suite started in the background (`bash .ci/run &`, nohup) inherits SIGINT ignored, and so would every
# render it starts: the interrupt tests need Ctrl-C's usual meaning, in this process and its children.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

# Every test that runs Dr.Jit runs on each variant this machine has: llvm_ad_mono, and cuda_ad_mono
# where a GPU is usable.
VARIANTS = available_variants()


@pytest.fixture(scope="session", autouse=True)
def model_cache(tmp_path_factory):
    """Keep model caches of test runs apart from the user's."""
    os.environ.setdefault("MITSUFOREST_CACHE", str(tmp_path_factory.mktemp("cache")))


@pytest.fixture(scope="session", params=VARIANTS)
def variant(request):
    return request.param


@pytest.fixture
def llvm_mono():
    """A test on ``llvm_ad_mono`` (the variant set for it, the one found put back after), as Mitsuba's own
    fixtures set theirs; Dr.Jit's kernel cache is flushed after it, so that its kernels do not stay in
    memory for the rest of the run."""
    import drjit as dr

    from mitsuforest.scene.variant import variant_scope
    if "llvm_ad_mono" not in VARIANTS:
        pytest.skip("needs llvm_ad_mono")
    with variant_scope("llvm_ad_mono"):
        yield "llvm_ad_mono"
    dr.flush_kernel_cache()


def _demo_scene(tmp_path_factory, variant, **understory):
    from mitsuforest.config import load_scene
    scene = load_scene(ROOT / "scenes" / "demo.yaml", variant=variant, output_dir=tmp_path_factory.mktemp("demo"))
    return scene.with_({"survey.pulse_frequency": 100000, "survey.lines": [[[10.0, -5.0], [10.0, 25.0]]],
                        "simulation.beam_samples": 7}, understory=understory)


@pytest.fixture(scope="session")
def demo_result(tmp_path_factory, variant):
    """The demo forest scanned along one leg (100 kHz, 7 sub-rays): a quick real forest scan."""
    from mitsuforest.pipeline import render
    return render(_demo_scene(tmp_path_factory, variant), write=False, progress=False, log=lambda *_: None)


@pytest.fixture(scope="session")
def demo_setup(tmp_path_factory, variant):
    """The demo's trees (no understory) loaded in Mitsuba: (scene, plan, models, scan_scene)."""
    from mitsuforest.survey import prepare
    scene = _demo_scene(tmp_path_factory, variant, bushes=0, rocks=0, deadwood=0, stumps=0)
    prepared = prepare(scene)
    return prepared.scene, prepared.plan, prepared.models, prepared.scan_scene
