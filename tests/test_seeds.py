"""The one seeding helper (mitsuforest/seeds.py): fixed numbers in every process, independent streams per
purpose and ids, every random draw of the package through it, and the plan's streams kept apart."""

import json
import os
import re
import subprocess
import sys

import numpy as np
import pytest
import yaml
from helpers import ROOT

from mitsuforest import seeds
from mitsuforest.cli import main
from mitsuforest.config import load_scene
from mitsuforest.survey import make_plan

# (seed, purpose, ids) -> numbers, as seeds.py derives them (numpy SeedSequence + PCG64, SHA-256 of the purpose).
EXPECTED = {"rng(7, terrain)": [2021138368, 1384810378, 4146494859], "key(7, beam)": 598996948,
            "key(7, unique-tree, 0, 3, bits=31)": 514150341, "key(2**70, beam)": 2582368277}
NUMBERS = ("import json; from mitsuforest import seeds; print(json.dumps({"
           "'rng(7, terrain)': seeds.rng(7, 'terrain').integers(0, 2**32, 3).tolist(), "
           "'key(7, beam)': seeds.key(7, 'beam'), "
           "'key(7, unique-tree, 0, 3, bits=31)': seeds.key(7, 'unique-tree', 0, 3, bits=31), "
           "'key(2**70, beam)': seeds.key(2**70, 'beam')}))")


@pytest.mark.parametrize("hash_seed", ["0", "12345"])
def test_same_inputs_give_the_same_numbers_in_every_process(hash_seed):
    """Python's ``hash`` of a str differs per process (PYTHONHASHSEED); the streams must not."""
    env = {**os.environ, "PYTHONHASHSEED": hash_seed}
    out = subprocess.run([sys.executable, "-c", NUMBERS], cwd=ROOT, env=env, capture_output=True, text=True, check=True)
    assert json.loads(out.stdout) == EXPECTED


def _correlation(a: np.random.Generator, b: np.random.Generator, n: int = 100_000) -> float:
    return float(np.corrcoef(a.standard_normal(n), b.standard_normal(n))[0, 1])


@pytest.mark.parametrize("a, b", [
    ((7, "trees"), (7, "understory")),
    ((7, "unique-tree", 0, 1), (7, "unique-tree", 1, 0)),        # ids are not summed or concatenated
    ((7, "unique-tree", 1), (7, "unique-tree", 1, 0)),
    ((1, "leaves"), (10_001, "skeleton")),     # the old seed + 10_000: archetype 1's leaves were 10001's skeleton
    ((7, "dataset-plot", 3), (8, "dataset-plot", 3)),
])
def test_purposes_and_ids_give_independent_streams(a, b):
    """Independent N(0, 1) samples of n = 100,000 have a correlation of sd 1/sqrt(n): below 5 sd here."""
    assert abs(_correlation(seeds.rng(*a), seeds.rng(*b))) < 5 / np.sqrt(100_000)
    assert seeds.key(*a) != seeds.key(*b)
    assert _correlation(seeds.rng(*a), seeds.rng(*a)) == pytest.approx(1.0)   # the same inputs: the same stream


def test_key_bits_and_refusals():
    assert seeds.key(7, "beam", bits=64) >> 32 == seeds.key(7, "beam")
    assert seeds.key(7, "beam", bits=64) >> 33 == seeds.key(7, "beam", bits=31)
    keys = [seeds.key(s, "bush-model", i, bits=31) for s in range(20) for i in range(20)]
    assert max(keys) < 2**31 and len(set(keys)) == 400
    for bad in (dict(seed=-1), dict(ids=(-2,))):
        with pytest.raises(ValueError, match=">= 0"):
            seeds.key(bad.get("seed", 7), "beam", *bad.get("ids", ()))
    with pytest.raises(ValueError, match="bits"):
        seeds.key(7, "beam", bits=65)


def test_no_seed_draws_fresh_entropy():
    assert seeds.rng(None, "sample", 0).integers(2**62) != seeds.rng(None, "sample", 0).integers(2**62)


RANDOM_SOURCES = re.compile(r"default_rng\(|SeedSequence\(|RandomState\(|np\.random\.seed\(|random\.Random\(|"
                            r"import random\b|seed\s*[+*]|\+\s*10_000\)")


def test_every_random_stream_of_the_package_comes_from_seeds():
    package = ROOT / "mitsuforest"
    found = [f"{p.relative_to(ROOT)}:{n}: {line.strip()}" for p in sorted(package.rglob("*.py")) if p.name != "seeds.py"
             for n, line in enumerate(p.read_text().splitlines(), 1) if RANDOM_SOURCES.search(line)]
    assert found == []


def _plan(trees: int):
    scene = load_scene(ROOT / "scenes" / "demo.yaml")
    return make_plan(scene.with_({"forest.trees": trees, "terrain.type": "noise", "terrain.amplitude": 2.0,
                                  "understory.grass.cover": 0.2}))


