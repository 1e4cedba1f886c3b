"""The render's pictures: rasters put each point in its pixel, the figures are written with the tile's
whole height, and a render writes all four."""

import numpy as np
from PIL import Image

from mitsuforest.classes import GROUND, TREE_LEAVES, TREE_WOOD
from mitsuforest.scan import POINT_DTYPE
from mitsuforest.write.figures import tile_z_range, write_tile_figure, write_top_figure
from mitsuforest.write.profile import ReturnCounts
from mitsuforest.write.quicklook import CLASS_COLOURS, SideTile, TopView, front_view


def points(rows):
    """Points from (x, y, z, classification, instance, return_number) rows."""
    p = np.zeros(len(rows), POINT_DTYPE)
    for name, column in zip(("x", "y", "z", "classification", "instance", "return_number"), np.array(rows).T):
        p[name] = column
    return p


def test_top_view_keeps_the_highest_point_of_each_pixel_across_batches():
    top = TopView((10, 10), pixels_per_m=1)
    top.add(points([(2.5, 7.5, 1.0, GROUND, 0, 1), (2.5, 7.5, 9.0, TREE_LEAVES, 1, 1)]))
    top.add(points([(2.5, 7.5, 5.0, TREE_WOOD, 1, 2), (8.5, 0.5, 0.0, GROUND, 0, 1)]))
    img = top.image()
    assert img.shape == (10, 10, 3)
    assert (img[2, 2] == CLASS_COLOURS[TREE_LEAVES]).all()      # row 2 from the north is y 7..8
    assert (img[9, 8] == CLASS_COLOURS[GROUND]).all()
    assert (img[0, 0] == 255).all()


def test_front_view_shows_the_nearest_point_of_each_pixel():
    p = points([(1.5, 5.0, 2.5, GROUND, 0, 1), (1.5, 2.0, 2.5, TREE_WOOD, 1, 1), (1.5, 8.0, 2.5, GROUND, 0, 1)])
    img = front_view(p, (0, 4), (0, 4), CLASS_COLOURS[p["classification"]], pixels_per_m=1)
    assert img.shape == (4, 4, 3)
    assert (img[1, 1] == CLASS_COLOURS[TREE_WOOD]).all()        # z 2.5 is row 1 from the top
    assert (img[[0, 2, 3]] == 255).all()


def test_tile_figure_spans_the_whole_height(tmp_path):
    tile = SideTile((40, 40))
    tile.add(points([(15, 15, -0.4, GROUND, 0, 1), (20, 20, 31.7, TREE_LEAVES, 3, 1), (1, 1, 50, TREE_LEAVES, 4, 1)]))
    z0, z1 = tile_z_range(tile.points())
    assert z0 < -0.4 and 31.7 < z1 < 33        # the tree outside the tile (z 50) does not count
    write_tile_figure(tmp_path / "side.png", tile)
    top = TopView((40, 40))
    write_top_figure(tmp_path / "top.png", top, tile, [GROUND])
    for name in ("side.png", "top.png"):
        with Image.open(tmp_path / name) as im:
            assert im.format == "PNG" and min(im.size) > 300


def test_a_narrow_plots_top_view_keeps_room_for_its_axes_and_title(tmp_path):
    """A 1 x 27 m strip (a twin of a narrow clip) once failed in matplotlib ("left cannot be >= right"):
    its figure is now as wide as its margins, an axes box of MIN_AXES_IN and no less; a square plot's
    is as before."""
    from mitsuforest.write.figures import DPI, MIN_AXES_IN
    for area, width_in in (((1, 27), 0.7 + 1.75 + MIN_AXES_IN), ((40, 40), 7.0 + 1.8)):
        top = TopView(area)
        top.add(points([(0.5, 13.0, 0.0, GROUND, 0, 1)]))
        write_top_figure(tmp_path / "top.png", top, None, [GROUND])
        with Image.open(tmp_path / "top.png") as im:
            assert im.size == (round(width_in * DPI), round(7.0 * DPI)), (area, im.size)


