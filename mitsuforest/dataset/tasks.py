"""What the workers run: a whole plot, a range of one plot's flight legs, or the merge of a plot's legs.

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

import numpy as np

from . import files

PARTS = ".parts"   # a split plot's per-leg point files, until the merge


def _quiet(*_):
    pass


def set_threads(threads: int | None) -> None:
    """Limit this worker process's Dr.Jit thread pool (LocalCluster: cores / workers), and its point
    writer's threads unless ``MITSUFOREST_WRITER_THREADS`` says otherwise."""
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


def scan_legs(root: str, name: str, first: int, stop: int, threads: int | None = None) -> dict:
    """Scan legs ``first .. stop-1`` of a plot into ``DIR/plots/NAME/.parts/``: the points of each batch
    appended to one file, the batch sizes and pulse counts in a JSON beside it (written last). Only the
    objects in reach of these legs are loaded. A part already there is reused."""
    part = _part_path(root, name, first, stop)
    scene_sha = files.sha256(files.scene_file(root, name))
    done = _read_part(part, scene_sha)
    if done is not None:
        return done
    started = time.perf_counter()
    set_threads(threads)
    from ..survey import prepare_plan, scan
    prepared = prepare_plan(*_plot_setup(files.scene_file(root, name)), legs=range(first, stop))
    part.parent.mkdir(parents=True, exist_ok=True)
    batches = scan(prepared)
    sizes = []
    with files.atomic_path(part.with_suffix(".points")) as tmp, open(tmp, "wb") as f:
        for points in batches:
            sizes.append(len(points))
            f.write(np.ascontiguousarray(points).data)
    result, scan_scene = batches.result, prepared.scan_scene
    info = {"first": first, "stop": stop, "scene_sha256": scene_sha, "batches": sizes, "points": part.with_suffix(".points").name,
            "emitted": result.pulses_emitted, "fired": result.pulses_fired, "cast": result.pulses_cast,
            "rays": result.rays, "seconds": result.seconds, "task_seconds": time.perf_counter() - started,
            "scene": {"objects": scan_scene.objects, "culled": scan_scene.culled, "loaded": scan_scene.loaded,
                      "triangles": scan_scene.triangles, "variant": scan_scene.variant}}
    files.write_json(part, info)
    return info


def merge_plot(root: str, name: str, parts: list[dict], tiles=None, threads: int | None = None) -> dict:
    """Write a split plot's files from its parts, in leg order, through the render's own writer: the
    same bytes as a render of the whole plot in one process. Then tiles and record; the parts go."""
    set_threads(threads)
    from ..config import load_scene
    from ..pipeline import write_files
    from ..survey import prepare
    start = time.perf_counter()
    files.remove_record(root, name)
    parts = sorted(parts, key=lambda p: p["first"])
    scene = load_scene(files.scene_file(root, name), output_dir=files.plot_folder(root, name))
    prepared = prepare(scene, legs=range(0))     # plan and models for the tables; no object loaded
    result = write_files(prepared, part_batches(files.plot_folder(root, name) / PARTS, parts), overwrite=True)
    merge = time.perf_counter() - start
    legs = [{"legs": [p["first"], p["stop"]], "pulses": p["emitted"], "points": sum(p["batches"]),
             "scan_seconds": round(p["seconds"], 3), "task_seconds": round(p.get("task_seconds", p["seconds"]), 3)}
            for p in parts]
    record = _finish(root, result, tiles, merge + sum(p["task_seconds"] for p in legs),
                     {"leg_tasks": legs, "merge_seconds": round(merge, 3)})
    shutil.rmtree(files.plot_folder(root, name) / PARTS, ignore_errors=True)
    return record


def part_batches(folder: Path, parts: list[dict]):
    """The batches of a plot's parts (:func:`scan_legs`' records, in leg order) read back from
    ``folder``, with their summed counts: the survey's batches as one scan would give them."""
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
    from ..scan import POINT_DTYPE
    for part in parts:
        data = np.fromfile(folder / part["points"], POINT_DTYPE)
        starts = np.concatenate([[0], np.cumsum(part["batches"])])
        for a, b in zip(starts[:-1], starts[1:]):
            yield data[a:b]


def _finish(root, result, tiles, seconds: float, extra: dict | None = None) -> dict:
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
        **(extra or {}),
    }
    files.write_record(root, scene.name, record)
    return record


def _part_path(root, name: str, first: int, stop: int) -> Path:
    return files.plot_folder(root, name) / PARTS / f"legs-{first:05d}-{stop:05d}.json"


def _read_part(path: Path, scene_sha: str) -> dict | None:
    """A finished part of the same scene (its points file complete), else None."""
    try:
        info = json.loads(path.read_text())
        size = (path.parent / info["points"]).stat().st_size
    except (OSError, ValueError, KeyError):
        return None
    from ..scan import POINT_DTYPE
    complete = size == sum(info["batches"]) * POINT_DTYPE.itemsize
    return info if complete and info.get("scene_sha256") == scene_sha else None


_SETUP: dict = {}   # this worker's plot in memory: {scene file: (scene, plan, models)}


def _plot_setup(path):
    """The plot's scene, plan and models, kept for the next leg tasks of the same plot (one plot at a
    time: a new plot replaces the last)."""
    key = (str(path), os.stat(path).st_mtime_ns)
    if key not in _SETUP:
        _SETUP.clear()
        from ..config import load_scene
        from ..survey import make_plan
        from ..scene import scene_variant
        from ..trees import build_models
        scene = load_scene(path)
        scene_variant(scene)
        plan = make_plan(scene)
        _SETUP[key] = (scene, plan, build_models(plan))
    return _SETUP[key]
