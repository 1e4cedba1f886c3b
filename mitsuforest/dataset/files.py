"""The dataset's files: plot scene files, plot records with checksums, tiles, the index, splits and
the manifest.

Layout of a dataset folder ``DIR``::

    DIR/scenes/plot_0000.yaml         each plot's resolved scene (``mitsuforest render`` takes it)
    DIR/plots/plot_0000/              the plot's render: every usual file (see README, Outputs)
    DIR/plots/plot_0000/tiles/        plot_0000_x00_y00.laz and plot_0000_x00_y00_trees.csv, ...
    DIR/plots/plot_0000/plot_0000_dataset.json   the plot's record: files and their SHA-256, counts
    DIR/index.csv, DIR/splits.json, DIR/dataset_manifest.json

A plot is finished exactly when its record exists and every file it lists has the listed checksum;
the record is written last, atomically. The index lists only finished plots.
"""

from __future__ import annotations

import csv
import hashlib
import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from .. import seeds
from ..classes import CLASS_NAMES, DEADWOOD, TREE_LEAVES, TREE_WOOD
from ..config.types import to_mapping
from ..fields import POINT_FORMATS, pcd_dtype
from ..write.atomic import write_json, write_text
from ..write.formats import read_points, write_points
from ..write.ground import fill_height, with_room_for_height
from ..write.las import las_data_points, las_header, las_points
from ..write.output_profiles import PROFILES, stem_ids_from_table, write_profile
from ..write.stream import georeference
from ..write.tables import csv_text
from . import tiles as tiling

RECORD_SUFFIX = "_dataset.json"


def plot_folder(root, name: str) -> Path:
    return Path(root) / "plots" / name


def scene_file(root, name: str) -> Path:
    return Path(root) / "scenes" / f"{name}.yaml"


def scene_yaml(scene) -> str:
    """A scene as a YAML file that loads back to the same scene (paths absolute; the sensor by its
    file when it has one)."""
    data = to_mapping(scene, plain=True)
    if scene.sensor.file:
        data["sensor"] = scene.sensor.file
    return yaml.safe_dump(data, sort_keys=False)


def write_scene_file(path, scene) -> None:
    """Write a plot's scene file, unless an identical one is there (a re-run keeps its time stamps)."""
    path = Path(path)
    text = scene_yaml(scene)
    if path.is_file() and path.read_text() == text:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text(path, text)


