"""Label purity: the share of points farther than 2 cm from the surface of the object they are labelled
with, for ``simulation.point_position: beam_axis`` and ``surface`` (README, "Label purity").

A point's object is its (instance, object_id): one component (stem and branches, leaves, a bush ...) of
one placed object, or the ground. Its distance is the exact point-to-triangle distance to that
component's triangles (in the model's frame), or for the ground the vertical distance to the terrain
(exact on flat ground, an upper bound elsewhere). Points are subsampled (``--points``) for speed.

    python benchmarks/label_purity.py                        # the demo scene, one leg (as README)
    python benchmarks/label_purity.py scenes/open.yaml --leg 3 --points 200000

Not run by the tests (a render of each setting, minutes on the open scene).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mitsuforest.config import load_scene  # noqa: E402
from mitsuforest.pipeline import render  # noqa: E402
from mitsuforest.survey import make_plan  # noqa: E402
from mitsuforest.trees import build_models  # noqa: E402


def point_triangle_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Exact distances (n,) from points p (n, 3) to triangles a, b, c (n, 3) (Ericson, *Real-Time
    Collision Detection*, 5.1.5: the closest point by Voronoi region)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(1), (ac * ap).sum(1)
    bp = p - b
    d3, d4 = (ab * bp).sum(1), (ac * bp).sum(1)
    cp = p - c
    d5, d6 = (ab * cp).sum(1), (ac * cp).sum(1)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = 1.0 / (va + vb + vc)
        v, w = vb * denom, vc * denom
        closest = a + ab * v[:, None] + ac * w[:, None]                       # inside the face
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    regions = [
        ((d1 <= 0) & (d2 <= 0), a),
        ((d3 >= 0) & (d4 <= d3), b),
        ((d6 >= 0) & (d5 <= d6), c),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + ab * t_ab[:, None]),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + ac * t_ac[:, None]),
        ((va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0), b + (c - b) * t_bc[:, None]),
    ]
    done = np.zeros(len(p), bool)
    out = closest.copy()
    for mask, q in regions:
        take = mask & ~done
        out[take] = q[take]
        done |= mask
    return np.linalg.norm(p - out, axis=1)


def within(points: np.ndarray, triangles: np.ndarray, limit: float, chunk: int = 2_000_000) -> np.ndarray:
    """Whether each point (n, 3) lies within ``limit`` of any triangle (m, 3, 3): candidates are the
    triangles whose bounding sphere about the centroid comes within ``limit``."""
    centre = triangles.mean(axis=1)
    radius = np.linalg.norm(triangles - centre[:, None], axis=2).max(axis=1)
    near = cKDTree(centre).query_ball_point(points, limit + radius.max())
    pairs_p = np.repeat(np.arange(len(points)), [len(x) for x in near])
    pairs_t = np.fromiter((t for x in near for t in x), np.int64, len(pairs_p))
    keep = np.linalg.norm(points[pairs_p] - centre[pairs_t], axis=1) <= limit + radius[pairs_t]
    pairs_p, pairs_t = pairs_p[keep], pairs_t[keep]
    hit = np.zeros(len(points), bool)
    for s in range(0, len(pairs_p), chunk):
        pp, tt = pairs_p[s:s + chunk], pairs_t[s:s + chunk]
        tri = triangles[tt]
        d = point_triangle_distance(points[pp], tri[:, 0], tri[:, 1], tri[:, 2])
        hit[pp[d <= limit]] = True
    return hit


def off_surface(points: np.ndarray, plan, models, limit: float = 0.02) -> np.ndarray:
    """(n,) whether each point lies farther than ``limit`` from the surface of its labelled object."""
    xyz = np.column_stack([points["x"], points["y"], points["z"]]).astype(np.float64)
    far = np.zeros(len(points), bool)
    ground = points["instance"] == 0
    far[ground] = np.abs(xyz[ground, 2] - plan.terrain.height(xyz[ground, 0], xyz[ground, 1])) > limit
    by_instance = {o.instance: o for o in plan.objects}
    for instance in np.unique(points["instance"][~ground]):
        obj = by_instance[int(instance)]
        model = models[obj.model]
        m = obj.matrix
        rows = np.flatnonzero(points["instance"] == instance)
        local = (xyz[rows] - m[:3, 3]) @ m[:3, :3]                           # R^T (p - t)
        component = points["object_id"][rows].astype(np.int64) - obj.object_id
        for k in np.unique(component):
            tris = np.concatenate([part.vertices[part.faces[part.component == k]] for part in model.parts])
            sel = component == k
            far[rows[sel]] = ~within(local[sel], tris, limit)
    return far


def measure(scene, points_wanted: int, rng) -> dict:
    plan = make_plan(scene)
    models = build_models(plan)
    out = {}
    for position in ("beam_axis", "surface"):
        result = render(scene.with_({"simulation.point_position": position}), write=False, progress=False,
                        log=lambda *_: None)
        pts = result.points
        pick = np.sort(rng.choice(len(pts), min(points_wanted, len(pts)), replace=False))
        sample = pts[pick]
        far = off_surface(sample, plan, models)
        out[position] = {"points": len(pts), "measured": len(sample), "off_surface": float(far.mean()),
                         "off_surface_non_ground": float(far[sample["instance"] > 0].mean()),
                         "off_surface_ground": float(far[sample["instance"] == 0].mean())}
    return out


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scene", nargs="?", default=str(ROOT / "scenes" / "demo.yaml"))
    parser.add_argument("--leg", type=int, default=None, help="only this planned leg (0-based)")
    parser.add_argument("--line", type=float, nargs=4, default=None, metavar=("X0", "Y0", "X1", "Y1"),
                        help="fly this one line instead (default for the demo: 10 -5 10 25)")
    parser.add_argument("--pulse-frequency", type=float, default=None)
    parser.add_argument("--sensor", default=None, help="another sensor file (its own pulse rate nearest 200 kHz)")
    parser.add_argument("--points", type=int, default=100_000, help="points measured per setting")
    parser.add_argument("--no-noise", action="store_true", help="without ranging noise (placement alone)")
    parser.add_argument("--quick", action="store_true", help="a 6 m line at 100 kHz, 7 sub-rays, 5,000 points")
    args = parser.parse_args(argv)
    scene = load_scene(args.scene)
    changes = {}
    if args.sensor:
        from mitsuforest.config import load_sensor
        scene = scene.with_({"sensor": load_sensor(args.sensor), "survey.pulse_frequency": None,
                             "survey.scan_frequency": None})
    if args.no_noise:
        changes.update({"sensor.range_precision": 0.0, "sensor.range_precision_per_metre": 0.0,
                        "sensor.footprint_range_noise": 0.0})
    if args.quick:
        args.line, args.pulse_frequency, args.points = [10.0, 7.0, 10.0, 13.0], 100_000, 5_000
        changes["simulation.beam_samples"] = 7
    if args.pulse_frequency:
        changes["survey.pulse_frequency"] = args.pulse_frequency
    if args.line:
        changes["survey.lines"] = [[args.line[:2], args.line[2:]]]
    elif args.leg is not None:
        leg = make_plan(scene).legs[args.leg]
        changes["survey.lines"] = [[list(leg.start[:2]), list(leg.end[:2])]]
    elif Path(args.scene).name == "demo.yaml":
        changes["survey.lines"] = [[[10.0, -5.0], [10.0, 25.0]]]
    scene = scene.with_(changes)
    print(f"{scene.name}: {scene.sensor.name} (ranging noise {'off' if args.no_noise else 'on'}), "
          f"{scene.simulation.beam_samples} sub-rays "
          f"({scene.simulation.beam_pattern}), {scene.pulse_frequency:g} Hz, lines {scene.survey.lines}")
    for position, r in measure(scene, args.points, np.random.default_rng(0)).items():
        print(f"{position:>9}: {r['measured']:,} of {r['points']:,} points; farther than 2 cm from their "
              f"labelled object: {100 * r['off_surface']:.2f} % (objects {100 * r['off_surface_non_ground']:.2f} %, "
              f"ground {100 * r['off_surface_ground']:.2f} %)")


if __name__ == "__main__":
    main()
