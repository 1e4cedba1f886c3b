"""Time and peak memory of writing COPC (``formats: [copc]``) for a synthetic forest-like cloud.

Points are written batch by batch as a render does (500,000 a batch): 40 % on a flat ground, the rest
spread through a 30 m canopy over a 100 m square. Reports the spooling time, the octree's (copc-lib's
LAZ compression included), the process's peak resident memory and the octree's shape.

    python benchmarks/copc_write.py 2000000 6000000
"""

from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import time
from pathlib import Path

import laspy
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mitsuforest.scan import POINT_DTYPE  # noqa: E402
from mitsuforest.write.copc import CopcStream  # noqa: E402

BATCH = 500_000


def cloud(rng, first: int, count: int) -> np.ndarray:
    p = np.zeros(count, POINT_DTYPE)
    p["x"], p["y"] = rng.uniform(0, 100, count) + 300_000, rng.uniform(0, 100, count) + 6_000_000
    ground = rng.random(count) < 0.4
    p["z"] = 50 + np.where(ground, rng.normal(0, 0.02, count), rng.uniform(0, 30, count))
    p["classification"] = np.where(ground, 1, 3)
    p["return_number"] = p["number_of_returns"] = 1
    p["gps_time"] = first + np.arange(count)
    return p


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("points", type=int, nargs="+")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    for n in args.points:
        with tempfile.TemporaryDirectory() as folder:
            path = Path(folder) / "cloud.copc.laz"
            stream = CopcStream(path, [300_000.0, 6_000_000.0, 50.0])
            start = time.perf_counter()
            for first in range(0, n, BATCH):
                stream.write(cloud(rng, first, min(BATCH, n - first)))
            spooled = time.perf_counter()
            spool_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
            stream.close()
            done = time.perf_counter()
            with laspy.CopcReader.open(str(path)) as reader:
                entries = reader.root_page.entries
                root = next(e.point_count for k, e in entries.items() if k.level == 0)
                levels = max(k.level for k in entries)
            print(f"{n:,} points: spool {spooled - start:.1f} s, octree {done - spooled:.1f} s, "
                  f"{path.stat().st_size / n:.1f} bytes/point, {len(entries)} nodes, levels 0-{levels}, "
                  f"root {root:,} points; peak RSS so far {spool_rss:.0f} MB after spooling, "
                  f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB after the octree")


if __name__ == "__main__":
    main()
