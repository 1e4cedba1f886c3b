"""Speed against error: the same pulses over a tile of the open forest at several beam samplings.

Every setting traces exactly the same pulses (one flight leg across the plot's centre, noise off) and
is compared with a reference render at ``--reference`` sub-rays:

- point error: distance from each point to the nearest true surface sample (hits of 128 sub-rays
  per pulse at random offsets within the beam), mean and 95th percentile, in mm;
- returns: total-variation distance between the returns-per-pulse histograms;
- classes: largest difference in any class's share of the points;
- intensity: median relative difference of the first-return intensity of pulses both renders see;
- time and pulses/s of the scan stage on the path a render runs (:meth:`PulseTracer.trace_slots`: pulses,
  rays, radiometry, waveform, labels and finished points, batch by batch).

A "numpy echo stage" row times the 7-sub-ray setting on the reference path (sub-ray hits copied back,
echoes found in numpy) to show what running the echo stage in Dr.Jit gains at equal error.

For each sub-ray count, "chains_not_maxima" is the share of pulses (of 5,000 that return something)
whose number of echoes under the waveform's chain rule differs from the number of maxima of their
summed waveform ("more_chains" / "fewer_chains": which way), the bias of that rule (README, step 6).

A "HELIOS-like" row places the 19-sub-ray echoes as HELIOS++ does (on the central ray, range
quantised to 7.5 cm) to compare point error with the incumbent's method.

    python benchmarks/speed_vs_error.py               # 10 s of flight (2 M pulses), ~5 min on 2 cores
    python benchmarks/speed_vs_error.py --quick       # 0.5 s of flight, for CI
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from mitsuforest.classes import CLASS_NAMES
from mitsuforest.config import load_scene
from mitsuforest.labels import labelled
from mitsuforest.scan import PulseTracer
from mitsuforest.scan.kernel import RayCaster
from mitsuforest.scan.pulses import upload_pulses
from mitsuforest.testing.reference import reaching_pulses, sub_ray_returns, trace_reference
from mitsuforest.testing.reference.echoes import pulse_echoes, waveform_maxima
from mitsuforest.scene import variant_scope
from mitsuforest.survey import prepare

ROOT = Path(__file__).resolve().parents[1]
HELIOS_BIN = 0.075  # m: HELIOS++ samples the waveform in 0.25 ns bins of one-way time


def setup(scene_file: Path, seconds: float, variant: str):
    """The scene with one leg of ``seconds`` across the plot centre, noise off; its scan scene, that leg,
    and the leg's pulses that can reach the scene (numpy: for the truth and HELIOS-like placement)."""
    scene = load_scene(scene_file, variant=variant)
    (w, h), half = scene.area.size, seconds * scene.survey.speed / 2
    scene = scene.with_({"survey.lines": [[[w / 2, h / 2 - half], [w / 2, h / 2 + half]]],
                         "sensor.range_precision": 0.0})
    prepared = prepare(scene)
    scan_scene, leg = prepared.scan_scene, prepared.plan.legs[0]
    box = PulseTracer(scan_scene, scene.sensor, 1, pattern="stratified").box   # the widest reach of any setting
    pulses, _ = reaching_pulses(leg, scene.sensor, scene.pulse_frequency, scene.scan_frequency, 0,
                                leg.pulse_count(scene.pulse_frequency), box)
    return scene, scan_scene, leg, pulses


