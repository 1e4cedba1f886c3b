"""What the workers run: a whole plot; or, for a plot split by flight legs, a range of its legs, the merge
of its legs into its files, a group of its tiles, and its record once they are done.

Each function takes plain arguments (paths, numbers) and returns plain data, so that Dask can ship
it to any worker and retry it elsewhere. Everything a task writes is atomic (a render's staging
folder, temporary names renamed when complete), so a worker killed mid-task leaves nothing that
looks finished, and the retry starts clean.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

from .. import seeds
from ..write import TABLES
from . import files, parts
from .tiles import tile_grid

TILE_FILES = (*parts.GRID, "format")   # the tile settings a tile task's files follow


def _quiet(*_):
    pass


def set_threads(threads: int | None) -> None:
    """Limit this worker process's Dr.Jit thread pool (LocalCluster: cores / workers), and its point
    writer's threads unless ``MITSUFOREST_WRITER_THREADS`` says otherwise; its writer uses no processes of
    its own unless ``MITSUFOREST_WRITER_PROCESSES`` says so (the workers share the cores already), nor does it
    build models in processes unless ``MITSUFOREST_BUILD_PROCESSES`` says so; with ``threads`` or without (a
    scheduler's workers without ``--threads``)."""
    from ..trees.parallel import PROCESSES_VARIABLE as BUILD_PROCESSES
    from ..write.processes import PROCESSES_VARIABLE
    os.environ.setdefault(PROCESSES_VARIABLE, "0")
    os.environ.setdefault(BUILD_PROCESSES, "0")
    if threads:
        from ..threads import THREADS_VARIABLE
        os.environ.setdefault(THREADS_VARIABLE, str(threads))
        import drjit as dr
        if dr.thread_count() != threads:
            dr.set_thread_count(threads)


def render_plot(root: str, name: str, tiles=None, threads: int | None = None) -> dict:
    """Render one plot from ``DIR/scenes/NAME.yaml`` into ``DIR/plots/NAME`` (every usual file), cut
    its tiles, and write its record; a plot whose record checks out is left as it is."""
    record = files.valid_record(root, name)
    if record is not None:
        return {**record, "skipped": True}
    set_threads(threads)
    from ..pipeline import render
    start = time.perf_counter()
    files.remove_record(root, name)
    result = render(files.scene_file(root, name), output_dir=files.plot_folder(root, name), overwrite=True,
                    progress=False, log=_quiet)
    return _finish(root, result, tiles, time.perf_counter() - start)


def check_plot(root: str, name: str) -> dict | None:
    """The plot's record when it is finished and undamaged (run on a worker: it reads every file)."""
    return files.valid_record(root, name)


def scan_legs(root: str, name: str, first: int, stop: int, threads: int | None = None, tiles=None) -> dict:
    """Scan legs ``first .. stop-1`` of a plot into ``DIR/plots/NAME/.parts/`` (:mod:`.parts`): the points
    of each batch appended to one file for the merge (unless ``tiles.plot_files`` is false), with
    ``tiles`` also sorted into the plot's tiles, and the part's record beside them (written last). Only
    the objects in reach of these legs are loaded. A part already there is reused."""
    path = parts.part_path(root, name, first, stop)
    scene_sha = files.sha256(files.scene_file(root, name))
    whole = _whole_plot(tiles)
    done = parts.read_part(path, scene_sha, tiles, whole)
    if done is not None:
        return done
    started = time.perf_counter()
    set_threads(threads)
    from ..survey import prepare_plan, scan
    from ..write import write_tables
    from ..write.ground import ground_surface
    scene, plan, models = _plot_setup(files.scene_file(root, name), first)
    prepared = prepare_plan(scene, plan, models, legs=range(first, stop))
    path.parent.mkdir(parents=True, exist_ok=True)
    info = {"first": first, "stop": stop, "scene_sha256": scene_sha}
    if tiles is not None and first == 0:       # the tables the tile tasks read (and a tiles-only plot keeps)
        write_tables(lambda suffix: path.parent / f"{name}{suffix}", scene=scene, plan=plan, models=models)
        info["tables"] = [f"{name}{suffix}" for suffix in TABLES]
    batches = scan(prepared)
    info.update(parts.write_part(path, batches, scene, tiles, ground_surface(plan.terrain), whole))
    result, scan_scene = batches.result, prepared.scan_scene
    info.update({"emitted": result.pulses_emitted, "fired": result.pulses_fired, "cast": result.pulses_cast,
                 "rays": result.rays, "seconds": result.seconds, "task_seconds": time.perf_counter() - started,
                 "scene": {"objects": scan_scene.objects, "culled": scan_scene.culled, "loaded": scan_scene.loaded,
                           "triangles": scan_scene.triangles, "variant": scan_scene.variant}})
    files.write_json(path, info)
    return json.loads(path.read_text())        # as a rerun reads it back


def merge_plot(root: str, name: str, legs: list[dict], threads: int | None = None) -> dict:
    """Write a split plot's files from its parts, in leg order, through the render's own writer: the
    same bytes as a render of the whole plot in one process. Returns the files' checksums, the counts
    and the seconds it took (:func:`finish_split_plot` makes the record)."""
    set_threads(threads)
    from ..pipeline import write_files
    from ..survey import prepare_plan
    start = time.perf_counter()
    files.remove_record(root, name)
    legs = sorted(legs, key=lambda p: p["first"])
    scene, plan, models = _plot_setup(files.scene_file(root, name))   # planned already where this worker scanned legs
    scene = scene.with_({"output.dir": str(files.plot_folder(root, name))})
    prepared = prepare_plan(scene, plan, models, legs=range(0))       # plan and models for the tables; no object loaded
    result = write_files(prepared, parts.part_batches(parts.parts_folder(root, name), legs), overwrite=True)
    manifest = result.manifest
    return {"files": files.checksums(root, sorted(result.files)), "points": manifest["points"],
            "classes": manifest["classes"], "pulses": manifest["pulses"]["emitted"],
            "merge_seconds": round(time.perf_counter() - start, 3)}


def write_tile_group(root: str, name: str, legs: list[dict], tiles, first: int, stop: int,
                     threads: int | None = None) -> dict:
    """Write tiles ``first .. stop-1`` (their numbers ``i * ny + j``) of a split plot from its leg tasks'
    parts into ``DIR/plots/NAME/tiles/``: the bytes :func:`~.files.write_tiles` cuts from the whole plot's
    files, which this does not need. Returns their records and seconds, also kept in ``.parts/`` so
    that a rerun whose tiles are still there and undamaged reuses them."""
    path = parts.tile_group_path(root, name, first, stop)
    scene_sha = files.sha256(files.scene_file(root, name))
    done = _read_tile_group(root, path, scene_sha, tiles)
    if done is not None:
        return done
    start = time.perf_counter()
    set_threads(threads)
    from ..config import load_scene
    files.remove_record(root, name)
    legs = sorted(legs, key=lambda p: p["first"])
    folder = parts.parts_folder(root, name)
    scene = load_scene(files.scene_file(root, name))
    labels = files.tile_labels(folder / f"{name}_volumes.csv", folder / f"{name}_ids.csv", scene.output.profile,
                               *parts.part_boxes(legs))
    reader = parts.TileReader(folder, legs)
    files.tiles_folder(root, name).mkdir(parents=True, exist_ok=True)
    ny = tile_grid(scene.area.size, tiles.size)[1]
    records = [files.write_tile(root, scene, tiles, labels, t // ny, t % ny, reader.points(t))
               for t in range(first, stop)]
    info = {"first": first, "stop": stop, "scene_sha256": scene_sha, "tiles": parts.tiles_key(tiles, TILE_FILES),
            "records": records, "task_seconds": round(time.perf_counter() - start, 3)}
    files.write_json(path, info)
    return json.loads(path.read_text())        # as a rerun reads it back


def _read_tile_group(root, path: Path, scene_sha: str, tiles) -> dict | None:
    """A tile task's record when it was made for this scene and tile settings and its files are there
    unchanged."""
    try:
        info = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if info.get("scene_sha256") != scene_sha or info.get("tiles") != parts.tiles_key(tiles, TILE_FILES):
        return None
    for rel, digest in ((k, v) for r in info["records"] for k, v in r["files"].items()):
        target = Path(root) / rel
        if not target.is_file() or files.sha256(target) != digest:
            return None
    return info


def finish_split_plot(root: str, name: str, legs: list[dict], merged: dict | None, groups: list[dict]) -> dict:
    """Write a split plot's record once its tasks are done: the merge's files (``merged``), or without one
    (``tiles.plot_files: false``) the tables the first leg task wrote, moved into the plot's folder;
    the tile tasks' records (``groups``); counts and seconds. Files of an earlier run that the record
    does not list (its tiles, or point files a tiles-only plot has none of) are removed, then the parts."""
    start = time.perf_counter()
    legs = sorted(legs, key=lambda p: p["first"])
    tile_records = [r for g in sorted(groups, key=lambda g: g["first"]) for r in g["records"]]
    if merged is None:
        merged = _tiles_only_files(root, name, legs)
    if groups:
        _remove_unlisted_tiles(root, name, tile_records)
    leg_rows = [{"legs": [p["first"], p["stop"]], "pulses": p["emitted"], "points": sum(p["batches"]),
                 "scan_seconds": round(p["seconds"], 3), "task_seconds": round(p.get("task_seconds", p["seconds"]), 3)}
                for p in legs]
    extra = {"merge_seconds": merged["merge_seconds"]} if "merge_seconds" in merged else {}
    if groups:
        extra["tile_tasks"] = [{"tiles": [g["first"], g["stop"]], "task_seconds": g["task_seconds"]}
                               for g in sorted(groups, key=lambda g: g["first"])]
    finish = time.perf_counter() - start
    extra["finish_seconds"] = round(finish, 3)
    seconds = (sum(r["task_seconds"] for r in leg_rows) + merged.get("merge_seconds", 0)
               + sum(g["task_seconds"] for g in groups) + finish)
    record = {
        "plot": name,
        "scene_sha256": legs[0]["scene_sha256"],
        "files": merged["files"],
        "points": merged["points"],
        "classes": merged["classes"],
        "pulses": merged["pulses"],
        "seconds": round(seconds, 3),
        "tiles": tile_records,
        "leg_tasks": leg_rows,
        **extra,
    }
    files.write_record(root, name, record)
    shutil.rmtree(parts.parts_folder(root, name), ignore_errors=True)
    return record


def _tiles_only_files(root, name: str, legs: list[dict]) -> dict:
    """A tiles-only plot's own files: the tables its first leg task wrote, moved into its folder (a
    render's files of an earlier run removed), with its counts summed over the parts."""
    from ..write import existing_outputs
    from ..write.atomic import durable_replace
    folder, source = files.plot_folder(root, name), parts.parts_folder(root, name)
    tables = [folder / f for f in legs[0]["tables"]]
    for stale in set(existing_outputs(folder, name)) - {t.name for t in tables}:
        (folder / stale).unlink(missing_ok=True)
    for table in tables:
        if (source / table.name).exists():            # else moved by an earlier try of this task
            durable_replace(source / table.name, table)
    classes = {}
    for part in legs:
        for code, count in part["classes"].items():
            classes[int(code)] = classes.get(int(code), 0) + count
    return {"files": files.checksums(root, sorted(tables)), "points": sum(sum(p["batches"]) for p in legs),
            "classes": dict(sorted(classes.items())), "pulses": sum(p["emitted"] for p in legs)}


def _remove_unlisted_tiles(root, name: str, records: list[dict]) -> None:
    """Remove what a plot's ``tiles/`` folder holds beyond the files of ``records`` (an earlier layout's
    tiles, a killed task's temporary files)."""
    folder = files.tiles_folder(root, name)
    listed = {Path(root) / rel for r in records for rel in r["files"]}
    for path in folder.iterdir():
        if path not in listed:
            shutil.rmtree(path) if path.is_dir() else path.unlink(missing_ok=True)


def _whole_plot(tiles) -> bool:
    """Whether a split plot gets its own point files (merged from its legs), not only tiles."""
    return tiles is None or tiles.plot_files


def _finish(root, result, tiles, seconds: float) -> dict:
    scene, manifest = result.scene, result.manifest
    tile_records = files.write_tiles(root, scene, tiles) if tiles else []
    record = {
        "plot": scene.name,
        "scene_sha256": files.sha256(scene.file),
        "files": files.checksums(root, sorted(result.files)),
        "points": manifest["points"],
        "classes": manifest["classes"],
        "pulses": manifest["pulses"]["emitted"],
        "seconds": round(seconds, 3),
        "tiles": tile_records,
    }
    files.write_record(root, scene.name, record)
    return record


_SETUP: dict = {}   # this worker's plot in memory: {(scene file, its SHA-256): (scene, plan, models)}


def _plot_setup(path, first_leg: int = 0):
    """The plot's scene, plan and models, kept for the next leg tasks of the same plot (one plot at a
    time: a new plot replaces the last). The plot is its scene file's path and content, as for its
    records (a file rewritten with other content may keep its time stamp: a file system that stamps
    whole seconds, ``cp -p``). A worker setting it up for a later leg than the first builds
    the models in an order of its own (drawn with the leg's number), so that workers setting up one plot
    at once seldom build the same model together: each reads from the cache what another has stored.
    (Walking the list from points spread along it was tried: a worker that caught up with another then
    built each model beside it.)"""
    key = (str(path), files.sha256(path))
    if key not in _SETUP:
        _SETUP.clear()
        from ..config import load_scene
        from ..survey import make_plan
        from ..scene import scene_variant
        from ..trees import build_models
        scene = load_scene(path)
        scene_variant(scene)
        plan = make_plan(scene)
        order = seeds.rng(first_leg, "model-order").permutation(len(plan.models)) if first_leg else None
        _SETUP[key] = (scene, plan, build_models(plan, order=order))
    return _SETUP[key]
