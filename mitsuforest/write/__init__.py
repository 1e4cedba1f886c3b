"""Stage 6: every file a render writes (see README, "Outputs").

Files are first written into a hidden staging folder inside ``output.dir`` and moved into place only
when all of them are complete, the manifest last: a render is finished exactly when
``<name>_manifest.json`` exists, and an interrupted one leaves nothing that looks finished.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np

from .atomic import write_text
from .las import write_las
from .pcd import read_pcd, write_pcd
from .quicklook import side_view, top_view, write_png
from .tables import write_ids, write_trajectory, write_volumes

__all__ = ["Staging", "output_files", "existing_outputs", "write_pcd", "read_pcd", "write_las",
           "point_statistics", "write_render_outputs", "write_manifest"]

SUFFIXES = (".pcd", ".las", ".laz", "_volumes.csv", "_ids.csv", "_plan.json", "_trajectory.csv",
            "_manifest.json", "_top.png", "_side.png")


def output_files(name: str) -> list[str]:
    return [name + s for s in SUFFIXES]


def existing_outputs(folder, name: str) -> list[str]:
    folder = Path(folder)
    return [f for f in output_files(name) if (folder / f).exists()]


class Staging:
    """A hidden folder collecting one render's files until :meth:`commit` moves them into place."""

    def __init__(self, folder, name: str):
        self.folder, self.name = Path(folder), name
        self.folder.mkdir(parents=True, exist_ok=True)
        for stale in self.folder.glob(f".{name}.partial-*"):
            shutil.rmtree(stale, ignore_errors=True)
        self.path = self.folder / f".{name}.partial-{os.getpid()}"
        self.path.mkdir()

    def file(self, suffix: str) -> Path:
        return self.path / (self.name + suffix)

    def commit(self) -> list[Path]:
        """Remove the previous render's files, then move the new ones in, the manifest last."""
        for old in existing_outputs(self.folder, self.name):
            (self.folder / old).unlink()
        staged = sorted(self.path.iterdir(), key=lambda p: p.name.endswith("_manifest.json"))
        moved = []
        for p in staged:
            target = self.folder / p.name
            os.replace(p, target)
            moved.append(target)
        self.path.rmdir()
        return moved

    def discard(self) -> None:
        shutil.rmtree(self.path, ignore_errors=True)


def point_statistics(points: np.ndarray, area, seed: int = 0) -> dict:
    """Density (points/m² over the plot), mean nearest-neighbour spacing, class and returns counts."""
    from scipy.spatial import cKDTree
    n = len(points)
    plot_area = float(area[0] * area[1])
    stats = {"points": n, "density_per_m2": n / plot_area if plot_area else 0.0,
             "classes": {int(k): int(v) for k, v in enumerate(np.bincount(points["classification"])) if v}}
    first = points["return_number"] == 1
    stats["pulses_with_returns"] = int(first.sum())
    stats["returns_histogram"] = {int(k): int(v) for k, v in
                                  enumerate(np.bincount(points["number_of_returns"][first])) if v}
    # Mean 3D nearest-neighbour spacing, measured in up to four random 5 m x 5 m tiles.
    rng = np.random.default_rng(seed)
    spacings = []
    for _ in range(4 if n else 0):
        x0, y0 = rng.uniform(0, max(area[0] - 5, 0)), rng.uniform(0, max(area[1] - 5, 0))
        sel = (points["x"] >= x0) & (points["x"] < x0 + 5) & (points["y"] >= y0) & (points["y"] < y0 + 5)
        xyz = np.column_stack([points["x"][sel], points["y"][sel], points["z"][sel]])
        if len(xyz) > 1:
            d, _ = cKDTree(xyz).query(xyz, k=2)
            spacings.append(d[:, 1])
    stats["mean_spacing_m"] = float(np.concatenate(spacings).mean()) if spacings else None
    return stats


def write_render_outputs(staging: Staging, *, scene, plan, models, points, offset, formats, plan_text: str) -> None:
    """Write the files of one render but its manifest into ``staging`` (points already georeferenced)."""
    if "pcd" in formats:
        write_pcd(staging.file(".pcd"), points)
    for fmt in ("las", "laz"):
        if fmt in formats:
            write_las(staging.file("." + fmt), points, offset, scene["origin"]["crs"])
    write_volumes(staging.file("_volumes.csv"), plan, models, offset)
    write_ids(staging.file("_ids.csv"), plan, models, offset)
    write_text(staging.file("_plan.json"), plan_text)
    write_trajectory(staging.file("_trajectory.csv"), plan["legs"], offset)
    _quicklooks(staging, points, scene, offset)


def write_manifest(staging: Staging, manifest: dict) -> None:
    write_text(staging.file("_manifest.json"), json.dumps(manifest, indent=1, sort_keys=True, default=str) + "\n")


def _quicklooks(staging: Staging, points, scene, offset):
    w, h = scene["area"]["size"]
    local = points.copy()
    for axis, o in zip("xyz", offset):
        local[axis] -= o
    write_png(staging.file("_top.png"), top_view(local, ((0, w), (0, h))))
    tile = min(20.0, w, h)
    x0, y0 = (w - tile) / 2, (h - tile) / 2
    in_tile = local[(local["y"] >= y0) & (local["y"] < y0 + tile)]
    write_png(staging.file("_side.png"), side_view(in_tile, (x0, x0 + tile)))
