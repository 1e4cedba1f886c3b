"""Tree meshes and wood volume against analytic truth (README, "Wood volume")."""

import dataclasses

import numpy as np
import pytest

from mitsuforest import seeds
from mitsuforest.cli import main
from mitsuforest.plan import ModelSpec
from mitsuforest.trees import DEFAULT_ARCHETYPES, build_model
from mitsuforest.specs.archetypes import FAMILY_ARCHETYPES, grown_to
from mitsuforest.trees.models import tree_model
from mitsuforest.trees.skeleton import crown_radius, grow
from mitsuforest.plan import CLEARANCE
from mitsuforest.trees.understory import MAX_SHRUB_REACH, SHRUB_FORMS, bush_model, deadwood_model, rock_model, stump_model
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
        leaves = m.parts[-1]
        assert len(leaves.faces) == 2 * round(a.leaf_area / (0.5 * a.leaf_length * a.leaf_width))   # 2 per blade
        assert 60_000 < m.triangles < 300_000
    again = tree_model(DEFAULT_ARCHETYPES[0], "x").volume.union
    assert again == volumes[0]  # to the last digit
    assert (round(min(volumes), 2), round(max(volumes), 2)) == (0.31, 1.37)   # README, "Wood volume"


def test_trees_command_writes_meshes_volumes_and_picture(tmp_path, monkeypatch):
    import mitsuforest.specs.archetypes as arch
    monkeypatch.setattr(arch, "DEFAULT_ARCHETYPES", arch.DEFAULT_ARCHETYPES[:2])
    assert main(["trees", "-o", str(tmp_path)]) == 0
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["tree01_leaves.ply", "tree01_wood.ply", "tree02_leaves.ply", "tree02_wood.ply",
                     "trees.png", "volumes.csv"]
    rows = (tmp_path / "volumes.csv").read_text().splitlines()
    assert rows[0].startswith("model,height_m,dbh_m,volume_union_m3") and len(rows) == 3


def _leaf_dispersion(centres: np.ndarray, voxel: float) -> float:
    """Variance-to-mean ratio of leaf counts over the voxels inside the leaves' convex hull: about 1
    for leaves spread uniformly through a volume (a dome), far above 1 for clumped foliage."""
    from scipy.spatial import ConvexHull
    lo = centres.min(0)
    grid = np.stack(np.meshgrid(*[np.arange(a + voxel / 2, b, voxel) for a, b in zip(lo, centres.max(0))],
                                indexing="ij"), -1).reshape(-1, 3)
    planes = ConvexHull(centres).equations
    in_hull = np.all(grid @ planes[:, :3].T + planes[:, 3] <= 1e-9, axis=1)
    inside = np.floor((grid[in_hull] - lo) / voxel).astype(int)
    keys, counts = np.unique(np.floor((centres - lo) / voxel).astype(int), axis=0, return_counts=True)
    held = {tuple(k): n for k, n in zip(keys, counts)}
    x = np.array([held.get(tuple(k), 0) for k in inside], float)
    return float(x.var() / x.mean())


@pytest.mark.parametrize("form", range(len(SHRUB_FORMS)))
def test_shrub_has_several_stems_branches_and_clumped_leaves_not_a_dome(form):
    """Every shrub form: two or more separate stems from the ground, side shoots, leaves; and the
    leaves are clumped (dispersion index > 4), where the same number of leaves filling the shrub's
    ellipsoid (the old dome) gives about 1."""
    import trimesh
    for seed in (1, 2):
        model = bush_model(seed, "bush", form)
        wood, leaves = model.parts
        assert [p.name for p in model.parts] == ["wood", "leaves"] and model.components[0].kind == "bush"
        mesh = trimesh.Trimesh(wood.vertices, wood.faces, process=False)
        pieces = trimesh.graph.connected_components(mesh.face_adjacency, nodes=np.arange(len(mesh.faces)))
        rooted = [p for p in pieces if wood.vertices[wood.faces[p].ravel(), 2].min() < 1e-9]
        assert len(rooted) == model.meta["stems"] >= 2
        assert len(pieces) == model.meta["stems"] + model.meta["shoots"] > len(rooted)   # branching
        centres = leaves.vertices.reshape(-1, 4, 3).mean(axis=1)
        assert len(centres) == model.meta["leaves"] > 300
        h, w = model.meta["height"], model.meta["width"]
        rng = np.random.default_rng(0)
        u = rng.normal(size=(len(centres), 3))
        u *= rng.random((len(centres), 1)) ** (1 / 3) / np.linalg.norm(u, axis=1, keepdims=True)
        dome = u * [w / 2, w / 2, h / 2] + [0, 0, h / 2]
        voxel = max(w, h) / 12   # small enough that a dome's partly filled rim voxels stay near 1 (up to 1.6)
        assert _leaf_dispersion(dome, voxel) < 4 < _leaf_dispersion(centres, voxel), (form, seed)
        assert np.hypot(*model.vertices()[:, :2].T).max() < MAX_SHRUB_REACH < CLEARANCE["bush"]
        lo, hi = SHRUB_FORMS[form].height
        assert lo <= model.meta["height"] <= hi + 0.05 and model.meta["width"] <= SHRUB_FORMS[form].crown[1]


