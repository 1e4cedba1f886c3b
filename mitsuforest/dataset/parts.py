"""A split plot's part files: what its leg tasks leave in ``DIR/plots/NAME/.parts/`` for the tasks after them.

A task of legs ``first .. stop-1`` writes::

    legs-FFFFF-SSSSS.points   its scanned points (POINT_DTYPE), batch after batch: the merge feeds them to
                              the render's writer (not with ``tiles.plot_files: false``)
    legs-FFFFF-SSSSS.tiles    with tiles asked for: its points as the plot's files read them back
                              (:func:`~.files.points_as_read`), each batch's sorted into tiles, a point
                              once for every tile whose extent holds it (:func:`~.tiles.tile_members`)
    legs-FFFFF-SSSSS.json     written last, the part's record: batch sizes, pulse counts, and with tiles the
                              tile of each chunk of the ``.tiles`` file, the boxes of the objects' points
                              and the class counts

and the task of the first legs, with tiles, the plot's tables (``NAME_volumes.csv``, ``_ids.csv``,
``_plan.json``, ``_trajectory.csv``, :func:`~mitsuforest.write.write_tables`). A tile's points are its chunks
in leg, then batch, then row order: the order of a render of the whole plot, whichever legs went to
which task. A tile task's record (``tiles-FFFFF-SSSSS.json``) is kept here too, for a rerun.

Every file is written atomically and the part's record last, so a part is reused exactly when its
record is there, made for the same scene and tiles, with every file it names complete.
"""

from __future__ import annotations

import json
from contextlib import ExitStack
from pathlib import Path

import numpy as np

from . import files
from . import tiles as tiling

PARTS = ".parts"


def parts_folder(root, name: str) -> Path:
    return files.plot_folder(root, name) / PARTS


def part_path(root, name: str, first: int, stop: int) -> Path:
    return parts_folder(root, name) / f"legs-{first:05d}-{stop:05d}.json"


def tile_group_path(root, name: str, first: int, stop: int) -> Path:
    return parts_folder(root, name) / f"tiles-{first:05d}-{stop:05d}.json"


GRID = ("size", "buffer")    # the tile settings a part's ``.tiles`` file follows


def tiles_key(tiles, settings=GRID) -> dict | None:
    """The tile ``settings`` a part (its grid) or a tile task (and its files' format) was made for, as
    JSON gives them back."""
    return None if tiles is None else json.loads(json.dumps({k: getattr(tiles, k) for k in settings}))


def write_part(path: Path, batches, scene, tiles, surface, whole_points: bool) -> dict:
    """Write a leg task's point files from its ``batches`` (its scan, taken as it runs): the scanned
    points when ``whole_points`` (for the merge), and with ``tiles`` the points sorted into tiles.
    Returns what the part's record says of them (the caller adds the counts and writes it)."""
    from ..write.atomic import atomic_path
    info = {"batches": []}
    with ExitStack() as stack:
        stack.callback(batches.close)       # the scan stopped if a write fails
        points = tiled = None
        if whole_points:
            tmp = stack.enter_context(atomic_path(path.with_suffix(".points")))
            points = stack.enter_context(open(tmp, "wb"))
            info["points"] = path.with_suffix(".points").name
        if tiles is not None:
            tmp = stack.enter_context(atomic_path(path.with_suffix(".tiles")))
            tiled = TileSorter(stack.enter_context(open(tmp, "wb")), scene, tiles, surface)
        for batch in batches:
            info["batches"].append(len(batch))
            if points is not None:
                points.write(np.ascontiguousarray(batch).data)
            if tiled is not None:
                tiled.add(batch)
        if tiled is not None:
            info.update(tiled.record(path.with_suffix(".tiles").name))
    return info


