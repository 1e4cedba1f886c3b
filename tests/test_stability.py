"""Numerically hard cases (from benchmarks/stability.py, which now only prints figures): huge
coordinate offsets, a sub-millimetre twig, a plane coincident with the ground, extreme ranges, rays
into the sky, and more echoes than ``max_returns``. Cases already in test_scan.py (grazing incidence,
grid vertices and edges, the 5e5/6e6 offset) are not repeated."""

import dataclasses

import numpy as np
import pytest
from helpers import analytic_scene, plane_model, pulses, scene_file

from mitsuforest.classes import GROUND, ROCK, TREE_WOOD
from mitsuforest.labels import labelled
from mitsuforest.pipeline import render
from mitsuforest.scan import PulseTracer
from mitsuforest.scan.beam import beam_pattern
from mitsuforest.trees.models import Component, Model, Part
from mitsuforest.trees.tubes import tube
from mitsuforest.trees.volume import union_volume

N = 50  # pulses per case, as in the benchmark's --quick mode


def _trace(setup, p, samples=1, **sensor_changes):
    scene, _, _, scan_scene = setup
    tracer = PulseTracer(scan_scene, dataclasses.replace(scene.sensor, **sensor_changes), samples)
    return labelled(*tracer.trace_pulses(p), tracer.table)


def _local_points(folder, offset):
    path = scene_file(folder, "riegl_vux-1uav22.yaml", area={"size": [10, 10]}, understory={"rocks": 3},
                      simulation={"beam_samples": 7},
                      survey={"pulse_frequency": 100000, "lines": [[[5, 0], [5, 10 * N / 4000]]]},
                      origin={"offset": offset})
    pts = render(path, write=False, progress=False, log=lambda *_: None).points
    return np.column_stack([pts[a] - o for a, o in zip("xyz", offset)])


@pytest.fixture(scope="module")
def unshifted(tmp_path_factory):
    return _local_points(tmp_path_factory.mktemp("offset0"), [0, 0, 0])


@pytest.mark.parametrize("offset", [[1e7, 1e7, 1000.0]])
def test_huge_origin_offset_moves_points_by_less_than_a_millimetre(unshifted, offset, tmp_path):
    local = _local_points(tmp_path, offset)
    assert len(local) == len(unshifted) > 0
    assert np.abs(local - unshifted).max() < 1e-3


def test_half_millimetre_twig_adds_its_outside_volume():
    """A 0.5 mm twig leaving a tapered stem's axis: the stem radius along the twig is
    0.175 - 0.005 s at parameter s, so the twig leaves it at s = 0.175 / 0.505."""
    stem = tube(np.array([[0, 0, 0], [0, 0, 20.0]]), np.array([0.3, 0.05]), 24)
    ends = np.array([[0, 0, 10.0], [0.5, 0, 10.4]])
    twig = tube(ends, np.array([0.0005, 0.0005]), 5)
    length = np.linalg.norm(ends[1] - ends[0])
    expected = np.pi * 0.0005 ** 2 * length * (1 - 0.175 / 0.505)
    assert union_volume([stem, twig]) - union_volume([stem]) == pytest.approx(expected, rel=0.05)


def test_thin_rays_hit_a_half_millimetre_twig_at_its_surface(tmp_path):
    """A horizontal 0.5 mm twig 10 m below thin-beam pulses offset by |y| ≤ 0.4 mm from its axis."""
    v, f = tube(np.array([[-1.0, 0, 0], [1.0, 0, 0]]), np.array([0.0005, 0.0005]), 5)
    model = Model("twig", [Part("wood", v, f.astype(np.uint32), np.zeros(len(f), np.uint16))],
                  [Component("branch", TREE_WOOD)])
    setup = analytic_scene(scene_file(tmp_path), [(model, (20, 20, 20), 0, (0, 0), 1)])
    ys = np.linspace(-0.0004, 0.0004, N)
    hits = _trace(setup, pulses(np.column_stack([np.full(N, 20.0), 20 + ys, np.full(N, 30.0)]), [0, 0, -1]))
    on_twig = hits[hits["classification"] == TREE_WOOD]
    assert len(on_twig) == N
    # A 5-sided tube, not a cylinder: within 1 mm of the round surface.
    assert np.abs(on_twig["range"] - (10 - np.sqrt(0.0005 ** 2 - ys ** 2))).max() < 1e-3