def test_one_more_tree_leaves_the_other_streams_alone():
    """Raising forest.trees by one adds a tree and moves none: the first trees keep their place, model,
    rotation and tilt, and the terrain, ground layer, drawn shrub models and ground-layer models, each
    drawn from its own stream, are unchanged. (The understory's other objects keep clear of the new stem,
    so they may move.)"""
    five, six = _plan(5), _plan(6)
    assert len(six.trees) == 6 and six.trees[:5] == five.trees
    assert np.array_equal(six.terrain.z, five.terrain.z) and np.ptp(five.terrain.z) == pytest.approx(2.0)
    ground = lambda plan: [(o.model, o.position, o.rotation, o.tilt)   # noqa: E731  (ids number on after the trees)
                           for o in plan.objects if o.kind in ("grass", "litter")]
    assert ground(five) and ground(five) == ground(six)
    fixed = [m for m in five.models if m.startswith(("bush", "grass", "litter"))]
    assert fixed and all(six.models[m] == five.models[m] for m in fixed)


@pytest.mark.slow
def test_the_demo_renders_to_the_same_bytes_in_another_process(tmp_path):
    """The demo (one short leg, 7 sub-rays) rendered here and in a process with another PYTHONHASHSEED."""
    data = yaml.safe_load((ROOT / "scenes" / "demo.yaml").read_text())
    data["sensor"] = str(ROOT / "sensors" / "riegl_vux-1uav22.yaml")
    data["survey"].update(pulse_frequency=100000, lines=[[[10.0, 2.0], [10.0, 18.0]]])
    data["simulation"]["beam_samples"] = 7
    scene = tmp_path / "demo.yaml"
    scene.write_text(yaml.safe_dump(data))
    assert main(["render", str(scene), "-o", str(tmp_path / "a"), "--quiet"]) == 0
    env = {**os.environ, "PYTHONHASHSEED": "4321"}
    subprocess.run([sys.executable, "-m", "mitsuforest", "render", str(scene), "-o", str(tmp_path / "b"), "--quiet"],
                   cwd=ROOT, env=env, check=True)
    names = sorted(p.name for p in (tmp_path / "a").iterdir() if not p.name.endswith("_manifest.json"))
    assert {"demo.laz", "demo.pcd", "demo_plan.json"} <= set(names)
    for name in names:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name


@pytest.mark.slow
def test_a_plot_rendered_after_other_plots_is_the_bytes_of_it_alone_in_a_fresh_process(tmp_path):
    """One process renders plots that differ in what a kept model, kernel, crown or writer might be keyed
    on wrongly (sensor, sub-rays and their pattern, point position, terrain, seed, species, formats and
    profile, georeference, a plot that fails on a bad tree file), then two of them again: each is the
    bytes a fresh process writes for it alone, with a model cache of its own (the manifest aside: times)."""
    from helpers import tiny_scene

    from mitsuforest.errors import ConfigError
    from mitsuforest.pipeline import render
    base = yaml.safe_load(tiny_scene(2, 2, 1, 1, 1))
    plots = {
        "plain": {},
        "livox": {"sensor": str(ROOT / "sensors" / "livox_mid-70.yaml"), "terrain": {"type": "noise"},
                  "simulation": {"beam_samples": 3, "beam_pattern": "stratified", "point_position": "surface"}},
        "other": {"seed": 4, "forest": {"type": "open", "trees": 2, "min_spacing": 4, "archetypes": [{"species": "acacia"}]},
                  "origin": {"offset": [500000.0, 6000000.0, 100.0], "crs": "EPSG:7855"},
                  "output": {"formats": ["las", "copc"], "profile": "for-instance", "waveforms": True}},
    }
    files = {}
    for name, changes in plots.items():
        files[name] = tmp_path / f"{name}.yaml"
        files[name].write_text(yaml.safe_dump({**base, **changes, "name": "plot"}))
    broken = tmp_path / "broken.yaml"
    (tmp_path / "broken.obj").write_text("v 0 0 0\nv 1 0 0\nf 1 2 3\n")
    broken.write_text(yaml.safe_dump({**base, "forest": {**base["forest"], "models": [{"mesh": "broken.obj"}]}}))
    for k, name in enumerate(["plain", "livox", "other", "broken", "plain", "livox"]):
        if name == "broken":
            with pytest.raises(ConfigError, match="broken.obj"):
                render(broken, output_dir=tmp_path / "seq" / "broken", progress=False, log=lambda *_: None)
            continue
        render(files[name], output_dir=tmp_path / "seq" / f"{k}-{name}", progress=False, log=lambda *_: None)
    fresh = {**os.environ, "MITSUFOREST_CACHE": str(tmp_path / "fresh-cache")}   # nothing this process stored
    for k, name in [(1, "livox"), (2, "other"), (4, "plain"), (5, "livox")]:
        alone = tmp_path / "alone" / name
        if not alone.exists():
            subprocess.run([sys.executable, "-m", "mitsuforest", "render", str(files[name]), "-o", str(alone), "--quiet"],
                           cwd=ROOT, check=True, env=fresh)
        after = tmp_path / "seq" / f"{k}-{name}"
        names = sorted(p.name for p in alone.iterdir() if not p.name.endswith("_manifest.json"))
        assert names == sorted(p.name for p in after.iterdir() if not p.name.endswith("_manifest.json"))
        assert len(names) >= 9
        for file in names:
            assert (after / file).read_bytes() == (alone / file).read_bytes(), (name, file)
