"""A survey prepared once, and the two steps that use it: scan its legs, write its files.

>>> prepared = prepare(load_scene("scenes/demo.yaml"))          # doctest: +SKIP
>>> written = write(prepared, scan(prepared), staging)          # doctest: +SKIP

:func:`prepare` makes the plan, builds the models and loads the Mitsuba scene (stages plan → trees →
scene); :func:`scan` flies legs of it, batch by batch (scan, labels); :func:`write` turns batches into
every output file (write). :func:`mitsuforest.pipeline.render` is their composition. A dataset's leg
task prepares only the objects in reach of its own legs and scans them; its merge writes the batches
the leg tasks saved, in leg order: the same bytes as one render.
"""

from __future__ import annotations

import functools
import importlib.metadata
import platform
import time
from collections.abc import Callable, Generator, Iterator
from contextlib import ExitStack, closing, nullcontext
from dataclasses import dataclass

import numpy as np

from . import __version__
from .config import Scene
from .plan import Plan, plan_scene
from .labels import label_points
from .realism import realism_table
from .scan import ScanResult, scan_batches
from .scene import HitTable, ScanScene, build_scene
from .threads import note_native_threads, refuse_forked_render
from .trees import build_models, tree_shapes
from .write.manifest import import_report
from .write import PointWriter, Staging, write_manifest, write_render_outputs
from .write.background import Background
from .write.output_profiles import stem_ids
from .write.waveforms import PulseRecordWriter

__all__ = ["make_plan", "PreparedSurvey", "Batches", "Written", "Timings", "prepare", "prepare_plan", "scan", "write", "versions"]

DEPENDENCIES = ("mitsuba", "drjit", "numpy", "trimesh", "manifold3d", "laspy", "scipy", "pyyaml", "pyproj", "rasterio",
                "matplotlib")


def _quiet(*_) -> None:
    pass


class Timings(dict):
    """Seconds per stage, each from the end of the previous one."""

    def __init__(self, *args):
        super().__init__(*args)
        self._clock = time.perf_counter()

    def lap(self, stage: str) -> None:
        now = time.perf_counter()
        self[stage] = round(now - self._clock, 3)
        self._clock = now


@dataclass
class PreparedSurvey:
    """A scene with its plan, its models and the Mitsuba scene of the objects in reach of ``legs``."""

    scene: Scene
    plan: Plan
    models: dict              # model name -> trees.models.Model
    scan_scene: ScanScene     # counts, box and triangles those of the whole survey (see build_scene)
    legs: range               # the legs it can scan (indices into plan.legs)
    timings: dict             # seconds of plan, trees and scene


@dataclass
class Batches:
    """Labelled points, batch by batch in the survey's order (POINT_DTYPE, local frame), and the counts of the
    scan that made them: complete once the batches are exhausted. With ``output.waveforms`` or
    ``output.pulses``, each batch's pulses (:class:`~mitsuforest.scan.waveform.PulseBatch`) go to
    ``on_pulses`` (set by :func:`write`; dropped while None)."""

    points: Iterator[np.ndarray]
    result: ScanResult
    on_pulses: Callable | None = None

    def _pulses(self, records) -> None:
        if self.on_pulses is not None:
            self.on_pulses(records)

    def __iter__(self) -> Iterator[np.ndarray]:
        return self.points

    def close(self) -> None:
        """Stop the scan behind the batches if they have not run out (its device thread stops after the
        batch it is tracing)."""
        close = getattr(self.points, "close", None)
        if close is not None:
            close()


@dataclass
class Written:
    """What :func:`write` made: the manifest and, when asked for, every point (local frame)."""

    manifest: dict
    points: np.ndarray | None


def make_plan(scene: Scene, progress: bool = False) -> Plan:
    """The plan of ``scene`` (:func:`~mitsuforest.plan.plan_scene`), its trees' crowns and components from
    the trees stage (:func:`~mitsuforest.trees.tree_shapes`); with ``progress``, a bar of the crowns had
    where that takes more than a second (a long tree list's, grown anew)."""
    if not progress:
        return plan_scene(scene, tree_shapes)
    with _slow_work_bar("crowns") as bar:
        return plan_scene(scene, functools.partial(tree_shapes, progress=bar.update))