def test_a_narrow_plots_side_view_keeps_a_bounded_height(tmp_path):
    """A 1 x 27 m plot's tile is 1 m wide: at the 20 m tile's scale its 31 m of height would make a
    figure 108 inches (10,800 pixels) tall; it stops at MAX_TILE_HEIGHT_IN."""
    from mitsuforest.write.figures import DPI, MAX_TILE_HEIGHT_IN
    tile = SideTile((1, 27))
    tile.add(points([(0.5, 13.5, 0.0, GROUND, 0, 1), (0.5, 13.5, 30.0, TREE_LEAVES, 1, 1)]))
    assert tile.tile == 1.0
    write_tile_figure(tmp_path / "side.png", tile)
    with Image.open(tmp_path / "side.png") as im:
        assert MAX_TILE_HEIGHT_IN * DPI < im.size[1] < (MAX_TILE_HEIGHT_IN + 4) * DPI


def test_the_top_view_outlines_the_tile_from_its_outline_alone(tmp_path):
    """The top view is sent the tile's outline, not its points: the same picture, the tile untouched."""
    tile = SideTile((40, 30))
    tile.add(points([(15, 10, 0.0, GROUND, 0, 1), (20, 14, 12.0, TREE_LEAVES, 3, 1)]))
    outline = tile.outline()
    assert len(outline.points()) == 0 and len(tile.points()) == 2
    assert (outline.x0, outline.y0, outline.tile, outline.x_range) == (tile.x0, tile.y0, 20.0, (10.0, 30.0))
    top = TopView((40, 30))
    top.add(tile.points())
    write_top_figure(tmp_path / "with_points.png", top, tile, [GROUND, TREE_LEAVES])
    write_top_figure(tmp_path / "outline.png", top, outline, [GROUND, TREE_LEAVES])
    assert (tmp_path / "with_points.png").read_bytes() == (tmp_path / "outline.png").read_bytes()


def test_a_stored_tile_reads_its_points_back_and_draws_the_same_side_view(tmp_path):
    """The side view's points go to a worker in a file: the same points, the same picture."""
    tile = SideTile((40, 40))
    tile.add(points([(15, 15, -0.4, GROUND, 0, 1), (20, 20, 31.7, TREE_LEAVES, 3, 1)]))
    tile.add(points([(25, 21, 3.0, TREE_WOOD, 3, 2)]))
    stored = tile.stored(tmp_path / "side.npy")
    assert stored.parts == [] and stored.x_range == tile.x_range
    assert np.array_equal(stored.points(), tile.points()) and len(stored.points()) == 3
    assert stored.outline().points().size == 0
    write_tile_figure(tmp_path / "kept.png", tile)
    write_tile_figure(tmp_path / "stored.png", stored)
    assert (tmp_path / "kept.png").read_bytes() == (tmp_path / "stored.png").read_bytes()


def test_return_counts_by_height_class_and_return_number():
    counts = ReturnCounts()
    counts.add(points([(1, 1, 0.1, GROUND, 0, 1), (1, 1, 12.2, TREE_LEAVES, 1, 1), (1, 1, 11.0, TREE_WOOD, 1, 2)]))
    edges = counts.bin_edges
    assert counts.by_height.sum() == 3
    row = np.searchsorted(edges, 12.2, "right") - 1
    assert counts.by_height[row, TREE_LEAVES] == 1 and edges[row] <= 12.2 < edges[row + 1]
    assert counts.first[GROUND] == 1 and counts.first[TREE_LEAVES] == 1 and counts.by_return[2, TREE_WOOD] == 1


PICTURES = ("_top.png", "_side.png", "_profile.png", "_returns.png")