class TileSorter:
    """Writes batches of scanned points into one file sorted into tiles, batch by batch (see the module
    docstring), and gathers the boxes of the objects' points and the class counts."""

    def __init__(self, file, scene, tiles, surface):
        self.file, self.scene, self.tiles, self.surface = file, scene, tiles, surface
        self.offset = np.asarray(scene.origin.offset, np.float64)
        self.chunks = []            # (tile, points) of each chunk, in file order
        self.boxes = []             # (ids, boxes) of each batch
        self.classes = np.zeros(256, np.int64)
        self.dtype = None

    def add(self, scanned: np.ndarray) -> None:
        points = files.points_as_read(scanned, self.scene, self.surface)
        self.dtype = points.dtype
        x, y = points["x"] - self.offset[0], points["y"] - self.offset[1]
        tile, row = tiling.tile_members(x, y, self.scene.area.size, self.tiles.size, self.tiles.buffer)
        records = points.view(np.dtype((np.void, points.dtype.itemsize)))     # whole records: a faster gather
        self.file.write(np.take(records, row).data)
        ids, counts = np.unique(tile, return_counts=True)
        self.chunks += zip(ids.tolist(), counts.tolist())
        self.boxes.append(files.object_boxes(points, self.offset))
        self.classes += np.bincount(points["classification"], minlength=256)

    def record(self, file_name: str) -> dict:
        if self.dtype is None:            # no batch: the dtype of an empty one
            self.dtype = files.points_as_read(np.zeros(0, _point_dtype()), self.scene, self.surface).dtype
        ids, boxes = tiling.combine_boxes(*_stacked(self.boxes))
        return {"tiles": tiles_key(self.tiles), "tile_points": file_name, "tile_dtype": self.dtype.descr,
                "tile_chunks": self.chunks, "boxes": [[i, *b] for i, b in zip(ids.tolist(), boxes.tolist())],
                "classes": {int(k): int(v) for k, v in enumerate(self.classes) if v}}


def _point_dtype():
    from ..fields import POINT_DTYPE
    return POINT_DTYPE


def _stacked(boxes: list) -> tuple[np.ndarray, np.ndarray]:
    if not boxes:
        return np.zeros(0, np.int64), np.zeros((0, 4))
    return np.concatenate([i for i, _ in boxes]), np.concatenate([b for _, b in boxes])


def read_part(path: Path, scene_sha: str, tiles, whole_points: bool) -> dict | None:
    """A finished part of the same scene, made for the same tile grid and holding the scanned points when
    ``whole_points`` (every file it names complete), else None."""
    try:
        info = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if info.get("scene_sha256") != scene_sha or info.get("tiles") != tiles_key(tiles):
        return None
    if whole_points and "points" not in info:
        return None
    sizes = {}
    if "points" in info:
        sizes[info["points"]] = sum(info["batches"]) * _point_dtype().itemsize
    if tiles is not None:
        sizes[info["tile_points"]] = sum(c for _, c in info["tile_chunks"]) * tile_dtype(info).itemsize
    try:
        complete = all((path.parent / f).stat().st_size == size for f, size in sizes.items())
        complete &= all((path.parent / f).is_file() for f in info.get("tables", []))
    except OSError:
        return None
    return info if complete else None


def tile_dtype(part: dict) -> np.dtype:
    return np.dtype([tuple(field) for field in part["tile_dtype"]])


def part_boxes(parts: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    """``(ids, boxes)`` of the objects' points over every part (:func:`~.tiles.combine_boxes`)."""
    rows = np.array([row for part in parts for row in part["boxes"]], np.float64).reshape(-1, 5)
    return tiling.combine_boxes(rows[:, 0].astype(np.int64), rows[:, 1:])


class TileReader:
    """The points of a tile from the ``.tiles`` files of a plot's parts (in leg order): its chunks,
    part after part, in file order."""

    def __init__(self, folder: Path, parts: list[dict]):
        self.dtype = tile_dtype(parts[0])
        self._parts = []
        for part in parts:
            chunks = np.array(part["tile_chunks"], np.int64).reshape(-1, 2)
            starts = np.concatenate([[0], np.cumsum(chunks[:, 1])])
            data = (np.memmap(folder / part["tile_points"], self.dtype, mode="r") if starts[-1]
                    else np.zeros(0, self.dtype))
            self._parts.append((chunks[:, 0], starts, data))

    def points(self, tile: int) -> np.ndarray:
        pieces = [data[starts[k]:starts[k + 1]] for tiles, starts, data in self._parts
                  for k in np.flatnonzero(tiles == tile)]
        return np.concatenate(pieces) if pieces else np.zeros(0, self.dtype)


def part_batches(folder: Path, parts: list[dict]):
    """The batches of a plot's parts (the leg tasks' records, in leg order) read back from ``folder``,
    with their summed counts: the survey's batches as one scan would give them."""
    from ..scan import ScanResult
    from ..survey import Batches
    result = ScanResult()
    for part in parts:
        result.pulses_emitted += part["emitted"]
        result.pulses_fired += part["fired"]
        result.pulses_cast += part["cast"]
        result.rays += part["rays"]
        result.seconds += part["seconds"]
    return Batches(_read_batches(folder, parts), result)


def _read_batches(folder: Path, parts: list[dict]):
    for part in parts:
        data = np.fromfile(folder / part["points"], _point_dtype())
        starts = np.concatenate([[0], np.cumsum(part["batches"])])
        for a, b in zip(starts[:-1], starts[1:]):
            yield data[a:b]
