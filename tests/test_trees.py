"""Tree meshes and wood volume against analytic truth (README, "Wood volume")."""

import numpy as np
import pytest

from mitsuforest.cli import main
from mitsuforest.plan import ModelSpec
from mitsuforest.trees import DEFAULT_ARCHETYPES, build_model
from mitsuforest.trees.models import tree_model
from mitsuforest.trees.tubes import area_correction, signed_volume, tube
from mitsuforest.trees.volume import InvalidPartError, union_volume, wood_volume


def _frustum(r0=0.2, r1=0.1, h=2.0, sides=16, base=(0.0, 0.0, 0.0), axis=(0.0, 0.0, 1.0)):
    base, axis = np.asarray(base, float), np.asarray(axis, float) / np.linalg.norm(axis)
    pts = np.array([base, base + h * axis])
    return tube(pts, np.array([r0, r1]), sides), pts


@pytest.mark.parametrize("sides", [8, 16, 64])
def test_single_frustum_is_exact_with_corrected_radii(sides):
    (v, f), pts = _frustum(sides=sides, axis=(0.3, -0.2, 1.0))
    exact = np.pi * 2.0 / 3 * (0.04 + 0.02 + 0.01)
    assert union_volume([(v, f)]) == pytest.approx(exact, rel=1e-12)
    assert signed_volume(v, f) == pytest.approx(exact, rel=1e-12)
    # Without the correction an n-gon undercounts by n sin(2π/n) / 2π (2.55 % at n = 16).
    assert area_correction(sides) ** 2 == pytest.approx(2 * np.pi / (sides * np.sin(2 * np.pi / sides)))


def test_overlapping_cylinders_union_has_the_known_volume():
    """Two coaxial cylinders r = 0.1 of 2 m overlapping by 0.5 m: union is one 3.5 m cylinder."""
    a, _ = _frustum(0.1, 0.1, 2.0, 32)
    b, _ = _frustum(0.1, 0.1, 2.0, 32, base=(0, 0, 1.5))
    area = np.pi * 0.01
    v = wood_volume([a, b], analytic=2 * area * 2.0)
    assert v.union == pytest.approx(area * 3.5, rel=1e-9)
    assert v.naive == pytest.approx(area * 4.0, rel=1e-9)
    assert v.naive - v.union == pytest.approx(area * 0.5, rel=1e-9)


def test_branch_entering_a_stem_loses_exactly_its_inside_part():
    """A thin branch entering a thick stem: the union removes exactly the part inside the stem."""
    stem, _ = _frustum(0.2, 0.2, 4.0, 64)
    # Branch along +x from the stem axis: its inside part is 0.2 m long, less r²/(8 R) = 0.25 mm.
    pts = np.array([[0.0, 0, 2.0], [1.0, 0, 2.0]])
    branch = tube(pts, np.array([0.02, 0.02]), 64)
    v = wood_volume([stem, branch], analytic=0)
    inside = np.pi * 0.02 ** 2 * (0.2 - 0.02 ** 2 / (8 * 0.2))
    assert v.naive - v.union == pytest.approx(inside, rel=2e-3)


def test_one_millimetre_twig_on_a_twenty_metre_stem():
    """A 1 mm twig leaving the axis of a tapered stem adds exactly its length outside the stem."""
    stem, _ = _frustum(0.3, 0.05, 20.0, 24)
    twig_pts = np.array([[0.0, 0, 10.0], [0.3, 0, 10.5], [0.6, 0.05, 10.8]])
    twig = tube(twig_pts, np.full(3, 0.001), 5)
    # Along the first segment, horizontal distance 0.3 s meets the stem radius 0.175 - 0.00625 s.
    s_exit = 0.175 / (0.3 + 0.00625)
    inside = s_exit * np.linalg.norm(twig_pts[1] - twig_pts[0])
    outside = np.pi * 1e-6 * (np.linalg.norm(np.diff(twig_pts, axis=0), axis=1).sum() - inside)
    added = union_volume([stem, twig]) - union_volume([stem])
    assert added == pytest.approx(outside, rel=0.02)


def test_translated_tree_keeps_its_volume():
    model = tree_model(DEFAULT_ARCHETYPES[3], "t")
    wood = model.parts[0]
    parts = _split_parts(wood)
    here = union_volume(parts)
    there = union_volume([(v + [1e6, -2e6, 1e6], f) for v, f in parts])
    assert there == pytest.approx(here, rel=1e-6)
    assert here == pytest.approx(model.volume.union, rel=1e-12)


def _split_parts(part):
    """The closed tubes of a wood mesh, by connected vertex ranges."""
    import trimesh
    mesh = trimesh.Trimesh(part.vertices, part.faces, process=False)
    return [(m.vertices.copy(), m.faces.copy()) for m in mesh.split(only_watertight=False)]


def test_inverted_part_is_a_clear_error():
    (v, f), _ = _frustum()
    with pytest.raises(InvalidPartError, match="faces point inward"):
        union_volume([(v, f), (v + [1, 0, 0], f[:, ::-1])], names=["ok", "flipped branch"])
    with pytest.raises(InvalidPartError, match="not a closed manifold"):
        union_volume([(v, f[:-3])])


def test_default_trees_are_reproducible_and_in_the_paper_range():
    volumes = []
    for i, a in enumerate(DEFAULT_ARCHETYPES):
        m = build_model(f"tree{i + 1:02d}", ModelSpec("tree", 0, archetype=a))
        v = m.volume
        volumes.append(v.union)
        assert 0.28 <= v.union <= 1.45, (i + 1, v.union)
        assert v.union < v.naive  # joints overlap: the paper's sum of parts overcounts
        assert (v.naive - v.union) / v.naive < 0.02
        assert m.components[0].kind == "stem" and m.components[-1].kind == "leaves"
        assert 30_000 < m.triangles < 150_000
    again = tree_model(DEFAULT_ARCHETYPES[0], "x").volume.union
    assert again == volumes[0]  # to the last digit


def test_trees_command_writes_meshes_volumes_and_picture(tmp_path, monkeypatch):
    import mitsuforest.trees.archetypes as arch
    monkeypatch.setattr(arch, "DEFAULT_ARCHETYPES", arch.DEFAULT_ARCHETYPES[:2])
    assert main(["trees", "-o", str(tmp_path)]) == 0
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["tree01_leaves.ply", "tree01_wood.ply", "tree02_leaves.ply", "tree02_wood.ply",
                     "trees.png", "volumes.csv"]
    rows = (tmp_path / "volumes.csv").read_text().splitlines()
    assert rows[0].startswith("model,height_m,dbh_m,volume_union_m3") and len(rows) == 3
