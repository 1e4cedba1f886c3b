"""The point writer alone (PCD, LAZ, statistics), on synthetic scan lines, with 1, 2, 4... threads.

Needs neither Mitsuba nor the tree libraries (numpy, laspy with lazrs, scipy, Pillow, matplotlib and
PyYAML do): the points are a leg's worth of first returns along a sweeping scan line over
the demo's kind of plot, every field varied. Each thread count writes the same points; the files'
SHA-256 must agree across thread counts (the writer's bytes do not depend on its threads), and the
script stops if they do not. CPU time counts every thread of the process.

    python benchmarks/writer.py                                  # 4 M points, 1 thread and this machine's cores
    python benchmarks/writer.py --quick                          # 400,000 points, 1 and 2 threads (CI)
    python benchmarks/writer.py --threads 1 2 4 8 16 --dir /dev/shm --repeat 3
    python benchmarks/writer.py --threads 16 --processes 15 --dir /dev/shm    # threads against worker processes
    python benchmarks/writer.py --parts          # one worker's part step by step: ns a point of one core
    PYTHONPATH=../base python benchmarks/writer.py       # an older commit's writer (one thread), for comparison
"""

from __future__ import annotations

import argparse
import hashlib
import os
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if not os.environ.get("PYTHONPATH"):     # else the writer of the checkout PYTHONPATH names
    sys.path.insert(0, str(ROOT))

from mitsuforest.write import PointWriter, Staging  # noqa: E402

try:
    from mitsuforest.threads import writer_threads
    THREADED = True
except ImportError:      # a commit from before the writer's threads (PYTHONPATH=that checkout), for comparison
    def writer_threads() -> int:
        return len(os.sched_getaffinity(0))
    THREADED = False

try:
    from mitsuforest.fields import POINT_DTYPE    # numpy only: no Mitsuba or tree libraries
except ImportError:      # a commit from before the point schema (PYTHONPATH=that checkout): its scan's (needs Mitsuba)
    from mitsuforest.scan import POINT_DTYPE


