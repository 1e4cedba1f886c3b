"""Numerical stability on hard cases, as one report of figures: each case and what was measured.

    python benchmarks/stability.py          # ~25 s on 2 cores
    python benchmarks/stability.py --quick  # the same cases with fewer pulses (~20 s)

Figures only: the checks live in tests/test_stability.py (and tests/test_scan.py for grazing incidence
and grid edges), which run the same cases with --quick pulse counts. Exit code 0 unless a case crashes.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from pathlib import Path

import numpy as np

from mitsuforest.classes import ROCK, TREE_WOOD
from mitsuforest.labels import labelled
from mitsuforest.pipeline import render
from mitsuforest.scan import PulseTracer
from mitsuforest.testing.reference.echoes import pulse_echoes, waveform_maxima
from mitsuforest.testing.analytic import analytic_scene, bare_scene_file, plane_model, pulses
from mitsuforest.trees.models import Component, Model, Part
from mitsuforest.trees.tubes import tube
from mitsuforest.trees.volume import union_volume

ROOT = Path(__file__).resolve().parents[1]
SENSORS = ROOT / "sensors"
RNG = np.random.default_rng(0)


def _trace(setup, p, samples=1, **sensor):
    scene, _, _, scan_scene = setup
    tracer = PulseTracer(scan_scene, dataclasses.replace(scene.sensor, **sensor), samples)
    return labelled(*tracer.trace_pulses(p), tracer.table)


def grazing(tmp, n):
    setup = analytic_scene(bare_scene_file(tmp / "g", SENSORS / "ideal.yaml"))
    theta = np.deg2rad(np.linspace(85, 89.9, n))
    d = np.column_stack([np.sin(theta), np.zeros(n), -np.cos(theta)])
    pts = _trace(setup, pulses(np.tile([0.5, 20, 0.05], (n, 1)), d), 19, beam_divergence=(1e-3, 1e-3))
    bad = sum(int((~np.isfinite(pts[k])).sum()) for k in ("x", "y", "z", "intensity", "range"))
    return f"{len(pts)} echoes from {n} pulses at 85-89.9°, {bad} non-finite values"


def offsets(tmp, n):
    rows, base = [], None
    for offset in ([0, 0, 0], [1e4, 1e4, 0], [5e5, 6e6, 100], [1e7, 1e7, 1000]):
        path = bare_scene_file(tmp / f"o{offset[0]:g}", SENSORS / "riegl_vux-1uav22.yaml", area={"size": [10, 10]},
                               understory={"rocks": 3}, simulation={"beam_samples": 7},
                               survey={"pulse_frequency": 100000, "lines": [[[5, 0], [5, 10 * n / 4000]]]},
                               origin={"offset": offset})
        pts = render(path, write=False, progress=False, log=lambda *_: None).points
        local = np.column_stack([pts[a] - o for a, o in zip("xyz", offset)])
        base = local if base is None else base
        rows.append(f"{offset[0]:g}: {np.abs(local - base).max() * 1e3:.3g} mm")
    return f"{len(base)} points; largest local deviation from offset 0 at offset {', '.join(rows[1:])}"


def thin_twig(tmp, n):
    stem = tube(np.array([[0, 0, 0], [0, 0, 20.0]]), np.array([0.3, 0.05]), 24)
    pts = np.array([[0, 0, 10.0], [0.5, 0, 10.4]])
    twig = tube(pts, np.array([0.0005, 0.0005]), 5)
    added = union_volume([stem, twig]) - union_volume([stem])
    inside = 0.175 / (0.5 + 0.25 * 0.4 / 20) * np.linalg.norm(pts[1] - pts[0])
    expected = np.pi * 0.0005 ** 2 * (np.linalg.norm(pts[1] - pts[0]) - inside)
    # The laser sees a horizontal 0.5 mm twig 10 m below a thin-beam sensor.
    v, f = tube(np.array([[-1.0, 0, 0], [1.0, 0, 0]]), np.array([0.0005, 0.0005]), 5)
    model = Model("twig", [Part("wood", v, f.astype(np.uint32), np.zeros(len(f), np.uint16))],
                  [Component("branch", TREE_WOOD)])
    setup = analytic_scene(bare_scene_file(tmp / "t", SENSORS / "ideal.yaml"), [(model, (20, 20, 20), 0, (0, 0), 1)])
    ys = np.linspace(-0.0004, 0.0004, n)
    hits = _trace(setup, pulses(np.column_stack([np.full(n, 20.0), 20 + ys, np.full(n, 30.0)]), [0, 0, -1]))
    on_twig = hits[hits["classification"] == TREE_WOOD]
    error = np.abs(on_twig["range"] - (10 - np.sqrt(0.0005 ** 2 - ys[:len(on_twig)] ** 2))).max() \
        if len(on_twig) == n else np.nan
    return (f"0.5 mm twig: union adds {added:.4g} m³ (analytic {expected:.4g}, {(added / expected - 1) * 100:+.2g} %); "
            f"{len(on_twig)}/{n} thin rays hit it, largest range error {error * 1e3:.3g} mm")


def coincident(tmp, n):
    plane = plane_model("plane", 10.0, ROCK)
    setup = analytic_scene(bare_scene_file(tmp / "c", SENSORS / "ideal.yaml"), [(plane, (20, 20, 0.0), 0, (0, 0), 0)])
    xy = RNG.uniform(16, 24, (n, 2))
    pts = _trace(setup, pulses(np.column_stack([xy, np.full(n, 30.0)]), [0, 0, -1]))
    classes = sorted(np.unique(pts["classification"]).tolist())
    return (f"plane coincident with the ground: {len(pts)} echoes for {n} pulses, "
            f"up to {pts['number_of_returns'].max(initial=0)} per pulse, classes {classes}")


def edges_and_vertices(tmp, n):
    setup = analytic_scene(bare_scene_file(tmp / "e", SENSORS / "ideal.yaml",
                                           terrain={"type": "noise", "amplitude": 0.0}))
    k = max(int(np.sqrt(n / 3)), 2)
    grid = np.stack(np.meshgrid(np.arange(5, 5 + k, 1.0), np.arange(5, 5 + k, 1.0)), -1).reshape(-1, 2)
    targets = np.vstack([grid, grid + [0.5, 0.0], grid + [0.5, 0.5]])
    pts = _trace(setup, pulses(np.column_stack([targets, np.full(len(targets), 30.0)]), [0, 0, -1]))
    return (f"{len(targets)} rays through grid vertices and edges: {len(pts)} echoes from "
            f"{len(np.unique(pts['pulse_id']))} distinct pulses")


def ranges(tmp, n):
    setup = analytic_scene(bare_scene_file(tmp / "r", SENSORS / "riegl_vux-1uav22.yaml"))
    short = _trace(setup, pulses(np.tile([20, 20, 2.0], (n, 1)), [0, 0, -1]), 1, range_precision=0.0)
    long_ = _trace(setup, pulses(np.tile([20, 20, 900.0], (n, 1)), [0, 0, -1]), 1, range_precision=0.0)
    return (f"range 2 m (< range_min 3 m): {len(short)} echoes; range 900 m: {len(long_)}/{n} echoes, "
            f"largest error {np.abs(long_['range'] - 900).max(initial=0) * 1e3:.3g} mm")


def misses(tmp, n):
    setup = analytic_scene(bare_scene_file(tmp / "m", SENSORS / "ideal.yaml"))
    pts = _trace(setup, pulses(np.tile([20, 20, 30.0], (n, 1)), [0, 0, 1]), 19, beam_divergence=(1e-3, 1e-3))
    return f"{n} pulses into the sky: {len(pts)} echoes"


def too_many_returns(tmp, n):
    """A staircase of 8 narrow steps under one wide 19-sub-ray beam, without and with max_returns = 3."""
    steps = [(plane_model(f"s{i}", 0.5, ROCK), (18.0 + 0.5 * i, 20, 1.0 * i), 0, (0, 0), 0) for i in range(8)]
    setup = analytic_scene(bare_scene_file(tmp / "x", SENSORS / "ideal.yaml"), steps)
    p = pulses(np.tile([19.9, 20, 30.0], (n, 1)), [0, 0, -1])    # beam centre and sub-rays clear of step edges
    wide = {"beam_divergence": [0.01, 0.3], "pulse_length": 1e-9}  # the second frame axis is x here
    free = _trace(setup, p, 19, max_returns=0, **wide)
    capped = _trace(setup, p, 19, max_returns=3, **wide)
    return (f"staircase: {np.unique(free['number_of_returns']).tolist()} returns per pulse unlimited, "
            f"{np.unique(capped['number_of_returns']).tolist()} with max_returns 3, "
            f"numbered {np.unique(capped['return_number']).tolist()}")


def chains_vs_maxima(tmp, n):
    """How often the chain rule (waveform.py) gives another echo count than the maxima of the summed
    waveform: pulses of 7 sub-rays at ranges uniform over a canopy depth, powers lognormal (σ_ln = 1),
    ΔR of a 4 ns pulse (0.60 m)."""
    resolving = 299_792_458.0 * 4e-9 / 2     # ΔR = c·τ/2 at 4 ns
    rng = np.random.default_rng(1)
    pulses_per_depth = 10 * n
    rows = []
    for depth in (1.0, 3.0, 10.0):
        r = 20 + rng.uniform(0, depth, (pulses_per_depth, 7))
        p = rng.lognormal(0, 1, (pulses_per_depth, 7))
        chains = np.bincount(pulse_echoes(r, p, resolving).pulse, minlength=pulses_per_depth)
        maxima = np.array([waveform_maxima(r[k], p[k], resolving) for k in range(pulses_per_depth)])
        rows.append(f"{depth:g} m: {np.mean(chains != maxima) * 100:.1f} % "
                    f"(chains > maxima {np.mean(chains > maxima) * 100:.1f} %, < {np.mean(chains < maxima) * 100:.1f} %)")
    return f"{pulses_per_depth} pulses per canopy depth, echo count differs from waveform maxima at " + "; ".join(rows)


CASES = [grazing, offsets, thin_twig, coincident, edges_and_vertices, ranges, misses, too_many_returns,
         chains_vs_maxima]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true")
    args = p.parse_args(argv)
    n = 50 if args.quick else 2000
    with tempfile.TemporaryDirectory() as tmp:
        for case in CASES:
            print(f"{case.__name__:18s} {case(Path(tmp), n)}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
