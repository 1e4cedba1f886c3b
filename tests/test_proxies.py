"""The models' proxies (scene/proxies.py): the cells a model occupies, and the scene of grown cells that the
scan aims its pulses at. A proxy must hold every surface of its model (else a pulse that would hit it is
dropped) and be grown by the widest sub-ray's distance in the world's metres, whatever the placement's scale."""

import numpy as np
import pytest

from mitsuforest.scene.proxies import CELL, Cells, model_cells, occupied_cells, proxy_scene, smallest_scale

RNG = np.random.default_rng(30)


def test_a_triangle_occupies_the_cells_of_its_bounding_box():
    """A small triangle inside one cell occupies that cell; one from (0.1, 0.1, 0.1) to x = 1.4 and z = 0.9
    at 0.5 m cells spans x cells 0-2 and z cells 0-1 in the row y = 0: 6 cells; negative coordinates floor."""
    small = np.array([[0.6, 0.6, 0.6], [0.7, 0.6, 0.6], [0.6, 0.7, 0.65]])
    assert occupied_cells(small, np.array([[0, 1, 2]])).tolist() == [[1, 1, 1]]
    wide = np.array([[0.1, 0.1, 0.1], [1.4, 0.1, 0.1], [0.1, 0.1, 0.9]])
    assert occupied_cells(wide, np.array([[0, 1, 2]])).tolist() == [[x, 0, z] for x in range(3) for z in range(2)]
    assert occupied_cells(small - 1.0, np.array([[0, 1, 2]])).tolist() == [[-1, -1, -1]]
    assert occupied_cells(wide, np.zeros((0, 3), int)).shape == (0, 3)


def test_every_surface_point_of_a_tree_lies_in_a_cell_of_its_proxy(demo_setup):
    """Points drawn uniformly on every triangle of the demo's models fall in their model's cells; the cells
    are few against the crown's box (the point of a proxy)."""
    _, plan, models, _ = demo_setup
    for name in sorted({o.model for o in plan.objects}):
        model = models[name]
        index, size = model_cells(model)
        assert size == CELL
        cells = {tuple(c) for c in index}
        for part in model.parts:
            t = part.vertices[part.faces]
            u, v = RNG.uniform(size=(2, len(t), 1))
            flip = u + v > 1
            u, v = np.where(flip, 1 - u, u), np.where(flip, 1 - v, v)
            points = t[:, 0] + u * (t[:, 1] - t[:, 0]) + v * (t[:, 2] - t[:, 0])
            assert {tuple(c) for c in np.floor(points / CELL).astype(int)} <= cells, name
        span = np.ptp(model.vertices(), axis=0) / CELL + 1
        assert len(cells) < 0.5 * np.prod(span), name      # an open crown fills under half its box


def test_a_proxy_is_grown_in_world_metres_under_a_scaled_placement(variant):
    """One cell [0, 0.5]³ placed scaled 2 × and moved to x = 10, grown by 0.1 m: a downward pulse 0.09 m
    beside the placed cell ([10, 11] in x) meets the proxy, one 0.11 m beside it does not; the ground's box,
    grown alike, catches pulses over it."""
    import mitsuba as mi
    from mitsuforest.scan.pulses import aimed_at, upload_pulses
    from mitsuforest.scene.variant import variant_scope
    from mitsuforest.testing.reference.pulses import Pulses
    matrix = np.diag([2.0, 2.0, 2.0, 1.0])
    matrix[:3, 3] = [10.0, 0.0, 0.0]
    assert smallest_scale(matrix) == pytest.approx(2.0)
    ground = np.array([[[30.0, 0.0, 0.0], [40.0, 10.0, 0.0]]])
    xs = [11.09, 11.11, 9.91, 9.89, 10.5, 35.0, 29.85]
    origin = np.array([[x, 0.5, 5.0] for x in xs])
    made = Pulses(np.arange(len(xs)), np.zeros(len(xs)), origin, np.tile([0.0, 0, -1], (len(xs), 1)),
                  np.tile([1.0, 0, 0], (len(xs), 1)), np.zeros(len(xs)))
    bounds, box = np.array([[10.0, 0, 0], [40.0, 10, 1]]), np.array([[9.0, -1, -1], [41.0, 11, 2]])
    with variant_scope(variant):
        scene = proxy_scene({"cube": Cells(np.array([[0, 0, 0]], np.int32), 0.5)}, [("cube", matrix)], 0.1, ground)
        kept = aimed_at(upload_pulses(made), [(100.0, scene)], bounds, box, range_max=100.0)
        assert kept.pulse_id.numpy().tolist() == [0, 2, 4, 5]
        assert isinstance(scene, mi.Scene)


def test_a_large_model_gets_larger_cells():
    """A 3 km square of two triangles would be 3.6 · 10^7 cells of 0.5 m a layer: its cells double until its
    box spans at most MAX_GRID of them (2 m), and it occupies them all (its triangles' boxes fill the layer)."""
    from mitsuforest.scene.proxies import MAX_GRID
    from mitsuforest.trees.models import Component, Model, Part
    square = np.array([[0, 0, 0], [3000, 0, 0], [3000, 3000, 0.3], [0, 3000, 0.3]], float)
    part = Part("ground", square, np.array([[0, 1, 2], [0, 2, 3]], np.uint32), np.zeros(2, np.uint16))
    index, size = model_cells(Model("plate", [part], [Component("rock", 65)]))
    side = int(np.floor(3000 / size)) + 1
    assert size == 2.0 and (np.floor(np.array([3000, 3000, 0.3]) / size) + 2).prod() <= MAX_GRID
    assert (np.floor(np.array([3000, 3000, 0.3]) / (size / 2)) + 2).prod() > MAX_GRID
    assert len(index) == side * side and index[:, 2].max() == 0


def test_a_model_without_vertices_has_no_cells():
    """No corners: no box to fill and no triangle to place, so no cells (not an error on an empty box)."""
    from mitsuforest.trees.models import Component, Model, Part
    part = Part("wood", np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint32), np.zeros(0, np.uint16))
    index, size = model_cells(Model("bare", [part], [Component("stem", 4)]))
    assert index.shape == (0, 3) and size == CELL
