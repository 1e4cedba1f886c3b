"""Where one flight leg's scan time goes, stage by stage, on the path a render runs.

Runs one leg of a scene twice (the first compiles the kernels) and reports the second: pulse
generation, tracing and labelling the sub-rays, the waveform, the echo records (compaction and the
copy back to numpy), the point array, and the writer (PCD and LAS into a temporary folder, closing
included). Each stage ends with ``dr.sync_thread()`` so that its time is its own; the total is
therefore a little above a render's, where stages overlap. CPU time counts every thread of the
process, the writer's own threads included (``MITSUFOREST_WRITER_THREADS`` sets how many).

    python benchmarks/profile_leg.py                                  # open scene, leg 5, the scene's settings
    python benchmarks/profile_leg.py --samples 19 --pattern stratified --variant cuda_ad_mono --batch 1000000
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import drjit as dr

from mitsuforest.config import load_scene
from mitsuforest.labels import label_points
from mitsuforest.scan import PulseTracer, tracer as tracer_module
from mitsuforest.scene import variant_scope
from mitsuforest.survey import prepare
from mitsuforest.write import PointWriter, Staging

ROOT = Path(__file__).resolve().parents[1]


class Stopwatch:
    """Accumulates the wall and CPU time (all threads of the process) of wrapped calls, each ended by
    a device sync. CPU time is the steadier figure on a shared machine."""

    def __init__(self):
        self.seconds, self.cpu = defaultdict(float), defaultdict(float)

    def wrap(self, name, fn):
        def timed(*args, **kwargs):
            start, cpu = time.perf_counter(), time.process_time()
            out = fn(*args, **kwargs)
            dr.sync_thread()
            self.seconds[name] += time.perf_counter() - start
            self.cpu[name] += time.process_time() - cpu
            return out
        return timed


def profile(scene, leg_index: int | None, batch: int, folder: Path) -> tuple[dict, dict, int, int, int]:
    """Stage seconds and CPU seconds of leg ``leg_index`` (None: leg 5, or the middle one of a survey of
    fewer than 11 legs), its time slots, points and index."""
    prepared = prepare(scene)
    plan, scan_scene = prepared.plan, prepared.scan_scene
    sim = scene.simulation
    if leg_index is None:
        leg_index = min(5, len(plan.legs) // 2)
    if not 0 <= leg_index < len(plan.legs):
        raise SystemExit(f"--leg {leg_index}: the survey has {len(plan.legs)} legs (0 to {len(plan.legs) - 1})")
    tracer = PulseTracer(scan_scene, scene.sensor, sim.beam_samples, scene.seed, sim.beam_pattern, sim.point_position)
    leg = plan.legs[leg_index]
    total = leg.pulse_count(scene.pulse_frequency)
    watch = Stopwatch()
    caster = tracer.caster
    tracer_module.reaching_pulses = watch.wrap("pulses", tracer_module.reaching_pulses)
    for name, method in (("rays and hit lookup", "_sub_ray_returns"), ("waveform", "_ranked_echoes"),
                         ("echo records to numpy", "_echo_records")):
        setattr(caster, method, watch.wrap(name, getattr(caster, method)))
    tracer._points = watch.wrap("point array", tracer._points)
    label = watch.wrap("labels", label_points)
    points = 0
    for run in range(2):                                  # the first run compiles
        watch.seconds.clear()
        watch.cpu.clear()
        writer = PointWriter(Staging(folder / str(run), scene.name), scene)
        add = watch.wrap("writer (PCD, LAS, statistics)", writer.add)
        close = watch.wrap("writer (PCD, LAS, statistics)", writer.close)   # LAZ's last chunk, headers
        start, cpu = time.perf_counter(), time.process_time()
        with variant_scope(scan_scene.variant):
            for first in range(0, total, batch):
                pts, hits, _, _ = tracer.trace_slots(leg, scene.pulse_frequency, scene.scan_frequency, first,
                                                     min(batch, total - first))
                label(pts, hits, scan_scene.table)
                add(pts)
                points += len(pts) if run else 0
        close()
        watch.seconds["total"] = time.perf_counter() - start
        watch.cpu["total"] = time.process_time() - cpu
    return dict(watch.seconds), dict(watch.cpu), total, points, leg_index


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scene", type=Path, default=ROOT / "scenes" / "open.yaml")
    p.add_argument("--leg", type=int, help="leg index (0-based; default 5, or the middle leg of fewer than 11)")
    p.add_argument("--samples", type=int, help="beam_samples (default: the scene's)")
    p.add_argument("--pattern", choices=["fixed", "stratified"], help="beam_pattern (default: the scene's)")
    p.add_argument("--batch", type=int, help="time slots per launch (default: the backend's)")
    p.add_argument("--variant", default="auto")
    args = p.parse_args(argv)
    scene = load_scene(args.scene, variant=args.variant)
    changes = {"simulation.beam_samples": args.samples, "simulation.beam_pattern": args.pattern}
    scene = scene.with_({k: v for k, v in changes.items() if v is not None})
    from mitsuforest.scan import default_batch
    from mitsuforest.scene import select_variant
    variant = select_variant(scene.simulation.variant)
    batch = args.batch or scene.simulation.pulses_per_batch or default_batch(variant, scene.simulation.beam_samples)
    with tempfile.TemporaryDirectory() as tmp:
        seconds, cpu, slots, points, leg = profile(scene.with_({"simulation.variant": variant}), args.leg, batch,
                                                   Path(tmp))
    total = seconds.pop("total")
    print(f"{args.scene.name}, leg {leg}: {slots:,} time slots, {points:,} points, {variant}, "
          f"{scene.simulation.beam_samples} {scene.simulation.beam_pattern} sub-rays, batch {batch:,}")
    print(f"  {'stage':32s} {'wall':>9s}  {'share':>6s}  {'CPU':>9s}")
    for name, s in seconds.items():
        print(f"  {name:32s} {s:7.2f} s  {s / total:6.1%}  {cpu[name]:7.2f} s")
    print(f"  {'total (with syncs)':32s} {total:7.2f} s  {'':6s}  {cpu['total']:7.2f} s  -> {points / total:,.0f} "
          f"points/s wall, {points / cpu['total']:,.0f} points per CPU-second")


if __name__ == "__main__":
    main()