def test_shrub_forms_differ_in_size_and_leaf_density():
    """The heath form is the lowest and densest (leaf area per envelope volume), the tall open form
    the tallest and sparsest."""
    def area(m):
        return leaf_count_area(m) / (np.pi / 6 * m.meta["width"] ** 2 * m.meta["height"])
    def leaf_count_area(m):
        v = m.parts[1].vertices.reshape(-1, 4, 3)
        return 0.5 * np.linalg.norm(np.cross(v[:, 2] - v[:, 0], v[:, 3] - v[:, 1]), axis=1).sum()
    heath, tall = [bush_model(1, "b", f) for f in (0, len(SHRUB_FORMS) - 1)]
    assert heath.meta["height"] < 1.0 < 2.2 < tall.meta["height"]
    assert area(heath) > 3 * area(tall)


def test_stump_and_log_volumes_are_unions_of_irregular_parts():
    """A stump's roots overlap its trunk: its union lies between its largest piece and the naive sum
    of its pieces. A knotty, bowed log of one piece has exactly its frustums' analytic volume."""
    one_piece_logs = 0
    for seed in range(4):
        stump = stump_model(seed, "s")
        v = stump.volume
        pieces = _parts(stump)
        assert len(pieces) == v.parts == stump.meta["roots"] + 1 >= 4
        sizes = [signed_volume(*p) for p in pieces]
        assert v.naive == pytest.approx(sum(sizes), rel=1e-9)
        assert max(sizes) < v.union < v.naive
    for seed in range(30):
        log = deadwood_model(seed, "d", 5.0, 0.15)
        if log.volume.parts == 1:
            one_piece_logs += 1
            assert log.volume.union == pytest.approx(log.volume.analytic, rel=1e-9)
            assert log.volume.union != pytest.approx(np.pi * 5.0 / 3 * 0.15 ** 2 * (1 + 0.5 + 0.25), rel=0.01)
    assert one_piece_logs >= 1


def _parts(model):
    """Closed pieces of a one-part understory model, as (vertices, faces) each."""
    import trimesh
    p = model.parts[0]
    mesh = trimesh.Trimesh(p.vertices, p.faces, process=False)
    return [(m.vertices, m.faces) for m in mesh.split(only_watertight=False)]


def test_rocks_are_irregular_closed_and_not_convex():
    """Rocks are closed unions of several lumps: their volume is below their convex hull's."""
    import trimesh
    concave = 0
    for seed in range(6):
        rock = rock_model(seed, "r")
        mesh = trimesh.Trimesh(rock.parts[0].vertices, rock.parts[0].faces, process=False)
        assert mesh.is_watertight and mesh.volume > 0
        concave += mesh.volume < 0.97 * mesh.convex_hull.volume
    assert concave >= 4


