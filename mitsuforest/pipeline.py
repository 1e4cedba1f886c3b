"""The whole pipeline: plan → trees → scene → scan → labels → write.

>>> result = render("scenes/demo.yaml", output_dir="out/demo")   # doctest: +SKIP
>>> result.manifest["points"], [f.name for f in result.files]    # doctest: +SKIP
"""

from __future__ import annotations

import importlib.metadata
import platform
import time
from collections.abc import Mapping
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import __version__
from .config import Scene, load_scene, scene_from_mapping
from .errors import UserError
from .interrupts import InterruptedAfterCommit, Terminated, deferred_signals
from .plan import Plan, make_plan
from .realism import realism_table
from .scan import scan
from .scene import build_scene, scene_variant
from .threads import writer_threads
from .trees import build_models
from .trees.imported import import_report
from .write import (PointWriter, Staging, check_output_folder, earlier_results, output_lock, write_manifest,
                    write_render_outputs)
from .write.background import Background
from .write.output_profiles import stem_ids
from .write.waveforms import PulseRecordWriter

DEPENDENCIES = ("mitsuba", "drjit", "numpy", "trimesh", "manifold3d", "laspy", "scipy", "pyyaml", "pyproj", "rasterio",
                "matplotlib")


@dataclass
class RenderResult:
    scene: Scene
    plan: Plan
    manifest: dict
    points: np.ndarray | None = None   # georeferenced, float64 coordinates (when kept)
    files: list[Path] = field(default_factory=list)


def render(scene, *, output_dir=None, seed=None, variant=None, overwrite=False, progress=True,
           write=True, keep_points=None, log=print, plan=None, models=None, reflectance=None,
           scan_source=None) -> RenderResult:
    """Render a scene: a file (path), a loaded :class:`~mitsuforest.config.types.Scene`, or a mapping of
    the scene file's form (validated like the file).

    :param seed, variant, output_dir: overrides, as on the command line.
    :param write: write the output files (see README, Outputs) into ``output.dir``. The folder is
        checked before any work and locked while the files are written: a second render of the same
        scene into it is refused, and earlier results are replaced only with ``overwrite``.
    :param keep_points: also return every point in memory; by default only when not writing.
    :param plan, models, reflectance: a plan and its models made elsewhere (a HELIOS++ survey's, see
        :mod:`mitsuforest.helios.render`) instead of the scene's, and their (256,) reflectance by class.
    :param scan_source: points scanned elsewhere instead of a scan here (the dataset's legs scanned on
        other workers): a callable ``(on_points) -> ScanResult`` that feeds the survey's batches in
        order, with the scene's ``objects``, ``culled``, ``triangles`` and ``variant`` as attributes.
        The files are then the same bytes as a render that scans itself.
    """
    scene = _as_scene(scene, seed=seed, variant=variant, output_dir=output_dir)
    keep_points = (not write) if keep_points is None else keep_points
    name, out = scene.name, Path(scene.output.dir)
    if scan_source is None:
        scene_variant(scene)    # before any work, naming the scene file
    elif scene.output.waveforms or scene.output.pulses:
        key = "output.waveforms" if scene.output.waveforms else "output.pulses"
        raise UserError(f"{scene.file or '<scene>'}: {key}: needs the scan in this process (not a plot split "
                        "by legs across workers)")
    writer_threads()            # likewise a bad MITSUFOREST_WRITER_THREADS
    if write:
        check_output_folder(out)
        _refuse_existing(out, name, overwrite)
    timings = Timings()
    plan = plan or make_plan(scene)
    timings.lap("plan")
    log(f"plan: {placed_summary(plan)}, canopy cover {plan.canopy_cover:.1%}, {len(plan.objects)} objects, "
        f"{len(plan.legs)} legs")
    models = models or build_models(plan)
    timings.lap("trees")
    if scan_source is None:
        scan_scene = build_scene(plan, models, scene.sensor, scene.simulation.variant)
        scan_scene.reflectance = reflectance
    else:
        scan_scene = scan_source
    timings.lap("scene")
    log(f"scene: {scan_scene.objects} objects ({scan_scene.culled} out of reach), "
        f"{scan_scene.triangles:,} distinct triangles, variant {scan_scene.variant}")
    with output_lock(out, name) if write else nullcontext():
        staging = Staging(out, name) if write else None
        run_scan = scan_source or (lambda on_points, on_pulses=None: scan(
            scene, plan, scan_scene, progress=progress, on_points=on_points, on_pulses=on_pulses))
        result, manifest, writer, files = _scan_and_write(scene, plan, models, scan_scene, timings, run_scan,
                                                          keep_points, staging, overwrite)
    log(f"scan: {result.pulses_cast:,} pulses cast in {result.seconds:.1f} s "
        f"({result.pulses_cast / max(result.seconds, 1e-9):,.0f} pulses/s), {manifest['points']:,} points, "
        f"{manifest['density_per_m2']:.0f} points/m2 over the plot ({scene.area.size[0]:g} x {scene.area.size[1]:g} m)")
    return RenderResult(scene, plan, manifest, writer.points, files)


