"""The ``mitsuforest`` command line: render, plan, trees, export, dataset, twin, info, compare.

User errors (bad files, bad values, refused overwrites, a busy or unwritable output folder) print
one line ``mitsuforest: ...`` and exit with code 2, without a traceback. A write that fails mid-run
(a full disk, say) prints ``mitsuforest: PATH: reason`` and exits with 1. Ctrl-C exits with 130 and
SIGTERM with 143; neither leaves finished-looking output. Run as a program, a signal while Python shuts
down after the command prints one line and exits with the same codes.
"""

from __future__ import annotations

import argparse
import errno
import gc
import os
import signal
import sys
from pathlib import Path

from . import __version__
from .errors import UserError
from .interrupts import (InterruptedAfterCommit, StoppedWithWorkKept, Terminated, deferred_signals, in_main_thread,
                         quiet_signals_until_exit, raise_terminated)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="mitsuforest", description="Labelled UAV LiDAR scans of synthetic forests.")
    p.add_argument("--version", action="version", version=f"mitsuforest {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add_subparser in _SUBPARSERS:
        add_subparser(sub)
    return p


def _add_render(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("render", help="plan, build, scan and write a scene",
                       description="Render a scene file: plan, trees, Mitsuba scene, scan, labelled outputs. "
                                   "A HELIOS++ survey (.xml) is flown over its scene parts, each part's id "
                                   "becoming its points' object_id.")
    p.add_argument("scene", type=_named("SCENE", "a file"), help="scene file (scenes/*.yaml) or HELIOS++ survey (.xml)")
    p.add_argument("--assets", type=_named("--assets", "a folder"), action="append", default=[],
                   help="HELIOS++ survey: a folder searched for relative paths, as helios++ --assets (repeatable)")
    p.add_argument("-o", "--output", type=_folder, help="output folder (default: the scene's output.dir)")
    p.add_argument("--variant", help="Mitsuba variant, e.g. llvm_ad_mono or cuda_ad_mono (default: scene's, auto)")
    p.add_argument("--seed", type=int, help="override the scene's seed")
    p.add_argument("--overwrite", action="store_true", help="replace earlier results in the output folder")
    p.add_argument("--quiet", action="store_true", help="no progress bars or summaries")


def _add_plan(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plan", help="write the placement plan only",
                       description="Place trees and understory, measure canopy cover, write <name>_plan.json. "
                                   "A folder holding a finished render of the scene is refused: "
                                   "its plan is the render's.")
    p.add_argument("scene", type=_named("SCENE", "a file"), help="scene file")
    p.add_argument("-o", "--output", type=_folder, help="output folder (default: the scene's output.dir)")
    p.add_argument("--seed", type=int, help="override the scene's seed")


def _add_trees(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("trees", help="write the tree archetypes' meshes, volumes and a picture",
                       description="Write each archetype's and imported model's wood and leaf meshes (PLY), "
                                   "volumes.csv, trees.png and (for imported meshes) repairs.csv.")
    p.add_argument("-o", "--output", type=_folder, default=Path("out/trees"), help="output folder (default: out/trees)")
    p.add_argument("--scene", type=_named("--scene", "a file"), help="take the archetypes and forest.models from this scene file (default: the built-in ten)")


def _add_export(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export", help="write the planned scene as meshes and a HELIOS++ survey that runs as it is",
                       description="Write each model's components (OBJ, with materials), the ground, "
                                   "<name>_transforms.csv, <name>_helios_parts.csv and the HELIOS++ scene, survey, "
                                   "platform and scanner (one part per component, id = object_id): "
                                   "helios++ OUTPUT/<name>_helios_survey.xml flies our survey.")
    p.add_argument("scene", type=_named("SCENE", "a file"), help="scene file")
    p.add_argument("-o", "--output", type=_folder, required=True, help="output folder")
    p.add_argument("--seed", type=int, help="override the scene's seed")


def _add_dataset(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("dataset", help="render many plots (or large ones split by leg) on Dask",
                       description="Render every plot of a dataset file on Dask (an embedded LocalCluster, or "
                                   "--scheduler), with tiles, index.csv, splits.json and dataset_manifest.json. "
                                   "Finished plots are kept; run again to finish an interrupted dataset.")
    p.add_argument("dataset", type=_named("DATASET", "a file"), help="dataset file (examples/dataset.yaml)")
    p.add_argument("-o", "--output", type=_folder, help="output folder (default: out/<dataset name>)")
    p.add_argument("--workers", type=int, help="worker processes of the embedded LocalCluster (default: one per core)")
    p.add_argument("--scheduler", help="address of a running Dask scheduler, e.g. tcp://HOST:8786")
    p.add_argument("--threads", type=int, help="Dr.Jit threads per worker (default: cores / workers locally, "
                                               "all cores of each machine with --scheduler)")
    p.add_argument("--quiet", action="store_true", help="no progress bars or summary")


def _add_twin(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("twin", help="write a scene that reproduces a real scan",
                       description="Write DIR/<name>.yaml (renderable as it is), its DEM GeoTIFF, trees.csv and "
                                   "twin.json from a real scan (LAS, LAZ or PCD): ground, trees on a canopy height "
                                   "model, understory and the survey estimated from the points.")
    p.add_argument("file", type=_named("REAL", "a file"), help="a .las, .laz or .pcd scan (ours or another tool's)")
    p.add_argument("-o", "--output", type=_folder, required=True, help="output folder")
    p.add_argument("--species", nargs="+", default=[], metavar="NAME",
                   help="procedural species of the trees, drawn in turn (default: pinus_radiata)")
    p.add_argument("--sensor", type=_named("--sensor", "a sensor"),
                   help="a built-in sensor's name (leica_als50-ii) or a sensor file, used instead of the estimated sensor")
    p.add_argument("--name", help="the scene's name (default: the file's name less .las, .laz, .copc.laz or .pcd)")
    p.add_argument("--calibrate", type=int, default=0, metavar="N",
                   help="render the twin up to N times, rescaling its crowns' leaf area, width and depth towards the "
                        "real scan's echoes per pulse (or gap fraction), canopy cover and canopy spread after each "
                        "(default 0: no renders)")
    p.add_argument("--variant", help="Mitsuba variant of the calibration renders (default: auto)")


def _add_info(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("info", help="summarise a point file", description="Summarise a PCD, LAS or LAZ file.")
    p.add_argument("file", type=_named("FILE", "a file"), help="a .pcd, .las or .laz file")


def _add_compare(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("compare", help="compare two point files: a table, compare.json and compare.png",
                       description="Two point files (PCD, LAS or LAZ; ours or another tool's) side by side: "
                                   "density, spacing, returns, heights above the ground, canopy, ground share, "
                                   "intensity and scan angles, and the distances between them (see README, "
                                   "\"Comparing scans\"). The table goes to stdout, compare.json and "
                                   "compare.png to the output folder.")
    p.add_argument("a", type=_named("A", "a file"), help="the first point file (A; a real scan, say)")
    p.add_argument("b", type=_named("B", "a file"), help="the second point file (B; distances are B against A)")
    p.add_argument("-o", "--output", type=_folder, default=Path("out/compare"),
                   help="output folder (default: out/compare)")
    p.add_argument("--within-a", action="store_true",
                   help="measure B only in the 1 m cells that hold a point of A: a render with the stand around "
                        "its plot, or of a circular clip's twin, where the real clip is")


_SUBPARSERS = (_add_render, _add_plan, _add_trees, _add_export, _add_dataset, _add_twin, _add_info, _add_compare)


def _named(argument: str, what: str, hint: str = ""):
    """A path argument's type: an empty one is refused, naming ``argument`` (``Path("")`` would be the
    working folder, and a message about it would name ".")."""
    def parse(text: str) -> Path:
        if not text:
            raise UserError(f"{argument}: must name {what}, got an empty path{hint}")
        if _too_long(text):       # else an OSError mid-command: exit 1, the whole path echoed
            shown = text if len(text) <= 80 else text[:80] + "..."
            raise UserError(f"{argument}: {shown}: path too long for the file system ({len(text):,} characters)")
        return Path(text)
    return parse


def _too_long(text: str) -> bool:
    """Whether the file system cannot hold the path ``text``: stat says so (a name of more than NAME_MAX
    bytes, or a path of more than PATH_MAX), or a name in it under a folder still to be made (an output
    folder's) is longer than the nearest existing folder's file system allows."""
    try:
        os.stat(text)
    except OSError as e:
        if e.errno == errno.ENAMETOOLONG:
            return True
    except ValueError:        # a NUL byte: the command says what it says of such a path
        return False
    folder = Path(os.path.abspath(text))
    while not folder.is_dir() and folder != folder.parent:
        folder = folder.parent
    try:
        longest = os.pathconf(folder, "PC_NAME_MAX")
    except (OSError, ValueError):
        longest = 255
    return any(len(os.fsencode(name)) > longest for name in Path(text).parts)


_folder = _named("-o", "a folder", " (give . for the working folder)")     # every command's output folder


def main(argv=None) -> int:
    try:
        args = _parser().parse_args(argv)
    except UserError as e:    # raised by an argument's type (_named): one line, like the file's errors
        print(f"mitsuforest: {e}", file=sys.stderr)
        return e.exit_code
    previous = signal.signal(signal.SIGTERM, raise_terminated) if in_main_thread() else None
    try:
        if args.command not in ("info", "compare"):
            _preload(args)
            from .trees.cache import cache_limit
            from .trees.parallel import build_processes
            cache_limit()                     # a bad MITSUFOREST_CACHE_SIZE, refused before any work
            build_processes()                 # and MITSUFOREST_BUILD_PROCESSES
            if argv is None:
                _spare_the_collector()
        code = _COMMANDS[args.command](args) or 0
        sys.stdout.flush()                    # a closed pipe shows here, not in a traceback at exit
        return code
    except UserError as e:
        print(f"mitsuforest: {e}", file=sys.stderr)
        return e.exit_code
    except InterruptedAfterCommit as e:
        print(f"mitsuforest: {_stopped(e.terminated)} as the finished files were being moved "
              "into place; they are all there and complete.", file=sys.stderr)
        return 143 if e.terminated else 130
    except StoppedWithWorkKept as e:
        print(f"mitsuforest: {_stopped(e.terminated)}; {e.kept}.", file=sys.stderr)
        return 143 if e.terminated else 130
    except KeyboardInterrupt as e:
        print(f"mitsuforest: {_stopped(isinstance(e, Terminated))}; no finished output was written (partial "
              "files removed). Run the same command again to redo it.", file=sys.stderr)
        return 143 if isinstance(e, Terminated) else 130
    except BrokenPipeError:                   # `mitsuforest info FILE | head`: the reader has gone
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as e:                      # a write failing mid-run: disk full, folder removed ...
        where = f"{e.filename}: " if e.filename else ""
        print(f"mitsuforest: {where}{e.strerror or e}; nothing was finished (partial files removed)",
              file=sys.stderr)
        return 1
    finally:
        if argv is None and in_main_thread():   # the program itself: signals until the process ends
            quiet_signals_until_exit()
            _spare_the_collector()
        elif previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _spare_the_collector() -> None:
    """Leave the objects alive now out of the cyclic collector's passes (``gc.freeze``). The program
    calls it once its heavy imports are done, whose modules live as long as the process (the full passes
    during a demo render: 0.10 -> 0.04 s), and once its command has ended, before the interpreter's own
    passes at exit (0.15 of the 0.2 s a render's exit took). Nothing waits on those passes: every file
    is closed and in place by the end, and exit handlers (threads joined, worker processes ended) still
    run."""
    gc.freeze()


def _stopped(by_sigterm: bool) -> str:
    return "stopped (SIGTERM)" if by_sigterm else "interrupted"


def _start_writer_processes(args) -> None:
    """Start the point writer's worker processes, if the scene file's render will use them, before the
    heavy imports: they start on cores the imports leave idle. A scene that does not load is left for
    the render to report."""
    if args.scene.suffix.lower() == ".xml":
        return
    from .config import load_scene
    from .write.processes import start_processes
    try:
        scene = load_scene(args.scene, seed=args.seed, variant=args.variant, output_dir=args.output)
    except (UserError, OSError):
        return
    start_processes(scene)


def _preload(args) -> None:
    """Import the heavy libraries up front, with signals held (see :func:`deferred_signals`); a render
    starts its writer's worker processes first."""
    with deferred_signals():
        if args.command == "render":
            _start_writer_processes(args)
        import drjit  # noqa: F401
        import laspy  # noqa: F401
        import manifold3d  # noqa: F401
        import mitsuba  # noqa: F401

        from . import pipeline  # noqa: F401


def _render(args) -> int:
    from .pipeline import render
    log = (lambda *a: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr))
    options = dict(output_dir=args.output, seed=args.seed, variant=args.variant, overwrite=args.overwrite,
                   progress=not args.quiet, log=log)
    if args.scene.suffix.lower() == ".xml":
        from .helios.render import render_survey
        result = render_survey(args.scene, assets=args.assets, **options)
    elif args.assets:
        raise UserError("--assets is for HELIOS++ surveys (.xml), not scene files")
    else:
        result = render(args.scene, **options)
    if not args.quiet:
        print(f"wrote {len(result.files)} files to {Path(result.scene.output.dir)}")
    return 0


def _plan(args) -> int:
    from .config import load_scene
    from .survey import make_plan
    from .write import check_output_folder, refuse_finished_render, write_plan
    scene = load_scene(args.scene, seed=args.seed, output_dir=args.output)
    out = Path(scene.output.dir)
    check_output_folder(out)
    refuse_finished_render(out, scene.name)
    plan = make_plan(scene, progress=sys.stderr.isatty())      # a bar at a terminal: a long tree list takes minutes
    path = write_plan(out, scene.name, plan)
    kinds = {}
    for obj in plan.objects:
        kinds[obj.kind] = kinds.get(obj.kind, 0) + 1
    print(f"{scene.name}: {kinds.get('tree', 0)} trees, canopy cover {plan.canopy_cover:.1%} "
          f"({scene.forest.type}), objects: " + ", ".join(f"{k} {v}" for k, v in kinds.items())
          + f"; {len(plan.legs)} flight legs, {plan.legs[-1].t1 - plan.legs[0].t0:.0f} s of flight")
    print(f"wrote {path}")
    return 0


def _trees(args) -> int:
    from .specs.archetypes import DEFAULT_ARCHETYPES, expanded
    from .write.gallery import write_gallery
    from .write import check_output_folder
    check_output_folder(args.output)
    models = ()
    if args.scene:
        from .config import load_scene
        scene = load_scene(args.scene)
        archetypes, models = expanded(scene.forest.archetypes, scene.seed), scene.forest.models   # unique: the plot's trees
        if scene.forest.trees_file:
            from .errors import display_path
            print(f"mitsuforest: {display_path(scene.forest.trees_file)}: these are the templates the listed trees grow from; each "
                  "is grown to its row's size when the plot is planned (`mitsuforest export` writes them)",
                  file=sys.stderr)
    else:
        archetypes = DEFAULT_ARCHETYPES
    write_gallery(archetypes, args.output, models=models)
    print(f"wrote {len(archetypes) + len(models)} trees, volumes.csv and trees.png to {args.output}")
    return 0


def _export(args) -> int:
    from .config import load_scene
    from .survey import make_plan
    from .trees import build_models
    from .write import check_output_folder
    from .helios.export import export_scene
    check_output_folder(args.output)
    scene = load_scene(args.scene, seed=args.seed)
    plan = make_plan(scene)
    export_scene(scene, plan, build_models(plan), args.output)
    return 0


def _dataset(args) -> int:
    from .dataset import run_dataset
    log = (lambda *a: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr))
    run_dataset(args.dataset, args.output, workers=args.workers, scheduler=args.scheduler, threads=args.threads,
                progress=not args.quiet, log=log)
    return 0


def _twin(args) -> int:
    from .twin import make_twin
    report = make_twin(args.file, args.output, species=args.species, sensor=args.sensor, name=args.name,
                       calibrate=args.calibrate, variant=args.variant)
    print(f"{report['name']}: {report['trees']['count']} trees, {report['understory']['bushes']} bushes, "
          f"plot {report['plot']['size'][0]:g} x {report['plot']['size'][1]:g} m; "
          f"wrote {args.output / (report['name'] + '.yaml')}")
    return 0


def _info(args) -> int:
    from .write.info import summary
    print(summary(args.file))
    return 0


def _compare(args) -> int:
    from .compare import compare_files, format_table
    result = compare_files(args.a, args.b, out_dir=args.output, within_a=args.within_a)
    for side in ("a", "b"):
        for note in result[side]["notes"]:
            print(f"mitsuforest: {result[side]['file']}: {note}", file=sys.stderr)
    print(format_table(result))
    print(f"wrote compare.json and compare.png to {args.output}")
    return 0


_COMMANDS = {"render": _render, "plan": _plan, "trees": _trees, "export": _export, "dataset": _dataset,
             "twin": _twin, "info": _info, "compare": _compare}

if __name__ == "__main__":
    raise SystemExit(main())
