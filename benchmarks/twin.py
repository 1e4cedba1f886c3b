"""Twins of the real scans in ../shared/data/real: tree detection against MixedConifer's treeID, and each
twin rendered and compared with its real scan.

    python benchmarks/twin.py                     # twin, render and compare both scans (a GPU helps)
    python benchmarks/twin.py --no-render         # twins and tree detection only (seconds)
    python benchmarks/twin.py --calibrate 3       # calibrate each twin's crowns in up to 3 renders first
    python benchmarks/twin.py --scans UAS_Clip.laz   # one scan only
    python benchmarks/twin.py --factors 2.7 1.07  # one render at fixed calibration factors (leaf area, radius)
    python benchmarks/twin.py --factors 3.31 1.09 0.25   # ... and crown contrast
    python benchmarks/twin.py --factors 3.31 1.09 --archetype leaf_lift=0.5   # ... with the twin's archetypes changed
    python benchmarks/twin.py --out DIR           # where twins and renders go (default benchmarks/out/twin)
    python benchmarks/twin.py --real DIR          # the real scans' folder (default ../shared/data/real)

The real scans are GPL-3 data kept beside the project (``../shared/data/real``, see its README); a scan
that is absent is skipped with the reason. The comparison uses ``mitsuforest.compare.compare_files``
where this checkout has it, and says so where it does not.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))   # this checkout's package, not an installed one
REAL = ROOT.parent / "shared" / "data" / "real"
SCANS = ("UAS_Clip.laz", "MixedConifer.laz")
MATCH_RADIUS = 2.0   # m: a detected top matches a labelled tree's highest point this close, one to one


def labelled_tops(scan) -> np.ndarray:
    """The highest point (x, y) of each labelled tree (treeID > 0), shape (k, 2)."""
    ids = scan.tree_id
    order = np.lexsort((scan.z, ids))                  # by tree, highest last
    last = np.r_[ids[order][1:] != ids[order][:-1], True]
    top = order[last & (ids[order] > 0)]
    return np.column_stack([scan.x[top], scan.y[top]])


def detection_scores(path: Path) -> dict:
    from mitsuforest.twin import analyse
    from mitsuforest.twin.detection import scores
    from mitsuforest.twin.points import read_scan
    scan = read_scan(path)
    found = analyse(scan)
    trees = found["trees"]
    result = scores(np.column_stack([trees.x, trees.y]), labelled_tops(scan), MATCH_RADIUS)
    result["cell"] = found["settings"].cell
    return result


def render_twin(scene_file: Path, out: Path, variant: str | None) -> Path:
    from mitsuforest.pipeline import render
    result = render(scene_file, output_dir=out, variant=variant, overwrite=True, progress=False, log=lambda *_: None)
    return next(Path(f) for f in result.files if str(f).endswith(".laz"))


def clip_to_plot(laz: Path, bounds, out: Path) -> Path:
    """The twin's points within the plot (x0, y0, x1, y1): its DEM reaches 1 m beyond the plot on each
    side, and ground hit there would count against the real scan's density over a larger area."""
    import laspy
    las = laspy.read(laz)
    x, y = np.asarray(las.x), np.asarray(las.y)
    inside = (x >= bounds[0]) & (x <= bounds[2]) & (y >= bounds[1]) & (y <= bounds[3])
    clipped = laspy.LasData(las.header)
    clipped.points = las.points[inside]
    out.parent.mkdir(parents=True, exist_ok=True)
    clipped.write(out)
    return out


def compare(real: Path, twin: Path, out: Path) -> dict | None:
    try:
        from mitsuforest.compare import compare_files
    except ImportError:
        print("  (mitsuforest.compare is not in this checkout: no comparison table)")
        return None
    return compare_files(real, twin, out_dir=out)


def print_comparison(result: dict) -> None:
    """compare's own table where the checkout has ``format_table``, else the distances."""
    try:
        from mitsuforest.compare import format_table
        print(format_table(result))
    except (ImportError, TypeError):
        print(f"  {'metric':16s} {'distance (twin vs real)':>24s}")
        for key, value in result["distance"].items():
            print(f"  {key:16s} {value:>24.4g}" if isinstance(value, (int, float)) else f"  {key:16s} {value!s:>24}")


def archetype_change(item: str, parser) -> tuple[str, float]:
    """``FIELD=VALUE`` of ``--archetype``: a numeric archetype field and its value."""
    from mitsuforest.specs.archetypes import FIELDS
    key, _, value = item.partition("=")
    if key not in FIELDS or FIELDS[key].metadata["choices"]:
        parser.error(f"--archetype: {key!r} is not a numeric archetype field")
    try:
        return key, float(value)
    except ValueError:
        parser.error(f"--archetype: {item!r} is not FIELD=NUMBER")