@pytest.mark.parametrize("family", ["acacia", "pinus_radiata"])
def test_species_families_have_their_own_form(family):
    """Acacia forks low into several leaders under a broad crown; Pinus radiata keeps one leader with
    branches in whorls (first-order branch bases in groups of four at one height)."""
    for a in FAMILY_ARCHETYPES[family]:
        branches = grow(a)
        firsts = [b for b in branches if b.order == 1]
        bases = np.array([b.points[0, 2] for b in firsts])
        if family == "pinus_radiata":
            assert bases.min() > a.height * (1 - a.crown_ratio) - 0.5
            whorls = np.sort(bases)[:len(bases) // 4 * 4].reshape(-1, 4)
            assert np.ptp(whorls, axis=1).max() < 0.5 < np.diff(whorls.mean(axis=1)).min()
            base = a.height * (1 - a.crown_ratio)   # a cone: widest at the crown base, 0 at the top
            assert crown_radius(a, base) == a.crown_diameter / 2 and crown_radius(a, a.height) == 0
            assert crown_radius(a, (base + a.height) / 2) == pytest.approx(a.crown_diameter / 2 * 0.5 ** 0.9)
        else:
            leaders = [b for b in firsts if abs(b.points[0, 2] - a.fork_height * a.height) < 0.3 and b.length > 3]
            assert len(leaders) >= a.forks - 1 >= 2
        m = tree_model(a, "t")
        assert m.meta["species"] == family and 0.1 < m.volume.union < m.volume.naive
        leaves = m.parts[-1]
        assert len(leaves.faces) == 2 * round(a.leaf_area / (0.5 * a.leaf_length * a.leaf_width))   # 2 per blade
        assert 60_000 < m.triangles < 300_000


def _shadow_area(vertices: np.ndarray, faces: np.ndarray, cell: float = 0.01) -> float:
    """Area (m²) of the union of the triangles' shadows seen from straight above: the cells of ``cell``
    metres whose centres lie in at least one triangle's x-y projection."""
    tri = vertices[faces.astype(np.int64)][:, :, :2]
    lo = np.floor(tri.min(1) / cell).astype(np.int64)
    k = int(np.ceil((tri.max(1) - tri.min(1)).max() / cell)) + 2
    di, dj = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    ci, cj = lo[:, None, 0] + di.ravel(), lo[:, None, 1] + dj.ravel()
    px, py = (ci + 0.5) * cell, (cj + 0.5) * cell

    def side(p, q):
        return (q[:, None, 0] - p[:, None, 0]) * (py - p[:, None, 1]) - (q[:, None, 1] - p[:, None, 1]) * (px - p[:, None, 0])
    s = [side(tri[:, 0], tri[:, 1]), side(tri[:, 1], tri[:, 2]), side(tri[:, 2], tri[:, 0])]
    inside = ((s[0] >= 0) & (s[1] >= 0) & (s[2] >= 0)) | ((s[0] <= 0) & (s[1] <= 0) & (s[2] <= 0))
    return len(np.unique((ci[inside] << 32) + cj[inside])) * cell * cell


def test_leaf_fill_spreads_leaves_through_the_crown_volume_as_beer_lambert_says():
    """A small pine's crown (a cone of radius R = 1.5 m and length L = 3.6 m, r(z) = R (1 - u)^0.9) with
    the same 6 m² of leaf on its twigs (``leaf_fill`` 0), half spread (0.5) and all spread through its
    volume (1). All spread, the leaves are a turbid medium: seen from above, a column at distance ρ from
    the axis holds ``a · L (1 - (ρ/R)^(1/0.9))`` of projected leaf area (``a`` the blades' projected area
    over the cone's volume π R² L / 2.8), and the crown's shadow is ∫ (1 - exp(-that)) 2πρ dρ. On the
    twigs the leaves pile into clumps and shade less than half of that; the gap fraction within the
    crown's footprint falls as the fill rises."""
    base = dataclasses.replace(FAMILY_ARCHETYPES["pinus_radiata"][2], height=6.0, dbh=0.1, crown_diameter=3.0,
                               crown_ratio=0.6, branches=12, leaf_area=6.0, leaf_length=0.06, leaf_width=0.012, lean=0.0)
    radius, length = 1.5, 3.6
    gaps = []
    for fill in (0.0, 0.5, 1.0):
        leaves = tree_model(dataclasses.replace(base, leaf_fill=fill), "t").parts[-1]
        assert abs(len(leaves.faces) - 2 * round(6.0 / (0.5 * 0.06 * 0.012))) <= 2   # the same leaf area, to a blade
        shadow = _shadow_area(leaves.vertices, leaves.faces)
        gaps.append(1 - shadow / (np.pi * radius ** 2))
    v = leaves.vertices[leaves.faces.astype(np.int64)]
    projected = 0.5 * np.abs(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])[:, 2]).sum()
    a = projected / (np.pi * radius ** 2 * length / 2.8)
    rho = np.linspace(0, radius, 4001)
    beer_lambert = np.trapezoid((1 - np.exp(-a * length * (1 - (rho / radius) ** (1 / 0.9)))) * 2 * np.pi * rho, rho)
    assert shadow == pytest.approx(beer_lambert, rel=0.02)
    assert gaps[0] > gaps[1] + 0.1 > gaps[2] + 0.1 and gaps[0] > 0.75 and gaps[2] == pytest.approx(0.578, abs=0.02)