def trace(scene, scan_scene, leg, samples, batch, pattern="fixed", reference_path=False):
    """Points and scan seconds of the leg on the path a render runs (:meth:`PulseTracer.trace_slots`);
    ``reference_path`` runs the numpy twin of the echo stage instead."""
    # Points on the surface: this measures how well the sub-rays place an echo on what it hit (on the
    # beam axis, an echo mixing two surfaces lies between them by design).
    tracer = PulseTracer(scan_scene, scene.sensor, samples, scene.seed, pattern, point_position="surface")
    f_p, f_s, total = scene.pulse_frequency, scene.scan_frequency, leg.pulse_count(scene.pulse_frequency)

    def run(first, count):
        if not reference_path:
            return labelled(*tracer.trace_slots(leg, f_p, f_s, first, count)[:2], tracer.table)
        pulses, _ = reaching_pulses(leg, scene.sensor, f_p, f_s, first, count, tracer.box)
        return trace_reference(tracer, pulses)

    run(total // 2, 1000)  # compile outside the timing
    start = time.perf_counter()
    parts = [run(first, min(batch, total - first)) for first in range(0, total, batch)]
    return np.concatenate(parts), time.perf_counter() - start


def surface_samples(scene, scan_scene, pulses, samples, batch):
    """True surface samples: sub-rays at random offsets drawn from the beam's Gaussian profile, so that no
    tested pattern shares its sub-rays with the truth."""
    offsets = np.random.default_rng(1).normal(0.0, 0.5, (samples, 2))  # I ∝ exp(-2r²/w²): σ = w/2 per axis
    with variant_scope(scan_scene.variant):
        caster = RayCaster(scan_scene.mitsuba, np.tan(offsets * np.asarray(scene.sensor.beam_divergence) / 2))
        pts = [caster.cast(upload_pulses(pulses.select(slice(i, i + batch))))["point"]
               for i in range(0, len(pulses.time), batch)]
    return cKDTree(np.vstack(pts))


def chain_rule_bias(scene, scan_scene, pulses, samples, pattern, count=5000):
    """How often the waveform's chain rule (testing/reference/echoes.py) finds another number of echoes
    than the summed waveform has maxima, over ``count`` pulses of the leg that return something:
    (share differing, share with more chains, share with fewer)."""
    tracer = PulseTracer(scan_scene, scene.sensor, samples, scene.seed, pattern)
    returns = sub_ray_returns(tracer, pulses.select(slice(0, len(pulses.time), max(len(pulses.time) // (3 * count), 1))))
    hit = np.flatnonzero(np.isfinite(returns["ranges"]).any(axis=1))[:count]
    ranges, power = returns["ranges"][hit], returns["power"][hit]
    resolving = scene.sensor.resolving_distance
    chains = np.bincount(pulse_echoes(ranges, power, resolving).pulse, minlength=len(hit))
    maxima = np.array([waveform_maxima(r, p, resolving) for r, p in zip(ranges, power)])
    return float(np.mean(chains != maxima)), float(np.mean(chains > maxima)), float(np.mean(chains < maxima))


def helios_like(points, pulses):
    """Echo points moved onto the central ray at a range quantised to HELIOS++'s 7.5 cm bins."""
    row = np.searchsorted(pulses.index, points["pulse_id"])
    r = np.round(points["range"] / HELIOS_BIN) * HELIOS_BIN
    xyz = pulses.origin[row] + pulses.direction[row] * r[:, None]
    out = points.copy()
    out["x"], out["y"], out["z"] = xyz.T
    return out


def returns_histogram(points, pulses_cast):
    first = points["return_number"] == 1
    h = np.bincount(points["number_of_returns"][first], minlength=32).astype(float)
    h[0] = pulses_cast - first.sum()
    return h / pulses_cast


def compare(points, ref, truth, pulses_cast):
    xyz = np.column_stack([points["x"], points["y"], points["z"]])
    d, _ = truth.query(xyz)
    codes = sorted(CLASS_NAMES)
    classes = [np.mean(p["classification"] == c) for p in (points, ref) for c in codes]
    a, b = np.array(classes[:len(codes)]), np.array(classes[len(codes):])
    fa = points[points["return_number"] == 1]
    fb = ref[ref["return_number"] == 1]
    common, ia, ib = np.intersect1d(fa["pulse_id"], fb["pulse_id"], return_indices=True)
    rel = np.abs(fa["intensity"][ia] / fb["intensity"][ib] - 1)
    return {
        "points": int(len(points)),
        "point_error_mean_mm": float(d.mean() * 1e3),
        "point_error_p95_mm": float(np.percentile(d, 95) * 1e3),
        "returns_tv_distance": float(0.5 * np.abs(returns_histogram(points, pulses_cast)
                                                  - returns_histogram(ref, pulses_cast)).sum()),
        "class_share_max_diff": float(np.abs(a - b).max()),
        "intensity_median_rel_error": float(np.median(rel)) if len(rel) else None,
        "multi_return_share": float(np.mean(fa["number_of_returns"] > 1)),
    }


def plot(rows, path):
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("(matplotlib not installed: no plot; pip install matplotlib)")
        return
    keys = [("point_error_mean_mm", "point error, mean (mm)"), ("returns_tv_distance", "returns histogram TV distance"),
            ("class_share_max_diff", "largest class share difference"),
            ("intensity_median_rel_error", "first-return intensity, median rel. error")]
    fig, axes = plt.subplots(1, 4, figsize=(16, 3.8))
    colours = {"fixed": "tab:blue", "stratified": "tab:orange"}
    for ax, (key, label) in zip(axes, keys):
        for pattern, colour in colours.items():
            curve = [r for r in rows if r.get("pattern") == pattern and r["seconds"] is not None
                     and r[key] is not None and "," not in r["setting"] and not r["setting"].startswith("reference")]
            ax.plot([r["seconds"] for r in curve], [r[key] for r in curve], "o-", color=colour, label=pattern)
            for r in curve:
                ax.annotate(str(r["samples"]), (r["seconds"], r[key]), textcoords="offset points", xytext=(3, 3),
                            fontsize=7)
        ax.set_xscale("log")
        ax.set_xlabel("scan time (s)")
        ax.set_title(label, fontsize=9)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scene", type=Path, default=ROOT / "scenes" / "open.yaml")
    p.add_argument("--seconds", type=float, default=10.0, help="flight time across the plot centre")
    p.add_argument("--samples", type=int, nargs="+", default=[1, 3, 5, 7, 11, 19, 37])
    p.add_argument("--patterns", nargs="+", default=["fixed", "stratified"], choices=["fixed", "stratified"])
    p.add_argument("--reference", type=int, default=61)
    p.add_argument("--reference-pattern", default="stratified", choices=["fixed", "stratified"],
                   help="stratified (default): unbiased, so its only error is noise averaged over the leg's pulses")
    p.add_argument("--batch", type=int, default=100_000, help="time slots per launch (a render's pulses_per_batch)")
    p.add_argument("--variant", default="llvm_ad_mono")
    p.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "out")
    p.add_argument("--quick", action="store_true", help="0.5 s of flight, samples 1 and 7, reference 19")
    args = p.parse_args(argv)
    if args.quick:
        args.seconds, args.samples, args.reference = 0.5, [1, 7], 19
    scene, scan_scene, leg, pulses = setup(args.scene, args.seconds, args.variant)
    n = len(pulses.time)
    print(f"{n:,} pulses over {args.seconds:g} s of flight, variant {scan_scene.variant}", flush=True)
    ref, ref_time = trace(scene, scan_scene, leg, args.reference, args.batch, args.reference_pattern)
    truth = surface_samples(scene, scan_scene, pulses, 128, args.batch // 4)
    rows = []
    for pattern in args.patterns:
        for samples in args.samples:
            if samples == 1 and pattern == "stratified":
                continue                                  # one random ray: a Monte Carlo beam, not a thin one
            points, seconds = trace(scene, scan_scene, leg, samples, args.batch, pattern)
            differ, more, fewer = chain_rule_bias(scene, scan_scene, pulses, samples, pattern,
                                                  1000 if args.quick else 5000)
            rows.append({"setting": f"{samples} {pattern}", "samples": samples, "pattern": pattern,
                         "seconds": seconds, "pulses_per_s": n / seconds, "points_per_s": len(points) / seconds,
                         **compare(points, ref, truth, n), "chains_not_maxima": differ,
                         "more_chains": more, "fewer_chains": fewer})
            print(f"  {rows[-1]['setting']}: {seconds:.2f} s, TV {rows[-1]['returns_tv_distance']:.4f}, "
                  f"class {rows[-1]['class_share_max_diff']:.4f}", flush=True)
            if samples == 7 and pattern == "fixed":
                slow, seconds = trace(scene, scan_scene, leg, samples, args.batch, pattern, reference_path=True)
                rows.append({"setting": "7 fixed, numpy echo stage", "samples": 7, "pattern": pattern,
                             "seconds": seconds, "pulses_per_s": n / seconds, "points_per_s": len(slow) / seconds,
                             **compare(slow, ref, truth, n)})
            if samples == 19 and pattern == "fixed":
                rows.append({"setting": "HELIOS-like (19 fixed)", "samples": 19, "pattern": pattern, "seconds": None,
                             "pulses_per_s": None, "points_per_s": None,
                             **compare(helios_like(points, pulses), ref, truth, n)})
    rows.append({"setting": f"reference {args.reference} {args.reference_pattern}", "samples": args.reference,
                 "pattern": args.reference_pattern, "seconds": ref_time, "pulses_per_s": n / ref_time,
                 "points_per_s": len(ref) / ref_time, **compare(ref, ref, truth, n)})
    header = ("setting", "seconds", "pulses_per_s", "points", "point_error_mean_mm", "point_error_p95_mm",
              "returns_tv_distance", "class_share_max_diff", "intensity_median_rel_error", "multi_return_share",
              "chains_not_maxima", "more_chains", "fewer_chains")
    print(" | ".join(header))
    for r in rows:
        print(" | ".join("-" if r.get(k) is None else f"{r[k]:.4g}" if isinstance(r[k], float) else str(r[k])
                         for k in header))
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "speed_vs_error.json").write_text(json.dumps({"pulses": n, "rows": rows}, indent=1))
    plot(rows, args.out / "speed_vs_error.png")
    return rows


if __name__ == "__main__":
    main()
