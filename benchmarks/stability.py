"""Numerical stability on hard cases, as one report: each case, what was measured, what it must be.

    python benchmarks/stability.py          # ~1 min on 2 cores
    python benchmarks/stability.py --quick  # the same cases with fewer pulses (CI)

Exit code 1 if any case fails.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from mitsuforest.classes import GROUND, ROCK, TREE_WOOD
from mitsuforest.render import render
from mitsuforest.scan import PulseTracer
from mitsuforest.scene.analytic import analytic_scene, bare_scene_file, plane_model, pulses
from mitsuforest.trees.tubes import tube
from mitsuforest.trees.models import Component, Model, Part
from mitsuforest.trees.volume import union_volume

ROOT = Path(__file__).resolve().parents[1]
SENSORS = ROOT / "sensors"
RNG = np.random.default_rng(0)


def _trace(setup, p, samples=1, **sensor):
    scene, _, _, scan_scene = setup
    return PulseTracer(scan_scene, {**scene["sensor"], **sensor}, samples).trace(p, RNG)


def grazing(tmp, n):
    setup = analytic_scene(bare_scene_file(tmp / "g", SENSORS / "ideal.yaml"))
    theta = np.deg2rad(np.linspace(85, 89.9, n))
    d = np.column_stack([np.sin(theta), np.zeros(n), -np.cos(theta)])
    pts = _trace(setup, pulses(np.tile([0.5, 20, 0.05], (n, 1)), d), 19, beam_divergence=[1e-3, 1e-3])
    finite = all(np.isfinite(pts[k]).all() for k in ("x", "y", "z", "intensity", "range"))
    return f"{len(pts)} echoes from {n} pulses at 85-89.9°, all finite: {finite}", finite and len(pts) > 0


def offsets(tmp, n):
    worst, rows = 0.0, []
    base = None
    for offset in ([0, 0, 0], [1e4, 1e4, 0], [5e5, 6e6, 100], [1e7, 1e7, 1000]):
        path = bare_scene_file(tmp / f"o{offset[0]:g}", SENSORS / "riegl_vux-1uav22.yaml", area={"size": [10, 10]},
                               understory={"rocks": 3}, simulation={"beam_samples": 7},
                               survey={"pulse_frequency": 100000, "lines": [[[5, 0], [5, 10 * n / 4000]]]},
                               origin={"offset": offset})
        pts = render(path, write=False, progress=False, log=lambda *_: None).points
        local = np.column_stack([pts[a] - o for a, o in zip("xyz", offset)])
        base = local if base is None else base
        worst = max(worst, float(np.abs(local - base).max()))
        rows.append(f"{offset[0]:g}")
    return f"offsets {', '.join(rows)} m: largest local deviation {worst * 1e3:.3g} mm (< 1 mm)", worst < 1e-3


def thin_twig(tmp, n):
    stem = tube(np.array([[0, 0, 0], [0, 0, 20.0]]), np.array([0.3, 0.05]), 24)
    pts = np.array([[0, 0, 10.0], [0.5, 0, 10.4]])
    twig = tube(pts, np.array([0.0005, 0.0005]), 5)
    added = union_volume([stem, twig]) - union_volume([stem])
    inside = 0.175 / (0.5 + 0.25 * 0.4 / 20) * np.linalg.norm(pts[1] - pts[0])
    expected = np.pi * 0.0005 ** 2 * (np.linalg.norm(pts[1] - pts[0]) - inside)
    ok_volume = abs(added / expected - 1) < 0.05
    # The laser sees a horizontal 0.5 mm twig 10 m below a thin-beam sensor.
    v, f = tube(np.array([[-1.0, 0, 0], [1.0, 0, 0]]), np.array([0.0005, 0.0005]), 5)
    model = Model("twig", [Part("wood", v, f.astype(np.uint32), np.zeros(len(f), np.uint16))],
                  [Component("branch", TREE_WOOD)])
    setup = analytic_scene(bare_scene_file(tmp / "t", SENSORS / "ideal.yaml"), [(model, (20, 20, 20), 0, (0, 0), 1)])
    ys = np.linspace(-0.0004, 0.0004, n)
    hits = _trace(setup, pulses(np.column_stack([np.full(n, 20.0), 20 + ys, np.full(n, 30.0)]), [0, 0, -1]))
    on_twig = hits[hits["classification"] == TREE_WOOD]
    ok_scan = len(on_twig) == n and np.abs(on_twig["range"] - (10 - np.sqrt(0.0005 ** 2 - ys ** 2))).max() < 1e-3
    return (f"0.5 mm twig: union adds {added:.4g} m³ (expected {expected:.4g}); {len(on_twig)}/{n} thin rays hit it "
            f"at the right range", ok_volume and ok_scan)


def coincident(tmp, n):
    plane = plane_model("plane", 10.0, ROCK)
    setup = analytic_scene(bare_scene_file(tmp / "c", SENSORS / "ideal.yaml"), [(plane, (20, 20, 0.0), 0, (0, 0), 0)])
    xy = RNG.uniform(16, 24, (n, 2))
    pts = _trace(setup, pulses(np.column_stack([xy, np.full(n, 30.0)]), [0, 0, -1]))
    one_each = len(pts) == n and np.all(pts["number_of_returns"] == 1)
    classes = set(np.unique(pts["classification"]).tolist())
    return (f"plane coincident with the ground: {len(pts)} echoes for {n} pulses, classes {sorted(classes)}",
            one_each and classes <= {GROUND, ROCK})


def edges_and_vertices(tmp, n):
    setup = analytic_scene(bare_scene_file(tmp / "e", SENSORS / "ideal.yaml",
                                           terrain={"type": "noise", "amplitude": 0.0}))
    k = max(int(np.sqrt(n / 3)), 2)
    grid = np.stack(np.meshgrid(np.arange(5, 5 + k, 1.0), np.arange(5, 5 + k, 1.0)), -1).reshape(-1, 2)
    targets = np.vstack([grid, grid + [0.5, 0.0], grid + [0.5, 0.5]])
    pts = _trace(setup, pulses(np.column_stack([targets, np.full(len(targets), 30.0)]), [0, 0, -1]))
    ok = len(pts) == len(targets) and len(np.unique(pts["pulse_id"])) == len(targets)
    return f"{len(targets)} rays through grid vertices and edges: {len(pts)} echoes, one each: {ok}", ok


def ranges(tmp, n):
    setup = analytic_scene(bare_scene_file(tmp / "r", SENSORS / "riegl_vux-1uav22.yaml"))
    short = _trace(setup, pulses(np.tile([20, 20, 2.0], (n, 1)), [0, 0, -1]), 1, range_precision=0.0)
    long_ = _trace(setup, pulses(np.tile([20, 20, 900.0], (n, 1)), [0, 0, -1]), 1, range_precision=0.0)
    ok = len(short) == 0 and len(long_) == n and np.abs(long_["range"] - 900).max() < 5e-3
    return (f"range 2 m (< range_min 3 m): {len(short)} echoes; range 900 m: {len(long_)} echoes, "
            f"largest error {np.abs(long_['range'] - 900).max() * 1e3:.3g} mm", ok)


def misses(tmp, n):
    setup = analytic_scene(bare_scene_file(tmp / "m", SENSORS / "ideal.yaml"))
    pts = _trace(setup, pulses(np.tile([20, 20, 30.0], (n, 1)), [0, 0, 1]), 19, beam_divergence=[1e-3, 1e-3])
    return f"{n} pulses into the sky: {len(pts)} echoes, no error", len(pts) == 0


def too_many_returns(tmp, n):
    """A staircase of 8 narrow steps under one wide beam: 8 echoes, capped to max_returns = 3."""
    steps = [(plane_model(f"s{i}", 0.5, ROCK), (18.0 + 0.5 * i, 20, 1.0 * i), 0, (0, 0), 0) for i in range(8)]
    setup = analytic_scene(bare_scene_file(tmp / "x", SENSORS / "ideal.yaml"), steps)
    p = pulses(np.tile([19.75, 20, 30.0], (n, 1)), [0, 0, -1])
    wide = dict(beam_divergence=[0.01, 0.3], pulse_length=1e-9)  # the second frame axis is x here
    free = _trace(setup, p, 61, max_returns=0, **wide)
    capped = _trace(setup, p, 61, max_returns=3, **wide)
    ok = free["number_of_returns"].max() > 3 and capped["number_of_returns"].max() == 3 and \
        np.array_equal(np.sort(np.unique(capped["return_number"])), [1, 2, 3])
    return (f"staircase: up to {free['number_of_returns'].max()} returns unlimited, "
            f"{capped['number_of_returns'].max()} with max_returns 3, numbered 1..3", ok)


CASES = [grazing, offsets, thin_twig, coincident, edges_and_vertices, ranges, misses, too_many_returns]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true")
    args = p.parse_args(argv)
    n = 50 if args.quick else 2000
    failed = 0
    with tempfile.TemporaryDirectory() as tmp:
        for case in CASES:
            text, ok = case(Path(tmp), n)
            failed += not ok
            print(f"{'ok  ' if ok else 'FAIL'} {case.__name__:18s} {text}")
    print(f"{len(CASES) - failed} passed, {failed} failed")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
