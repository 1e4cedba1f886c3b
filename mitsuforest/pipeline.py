"""The whole pipeline: plan → trees → scene → scan → labels → write, as the composition of
:func:`~mitsuforest.survey.prepare`, :func:`~mitsuforest.survey.scan` and :func:`~mitsuforest.survey.write`.

>>> result = render("scenes/demo.yaml", output_dir="out/demo")   # doctest: +SKIP
>>> result.manifest["points"], [f.name for f in result.files]    # doctest: +SKIP
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .config import Scene, load_scene, scene_from_mapping
from .errors import UserError
from .plan import Plan
from .scan import read_ahead_variable
from .scene import scene_variant
from .survey import Batches, PreparedSurvey, prepare, scan, write as write_survey
from .threads import writer_threads
from .trees.cache import cache_limit
from .trees.parallel import build_processes
from .write import Staging, check_output_folder, earlier_results, output_lock
from .write.processes import start_processes, writer_processes


@dataclass
class RenderResult:
    scene: Scene
    plan: Plan
    manifest: dict
    points: np.ndarray | None = None   # georeferenced, float64 coordinates (when kept)
    files: list[Path] = field(default_factory=list)


def render(scene, *, output_dir=None, seed=None, variant=None, overwrite=False, progress=True,
           write=True, keep_points=None, log=print) -> RenderResult:
    """Render a scene: a file (path), a loaded :class:`~mitsuforest.config.types.Scene`, a mapping of
    the scene file's form (validated like the file), or a :class:`~mitsuforest.survey.PreparedSurvey`
    (a HELIOS++ survey's, see :mod:`mitsuforest.helios.render`).

    :param seed, variant, output_dir: overrides, as on the command line (not for a prepared survey).
    :param write: write the output files (see README, Outputs) into ``output.dir``. The folder is
        checked before any work and locked while the files are written: a second render of the same
        scene into it is refused, and earlier results are replaced only with ``overwrite``.
    :param keep_points: also return every point in memory; by default only when not writing.
    """
    prepared = scene if isinstance(scene, PreparedSurvey) else None
    if prepared is not None:
        if (seed, variant, output_dir) != (None, None, None):
            raise TypeError("a prepared survey is rendered as it was prepared (no seed, variant or output_dir)")
        scene = prepared.scene
    else:
        scene = _as_scene(scene, seed=seed, variant=variant, output_dir=output_dir)
        scene_variant(scene)    # before any work, naming the scene file
    keep_points = (not write) if keep_points is None else keep_points
    if write:
        check_output(scene, overwrite)
        start_processes(scene, keep_points)
    else:
        check_variables()
    prepared = prepared or prepare(scene, log=log, progress=progress)
    batches = scan(prepared, progress=progress)
    if write:
        result = write_files(prepared, batches, overwrite=overwrite, keep_points=keep_points)
    else:
        written = write_survey(prepared, batches, None, keep_points=keep_points)
        result = RenderResult(scene, prepared.plan, written.manifest, written.points)
    counts, manifest = batches.result, result.manifest
    log(f"scan: {counts.pulses_cast:,} pulses cast in {counts.seconds:.1f} s "
        f"({counts.pulses_cast / max(counts.seconds, 1e-9):,.0f} pulses/s), {manifest['points']:,} points, "
        f"{manifest['density_per_m2']:.0f} points/m2 over the plot ({scene.area.size[0]:g} x {scene.area.size[1]:g} m)")
    return result


def check_output(scene: Scene, overwrite: bool) -> None:
    """Refuse, before any work, a bad variable (:func:`check_variables`), an output folder that cannot
    be written, or one holding results of the scene when not ``overwrite``."""
    check_variables()
    out = Path(scene.output.dir)
    check_output_folder(out)
    _refuse_existing(out, scene.name, overwrite)


def check_variables() -> None:
    """Refuse a bad ``MITSUFOREST_WRITER_THREADS``, ``MITSUFOREST_WRITER_PROCESSES``,
    ``MITSUFOREST_READ_AHEAD``, ``MITSUFOREST_CACHE_SIZE`` or ``MITSUFOREST_BUILD_PROCESSES`` (one line
    naming it, see :class:`~mitsuforest.errors.UserError`)."""
    writer_threads()
    writer_processes()
    read_ahead_variable()
    cache_limit()
    build_processes()


def write_files(prepared: PreparedSurvey, batches: Batches, *, overwrite: bool = False,
                keep_points: bool = False) -> RenderResult:
    """Write the files of a prepared survey's ``batches`` into its ``output.dir``: the folder locked,
    every file staged and moved into place only when all are complete, the manifest last; on any
    failure or interrupt the staging folder is removed."""
    scene = prepared.scene
    out, name = Path(scene.output.dir), scene.name
    check_output(scene, overwrite)
    written = []

    def write_all() -> None:
        written.append(write_survey(prepared, batches, staging, keep_points=keep_points))
        _refuse_existing(out, name, overwrite)   # results that appeared meanwhile

    with output_lock(out, name):
        staging = Staging(out, name)
        files = staging.commit_or_discard(write_all, replaced=None)
    return RenderResult(scene, prepared.plan, written[0].manifest, written[0].points, files)


def _refuse_existing(out: Path, name: str, overwrite: bool) -> None:
    found = earlier_results(out, name)
    if found and not overwrite:
        raise UserError(f"{out} already holds results of '{name}' ({', '.join(found[:3])}, ...);"
                        " pass --overwrite to replace them")


def _as_scene(scene, seed, variant, output_dir) -> Scene:
    if not isinstance(scene, (Scene, Mapping)):
        return load_scene(scene, seed=seed, variant=variant, output_dir=output_dir)
    if isinstance(scene, Mapping):
        scene = scene_from_mapping(dict(scene))
    changes = {"seed": seed, "simulation.variant": variant,
               "output.dir": output_dir and str(Path(output_dir).resolve())}
    changes = {k: v for k, v in changes.items() if v is not None}
    return scene.with_(changes) if changes else scene