def placed_summary(plan: Plan) -> str:
    """``12 trees``; for a HELIOS++ survey, whose objects are its parts and none a tree, ``40 HELIOS++ parts``."""
    parts = sum(o.kind == "helios_part" for o in plan.objects)
    if parts and not plan.trees:
        return f"{parts} HELIOS++ part{'s' * (parts != 1)}"
    return f"{len(plan.trees)} trees"


def prepare(scene: Scene, legs: range | None = None, *, log=_quiet, progress: bool = False) -> PreparedSurvey:
    """Plan ``scene``, build its models and load into Mitsuba the objects in reach of ``legs``.

    :param legs: the legs to be scanned (indices into the plan's legs; all by default). A survey
        prepared for some legs loads only the objects in their reach, and scans them into the same
        points as a survey prepared for all; ``range(0)`` loads the ground alone (for writing batches
        scanned elsewhere).
    :param log: called with a line on the plan and one on the Mitsuba scene.
    :param progress: a bar of the models built, where that takes more than a second.
    """
    refuse_forked_render()
    timings = Timings()
    plan = make_plan(scene, progress)
    timings.lap("plan")
    models = _built_models(plan, progress)
    timings.lap("trees")
    return _load(scene, plan, models, legs, None, timings, log)


def _built_models(plan: Plan, progress: bool) -> dict:
    if not progress:
        return build_models(plan)
    with _slow_work_bar("models", len(plan.models)) as bar:
        return build_models(plan, progress=lambda name: bar.update())


def _slow_work_bar(what: str, total: int | None = None):
    """A progress bar of ``what`` (crowns, models) that shows only once the work has taken a second."""
    from tqdm import tqdm
    return tqdm(total=total, desc=what, unit=f" {what}", leave=False, delay=1.0, dynamic_ncols=True)


def prepare_plan(scene: Scene, plan: Plan, models: dict, legs: range | None = None, *,
                 reflectance: np.ndarray | None = None, log=_quiet) -> PreparedSurvey:
    """:func:`prepare` for a plan and models made elsewhere (a HELIOS++ survey's parts, a dataset
    worker's plot kept between its leg tasks).

    :param reflectance: (256,) reflectance by class; None: ours at the sensor's wavelength.
    """
    refuse_forked_render()
    timings = Timings({"plan": 0.0, "trees": 0.0})
    return _load(scene, plan, models, legs, reflectance, timings, log)


def _load(scene, plan, models, legs, reflectance, timings, log) -> PreparedSurvey:
    legs = range(len(plan.legs)) if legs is None else legs
    if legs.step != 1 or not (0 <= legs.start <= legs.stop <= len(plan.legs)):
        raise ValueError(f"legs {legs} are not consecutive legs of the plan's {len(plan.legs)}")
    log(f"plan: {placed_summary(plan)}, canopy cover {plan.canopy_cover:.1%}, {len(plan.objects)} objects, "
        f"{len(plan.legs)} legs")
    note_native_threads()
    scan_scene = build_scene(plan, models, scene.sensor, scene.simulation.variant,
                             None if len(legs) == len(plan.legs) else legs, reflectance, scene.survey.attitude)
    timings.lap("scene")
    log(f"scene: {scan_scene.objects} objects ({scan_scene.culled} out of reach), "
        f"{scan_scene.triangles:,} distinct triangles, variant {scan_scene.variant}")
    return PreparedSurvey(scene, plan, models, scan_scene, legs, dict(timings))