def change_archetypes(scene_file: Path, changes: dict) -> None:
    """Set ``changes`` on every archetype of the twin's scene file."""
    import yaml
    doc = yaml.safe_load(scene_file.read_text())
    for archetype in doc["forest"].get("archetypes", []):
        archetype.update(changes)
    scene_file.write_text(yaml.safe_dump(doc, sort_keys=False))


def apply_factors(trees_file: Path, stand_ratio, leaf: float, radius: float, contrast: float | None = None) -> int:
    """Rescale a new twin's ``trees.csv`` as a calibration that ended at these factors would (twin/calibrate.py);
    returns the trees at the leaf area cap."""
    from mitsuforest.twin import calibrate
    ratios = None
    if contrast is not None:
        basis = calibrate.contrast_basis(calibrate.read_trees(trees_file), stand_ratio)
        if basis is None:
            raise SystemExit(f"{trees_file}: the trees have no crown ratio for a crown contrast")
        ratios = calibrate.contrast_ratios(*basis, contrast)
    return calibrate.rescale_trees(trees_file, leaf, radius, ratios)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "out" / "twin")
    p.add_argument("--no-render", action="store_true", help="twins and detection only")
    p.add_argument("--real", type=Path, default=REAL, help="folder of the real scans (default ../shared/data/real)")
    p.add_argument("--variant", help="Mitsuba variant for the renders (default: auto)")
    p.add_argument("--calibrate", type=int, default=0, metavar="N",
                   help="calibrate each twin's crowns against its scan in up to N renders (mitsuforest twin --calibrate)")
    p.add_argument("--factors", nargs="+", type=float, metavar="LEAF RADIUS [CONTRAST]",
                   help="instead of calibrating: leaf area per crown area and crown radius times these, and the crown "
                        "contrast when given (default 0), one render")
    p.add_argument("--archetype", nargs="+", default=[], metavar="FIELD=VALUE",
                   help="with --factors: set these archetype fields of the twin's trees (e.g. leaf_lift=0.5)")
    p.add_argument("--scans", nargs="+", default=list(SCANS), metavar="NAME", help="which scans (default: both)")
    args = p.parse_args()
    if args.factors and args.calibrate:
        p.error("--factors and --calibrate: choose one")
    if args.archetype and not args.factors:
        p.error("--archetype needs --factors")
    if args.factors and len(args.factors) not in (2, 3):
        p.error("--factors: LEAF RADIUS [CONTRAST], two or three numbers")
    changes = dict(archetype_change(item, p) for item in args.archetype)
    from mitsuforest.twin import make_twin
    for name in args.scans:
        path = args.real / name
        if not path.is_file():
            print(f"{name}: skipped: {path} is absent (the real scans live in ../shared/data/real)")
            continue
        folder = args.out / path.stem
        start = time.perf_counter()
        report = make_twin(path, folder, log=lambda msg: print("  " + msg),
                           calibrate=0 if args.no_render else args.calibrate, variant=args.variant)
        if args.factors:
            capped = apply_factors(folder / "trees.csv", report["trees"]["crown_ratio"], *args.factors)
            print(f"  trees.csv: leaf area per crown area x{args.factors[0]:g}, crown radius x{args.factors[1]:g}"
                  + (f", crown contrast {args.factors[2]:g}" if len(args.factors) > 2 else "")
                  + (f" ({capped} trees at the leaf area cap)" if capped else ""))
            if changes:
                change_archetypes(folder / f"{path.stem}.yaml", changes)
                print("  archetypes: " + ", ".join(f"{k} {v:g}" for k, v in changes.items()))
        print(f"{name}: twin with {report['trees']['count']} trees, {report['understory']['bushes']} bushes in "
              f"{time.perf_counter() - start:.1f} s -> {folder}")
        for key, item in report["survey"].items():
            value = item["value"]
            print(f"  survey.{key:16s} {value:>12.6g}  {item['source']}" if isinstance(value, float)
                  else f"  survey.{key:16s} {value!s:>12}  {item['source']}")
        if name == "MixedConifer.laz":
            s = detection_scores(path)
            print(f"  tree detection vs treeID (CHM cell {s['cell']:g} m, match within {MATCH_RADIUS:g} m): "
                  f"{s['found']} found, {s['true']} labelled, {s['matched']} matched: precision {s['precision']:.3f}, "
                  f"recall {s['recall']:.3f}, F1 {s['f1']:.3f}")
        if args.no_render:
            continue
        start = time.perf_counter()
        laz = render_twin(folder / f"{path.stem}.yaml", folder / "render", args.variant)
        print(f"  rendered the twin in {time.perf_counter() - start:.1f} s -> {laz}")
        bounds = report["plot"]["offset"][:2] + [o + w for o, w in zip(report["plot"]["offset"], report["plot"]["size"])]
        clipped = clip_to_plot(laz, bounds, folder / "clipped" / laz.name)
        result = compare(path, clipped, folder / "compare")
        if result:
            print_comparison(result)


if __name__ == "__main__":
    main()
