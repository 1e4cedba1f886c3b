"""The pictures name what they show: legends clear of the axis labels on a short tile, trees named by
their model (an imported tree is no "archetype"), a HELIOS++ part called an object, not a tree, a top
view without no-data stripes between scan lines, and trees.png with names and a height scale."""

import numpy as np
import pytest

from mitsuforest.classes import CLASS_NAMES, GROUND, ROCK, TREE_LEAVES, TREE_WOOD
from mitsuforest.scan import POINT_DTYPE
from mitsuforest.write.figures import tile_figure
from mitsuforest.write.quicklook import SideTile, TopView


def _drawn(fig):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return canvas.get_renderer()


def _tile(z_top: float, classes, instances, treeids, n=4000) -> SideTile:
    rng = np.random.default_rng(1)
    pts = np.zeros(n, POINT_DTYPE)
    pts["x"], pts["y"], pts["z"] = rng.uniform(0, 20, n), rng.uniform(0, 20, n), rng.uniform(0, z_top, n)
    pts["classification"] = rng.choice(classes, n)
    tree = np.isin(pts["classification"], (TREE_WOOD, TREE_LEAVES))
    k = rng.integers(0, len(instances), n)
    pts["instance"] = np.where(tree, np.array(instances)[k], 0)
    pts["treeid"] = np.where(tree, np.array(treeids)[k], 0)
    tile = SideTile((20, 20))
    tile.add(pts)
    return tile


@pytest.mark.parametrize("z_top", [1.5, 25.0])
def test_tile_legends_clear_the_axis_labels(z_top):
    """A tile 1.5 m high (a young stand, a meadow) put its legends over the x labels; every legend now
    lies below its axes' x label and inside the picture."""
    fig = tile_figure(_tile(z_top, sorted(CLASS_NAMES), list(range(1, 13)), [1 + i % 10 for i in range(12)]))
    renderer = _drawn(fig)
    picture = fig.bbox
    for ax in fig.axes:
        legend = ax.get_legend().get_window_extent(renderer)
        label = ax.xaxis.label.get_window_extent(renderer)
        ticks = ax.xaxis.get_tightbbox(renderer)
        assert legend.y1 < label.y0 and legend.y1 < ticks.y0, (legend, label)
        assert legend.y0 >= picture.y0 and legend.x0 >= picture.x0 and legend.x1 <= picture.x1


def test_the_instance_legend_names_models_and_objects():
    """treeid N is model treeNN, an archetype's or an imported tree's alike; treeid 0 (a HELIOS++ part of
    a tree class) is an object."""
    fig = tile_figure(_tile(20, [GROUND, TREE_WOOD, TREE_LEAVES, ROCK], [1, 2, 3], [3, 12, 0]))
    labels = sorted(t.get_text() for t in fig.axes[2].get_legend().get_texts())
    assert labels == ["not a tree", "object 3", "tree 1 (tree03)", "tree 2 (tree12)"]
    assert fig.axes[2].get_xlabel() == "x (m)" and fig.axes[0].get_ylabel() == "z (m)"


def test_the_top_view_fills_the_gaps_between_scan_lines():
    """Scan lines 0.12 m apart under 0.05 m pixels left every other row empty (the DEM example's stripes):
    the gaps are filled, while ground without points (past x = 15 m) stays white."""
    top = TopView((20, 20))
    x, y = np.meshgrid(np.arange(0, 15, 0.03), np.arange(0, 20, 0.12))
    pts = np.zeros(x.size, POINT_DTYPE)
    pts["x"], pts["y"], pts["classification"] = x.ravel(), y.ravel(), GROUND
    top.add(pts)
    white = (top.image() == 255).all(axis=2)
    covered = white[:, : int(14.9 * top.scale)]
    assert covered.mean() == 0.0
    assert white[:, int(15.6 * top.scale):].all()
    unfilled = (top.image(fill_m=0) == 255).all(axis=2)[:, : int(14.9 * top.scale)]
    assert unfilled.mean() > 0.5          # what the picture showed before


def test_trees_png_names_each_tree_with_a_height_scale():
    from mitsuforest.write.gallery import PIXELS_PER_M, gallery_figure
    tall, short = np.zeros((280, 70, 3), np.uint8), np.zeros((140, 42, 3), np.uint8)
    fig = gallery_figure([tall, short], ["tree01", "tree02\nbirch.ply"])
    ax = fig.axes[0]
    assert [t.get_text() for t in ax.get_xticklabels()] == ["tree01", "tree02\nbirch.ply"]
    assert np.allclose(ax.get_xticks(), [(10 + 35) / PIXELS_PER_M, (10 + 70 + 10 + 21) / PIXELS_PER_M])
    assert ax.get_ylabel() == "height above the tree's base (m)"
    assert ax.get_ylim()[1] == pytest.approx((280 + 10) / PIXELS_PER_M)     # the tall tree is 20 m
    assert ax.get_title() == "2 trees seen from the side: wood brown, leaves green"


def test_a_helios_survey_is_summarised_by_its_parts(tmp_path, monkeypatch):
    """Its plan has no trees, only parts: "plan: 1 HELIOS++ part", not "0 trees"."""
    from test_helios import _demo_like_survey
    from mitsuforest.helios.render import survey_scene
    from mitsuforest.helios.survey import read_survey
    from mitsuforest.survey import placed_summary
    _demo_like_survey(tmp_path)
    monkeypatch.chdir(tmp_path)
    scene, plan, *_ = survey_scene(read_survey("data/survey.xml", ["assets"]))
    assert placed_summary(plan) == "1 HELIOS++ part"


def test_a_forest_is_summarised_by_its_trees(demo_result):
    assert placed_summary_of(demo_result.plan) == f"{len(demo_result.plan.trees)} trees" != "0 trees"


def placed_summary_of(plan):
    from mitsuforest.survey import placed_summary
    return placed_summary(plan)