def test_a_render_writes_every_picture_unless_told_not_to(tmp_path):
    """``output.pictures: false`` leaves the four pictures out and changes no other file."""
    from mitsuforest.pipeline import render
    from helpers import scene_file
    survey = {"altitude": 30, "pulse_frequency": 100000, "scan_frequency": 50, "speed": 20,
              "lines": [[[20.0, 0.0], [20.0, 40.0]]]}
    result = render(scene_file(tmp_path / "a", survey=survey), progress=False, log=lambda *_: None)
    names = {f.name for f in result.files}
    for suffix in PICTURES:
        assert "test" + suffix in names
        with Image.open(tmp_path / "a" / "out" / ("test" + suffix)) as im:
            assert im.format == "PNG"
    bare = render(scene_file(tmp_path / "b", survey=survey, output={"pictures": False}), progress=False,
                  log=lambda *_: None)
    assert {f.name for f in bare.files} == {n for n in names if not n.endswith(PICTURES)}
    for name in ("test.pcd", "test_ids.csv", "test_volumes.csv"):
        assert (tmp_path / "b" / "out" / name).read_bytes() == (tmp_path / "a" / "out" / name).read_bytes()


def test_heights_above_a_ground_given_only_as_a_mesh():
    """A HELIOS++ scene's ground has triangles and no height field: heights come from the triangles."""
    from types import SimpleNamespace
    vertices = np.array([[-1, -1, 2.0], [11, -1, 2.0], [11, 11, 8.0], [-1, 11, 8.0]])   # z = 2.5 + 0.5 y
    ground = SimpleNamespace(mesh=lambda: (vertices, np.array([[0, 1, 2], [0, 2, 3]])), mean_height=5.0)
    counts = ReturnCounts(ground, (10, 10))
    assert np.allclose(counts.ground(np.array([3.0, 7.0]), np.array([4.0, 9.5])), [4.5, 7.25])


def test_a_picture_is_drawn_once_into_the_pixels_savefig_writes(tmp_path, monkeypatch):
    """The pictures are drawn once, with fixed margins and no layout engine, into the same pixels as
    ``savefig``: the tile with its legends, and the returns chart's log axis."""
    from matplotlib.figure import Figure

    from mitsuforest.write import figures
    p = points([(5, 10, 0.1, GROUND, 0, 1), (8, 12, 14.0, TREE_LEAVES, 2, 1), (9, 12, 9.0, TREE_WOOD, 2, 2)])
    tile, counts = SideTile((20, 20)), ReturnCounts(None, (20, 20))
    tile.add(p)
    counts.add(p)
    draws = []
    draw = Figure.draw
    monkeypatch.setattr(Figure, "draw", lambda fig, renderer: draws.append(fig) or draw(fig, renderer))
    for name, make in (("side", lambda: figures.tile_figure(tile)),
                       ("returns", lambda: figures.returns_figure(np.array([5, 2, 1]), counts))):
        figures._save(make(), tmp_path / f"{name}.png")
        assert len(draws) == 1
        make().savefig(tmp_path / f"{name}_savefig.png", format="png", dpi=figures.DPI)
        assert len(draws) == 2
        with Image.open(tmp_path / f"{name}.png") as ours, Image.open(tmp_path / f"{name}_savefig.png") as theirs:
            assert ours.mode == "RGB" and ours.size == theirs.size and ours.info["dpi"] == theirs.info["dpi"]
            assert np.array_equal(np.asarray(ours), np.asarray(theirs.convert("RGB")))
        draws.clear()


def test_the_charts_of_a_scan_without_points_draw_without_a_warning(tmp_path):
    """A render of no points (a twin of a one-point file) draws empty charts without matplotlib's "No
    artists with labels found to put in legend"."""
    import warnings

    from mitsuforest.write import figures
    counts = ReturnCounts(None, (20, 20))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        figures.write_profile_figure(tmp_path / "profile.png", counts)
        figures.write_returns_figure(tmp_path / "returns.png", np.zeros(3, np.int64), counts)
    assert (tmp_path / "profile.png").stat().st_size > 1000 and (tmp_path / "returns.png").stat().st_size > 1000
