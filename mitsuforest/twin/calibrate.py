"""Calibrating a twin's crowns against its real scan: render, measure, rescale, render again.

Two measures of the canopy, taken the same way on the real scan and on the twin's render, both over the
real scan's DEM (:func:`canopy_state`):

- the crown gap fraction ``P``: the share of first returns under crowns (CHM at or above 2 m) that reach
  within :data:`~.foliage.GROUND_BAND` of the ground (:func:`~.foliage.crown_gap_fraction`);
- the canopy cover: the share of the plot's 1 m cells whose highest first return stands 2 m or more
  above the ground (compare's ``canopy_cover_2m``).

Each step rescales every tree's crown (pure functions, :func:`lai_scale`, :func:`crown_scale`):

- leaf area per crown area by Beer-Lambert, ``P = exp(-k · LAI)``: ``LAI_new = LAI_old · ln P_real / ln P_twin``,
  which reaches ``P_real`` in one step where the crowns follow Beer-Lambert;
- crown radius by the square root of the cover ratio (a crown's area goes as its radius squared), so that
  the twin's crowns cover as much of the plot as the real ones. A tree's leaf area is its LAI times its
  crown area, so a wider crown carries more leaf at the same LAI.

From the second step on, each exponent (1 for Beer-Lambert, 2 for the crown area) is the one the last
step showed (:func:`response_exponent`, a secant step): clumped shoots answer more leaf area with less
shade than random leaves, and overlapping crowns answer a wider radius with less cover than discs apart.

The loop (:func:`calibrate`) stops when both are within tolerance or after ``iterations`` renders; each
render is the scene as written (same seed, same beam), so the result is deterministic.
"""

from __future__ import annotations

import csv
import json
import math
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

from ..specs.archetypes import FIELDS
from . import detection, foliage, ground

CHM_CELL = 1.0          # m: cover is counted in 1 m cells, as compare's canopy_cover_2m
CANOPY_HEIGHT = 2.0     # m: a cell is canopy, a first return under a crown, at or above this
GAP_TOLERANCE = 0.2     # |ln P_twin / ln P_real - 1|: the LAI step still to take, at most 20 %
COVER_TOLERANCE = 0.03  # |cover_twin - cover_real|
SCALE_LIMITS = (0.25, 4.0)   # one step changes LAI or crown radius by at most this factor
MIN_GAP = foliage.MIN_GAP
MAX_LEAF_AREA = FIELDS["leaf_area"].metadata["hi"]   # m²: the most a procedural tree carries


def lai_scale(p_real: float, p_twin: float, exponent: float = 1.0) -> float:
    """The factor on leaf area per crown area that moves the twin's gap fraction from ``p_twin`` to
    ``p_real`` where ``-ln P`` goes as ``LAI ** exponent``: ``(ln P_real / ln P_twin) ** (1 / exponent)``
    (both clipped to [MIN_GAP, 1 - MIN_GAP]), kept within :data:`SCALE_LIMITS`. ``exponent`` 1 is
    Beer-Lambert; clumped foliage answers less (see :func:`response_exponent`)."""
    lo, hi = MIN_GAP, 1.0 - MIN_GAP
    k = (math.log(min(max(p_real, lo), hi)) / math.log(min(max(p_twin, lo), hi))) ** (1.0 / exponent)
    return _bounded(k)


def crown_scale(cover_real: float, cover_twin: float, exponent: float = 2.0) -> float:
    """The factor on crown radius that moves the twin's canopy cover to the real one where cover goes as
    ``radius ** exponent`` (2: crowns' areas, apart): ``(cover_real / cover_twin) ** (1 / exponent)``,
    kept within :data:`SCALE_LIMITS`."""
    return _bounded((cover_real / max(cover_twin, 1e-6)) ** (1.0 / exponent))


def response_exponent(before: float, after: float, factor: float, default: float) -> float:
    """How a measure answered a step: ``ln(after / before) / ln(factor)``, the exponent of a power law
    through the two renders (a secant step), within [0.1, 4 · default]; ``default`` where the step or
    a measure was nil."""
    if before <= 0 or after <= 0 or abs(math.log(factor)) < 1e-3:
        return default
    return float(min(max(math.log(after / before) / math.log(factor), 0.1), 4.0 * default))


def _bounded(k: float) -> float:
    return float(min(max(k, SCALE_LIMITS[0]), SCALE_LIMITS[1]))


def canopy_state(x, y, z, return_number, dem: np.ndarray, dem_origin, frame) -> dict:
    """The crown gap fraction and canopy cover of a scan over the plot ``frame`` (a :class:`~.TwinFrame`),
    heights over ``dem`` (1 m cells from ``dem_origin``). Arrays of shape (n,)."""
    from . import DEM_CELL
    x, y, z = (np.asarray(a, float) for a in (x, y, z))
    h = z - ground.ground_height(dem, dem_origin[0], dem_origin[1], DEM_CELL, x, y)
    first = np.asarray(return_number) == 1
    x0, y0 = frame.offset[0], frame.offset[1]
    shape = (int(math.ceil(frame.size[1] / CHM_CELL)), int(math.ceil(frame.size[0] / CHM_CELL)))
    inside = first & (x >= x0) & (y >= y0) & (x < x0 + shape[1] * CHM_CELL) & (y < y0 + shape[0] * CHM_CELL)
    chm = detection.canopy_height_model(x[inside], y[inside], h[inside], x0, y0, shape, CHM_CELL)
    row, col = ground.grid_index(x[inside], y[inside], x0, y0, CHM_CELL, shape)
    counted = np.zeros(shape, bool)
    counted[row, col] = True
    gap = foliage.crown_gap_fraction(h[inside], chm[row, col] >= CANOPY_HEIGHT)
    cover = float(np.mean(chm[counted] >= CANOPY_HEIGHT)) if counted.any() else 0.0
    return {"gap_fraction": gap, "cover": cover}