def scan_lines(count: int, batch: int, side: float = 100.0, seed: int = 0) -> list[np.ndarray]:
    """``count`` points in batches: a 50 Hz line sweeping ±side/2 across track, 8 m/s along it, over a
    wavy ground with crowns (class and height correlated in space, as in a forest)."""
    rng = np.random.default_rng(seed)
    t = np.arange(count) / 600_000.0                                     # 600 kHz of returns
    p = np.zeros(count, POINT_DTYPE)
    phase = (t * 50.0) % 1.0
    p["x"] = side / 2 + side / 2 * np.sin(2 * np.pi * phase) + rng.normal(0, 0.02, count)
    p["y"] = (t * 8.0) % side + rng.normal(0, 0.02, count)
    ground = 0.5 * np.sin(p["x"] / 7.0) + 0.3 * np.cos(p["y"] / 5.0)
    crown = np.clip(12 + 6 * np.sin(p["x"] / 3.1) * np.cos(p["y"] / 2.7), 0, None)
    tree = rng.random(count) < 0.6
    p["z"] = ground + np.where(tree, crown * rng.random(count), 0.0)
    p["classification"] = np.where(tree, np.where(rng.random(count) < 0.8, 3, 2), 1)
    p["instance"] = np.where(tree, (p["x"] // 7).astype(int) * 20 + (p["y"] // 7).astype(int) + 1, 0)
    p["treeid"] = np.where(tree, p["instance"] % 10 + 1, 0)
    p["object_id"] = p["instance"] * 1000 + rng.integers(0, 1000, count) * tree
    p["number_of_returns"] = p["return_number"] = 1
    p["intensity"] = rng.uniform(0, 0.05, count)
    p["gps_time"] = 1000.0 + t
    p["scan_angle"] = 45 * np.sin(2 * np.pi * phase)
    p["pulse_id"], p["range"], p["species"] = np.arange(count), 30 - p["z"], p["treeid"] % 4
    return [p[i:i + batch] for i in range(0, count, batch)]


def write_once(batches, scene, threads: int, folder: Path, processes: int = 0) -> tuple[float, float, dict]:
    staging = Staging(folder, scene.name)
    start, cpu = time.perf_counter(), time.process_time()
    if processes:
        writer = PointWriter(staging, scene, threads=threads, processes=processes)
    else:
        writer = PointWriter(staging, scene, threads=threads) if THREADED else PointWriter(staging, scene)
    for batch in batches:
        writer.add(batch)
    writer.close()
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    digests = {p.suffix: hashlib.sha256(p.read_bytes()).hexdigest()[:16] for p in staging.path.iterdir()}
    staging.discard()
    return wall, cpu, digests


def profile_part(points: np.ndarray, folder: Path, repeat: int) -> None:
    """Time each step a writer worker takes for a part (``write/processes.py``'s ``PartWork.write``) on
    ``points``, in nanoseconds a point of one core, the best of ``repeat`` runs: on a GPU's host these
    workers write the points, so their sum bounds the scan at about (cores - 1) / sum points a second."""
    from mitsuforest.fields import pcd_dtype
    from mitsuforest.write.ground import fill_height, ground_surface, with_room_for_height
    from mitsuforest.write.las import HeaderSummary, compress_chunks, las_header, las_records
    from mitsuforest.write.parts import SPACING_TILE, georeference, tallies, write_pcd_rows
    from mitsuforest.write.profile import ReturnCounts
    from mitsuforest.write.quicklook import SideTile, TopView

    area, offset = (100.0, 100.0), np.zeros(3)
    tiles = np.array([[0.0, 0.0], [50.0, 50.0], [90.0, 10.0], [100.0 - SPACING_TILE, 95.0]])
    header = las_header(offset)
    made = {"points": fill_height(points, with_room_for_height(points), ground_surface(None))}
    made["geo"] = georeference(made["points"], offset)
    record = pcd_dtype(made["geo"].dtype, local=True)
    made["records"] = las_records(header, made["geo"])
    pcd = folder / "part.pcd"
    fd = os.open(pcd, os.O_WRONLY | os.O_CREAT)
    steps = {
        "height above ground": lambda: fill_height(points, with_room_for_height(points), ground_surface(None)),
        "PCD records written": lambda: write_pcd_rows(fd, pcd, record, 0, made["geo"]),
        "LAS records packed": lambda: las_records(header, made["geo"]),
        "LAZ chunks compressed": lambda: compress_chunks(header, made["records"]),
        "header summary": lambda: HeaderSummary.of(made["records"], header.point_format),
        "tallies": lambda: tallies(made["points"], ReturnCounts(None, area), SideTile(area), tiles),
        "top view": lambda: TopView(area).part(made["points"]),
    }
    print(f"one worker's part, {len(points):,} points, best of {repeat}:")
    total = 0.0
    try:
        for label, step in steps.items():
            best = min(_cpu_seconds(step) for _ in range(repeat)) / len(points) * 1e9
            total += best
            print(f"  {label:24s} {best:7.1f} ns a point")
    finally:
        os.close(fd)
    print(f"  {'sum':24s} {total:7.1f} ns a point: {1e3 / total:.2f} M points/s a core")


def _cpu_seconds(step) -> float:
    start = time.thread_time()
    step()
    return time.thread_time() - start


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--points", type=int, default=4_000_000)
    p.add_argument("--batch", type=int, default=370_000, help="points per batch (a GPU batch of 1 M slots: ~370 k)")
    p.add_argument("--threads", type=int, nargs="+", help="thread counts (default: 1 and this machine's)")
    p.add_argument("--processes", type=int, nargs="+", default=[],
                   help="worker process counts to run too (one thread each; the first run of each starts them)")
    p.add_argument("--formats", nargs="+", default=["pcd", "laz"])
    p.add_argument("--repeat", type=int, default=2)
    p.add_argument("--dir", type=Path, help="where to write (default: the system's temporary folder)")
    p.add_argument("--quick", action="store_true", help="400,000 points, 1 and 2 threads, once (CI)")
    p.add_argument("--parts", action="store_true",
                   help="instead: one worker's part of 100,000 points (two LAZ chunks) step by step, "
                        "the best of --repeat runs (at least 5)")
    args = p.parse_args(argv)
    if args.parts:
        with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
            profile_part(scan_lines(100_000, 100_000)[0], Path(tmp), max(args.repeat, 5))
        return
    if args.quick:
        args.points, args.threads, args.repeat = 400_000, [1, 2], 1
    threads = (args.threads or sorted({1, writer_threads()})) if THREADED else [1]
    scene = SimpleNamespace(name="writer", seed=1, area=SimpleNamespace(size=(100.0, 100.0)),   # what the writer reads
                            origin=SimpleNamespace(offset=(0.0, 0.0, 0.0), crs=None),
                            output=SimpleNamespace(formats=args.formats, profile="ours"),
                            sensor=SimpleNamespace(intensity=None))   # None: the default intensity mapping
    batches = scan_lines(args.points, args.batch)
    cpu_name = next((line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name")),
                    "?") if os.path.exists("/proc/cpuinfo") else "?"
    print(f"{args.points:,} points in batches of {args.batch:,}, {' '.join(args.formats)}; {cpu_name}, "
          f"{len(os.sched_getaffinity(0))} cores")
    if not THREADED:
        print(f"  the writer of {sys.modules['mitsuforest'].__file__}: one thread, LAZ by laspy's default backend")
    print(f"  {'threads':>9s} {'wall':>8s} {'CPU':>8s} {'M points/s':>11s}  files   (CPU: the writing process's)")
    reference = None
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        for run in range(args.repeat):
            for n in [*threads, *(-k for k in args.processes)]:
                wall, cpu, digests = write_once(batches, scene, max(n, 1), Path(tmp), processes=max(-n, 0))
                reference = reference or digests
                if digests != reference:
                    raise SystemExit(f"{abs(n)} {'threads' if n > 0 else 'processes'} wrote other bytes: "
                                     f"{digests} != {reference}")
                label = f"{n} thr" if n > 0 else f"{-n} proc"
                print(f"  {label:>9s} {wall:6.2f} s {cpu:6.2f} s {args.points / wall / 1e6:11.2f}  "
                      f"{' '.join(f'{k}:{v}' for k, v in sorted(digests.items()))}")


if __name__ == "__main__":
    main()