def placed_summary(plan) -> str:
    """``12 trees``; for a HELIOS++ survey, whose objects are its parts and none a tree, ``40 HELIOS++ parts``."""
    parts = sum(o.kind == "helios_part" for o in plan.objects)
    if parts and not plan.trees:
        return f"{parts} HELIOS++ part{'s' * (parts != 1)}"
    return f"{len(plan.trees)} trees"


class Timings(dict):
    """Seconds per stage, each from the end of the previous one."""

    def __init__(self):
        super().__init__()
        self._clock = time.perf_counter()

    def lap(self, stage: str) -> None:
        now = time.perf_counter()
        self[stage] = round(now - self._clock, 3)
        self._clock = now


def _refuse_existing(out: Path, name: str, overwrite: bool) -> None:
    found = earlier_results(out, name)
    if found and not overwrite:
        raise UserError(f"{out} already holds results of '{name}' ({', '.join(found[:3])}, ...);"
                        " pass --overwrite to replace them")


def _scan_and_write(scene, plan, models, scan_scene, timings, run_scan, keep_points, staging, overwrite):
    """Scan, streaming points to the writer, then write every file into ``staging`` and move them into
    place; on any failure or interrupt the staging folder is removed."""
    writer = records = None
    try:
        writer = PointWriter(staging, scene, keep=keep_points, terrain=plan.terrain, stems=stem_ids(plan, models))
        if staging and (scene.output.waveforms or scene.output.pulses):
            records = PulseRecordWriter(staging, scene)
        sink = Background(writer.add)
        pulse_sink = Background(records.add) if records else None
        try:
            result = run_scan(sink, pulse_sink) if pulse_sink else run_scan(sink)
        finally:
            try:
                sink.close()
            finally:
                if pulse_sink:
                    pulse_sink.close()
        writer.close()
        if records:
            records.close()
        timings.lap("scan")
        manifest = _manifest(scene, plan, scan_scene, result, writer.statistics(), timings)
        if records:
            manifest.update(records.statistics())
        manifest["imported_trees"] = import_report(plan, models)
        manifest["realism"] = realism_table(plan, models, writer.classes, writer.counts)
        files = []
        if staging:
            write_render_outputs(staging, scene=scene, plan=plan, models=models, writer=writer)
            timings.lap("write")
            manifest["timings_s"] = dict(timings)
            write_manifest(staging, manifest)
            _refuse_existing(staging.folder, scene.name, overwrite)   # results that appeared meanwhile
            staging.sync()             # flushing to disk may take seconds: before signals are deferred
            try:
                with deferred_signals():   # never half the files in place
                    files = staging.commit()
            except KeyboardInterrupt as e:
                raise InterruptedAfterCommit(isinstance(e, Terminated)) from None
    except BaseException as e:
        if writer:
            writer.abort()
        if records:
            records.abort()
        if staging:
            staging.discard()
            if isinstance(e, OSError):
                raise staging.public_error(e) from e
        raise
    return result, manifest, writer, files


def _as_scene(scene, seed, variant, output_dir) -> Scene:
    if not isinstance(scene, (Scene, Mapping)):
        return load_scene(scene, seed=seed, variant=variant, output_dir=output_dir)
    if isinstance(scene, Mapping):
        scene = scene_from_mapping(dict(scene))
    changes = {"seed": seed, "simulation.variant": variant,
               "output.dir": output_dir and str(Path(output_dir).resolve())}
    changes = {k: v for k, v in changes.items() if v is not None}
    return scene.with_(changes) if changes else scene


def _versions() -> dict:
    out = {"mitsuforest": __version__, "python": platform.python_version()}
    for dist in DEPENDENCIES:
        try:
            out[dist] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            out[dist] = None
    return out


def _manifest(scene, plan, scan_scene, result, stats, timings) -> dict:
    return {
        "versions": _versions(),
        "scene": scene.describe(),
        "seed": scene.seed,
        "variant": scan_scene.variant,
        "machine": {"platform": platform.platform(), "processor": platform.processor()},
        "timings_s": dict(timings),
        "canopy_cover": plan.canopy_cover,
        "scene_objects": {"modelled": scan_scene.objects, "culled": scan_scene.culled,
                          "distinct_triangles": scan_scene.triangles},
        "pulses": {"emitted": result.pulses_emitted, "fired": result.pulses_fired, "cast": result.pulses_cast,
                   "rays": result.rays},
        **stats,
    }