def test_leaf_fill_zero_leaves_the_default_trees_as_they_were():
    """``leaf_fill`` 0 (every built-in archetype's) takes the twig path alone: the blades are those of
    ``leaves_on_twigs`` from the tree's leaf stream, bit for bit, as before the field existed; a fill
    above 0 moves them."""
    from mitsuforest.trees.leaves import leaves_on_twigs
    from mitsuforest.trees.skeleton import terminal_branches
    assert all(t.leaf_fill == 0.0 for family in FAMILY_ARCHETYPES.values() for t in family)
    a = FAMILY_ARCHETYPES["pinus_radiata"][2]
    twigs = [t.points for t in terminal_branches(grow(a))]
    expected, _ = leaves_on_twigs(twigs, a.leaf_area, a.leaf_length, a.leaf_width, a.leaf_inclination,
                                  a.leaf_clumping, seeds.rng(a.seed, "leaves"))
    assert np.array_equal(tree_model(a, "t").parts[-1].vertices, expected)
    filled = tree_model(dataclasses.replace(a, leaf_fill=0.25), "t").parts[-1].vertices
    assert len(filled) == len(expected) and not np.array_equal(filled, expected)


def test_a_cached_models_normals_are_computed_once_a_plot_and_a_new_seed_gets_its_own():
    """A dataset worker asks for a model's face normals (scene) and triangle areas (realism table) for
    each plot: copies of a cached model share them, computed once; a rock of another seed, or a mesh
    that may still change (writable), gets its own."""
    from mitsuforest.realism import triangle_areas
    from mitsuforest.scene.meshes import face_normals
    calls = []

    def normals(vertices, faces):
        calls.append(len(faces))
        return face_normals(vertices, faces)

    first, again = (build_model("rock001", ModelSpec("rock", 1, seed=11)) for _ in range(2))
    other = build_model("rock002", ModelSpec("rock", 1, seed=12))
    assert first is not again and first.parts[0] is again.parts[0]      # copies over the same part
    kept = first.parts[0].of_mesh(normals)
    assert again.parts[0].of_mesh(normals) is kept and len(calls) == 1
    assert not kept.flags.writeable
    np.testing.assert_array_equal(kept, face_normals(first.parts[0].vertices, first.parts[0].faces))
    assert not np.array_equal(other.parts[0].of_mesh(normals), kept) and len(calls) == 2
    # Another function is another value: the areas, not the normals.
    np.testing.assert_array_equal(first.parts[0].of_mesh(triangle_areas),
                                  triangle_areas(first.parts[0].vertices, first.parts[0].faces))
    fresh = rock_model(11, "rock001").parts[0]                         # built here: writable, not kept
    assert fresh.vertices.flags.writeable
    before = fresh.of_mesh(normals)
    fresh.vertices[:, 2] *= 2.0                                         # taller: other normals
    after = fresh.of_mesh(normals)
    assert len(calls) == 4 and not np.array_equal(after, before)
    np.testing.assert_array_equal(after, face_normals(fresh.vertices, fresh.faces))


def test_crown_exponent_sets_how_blunt_a_pine_crown_is():
    """Pinus radiata's envelope r(z) = R (1 - u)^e: at mid-crown R · 0.5^e, for the default cone (0.9) and a
    blunter crown (0.6). Leaves spread through it stay inside it; evenly through its volume (``leaf_lift``
    0), 1 - 0.5^(2e + 1) of them lie below mid-crown; with a lift, a metre of crown holds leaves in
    proportion to its cross-section to the power 1 - lift (1: as many in every metre)."""
    from mitsuforest.trees.skeleton import crown_volume_points
    a = FAMILY_ARCHETYPES["pinus_radiata"][2]
    base, mid = a.height * (1 - a.crown_ratio), a.height * (1 - a.crown_ratio / 2)
    for e, lift in ((0.9, 0.0), (0.6, 0.0), (0.6, 0.5), (0.9, 1.0)):
        b = dataclasses.replace(a, crown_exponent=e, leaf_lift=lift)
        assert crown_radius(b, mid) == pytest.approx(a.crown_diameter / 2 * 0.5 ** e)
        stem = grow(b)[0]
        points = crown_volume_points(b, stem, 20_000, np.random.default_rng(1))
        u = (points[:, 2] - base) / (a.height - base)
        axis = [np.interp(points[:, 2], stem.points[:, 2], stem.points[:, k]) for k in (0, 1)]
        radial = np.hypot(points[:, 0] - axis[0], points[:, 1] - axis[1])
        assert np.all(radial <= crown_radius(b, points[:, 2]) + 1e-9)
        k = 2 * e * (1 - lift) + 1      # points a metre ∝ cross-section^(1 - lift) = (1 - u)^(2e(1 - lift))
        assert np.mean(u < 0.5) == pytest.approx(1 - 0.5 ** k, abs=0.015)