def scan(prepared: PreparedSurvey, legs: range | None = None, *, progress: bool = False) -> Batches:
    """Fly ``legs`` (all the prepared legs by default) of a prepared survey: the batches of consecutive
    leg ranges, concatenated in order, are those of the whole survey, byte for byte. The scan runs as
    the batches are taken."""
    legs = prepared.legs if legs is None else legs
    if len(legs) and (legs.step != 1 or legs.start < prepared.legs.start or legs.stop > prepared.legs.stop):
        raise ValueError(f"legs {legs} were not prepared (the survey holds the objects in reach of {prepared.legs})")
    refuse_forked_render()
    result = ScanResult()
    batches = Batches(iter(()), result)
    records = prepared.scene.output.waveforms or prepared.scene.output.pulses
    scanned = scan_batches(prepared.scene, prepared.plan, prepared.scan_scene, result, progress, legs,
                           batches._pulses if records else None)
    batches.points = _labelled(scanned, prepared.scan_scene.table)
    return batches


def _labelled(scanned: Generator[tuple[np.ndarray, np.ndarray], None, None], table: HitTable) -> Iterator[np.ndarray]:
    """The scan's batches (points, hits), each batch's points labelled (stage labels)."""
    with closing(scanned):
        for points, hits in scanned:
            label_points(points, hits, table)
            yield points


def write(prepared: PreparedSurvey, batches: Batches, staging: Staging | None, *, keep_points: bool = False) -> Written:
    """Write every output file of ``batches`` (the whole survey's, in order) into ``staging``, the
    manifest last; with ``staging`` None, write nothing but count and keep points as asked.

    Each batch is handed to a writer thread as it comes, so writing overlaps scanning. On failure the
    point files are abandoned and the exception raised; the caller discards the staging folder.
    """
    scene, plan, models = prepared.scene, prepared.plan, prepared.models
    timings = Timings(prepared.timings)
    with_records = bool(staging) and (scene.output.waveforms or scene.output.pulses)
    with (PointWriter(staging, scene, keep=keep_points, terrain=plan.terrain, stems=stem_ids(plan, models),
                      warm_pictures=bool(staging) and scene.output.pictures and scans_off_host(prepared)) as writer,
          PulseRecordWriter(staging, scene) if with_records else nullcontext() as records):
        sinks = [Background(writer.add)]
        if records:
            sinks.append(Background(records.add))
            batches.on_pulses = sinks[1]
        _drain(batches, sinks)
    timings.lap("scan")
    manifest = _manifest(prepared, batches.result, writer.statistics(), timings)
    if records:
        manifest.update(records.statistics())
    manifest["imported_trees"] = import_report(plan, models)
    manifest["realism"] = realism_table(plan, models, writer.classes, writer.counts)
    if staging:
        write_render_outputs(staging, scene=scene, plan=plan, models=models, writer=writer)
        timings.lap("write")
        manifest["timings_s"] = dict(timings)
        write_manifest(staging, manifest)
    return Written(manifest, writer.points)


def scans_off_host(prepared: PreparedSurvey) -> bool:
    """Whether the survey's scan runs on a GPU, leaving the host's cores mostly idle: there the writer's
    workers ready themselves to draw the pictures while the points come; on a CPU that would take from
    the scan what it gives back at the end (0.5 CPU s a worker)."""
    return prepared.scan_scene.variant.startswith("cuda")


def _drain(batches: Batches, sinks: list[Background]) -> None:
    """Each batch to the first sink (the points' writer); every sink closed in order, and the scan
    stopped, even on failure."""
    with ExitStack() as stack:
        for sink in reversed(sinks):
            stack.callback(sink.close)
        stack.callback(batches.close)
        for points in batches:
            sinks[0](points)


def versions() -> dict:
    """The versions of mitsuforest, Python and the libraries it runs on (None: not installed), read once
    per process (a dataset worker writes them into every plot's manifest)."""
    return dict(_versions())


@functools.cache
def _versions() -> dict:
    out = {"mitsuforest": __version__, "python": platform.python_version()}
    for dist in DEPENDENCIES:
        try:
            out[dist] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            out[dist] = None
    return out


def _manifest(prepared: PreparedSurvey, result: ScanResult, stats: dict, timings: dict) -> dict:
    scene, plan, scan_scene = prepared.scene, prepared.plan, prepared.scan_scene
    return {
        "versions": versions(),
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
