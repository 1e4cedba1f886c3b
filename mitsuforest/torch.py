"""PyTorch access to a dataset folder's tiles (``pip install mitsuforest[torch]``; nothing else in the
package imports torch).

>>> from torch.utils.data import DataLoader                          # doctest: +SKIP
>>> tiles = TileDataset("out/dataset", "train", fields=("x", "y", "z", "height_above_ground"), points=4096)
>>> batch = next(iter(DataLoader(tiles, batch_size=8, shuffle=True, num_workers=2)))
>>> batch["points"].shape, batch["labels"].shape                      # (8, 4096, 4), (8, 4096)

A :class:`TileDataset` lists the tiles of one split from ``index.csv`` (rows of kind ``tile`` whose
plot ``splits.json`` puts in that split) and reads each tile's point file (PCD, LAS or LAZ, see
README, "Datasets") when it is asked for it.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import yaml

try:
    import torch
except ModuleNotFoundError as missing:       # the optional extra
    raise ModuleNotFoundError("mitsuforest.torch needs PyTorch, the optional extra: "
                              "pip install 'mitsuforest[torch]' (or torch itself)", name="torch") from missing

from . import seeds
from .write.formats import format_of, read_points


class TileDataset(torch.utils.data.Dataset):
    """The tiles of one split of a dataset folder, as fixed-size point samples.

    Each item is a dict: ``points`` float32 (points, len(fields)), ``labels`` int64 (points,) of the
    field ``label``, ``tile`` (its id) and ``index`` int64 (points,), the sampled rows of the tile's
    file. ``x``, ``y`` are metres from the centre of the tile's core and ``z`` metres above the
    scene's datum (the local frame, whatever ``origin.offset`` is); other fields are as in the files.

    :param root: the dataset folder (``mitsuforest dataset -o``).
    :param split: ``train``, ``validation`` or ``test`` (a key of ``splits.json``).
    :param fields: the point fields that make ``points``, in order (any field of the tile files:
        ``intensity``, ``height_above_ground``, ``return_number`` ...).
    :param label: the field that makes ``labels`` (``classification``, ``instance``, ``treeid`` ...).
    :param points: the sample size: drawn without replacement from a larger tile, with replacement
        (every point at least once) from a smaller one; ``None`` keeps every point in file order.
    :param transform: called with each item (the dict, tensors already made), returns the item.
    :param seed: makes item ``i``'s sample the same on every call (``seeds.rng(seed, "sample", i)``); ``None``
        draws a new sample on every call (new on every epoch, different in each DataLoader worker).
    :raises ValueError: an unknown split, a sample size that is not a whole number of at least 1, or a
        field the tiles do not have (on first read).
    """

    def __init__(self, root, split: str = "train", fields: Sequence[str] = ("x", "y", "z"),
                 label: str = "classification", points: int | None = 4096,
                 transform: Callable[[dict], dict] | None = None, seed: int | None = None):
        if points is not None and (isinstance(points, bool) or not isinstance(points, (int, np.integer)) or points < 1):
            raise ValueError(f"points: the sample size must be a whole number >= 1 or None, got {points!r}")
        self.root = Path(root)
        splits = json.loads((self.root / "splits.json").read_text())
        if split not in splits:
            raise ValueError(f"{self.root / 'splits.json'} has no split {split!r} (it has {', '.join(splits)})")
        plots = set(splits[split])
        with open(self.root / "index.csv", newline="") as f:
            self.tiles = [row for row in csv.DictReader(f) if row["kind"] == "tile" and row["plot"] in plots]
        self.fields, self.label, self.size = tuple(fields), label, points
        self.transform, self.seed = transform, seed
        self._offsets: dict = {}

    def __len__(self) -> int:
        return len(self.tiles)

    def tile_file(self, i: int) -> Path:
        """The point file of tile ``i``."""
        listed = self.tiles[i]["files"].split(";")
        return self.root / next(f for f in listed if format_of(f) and Path(f).name.startswith(self.tiles[i]["id"] + "."))

    def read_tile(self, i: int) -> np.ndarray:
        """Every point of tile ``i`` (structured array), x, y, z in the local frame."""
        path = self.tile_file(i)
        points = read_points(path)
        offset = self._offset(self.tiles[i]["plot"])
        if format_of(path) != "pcd" or np.any(offset):   # LAS always, a PCD with an offset: georeferenced
            for axis, o in zip("xyz", offset):
                points[axis] -= o
        return points

    def __getitem__(self, i: int) -> dict:
        tile = self.tiles[i]
        points = self.read_tile(i)
        missing = [f for f in (*self.fields, self.label) if f not in points.dtype.names]
        if missing:
            raise ValueError(f"{self.tile_file(i)}: no field {', '.join(missing)} "
                             f"(it has {', '.join(points.dtype.names)})")
        rows = self._sample(i, len(points))
        centre = {"x": (float(tile["x0"]) + float(tile["x1"])) / 2, "y": (float(tile["y0"]) + float(tile["y1"])) / 2}
        columns = [points[f][rows].astype(np.float64) - centre.get(f, 0.0) for f in self.fields]
        item = {"points": torch.from_numpy(np.column_stack(columns).astype(np.float32)),
                "labels": torch.from_numpy(points[self.label][rows].astype(np.int64)),
                "index": torch.from_numpy(rows.astype(np.int64)), "tile": tile["id"]}
        return self.transform(item) if self.transform else item

    def _sample(self, i: int, count: int) -> np.ndarray:
        if self.size is None:
            return np.arange(count)
        rng = seeds.rng(self.seed, "sample", i)
        if count >= self.size:
            return np.sort(rng.choice(count, self.size, replace=False))
        if count == 0:
            raise ValueError(f"{self.tile_file(i)}: the tile has no points to sample")
        return np.concatenate([rng.permutation(count), rng.integers(0, count, self.size - count)])

    def _offset(self, plot: str) -> np.ndarray:
        """The plot's ``origin.offset`` from its scene file (0 when it has none)."""
        if plot not in self._offsets:
            scene = yaml.safe_load((self.root / "scenes" / f"{plot}.yaml").read_text())
            self._offsets[plot] = np.asarray((scene.get("origin") or {}).get("offset") or (0.0, 0.0, 0.0), float)
        return self._offsets[plot]