def converged(real: dict, twin: dict) -> bool:
    """Both measures within tolerance (:data:`GAP_TOLERANCE` on the LAI step, :data:`COVER_TOLERANCE`)."""
    lai_step = abs(lai_scale(real["gap_fraction"], twin["gap_fraction"]) - 1.0)
    return lai_step <= GAP_TOLERANCE and abs(twin["cover"] - real["cover"]) <= COVER_TOLERANCE


def rescale_trees(path: Path, lai_factor: float, radius_factor: float) -> int:
    """Rewrite ``trees.csv``: each crown radius times ``radius_factor``, each leaf area times
    ``lai_factor · radius_factor²`` (its LAI times the new crown area), at most the
    :data:`MAX_LEAF_AREA` a tree may carry; returns how many trees are at that cap."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    fields = list(rows[0].keys()) if rows else []
    capped = 0
    for r in rows:
        r["crown_radius"] = f"{float(r['crown_radius']) * radius_factor:.3f}"
        if r.get("leaf_area"):
            leaf = float(r["leaf_area"]) * lai_factor * radius_factor ** 2
            capped += leaf >= MAX_LEAF_AREA
            r["leaf_area"] = f"{min(leaf, MAX_LEAF_AREA):.2f}"
    with open(path, "w", newline="") as f:
        out = csv.DictWriter(f, fieldnames=fields, lineterminator="\n")
        out.writeheader()
        out.writerows(rows)
    return capped


def calibrate(real_scan, analysis: dict, folder: Path, name: str, iterations: int, variant: str | None = None,
              log=None) -> dict:
    """Render the twin in ``folder`` up to ``iterations`` times, rescaling ``trees.csv`` after each render
    that is not within tolerance; returns the record kept in ``twin.json`` (``calibration``): the real
    measures, each step's twin measures and factors, and the total factors applied."""
    from ..pipeline import render
    from .points import read_scan
    log = log or (lambda msg: print(msg, file=sys.stderr))
    frame, dem, origin = analysis["frame"], analysis["dem"], analysis["dem_origin"]
    real = canopy_state(real_scan.x, real_scan.y, real_scan.z, real_scan.return_number, dem, origin, frame)
    record = {"real": real, "steps": [], "lai_factor": 1.0, "crown_factor": 1.0, "converged": False}
    if real["gap_fraction"] is None:
        record["note"] = "the real scan has no canopy: nothing to calibrate"
        return record
    for i in range(iterations):
        work = Path(tempfile.mkdtemp(prefix=".calibrate.", dir=folder))
        try:
            result = render(folder / f"{name}.yaml", output_dir=work, variant=variant, overwrite=True,
                            progress=False, log=lambda *_: None)
            twin_scan = read_scan(next(f for f in map(str, result.files) if f.endswith((".laz", ".las"))))
        finally:
            shutil.rmtree(work, ignore_errors=True)
        twin = canopy_state(twin_scan.x, twin_scan.y, twin_scan.z, twin_scan.return_number, dem, origin, frame)
        step = {"gap_fraction": twin["gap_fraction"], "cover": twin["cover"]}
        if twin["gap_fraction"] is None or converged(real, twin):
            record["steps"].append(step)
            record["converged"] = twin["gap_fraction"] is not None
            log(f"twin: calibration {i + 1}: gap fraction {_f(twin['gap_fraction'])} (real {real['gap_fraction']:.3f}), "
                f"cover {twin['cover']:.3f} (real {real['cover']:.3f}): within tolerance")
            break
        if record["steps"]:          # secant: the exponents the last step showed
            last = record["steps"][-1]
            lai_exp = response_exponent(-math.log(max(last["gap_fraction"], MIN_GAP)),
                                        -math.log(max(twin["gap_fraction"], MIN_GAP)), last["lai_factor"], 1.0)
            cover_exp = response_exponent(last["cover"], twin["cover"], last["crown_factor"], 2.0)
        else:
            lai_exp, cover_exp = 1.0, 2.0
        k_lai = lai_scale(real["gap_fraction"], twin["gap_fraction"], lai_exp)
        k_r = crown_scale(real["cover"], twin["cover"], cover_exp)
        step.update(lai_factor=k_lai, crown_factor=k_r, lai_exponent=lai_exp, cover_exponent=cover_exp)
        record["steps"].append(step)
        record["lai_factor"] *= k_lai
        record["crown_factor"] *= k_r
        log(f"twin: calibration {i + 1}: gap fraction {twin['gap_fraction']:.3f} (real {real['gap_fraction']:.3f}), "
            f"cover {twin['cover']:.3f} (real {real['cover']:.3f}): leaf area per crown area x{k_lai:.3f}, "
            f"crown radius x{k_r:.3f}")
        step["trees_at_leaf_cap"] = rescale_trees(folder / "trees.csv", k_lai, k_r)
        if step["trees_at_leaf_cap"]:
            log(f"twin: calibration {i + 1}: {step['trees_at_leaf_cap']} trees at the {MAX_LEAF_AREA:g} m² leaf area "
                "a tree may carry")
    report_file = folder / "twin.json"
    report = json.loads(report_file.read_text())
    report["calibration"] = record
    report_file.write_text(json.dumps(report, indent=1) + "\n")
    return record


def _f(value) -> str:
    return "none" if value is None else f"{value:.3f}"