@pytest.mark.parametrize("family, crown_ratio", [("acacia", None), ("acacia", 0.1), ("eucalyptus", 0.1),
                                                 ("eucalyptus", 0.3)])
def test_forked_trees_bear_branches_and_leaves_only_in_the_crown(family, crown_ratio):
    """The crown starts at H · (1 − crown_ratio) (README, "Archetypes") on a forked tree too: its
    co-dominant leaders rise from the fork below the crown base as bare stems, and no first-order branch,
    leader child or leaf stands below it. Acacia 3 forks at 4.5 m under a crown base of 6 m; a crown
    ratio of 0.1 puts the base of Eucalyptus 1 (fork 13.65 m) at 18.9 m, of Acacia 1 (fork 3.6 m) at
    10.8 m. A branch starts half a parent radius off its parent's axis and its tube reaches its own radius
    around it, and blades hang a few centimetres from their petioles: 0.15 m of slack for wood, 0.3 m for
    leaves."""
    template = FAMILY_ARCHETYPES[family][2 if crown_ratio is None else 0]
    a = template if crown_ratio is None else dataclasses.replace(template, crown_ratio=crown_ratio)
    base = a.height * (1 - a.crown_ratio)
    assert a.fork_height * a.height < base - 1.0                 # the leaders fork well below the crown
    branches = grow(a)
    leaders = [b for b in branches[1:a.forks] if b.order == 1]
    assert len(leaders) == a.forks - 1 and all(b.points[0, 2] < base - 1.0 for b in leaders)
    m = tree_model(a, "t")
    wood, leaves = m.parts
    on_leaders = np.isin(wood.component, np.arange(1, a.forks))
    branch_wood = wood.vertices[wood.faces[~on_leaders & (wood.component > 0)].ravel()]
    assert branch_wood[:, 2].min() > base - 0.15
    leader_children = [b for b in branches if b.order >= 2 and 1 <= b.component < a.forks]
    assert min(b.points[:, 2].min() for b in leader_children) > base - 0.15
    assert leaves.vertices[:, 2].min() > base - 0.3


def _one_sided_area(part) -> float:
    tri = part.vertices[part.faces.astype(np.int64)]
    return float(0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum())


@pytest.mark.parametrize("family, index, fill", [("eucalyptus", 3, 0.0), ("acacia", 1, 0.0), ("pinus_radiata", 2, 0.0),
                                                 ("pinus_radiata", 2, 0.5)])
def test_leaf_triangles_hold_the_asked_one_sided_leaf_area(family, index, fill):
    """The leaf part's one-sided area, summed over its triangles, is the archetype's ``leaf_area`` to
    within half a blade (the count is rounded), on the twigs and spread through the crown alike. Blade
    sizes vary by a factor drawn uniformly from 0.8-1.2, whose square averages 1 + 0.4²/12: unnormalised,
    the leaves held 1.3 % more than asked (53.63 m² for Eucalyptus 4's 53)."""
    a = dataclasses.replace(FAMILY_ARCHETYPES[family][index], leaf_fill=fill)
    blade = 0.5 * a.leaf_length * a.leaf_width
    area = _one_sided_area(tree_model(a, "t").parts[-1])
    assert abs(area - a.leaf_area) <= (1 if fill else 0.5) * blade + 1e-9, (area, a.leaf_area)