def test_plane_coincident_with_the_ground_gives_one_echo(tmp_path):
    setup = analytic_scene(scene_file(tmp_path), [(plane_model("plane", 10.0, ROCK), (20, 20, 0.0), 0, (0, 0), 0)])
    xy = np.random.default_rng(0).uniform(16, 24, (N, 2))
    pts = _trace(setup, pulses(np.column_stack([xy, np.full(N, 30.0)]), [0, 0, -1]))
    assert len(pts) == N and np.all(pts["number_of_returns"] == 1)
    assert set(np.unique(pts["classification"]).tolist()) <= {GROUND, ROCK}
    assert np.abs(pts["z"]).max() < 1e-3


@pytest.fixture(scope="module")
def vux(tmp_path_factory):
    """Flat ground, RIEGL VUX-1UAV22 sensor (range_min 3 m)."""
    return analytic_scene(scene_file(tmp_path_factory.mktemp("vux"), "riegl_vux-1uav22.yaml"))


@pytest.mark.parametrize("height, echoes", [(2.0, 0), (900.0, N)])
def test_range_limits_and_a_long_range(vux, height, echoes):
    """2 m is below range_min (no echo); 900 m is ranged to < 5 mm in float32."""
    pts = _trace(vux, pulses(np.tile([20, 20, height], (N, 1)), [0, 0, -1]), 1, range_precision=0.0)
    assert len(pts) == echoes
    if echoes:
        assert np.abs(pts["range"] - height).max() < 5e-3


def test_pulses_into_the_sky_give_nothing(vux):
    pts = _trace(vux, pulses(np.tile([20, 20, 30.0], (N, 1)), [0, 0, 1]), 19, beam_divergence=(1e-3, 1e-3))
    assert len(pts) == 0


def _staircase_echoes(samples, x0, divergence):
    """Echo count of a nadir pulse from (x0, 20, 30) over the staircase below, from the geometry.

    The pulse frame of :func:`pulses` for a nadir beam has first axis (0, -1, 0) and second
    (-1, 0, 0), so a sub-ray of tangents (tx, ty) runs along (-ty, -tx, -1). Step i is a 0.5 m
    square at height i centred at (18 + 0.5 i, 20); the ground (z = 0) lies under all. Echoes are
    chains of the sorted sub-ray ranges with gaps ≤ ΔR.
    """
    offsets, _ = beam_pattern(samples)
    ranges = []
    for tx, ty in np.tan(offsets * np.asarray(divergence) / 2):
        for i in range(7, -1, -1):
            h = 30.0 - i
            x, y = x0 - ty * h, 20 - tx * h
            if i == 0 or (abs(x - (18 + 0.5 * i)) <= 0.25 and abs(y - 20) <= 0.25):
                ranges.append(h * np.sqrt(1 + tx ** 2 + ty ** 2))
                break
    return 1 + int(np.count_nonzero(np.diff(np.sort(ranges)) > (299_792_458.0 * 1e-9 / 2)))


@pytest.mark.parametrize("samples, expected", [(7, 4), (19, 6)])
def test_more_echoes_than_max_returns(tmp_path, samples, expected):
    """A wide beam over a staircase of 8 steps: every step and ground slant it sees is an echo;
    ``max_returns = 3`` keeps the nearest three, numbered 1..3. The beam centre (x = 19.9) and every
    sub-ray stay > 4 cm from step edges and every range gap > 3 cm from ΔR = 0.15 m."""
    steps = [(plane_model(f"s{i}", 0.5, ROCK), (18.0 + 0.5 * i, 20, 1.0 * i), 0, (0, 0), 0) for i in range(8)]
    setup = analytic_scene(scene_file(tmp_path), steps)
    p = pulses(np.tile([19.9, 20, 30.0], (N, 1)), [0, 0, -1])
    wide = {"beam_divergence": [0.01, 0.3], "pulse_length": 1e-9}
    assert _staircase_echoes(samples, 19.9, wide["beam_divergence"]) == expected
    free = _trace(setup, p, samples, max_returns=0, **wide)
    capped = _trace(setup, p, samples, max_returns=3, **wide)
    assert np.all(free["number_of_returns"] == expected) and len(free) == N * expected
    assert np.all(capped["number_of_returns"] == 3) and len(capped) == N * 3
    assert np.array_equal(capped["return_number"], np.tile([1, 2, 3], N))
    nearest = free[free["return_number"] <= 3]
    assert np.array_equal(capped["range"], nearest["range"])