def sha256(path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(1 << 22):
            digest.update(block)
    return digest.hexdigest()


def checksums(root, paths) -> dict:
    """``{path relative to root: sha256}``, in the given order."""
    root = Path(root)
    return {str(Path(p).relative_to(root)): sha256(p) for p in paths}


def read_record(root, name: str) -> dict | None:
    """The plot's record if it exists and is readable, else None."""
    path = plot_folder(root, name) / f"{name}{RECORD_SUFFIX}"
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def valid_record(root, name: str) -> dict | None:
    """The plot's record if it was made from the plot's current scene file and every file it lists
    (tiles included) is there with its checksum."""
    record = read_record(root, name)
    if record is None or record.get("scene_sha256") != sha256(scene_file(root, name)):
        return None
    listed = {**record["files"], **{k: v for t in record.get("tiles", []) for k, v in t["files"].items()}}
    for rel, digest in listed.items():
        path = Path(root) / rel
        if not path.is_file() or sha256(path) != digest:
            return None
    return record


def write_record(root, name: str, record: dict) -> None:
    write_json(plot_folder(root, name) / f"{name}{RECORD_SUFFIX}", record)


def remove_record(root, name: str) -> None:
    (plot_folder(root, name) / f"{name}{RECORD_SUFFIX}").unlink(missing_ok=True)


def class_shares(classes: dict) -> dict:
    """``{class name: share of points}`` from ``{class code: count}`` (codes as ints or strings)."""
    total = sum(classes.values())
    return {name: (classes.get(code, classes.get(str(code), 0)) / total if total else 0.0)
            for code, name in CLASS_NAMES.items()}


# --- tiles ----------------------------------------------------------------------------------------

def read_plot_points(folder, name: str, formats) -> np.ndarray:
    """A plot's points as written: the PCD when there is one (all fields; x, y, z georeferenced when
    ``origin.offset`` is set, local otherwise), else the LAS/LAZ (our fields; no pulse_id or range).
    Both carry ``height_above_ground``, which the tiles keep."""
    fmt = "pcd" if "pcd" in formats else next(f for f in ("las", "laz", "copc") if f in formats)
    return read_points(Path(folder) / (name + POINT_FORMATS[fmt]))


def read_volumes(path) -> dict:
    """``{instance: (kind, treeid, union volume m³, x, y)}`` of the placed trees and deadwood pieces of a
    render's ``_volumes.csv`` (x, y: the object's position as written there, georeferenced)."""
    out = {}
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            if row["row"] in ("tree", "deadwood") and row["instance"]:
                out[int(row["instance"])] = (row["row"], int(row["treeid"]), float(row["volume_union_m3"]),
                                             float(row["x"]), float(row["y"]))
    return out


def owned_objects(volumes: dict, offset, i: int, j: int, area_size, size: float) -> set:
    """The instances of ``volumes`` (:func:`read_volumes`) whose position lies in tile ``(i, j)``'s core:
    each object is owned by exactly one tile of its plot, as each point is in one core."""
    ids = list(volumes)
    xy = np.array([volumes[k][3:5] for k in ids], np.float64).reshape(-1, 2) - np.asarray(offset, np.float64)[:2]
    ci, cj = tiling.core_tile(xy[:, 0], xy[:, 1], area_size, size)
    return {k for k, a, b in zip(ids, ci.tolist(), cj.tolist()) if (a, b) == (i, j)}


KEPT_CLASSES = (TREE_WOOD, TREE_LEAVES, DEADWOOD)   # the classes whose objects the tiles' tables list


@dataclass(frozen=True)
class TileLabels:
    """What every tile of a plot needs beside its points: the plot's tree and deadwood volumes
    (:func:`read_volumes`), the box of each one's points over the whole plot (``instances`` sorted,
    ``boxes`` (k, 4) aligned with them, NaN for none), and the stems' object ids for an
    ``output.profile`` that tells stems from branches (None without one)."""

    volumes: dict
    instances: np.ndarray
    boxes: np.ndarray
    stems: np.ndarray | None


def tile_labels(volumes_table, ids_table, profile: str, ids: np.ndarray, boxes: np.ndarray) -> TileLabels:
    """The :class:`TileLabels` of a plot from its ``_volumes.csv`` and ``_ids.csv`` tables and the boxes
    of its objects' points (:func:`object_boxes`, ``ids`` sorted)."""
    volumes = read_volumes(volumes_table)
    instances = np.array(sorted(volumes), np.int64)
    aligned = np.full((len(instances), 4), np.nan)
    at = np.searchsorted(ids, instances)
    found = at < len(ids)
    found[found] = ids[at[found]] == instances[found]
    aligned[found] = boxes[at[found]]
    stems = stem_ids_from_table(ids_table) if profile in PROFILES else None
    return TileLabels(volumes, instances, aligned, stems)


def object_boxes(points: np.ndarray, offset) -> tuple[np.ndarray, np.ndarray]:
    """``(ids, boxes)``: the sorted instances of the tree, leaf and deadwood points among ``points`` (as
    :func:`read_plot_points` reads them) and the (k, 4) box ``xmin, ymin, xmax, ymax`` of each one's
    points in the local frame. Boxes of several sets of points combine with
    :func:`~.tiles.combine_boxes`."""
    kept = np.isin(points["classification"], KEPT_CLASSES)
    instance = points["instance"][kept].astype(np.int64)
    ids = np.unique(instance)
    x, y = _local_xy(points[kept], offset)
    return ids, tiling.instance_boxes(instance, x, y, ids)


def _local_xy(points: np.ndarray, offset) -> tuple[np.ndarray, np.ndarray]:
    """x, y in the local frame (float64) of points as read back (PCD x, y include the offset when it is set)."""
    return points["x"] - offset[0], points["y"] - offset[1]


def points_as_read(scanned: np.ndarray, scene, surface) -> np.ndarray:
    """A batch of scanned points (POINT_DTYPE, local frame) as :func:`read_plot_points` reads them back from
    the plot's files once the render's writer has written them: the PCD's records (height above the
    ``surface``, georeferenced, x, y, z float32 when local), else the LAS's (no ``pulse_id`` or ``range``,
    coordinates to the LAS's precision).

    :param surface: the plan's ground (:func:`~mitsuforest.write.ground.ground_surface`).
    """
    offset = np.asarray(scene.origin.offset, np.float64)
    points = georeference(fill_height(scanned, with_room_for_height(scanned), surface), offset)
    if "pcd" in scene.output.formats:
        return points.astype(pcd_dtype(points.dtype, local=not np.any(offset)))
    header = las_header(offset, scene.origin.crs, scene.sensor.intensity)
    return las_data_points(las_points(header, points, scene.sensor.intensity))


def tile_name(name: str, i: int, j: int, nx: int, ny: int) -> str:
    """``NAME_xI_yJ``, I and J zero-padded to the grid's widest."""
    return f"{name}_x{i:0{len(str(nx - 1))}d}_y{j:0{len(str(ny - 1))}d}"


def tiles_folder(root, name: str) -> Path:
    return plot_folder(root, name) / "tiles"


def write_tiles(root, scene, tiles) -> list[dict]:
    """Cut a rendered plot's points into tiles (see :mod:`.tiles`): one point file and one tree table
    per tile, and the ``output.profile``'s file unless it is ``ours``, each written atomically. Returns one
    record per tile."""
    name, folder = scene.name, plot_folder(root, scene.name)
    points = read_plot_points(folder, name, scene.output.formats)
    offset = np.asarray(scene.origin.offset, np.float64)
    labels = tile_labels(folder / f"{name}_volumes.csv", folder / f"{name}_ids.csv", scene.output.profile,
                         *object_boxes(points, offset))
    out_dir = tiles_folder(root, name)
    shutil.rmtree(out_dir, ignore_errors=True)      # an earlier run's tiles (another layout, or damaged)
    out_dir.mkdir()
    nx, ny = tiling.tile_grid(scene.area.size, tiles.size)
    tile, row = tiling.tile_members(*_local_xy(points, offset), scene.area.size, tiles.size, tiles.buffer)
    bounds = np.searchsorted(tile, np.arange(nx * ny + 1))
    return [write_tile(root, scene, tiles, labels, t // ny, t % ny, points[row[bounds[t]:bounds[t + 1]]])
            for t in range(nx * ny)]


def write_tile(root, scene, tiles, labels: TileLabels, i: int, j: int, points: np.ndarray) -> dict:
    """Write tile ``(i, j)`` of a plot into its ``tiles/`` folder: ``points`` (every point of the plot in the
    tile's extent, as :func:`read_plot_points` reads them, in the plot's order) as its point file, its
    tree table, and the ``output.profile``'s file unless it is ``ours``, each atomically. Returns the
    tile's record (counts and the files' checksums)."""
    name, area = scene.name, scene.area.size
    nx, ny = tiling.tile_grid(area, tiles.size)
    tile_id = tile_name(name, i, j, nx, ny)
    offset = np.asarray(scene.origin.offset, np.float64)
    x, y = _local_xy(points, offset)
    ci, cj = tiling.core_tile(x, y, area, tiles.size)
    out_dir = tiles_folder(root, name)
    point_file = out_dir / (tile_id + POINT_FORMATS[tiles.format])
    write_points(point_file, points, offset, scene.origin.crs, scene.sensor.intensity)
    written = [point_file]
    if labels.stems is not None:
        written.append(out_dir / f"{tile_id}{PROFILES[scene.output.profile].suffix}")
        write_profile(written[-1], scene.output.profile, points, offset, scene.origin.crs, labels.stems,
                      scene.sensor.intensity)
    rows = _tree_rows(points, labels, tiling.tile_extent(i, j, area, tiles.size, tiles.buffer),
                      owned_objects(labels.volumes, offset, i, j, area, tiles.size))
    table = out_dir / f"{tile_id}_trees.csv"
    write_text(table, csv_text(["instance", "kind", "treeid", "volume_union_m3", "points", "whole_inside", "core"],
                               rows))
    classes = np.bincount(points["classification"], minlength=8)
    return {
        "tile": tile_id, "i": i, "j": j,
        "core": list(tiling.core_bounds(i, j, area, tiles.size)),
        "points": len(points), "core_points": int(((ci == i) & (cj == j)).sum()), "trees": len(rows),
        "classes": {int(k): int(v) for k, v in enumerate(classes) if v},
        "files": checksums(root, [*written, table]),
    }


def _tree_rows(points, labels: TileLabels, extent, owned: set) -> list[list]:
    kept = np.isin(points["classification"], KEPT_CLASSES)
    ids, counts = np.unique(points["instance"][kept], return_counts=True)
    rows = []
    for inst, count in zip(ids.tolist(), counts.tolist()):
        if inst not in labels.volumes:
            continue
        kind, treeid, volume = labels.volumes[inst][:3]
        box = labels.boxes[np.searchsorted(labels.instances, inst)]
        rows.append([inst, kind, treeid, f"{volume:.9g}", count, int(tiling.box_inside(box, extent)),
                     int(inst in owned)])
    return rows


# --- the dataset's own files ------------------------------------------------------------------------

INDEX_COLUMNS = ["kind", "id", "plot", "split", "points", "core_points", "trees", "x0", "y0", "x1", "y1",
                 "files", "sha256"]


def index_rows(records: list[dict], varied, splits: dict) -> tuple[list[str], list[list]]:
    """One row per plot, then its tiles: parameters (one column per varied key), files, counts, class
    shares and checksums (files and checksums ``;``-separated, in the same order)."""
    split_of = {plot: split for split, plots in splits.items() for plot in plots}
    shares = [f"share_{n}" for n in CLASS_NAMES.values()]
    header = [*INDEX_COLUMNS, *shares, *varied, "seconds"]
    rows = []
    for rec in sorted(records, key=lambda r: r["plot"]):
        plot = rec["plot"]
        params = [_cell(rec["values"].get(k)) for k in varied]
        rows.append(["plot", plot, plot, split_of.get(plot, ""), rec["points"], "", "", "", "", "", "",
                     ";".join(rec["files"]), ";".join(rec["files"].values()),
                     *_shares(rec["classes"]), *params, rec.get("seconds", "")])
        for t in rec.get("tiles", []):
            x0, y0, x1, y1 = t["core"]
            rows.append(["tile", t["tile"], plot, split_of.get(plot, ""), t["points"], t["core_points"], t["trees"],
                         x0, y0, x1, y1, ";".join(t["files"]), ";".join(t["files"].values()),
                         *_shares(t["classes"]), *params, ""])
    return header, rows


def _shares(classes: dict) -> list[str]:
    return [f"{v:.6f}" for v in class_shares(classes).values()]


def _cell(value):
    if isinstance(value, (list, dict)):
        return json.dumps(value)
    return "" if value is None else value


def write_index(root, records, varied, splits) -> None:
    header, rows = index_rows(records, varied, splits)
    write_text(Path(root) / "index.csv", csv_text(header, rows))


SPLIT_BLOCK = 10   # plots per block of the split assignment


def assign_splits(names: list[str], ratios: dict, seed: int) -> dict:
    """``{split: [plot names]}``: every plot in exactly one split, and a plot's split depends only on the
    seed and its place in ``names``, so raising ``plots`` never moves a plot to another split.

    Plots are taken in blocks of :data:`SPLIT_BLOCK`. Each block's quota per split is what brings the
    running counts to the ratios times the plots so far (:func:`split_quotas`), so after every whole
    block each split is within one plot of its ratio. Inside a block the j-th of a split's q places
    falls at ``(j + u) / q`` of the block, u uniform from ``seeds.rng(seed, "splits", block)``: each split
    is spread evenly through the block, so a partial block (a dataset of 3 plots) stays close to the ratios too,
    yet no split follows a period of the plot list (a grid's combinations repeat along it). Each split's
    first place (j = 0) comes before all second places, so the block's first plots hold one of every
    split that has a place in it: 8 plots at 0.75 / 0.125 / 0.125 give 6 / 1 / 1 (a block of 10 quotas
    8 / 1 / 1, whose last places would otherwise fall past the eighth plot)."""
    out = {key: [] for key in ratios}
    keys = list(ratios)
    for block, quota in enumerate(split_quotas(ratios, -(-len(names) // SPLIT_BLOCK))):
        split = np.repeat(np.arange(len(keys)), quota)
        place = np.concatenate([np.arange(q) for q in quota])
        u = seeds.rng(seed, "splits", block).random(len(split))
        order = split[np.lexsort(((place + u) / quota[split], place > 0))]
        for name, k in zip(names[block * SPLIT_BLOCK:(block + 1) * SPLIT_BLOCK], order):
            out[keys[k]].append(name)
    return {key: sorted(plots) for key, plots in out.items()}


def split_quotas(ratios: dict, blocks: int) -> list[np.ndarray]:
    """Plots per split in each of ``blocks`` blocks of :data:`SPLIT_BLOCK`: the largest-remainder
    apportionment of the running total, so the counts after block b are within one of the ratios times
    ``(b + 1) · SPLIT_BLOCK``."""
    share = np.array(list(ratios.values()), float)
    quotas, done = [], np.zeros(len(share), int)
    for block in range(blocks):
        exact = share * (block + 1) * SPLIT_BLOCK
        total = np.floor(exact).astype(int)
        for k in np.argsort(-(exact - total), kind="stable")[: (block + 1) * SPLIT_BLOCK - total.sum()]:
            total[k] += 1
        quotas.append(total - done)
        done = total
    return quotas


