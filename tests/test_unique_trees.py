"""Every tree unique: ``forest.archetypes: [{species: S, unique: N}]`` draws N distinct trees per plot."""

import dataclasses
import itertools

import manifold3d
import numpy as np
import pytest
import trimesh
from helpers import ROOT

from mitsuforest.cli import main
from mitsuforest.config import load_scene
from mitsuforest.plan import plan_json
from mitsuforest.survey import make_plan
from mitsuforest.trees import build_model, build_models
from mitsuforest.specs.archetypes import (ABSOLUTE_SPREAD, FAMILY_ARCHETYPES, RELATIVE_SPREAD, UniqueTrees,
                                          unique_archetypes)


def _scene(unique=4, trees=100, seed=7, species="eucalyptus"):
    """A 60 m plot without understory whose trees are ``unique`` drawn ones."""
    scene = load_scene(ROOT / "scenes" / "demo.yaml", seed=seed)
    return scene.with_({"area.size": [60, 60], "forest.trees": trees, "forest.min_spacing": 3.0,
                        "forest.archetypes": [{"species": species, "unique": unique}]},
                       understory={"bushes": 0, "rocks": 0, "deadwood": 0, "stumps": 0})


def _exact_union(part) -> float:
    """The union volume of a model's wood part, recomputed here: each closed tube (a connected piece of
    the merged mesh) to a float64 manifold, then manifold3d's union of them."""
    tubes = trimesh.Trimesh(part.vertices, part.faces, process=False).split(only_watertight=False)
    centre = part.vertices.mean(axis=0)
    manifolds = [manifold3d.Manifold(manifold3d.Mesh64(vert_properties=np.ascontiguousarray(t.vertices - centre),
                                                       tri_verts=np.ascontiguousarray(t.faces, np.uint64)))
                 for t in tubes]
    return manifold3d.Manifold.batch_boolean(manifolds, manifold3d.OpType.Add).volume()


@pytest.fixture(scope="module")
def hundred_trees():
    plan = make_plan(_scene(unique=4, trees=100))
    return plan, build_models(plan)


def test_n_unique_models_placed_in_turn_among_a_hundred_trees(hundred_trees):
    plan, models = hundred_trees
    trees = [name for name in plan.models if name.startswith("tree")]
    assert trees == ["tree01", "tree02", "tree03", "tree04"]
    assert sorted(n for n in models if n.startswith("tree")) == trees      # memory: 4 models, not 100
    assert len(plan.trees) == 100
    used = {name: sum(t.model == name for t in plan.trees) for name in trees}
    assert used == {name: 25 for name in trees}                           # each in turn: 100 / 4
    assert all(t.treeid == int(t.model[4:]) for t in plan.trees)
    assert all(plan.models[n].drawn and plan.models[n].archetype.weight == 0.25 for n in trees)


def test_unique_trees_differ_and_their_volumes_are_exact_unions(hundred_trees):
    plan, models = hundred_trees
    trees = [models[f"tree{i:02d}"] for i in range(1, 5)]
    for a, b in itertools.combinations(trees, 2):
        va, vb = a.vertices(), b.vertices()
        assert va.shape != vb.shape or not np.allclose(va, vb)
    heights = [plan.models[m.name].archetype.height for m in trees]
    assert len(set(heights)) == 4
    for m in trees:
        assert m.volume.union == pytest.approx(_exact_union(m.parts[0]), rel=1e-9)
        assert 0 < m.volume.union < m.volume.naive     # joints overlap
        top = m.parts[0].vertices[:, 2].max()
        assert top == pytest.approx(plan.models[m.name].archetype.height, abs=0.05)


def test_same_seed_same_trees_other_seed_other_trees():
    a, b, c = (make_plan(_scene(trees=8, seed=s)) for s in (7, 7, 8))
    assert plan_json(a) == plan_json(b)
    drawn = lambda plan: [plan.models[f"tree{i:02d}"].archetype for i in range(1, 5)]   # noqa: E731
    assert drawn(a) == drawn(b)
    assert not set(drawn(a)) & set(drawn(c))
    again = build_model("tree02", b.models["tree02"])   # built anew (drawn models skip the disk cache): same bytes
    first = build_model("tree02", a.models["tree02"])
    assert np.array_equal(again.vertices(), first.vertices())
    assert again.volume == first.volume


