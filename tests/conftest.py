import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).parent))


def pytest_addoption(parser):
    parser.addoption("--runslow", action="store_true", help="also run slow full-scale tests")


def pytest_collection_modifyitems(config, items):
    if config.getoption("--runslow"):
        return
    skip = pytest.mark.skip(reason="slow full-scale run: use --runslow")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)


@pytest.fixture(scope="session", autouse=True)
def model_cache(tmp_path_factory):
    """Keep model caches of test runs apart from the user's."""
    os.environ.setdefault("MITSUFOREST_CACHE", str(tmp_path_factory.mktemp("cache")))


def _demo_scene(tmp_path_factory, **understory):
    from mitsuforest.config import load_scene
    scene = load_scene(ROOT / "scenes" / "demo.yaml", variant="llvm_ad_mono",
                       output_dir=tmp_path_factory.mktemp("demo"))
    scene["survey"]["pulse_frequency"] = 100000
    scene["survey"]["lines"] = [[[10.0, -5.0], [10.0, 25.0]]]
    scene["simulation"]["beam_samples"] = 7
    scene["understory"].update(understory)
    return scene


@pytest.fixture(scope="session")
def demo_result(tmp_path_factory):
    """The demo forest scanned along one leg (100 kHz, 7 sub-rays): a quick real forest scan."""
    from mitsuforest.render import render
    return render(_demo_scene(tmp_path_factory), write=False, progress=False, log=lambda *_: None)


@pytest.fixture(scope="session")
def demo_setup(tmp_path_factory):
    """The demo's trees (no understory) loaded in Mitsuba: (scene, plan, models, scan_scene)."""
    from mitsuforest.plan import make_plan
    from mitsuforest.scene import build_scene
    from mitsuforest.trees import build_models
    scene = _demo_scene(tmp_path_factory, bushes=0, rocks=0, deadwood=0, stumps=0)
    plan = make_plan(scene)
    models = build_models(plan)
    return scene, plan, models, build_scene(plan, models, scene)
