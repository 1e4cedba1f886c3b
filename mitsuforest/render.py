"""The whole pipeline: plan → trees → scene → scan → labels → write.

>>> result = render("scenes/demo.yaml", output_dir="out/demo")   # doctest: +SKIP
>>> result.manifest["points"], [f.name for f in result.files]    # doctest: +SKIP
"""

from __future__ import annotations

import importlib.metadata
import platform
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import __version__
from .config import Scene, load_scene, scene_from_mapping
from .errors import UserError
from .plan import Plan, make_plan
from .scan import scan
from .scene import build_scene
from .trees import build_models
from .write import PointWriter, Staging, existing_outputs, write_manifest, write_render_outputs
from .write.background import Background

DEPENDENCIES = ("mitsuba", "drjit", "numpy", "trimesh", "manifold3d", "laspy", "scipy", "pyyaml", "pyproj")


@dataclass
class RenderResult:
    scene: Scene
    plan: Plan
    manifest: dict
    points: np.ndarray | None = None   # georeferenced, float64 coordinates (when kept)
    files: list[Path] = field(default_factory=list)


def render(scene, *, output_dir=None, seed=None, variant=None, overwrite=False, progress=True,
           write=True, keep_points=None, log=print) -> RenderResult:
    """Render a scene: a file (path), a loaded :class:`~mitsuforest.config.types.Scene`, or a mapping of
    the scene file's form (validated like the file).

    :param seed, variant, output_dir: overrides, as on the command line.
    :param write: write the output files (see README, Outputs) into ``output.dir``.
    :param keep_points: also return every point in memory; by default only when not writing.
    """
    scene = _as_scene(scene, seed=seed, variant=variant, output_dir=output_dir)
    keep_points = (not write) if keep_points is None else keep_points
    name, out = scene.name, Path(scene.output.dir)
    if write and not overwrite and existing_outputs(out, name):
        raise UserError(f"{out} already holds results of '{name}' ({', '.join(existing_outputs(out, name)[:3])}, ...);"
                        " pass --overwrite to replace them")
    timings = {}
    clock = time.perf_counter()

    def lap(stage):
        nonlocal clock
        now = time.perf_counter()
        timings[stage] = round(now - clock, 3)
        clock = now

    plan = make_plan(scene)
    lap("plan")
    log(f"plan: {len(plan.trees)} trees, canopy cover {plan.canopy_cover:.1%}, {len(plan.objects)} objects, "
        f"{len(plan.legs)} legs")
    models = build_models(plan)
    lap("trees")
    scan_scene = build_scene(plan, models, scene.sensor, scene.simulation.variant)
    lap("scene")
    log(f"scene: {scan_scene.objects} objects ({scan_scene.culled} out of reach), "
        f"{scan_scene.triangles:,} distinct triangles, variant {scan_scene.variant}")
    staging = Staging(out, name) if write else None
    writer = None
    try:
        writer = PointWriter(staging, scene, keep=keep_points)
        sink = Background(writer.add)
        try:
            result = scan(scene, plan, scan_scene, progress=progress, on_points=sink)
        finally:
            sink.close()
        writer.close()
        lap("scan")
        stats = writer.statistics()
        manifest = _manifest(scene, plan, scan_scene, result, stats, timings)
        files = []
        if write:
            write_render_outputs(staging, scene=scene, plan=plan, models=models, writer=writer)
            lap("write")
            manifest["timings_s"] = dict(timings)
            write_manifest(staging, manifest)
            files = staging.commit()
    except BaseException:
        if writer:
            writer.abort()
        if staging:
            staging.discard()
        raise
    log(f"scan: {result.pulses_cast:,} pulses cast in {result.seconds:.1f} s "
        f"({result.pulses_cast / max(result.seconds, 1e-9):,.0f} pulses/s), {stats['points']:,} points, "
        f"{stats['density_per_m2']:.0f} points/m2")
    return RenderResult(scene, plan, manifest, writer.points, files)


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