def _within_spread(a, template) -> bool:
    """Whether ``a`` departs from ``template`` by no more than two standard deviations of each spread."""
    r = RELATIVE_SPREAD
    ratio = a.crown_diameter / a.height / (template.crown_diameter / template.height)
    return (all(abs(getattr(a, k) - getattr(template, k)) <= 2 * sd + 1e-3 for k, sd in ABSOLUTE_SPREAD.items())
            and abs(a.height / template.height - 1) <= 2 * r["height"] + 1e-3
            and abs(ratio - 1) <= 2 * r["crown_diameter"] + 1e-3
            and abs(a.branches / template.branches - 1) <= 2 * r["branches"] + 0.5 / template.branches)


@pytest.mark.parametrize("species", sorted(FAMILY_ARCHETYPES))
def test_drawn_parameters_stay_within_the_documented_spread(species):
    family = FAMILY_ARCHETYPES[species]
    drawn = unique_archetypes(UniqueTrees(species, 200), seed=3, index=0)
    assert len({a.seed for a in drawn}) == 200 and all(a.species == species for a in drawn)
    heights = np.array([a.height for a in drawn])
    lo, hi = min(t.height for t in family), max(t.height for t in family)
    bound = 2 * RELATIVE_SPREAD["height"]
    assert lo * (1 - bound) <= heights.min() and heights.max() <= hi * (1 + bound)
    assert heights.max() - heights.min() > 0.5 * (hi - lo) * (1 + bound)   # the draws span the family
    for a in drawn:      # some built-in archetype of the family is its template, within every spread
        assert any(_within_spread(a, template) for template in family), a


    # Raising unique keeps the first trees: tree i is drawn from its own key.
    unweighted = lambda trees: [dataclasses.replace(a, weight=1.0) for a in trees]   # noqa: E731
    assert unweighted(unique_archetypes(UniqueTrees(species, 3), seed=3, index=0)) == unweighted(drawn[:3])


def test_mixed_entries_keep_their_order_and_the_archetypes_stream():
    scene = _scene(trees=12).with_({"forest.archetypes": [{"base": 2}, {"species": "acacia", "unique": 3, "weight": 2}]})
    plan = make_plan(scene)
    species = [plan.models[f"tree{i:02d}"].species for i in range(1, 5)]
    assert species == ["eucalyptus", "acacia", "acacia", "acacia"]
    assert plan.models["tree01"].drawn is None and "drawn" not in plan_json(plan).split('"tree01"')[1].split('"tree02"')[0]
    assert plan.models["tree01"].archetype == FAMILY_ARCHETYPES["eucalyptus"][1]
    assert {dataclasses.asdict(plan.models[f"tree{i:02d}"].archetype)["weight"] for i in (2, 3, 4)} == {2 / 3}


BAD = {
    "unique 0": ("{species: eucalyptus, unique: 0}", "forest.archetypes[0].unique: must be >= 1, got 0"),
    "unique 1e9": ("{species: eucalyptus, unique: 1e9}", "forest.archetypes[0].unique: must be <= 1000, got 1e+09"),
    "unknown species": ("{species: oak, unique: 5}",
                        "forest.archetypes[0].species: must be one of eucalyptus, acacia, pinus_radiata, got 'oak'"),
    "a drawn parameter": ("{species: acacia, unique: 5, height: 3}",
                          "forest.archetypes[0].height: is drawn for each unique tree; give only species, unique and weight"),
    "base": ("{unique: 5, base: 2}", "forest.archetypes[0].base: each unique tree starts from a random built-in"),
    "fraction": ("{unique: 2.5}", "forest.archetypes[0].unique: must be an integer, got 2.5"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_unique_entry_gives_one_line_and_exit_2(case, tmp_path, monkeypatch, capsys):
    entry, message = BAD[case]
    text = (ROOT / "scenes" / "demo.yaml").read_text().replace("../sensors", str(ROOT / "sensors"))
    text = text.replace("  min_spacing: 5.0\n", f"  min_spacing: 5.0\n  archetypes: [{entry}]\n")
    monkeypatch.chdir(tmp_path)
    (tmp_path / "scene.yaml").write_text(text)
    code = main(["render", "scene.yaml", "-o", "out"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.count("\n") == 0 and "Traceback" not in err
    assert err.startswith(f"mitsuforest: scene.yaml: {message}")
    assert not (tmp_path / "out").exists()
