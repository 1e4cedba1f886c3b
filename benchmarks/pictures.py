"""How long a render's pictures take: the point rasters accumulated batch by batch, then the figures.

Wall and CPU seconds are both printed: on a shared machine the wall time counts other people's work.

Synthetic points stand in for a 1 ha scene's (made outside the timing): 60 % ground, the rest trees
and understory up to 30 m, in batches of 1 M as the scan hands them to the writer.

    python benchmarks/pictures.py              # 40 M points over 100 m x 100 m
    python benchmarks/pictures.py --quick      # 2 M points (CI)
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from mitsuforest.classes import BUSH, GROUND, TREE_LEAVES, TREE_WOOD
from mitsuforest.scan import POINT_DTYPE
from mitsuforest.write.figures import write_profile_figure, write_returns_figure, write_tile_figure, write_top_figure
from mitsuforest.write.profile import ReturnCounts
from mitsuforest.write.quicklook import SideTile, TopView

AREA = (100.0, 100.0)
BATCH = 1_000_000


def batch(rng, n: int) -> np.ndarray:
    p = np.zeros(n, POINT_DTYPE)
    p["x"], p["y"] = rng.uniform(0, AREA[0], n), rng.uniform(0, AREA[1], n)
    cls = rng.choice([GROUND, TREE_WOOD, TREE_LEAVES, BUSH], n, p=[0.60, 0.13, 0.25, 0.02])
    p["classification"] = cls
    p["z"] = np.where(cls == GROUND, rng.normal(0, 0.01, n), rng.uniform(0, 30, n))
    p["instance"] = np.where(cls == GROUND, 0, rng.integers(1, 122, n))
    p["return_number"] = rng.choice([1, 2, 3], n, p=[0.85, 0.13, 0.02])
    return p


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--points", type=float, default=40e6)
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args(argv)
    total = int(2e6 if args.quick else args.points)
    rng = np.random.default_rng(0)
    top, tile, counts = TopView(AREA), SideTile(AREA), ReturnCounts(None, AREA)
    classes = np.zeros(256, np.int64)
    returns = np.zeros(256, np.int64)
    accumulate = cpu = 0.0
    for start in range(0, total, BATCH):
        p = batch(rng, min(BATCH, total - start))
        t, c = time.perf_counter(), time.process_time()
        top.add(p)
        tile.add(p)
        counts.add(p)
        accumulate += time.perf_counter() - t
        cpu += time.process_time() - c
        classes += np.bincount(p["classification"], minlength=256)
        returns += np.bincount(rng.choice([1, 2, 3], len(p) // 2), minlength=256)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        c = time.process_time()
        t = time.perf_counter()
        write_top_figure(folder / "top.png", top, tile, [int(c) for c in np.flatnonzero(classes)])
        t_top = time.perf_counter() - t
        t = time.perf_counter()
        write_tile_figure(folder / "side.png", tile)
        t_side = time.perf_counter() - t
        t = time.perf_counter()
        write_profile_figure(folder / "profile.png", counts)
        write_returns_figure(folder / "returns.png", returns, counts)
        t_charts = time.perf_counter() - t
        cpu += time.process_time() - c
        sizes = {p.name: p.stat().st_size for p in folder.iterdir()}
    print(f"points: {total:,} in batches of {BATCH:,}; tile points: {len(tile.points()):,}")
    print(f"accumulate (top view, tile, counts): {accumulate:.2f} s ({total / accumulate / 1e6:.1f} M points/s)")
    print(f"figures: top {t_top:.2f} s, tile (3 views) {t_side:.2f} s, profile + returns charts {t_charts:.2f} s")
    print(f"pictures in all: {accumulate + t_top + t_side + t_charts:.2f} s wall, {cpu:.2f} s CPU; PNG sizes (kB): "
          + ", ".join(f"{k} {v / 1e3:.0f}" for k, v in sorted(sizes.items())))


if __name__ == "__main__":
    main()