def _diameter_at(part, z: float) -> float:
    """The stem's diameter at height ``z`` from its mesh: the area-equivalent diameter of the polygon where
    the stem's (component 0) triangles cross the plane z (its convex hull; the tube is convex there)."""
    from scipy.spatial import ConvexHull
    v, f = part.vertices, part.faces[part.component == 0].astype(np.int64)
    cuts = []
    for i, j in ((0, 1), (1, 2), (2, 0)):
        p, q = v[f[:, i]], v[f[:, j]]
        c = (p[:, 2] - z) * (q[:, 2] - z) < 0
        t = (z - p[c, 2]) / (q[c, 2] - p[c, 2])
        cuts.append((p[c] + t[:, None] * (q[c] - p[c]))[:, :2])
    return 2 * np.sqrt(ConvexHull(np.vstack(cuts)).volume / np.pi)


@pytest.mark.parametrize("family", sorted(FAMILY_ARCHETYPES))
def test_stem_diameter_at_breast_height_is_the_archetypes_dbh(family):
    """``dbh`` is the stem diameter at 1.3 m (README, "Archetypes"): measured on the mesh it is the
    archetype's to 0.5 %, for a built-in tree and a crown down to 1.05 m (crown_ratio 0.95), and to 1.5 %
    (the mesh is linear between stem rings 9 cm apart, on a steep taper) for the smallest tree, 2 m tall
    with a 1 m crown and the 2 cm floor of dbh, whose crown (from 0.6-1.1 m) is squeezed to fit its
    height. The basal flare added 1 % at 1.3 m, and the squeeze took the stem's thinner part above down
    to 1.3 m: 1.6-1.7 cm for 2 cm."""
    template = FAMILY_ARCHETYPES[family][0]
    small = grown_to(template, 2.0, 1.0, seed=5)
    assert small.dbh == 0.02 and small.height * (1 - small.crown_ratio) < 1.3
    for a, within in ((template, 0.005), (dataclasses.replace(template, crown_ratio=0.95), 0.005), (small, 0.015)):
        wood = tree_model(a, "t").parts[0]
        assert _diameter_at(wood, 1.3) == pytest.approx(a.dbh, rel=within), a


@pytest.mark.parametrize("inclination", [75.0, 40.0, 0.0, 90.0])
def test_leaf_blades_hang_at_the_asked_mean_angle(inclination):
    """``leaf_inclination`` is the blades' mean angle below horizontal (README: 75° on average, ±15°).
    Each blade's angle is drawn ±15° about it and kept within 0-90°; clipped about the asked angle, the
    mean fell short of it near the bounds: 73.8° for 75°, 6.0° for 0°, 84.0° for 90°. Measured on the
    mesh (base to tip of each blade) over Eucalyptus 4's 32,600 blades, the mean is the asked one to
    0.3° (its standard error is 0.08°), and the spread stays about 15° away from the bounds."""
    a = dataclasses.replace(DEFAULT_ARCHETYPES[3], leaf_inclination=inclination)
    v = tree_model(a, "t").parts[-1].vertices.reshape(-1, 4, 3)
    axis = v[:, 2] - v[:, 0]
    dip = np.degrees(np.arcsin(-axis[:, 2] / np.linalg.norm(axis, axis=1)))
    assert dip.min() >= -1e-9 and dip.max() <= 90 + 1e-9
    assert dip.mean() == pytest.approx(inclination, abs=0.3)
    if 30 <= inclination <= 60:
        assert dip.std() == pytest.approx(15, abs=0.5)


@pytest.mark.parametrize("family", sorted(FAMILY_ARCHETYPES))
def test_the_tree_is_as_tall_as_asked_leaves_included(family):
    """``height`` is the total height: the highest vertex of the model, wood or leaf, is the asked height
    to 1 cm (the tip's ring of a 3 mm twig, tilted). Petioles are scattered about the twig tips, so the
    top blades rose above it: Eucalyptus 1 to 21.045 m for 21 m, Acacia 3 to 15.052 m for 15 m. A blade
    rising above the top is lowered, whole, to it."""
    for a in FAMILY_ARCHETYPES[family]:
        m = tree_model(a, "t")
        wood, leaves = m.parts
        assert leaves.vertices[:, 2].max() <= a.height + 1e-9
        assert m.vertices()[:, 2].max() == pytest.approx(a.height, abs=0.01)
        assert _one_sided_area(leaves) == pytest.approx(a.leaf_area, abs=0.5 * 0.5 * a.leaf_length * a.leaf_width)
