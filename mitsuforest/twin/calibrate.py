"""Calibrating a twin's crowns against its real scan: render, measure, rescale, render again.

Measures of the canopy, taken the same way on the real scan and on the twin's render, both over the
real scan's DEM and within its footprint, the plot's 1 m cells holding a first return of it (:func:`footprint`:
a circular or holed clip's twin is rendered over the whole rectangle, whose corners would count as gaps):

- the echoes per pulse: all returns over first returns;
- the crown gap fraction ``P``: the share of first returns under crowns (CHM at or above 2 m) that reach
  within :data:`~.foliage.GROUND_BAND` of the ground (:func:`~.foliage.crown_gap_fraction`);
- the canopy cover: the share of the plot's 1 m cells whose highest first return stands 2 m or more
  above the ground (compare's ``canopy_cover_2m``);
- the canopy's vertical spread: the interquartile range of the heights of all returns 2 m or more above
  the ground (:func:`canopy_spread`).

Each step rescales every tree's crown (pure functions):

- leaf area per crown area by the echoes per pulse (:func:`echo_scale`): the denser a crown's leaves, the
  sooner a pulse is spent in it, and the echoes beyond the first, ``E - 1``, fall as leaf area rises
  (UAS_Clip's twin: as ``LAI^-1``), so ``LAI_new = LAI_old · (E_twin - 1) / (E_real - 1)``. A scan with
  (almost) one return a pulse says nothing of that; there the gap fraction sets it by Beer-Lambert,
  ``P = exp(-k · LAI)``: ``LAI_new = LAI_old · ln P_real / ln P_twin`` (:func:`lai_scale`). The gap
  fraction alone does not tell leaf from width: wider crowns close the gaps between them too, and on
  UAS_Clip a calibration on it reached the real gap fraction with wide, thin crowns that gave 1.86 echoes
  a pulse against the real 1.59;
- crown radius by the square root of the cover ratio (a crown's area goes as its radius squared), so that
  the twin's crowns cover as much of the plot as the real ones (:func:`crown_scale`). A tree's leaf area is
  its LAI times its crown area, so a wider crown carries more leaf at the same LAI;
- the crowns' depth by their rank, from the spread. A real stand holds dominant crowns, whose dense tops
  stop the pulses high, and smaller ones whose returns reach far down; crowns whose depth is measured on
  each tree's returns (``crown_ratio``) and then filled as cones of uniform leaf density pile the twin's
  returns into a narrower band (UAS_Clip: 5.2 m against the real 8.9 m). The crown contrast ``c``
  (:func:`contrast_ratios`) makes the widest quarter of the crowns (the dominants) shallower, their crown
  ratio times ``1 - c``, and the others deeper, times ``1 + 2 c``; each step moves ``c`` by the spread still
  missing over the spread a unit of ``c`` gave (:func:`contrast_step`; the first step assumes
  :data:`CONTRAST_SLOPE`, later ones the last step's secant).

From the second step on, the leaf and cover exponents (1 and 2) are the ones the last step showed
(:func:`response_exponent`, a secant step): clumped shoots answer more leaf area with less shade than
random leaves, and overlapping crowns answer a wider radius with less cover than discs apart.

The loop (:func:`calibrate`) stops when all are within tolerance or after ``iterations`` renders; each
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
ECHO_TOLERANCE = 0.1    # |(E_twin - 1) / (E_real - 1) - 1|: the LAI step still to take by the echoes, at most 10 %
MIN_EXCESS = 0.02       # echoes per pulse beyond the first under which the LAI follows the gap fraction
COVER_TOLERANCE = 0.03  # |cover_twin - cover_real|
SCALE_LIMITS = (0.25, 4.0)   # one step changes LAI or crown radius by at most this factor
MIN_SECANT_STEP = 0.05  # |ln factor| of a step under which its secant says nothing of the exponent (5 %)
# The leaf area per crown area all steps together may reach, against the scan's: a twin that asks for more
# is missing something else, and its leaf cards outgrow memory (MixedConifer's airborne twin asked x 8 at
# its third step, 209 trees, and its render passed 24 GB).
TOTAL_LEAF_LIMITS = (0.25, 4.0)
MIN_GAP = foliage.MIN_GAP
MAX_LEAF_AREA = FIELDS["leaf_area"].metadata["hi"]   # m²: the most a procedural tree carries
RATIO_LIMITS = (FIELDS["crown_ratio"].metadata["lo"], FIELDS["crown_ratio"].metadata["hi"])
SPREAD_TOLERANCE = 0.5      # m: |spread_twin - spread_real|
CONTRAST_LIMITS = (0.0, 0.45)
CONTRAST_SLOPE = 10.0       # m of spread per unit of contrast, the first step's guess (UAS_Clip's twin showed 11)
DOMINANT_SHARE = 0.25       # the widest quarter of the crowns are the dominants
MIN_SPREAD_RETURNS = 100    # returns in the canopy, fewer and the spread is not measured


def lai_scale(p_real: float, p_twin: float, exponent: float = 1.0) -> float:
    """The factor on leaf area per crown area that moves the twin's gap fraction from ``p_twin`` to
    ``p_real`` where ``-ln P`` goes as ``LAI ** exponent``: ``(ln P_real / ln P_twin) ** (1 / exponent)``
    (both clipped to [MIN_GAP, 1 - MIN_GAP]), kept within :data:`SCALE_LIMITS`. ``exponent`` 1 is
    Beer-Lambert; clumped foliage answers less (see :func:`response_exponent`)."""
    lo, hi = MIN_GAP, 1.0 - MIN_GAP
    k = (math.log(min(max(p_real, lo), hi)) / math.log(min(max(p_twin, lo), hi))) ** (1.0 / exponent)
    return _bounded(k)


def echo_scale(echoes_real: float, echoes_twin: float, exponent: float = 1.0) -> float:
    """The factor on leaf area per crown area that moves the twin's echoes per pulse from ``echoes_twin``
    to ``echoes_real`` where the echoes beyond the first go as ``LAI ** -exponent``:
    ``((E_twin - 1) / (E_real - 1)) ** (1 / exponent)``, kept within :data:`SCALE_LIMITS`."""
    return _bounded((_excess(echoes_twin) / _excess(echoes_real)) ** (1.0 / exponent))


def _excess(echoes_per_pulse: float) -> float:
    """The echoes per pulse beyond the first, at least :data:`MIN_EXCESS`."""
    return max(echoes_per_pulse - 1.0, MIN_EXCESS)


def leaf_rule(real: dict) -> str:
    """Which measure sets the leaf area: ``"echoes"`` where the real scan has multiple returns
    (:data:`MIN_EXCESS`), else ``"gap fraction"``."""
    echoes = real.get("echoes_per_pulse")
    return "echoes" if echoes is not None and echoes - 1.0 >= MIN_EXCESS else "gap fraction"


def leaf_scale(real: dict, twin: dict, exponent: float = 1.0) -> float:
    """The factor on leaf area per crown area by :func:`leaf_rule`'s measure (:func:`echo_scale` or
    :func:`lai_scale`)."""
    if leaf_rule(real) == "echoes":
        return echo_scale(real["echoes_per_pulse"], twin["echoes_per_pulse"], exponent)
    return lai_scale(real["gap_fraction"], twin["gap_fraction"], exponent)


def leaf_exponent(real: dict, last: dict, twin: dict, factor: float) -> float:
    """The exponent the last leaf step (``factor``, from the measures ``last`` to ``twin``) showed, for
    :func:`leaf_scale`'s measure (:func:`response_exponent`)."""
    if leaf_rule(real) == "echoes":    # the excess echoes fall as leaf rises: the exponent of 1 / factor
        return response_exponent(_excess(last["echoes_per_pulse"]), _excess(twin["echoes_per_pulse"]),
                                 1.0 / factor, 1.0)
    return response_exponent(-math.log(max(last["gap_fraction"], MIN_GAP)),
                             -math.log(max(twin["gap_fraction"], MIN_GAP)), factor, 1.0)


def crown_scale(cover_real: float, cover_twin: float, exponent: float = 2.0) -> float:
    """The factor on crown radius that moves the twin's canopy cover to the real one where cover goes as
    ``radius ** exponent`` (2: crowns' areas, apart): ``(cover_real / cover_twin) ** (1 / exponent)``,
    kept within :data:`SCALE_LIMITS`."""
    return _bounded((cover_real / max(cover_twin, 1e-6)) ** (1.0 / exponent))


def response_exponent(before: float, after: float, factor: float, default: float) -> float:
    """How a measure answered a step: ``ln(after / before) / ln(factor)``, the exponent of a power law
    through the two renders (a secant step), within [0.1, 4 · default]; ``default`` where the step or
    a measure was nil, or where the measure moved against the step: the other factors, stepped at the
    same time, moved it more (MixedConifer's twin: leaf area × 1.06 with crowns × 1.16 raised its echoes
    per pulse, and an exponent of 0.1 then asked for × 4 the leaf), or where the step was under
    :data:`MIN_SECANT_STEP`: the render's noise and the other factors move the measure as much (leaf area
    × 1.029 with crowns × 1.084 left its echoes per pulse at 1.387, a secant exponent of 0.09 asked for
    × 3.1 the leaf). At least a quarter of ``default``, so a step asks at most its measure's miss to the 4th."""
    if before <= 0 or after <= 0 or abs(math.log(factor)) < MIN_SECANT_STEP:
        return default
    exponent = math.log(after / before) / math.log(factor)
    return default if exponent <= 0 else float(min(max(exponent, 0.25 * default), 4.0 * default))


def canopy_spread(h) -> float | None:
    """The canopy's vertical spread (m): the interquartile range of the heights ``h`` (n,) above the
    ground that are at or above :data:`CANOPY_HEIGHT`; ``None`` under :data:`MIN_SPREAD_RETURNS` of them."""
    canopy = np.asarray(h, float)
    canopy = canopy[canopy >= CANOPY_HEIGHT]
    if len(canopy) < MIN_SPREAD_RETURNS:
        return None
    q1, q3 = np.quantile(canopy, [0.25, 0.75])
    return float(q3 - q1)


def dominant_crowns(radius) -> np.ndarray:
    """(k,) bool: the crowns of ``radius`` (k,) in the widest :data:`DOMINANT_SHARE` (at or above its quantile)."""
    radius = np.asarray(radius, float)
    if not len(radius):
        return np.zeros(0, bool)
    return radius >= np.quantile(radius, 1.0 - DOMINANT_SHARE)


def contrast_ratios(base, dominant, contrast: float) -> np.ndarray:
    """(k,) crown ratios at crown contrast ``contrast``: the ``dominant`` crowns' ``base`` ratio times
    ``1 - contrast``, the others' times ``1 + 2 contrast``, within :data:`RATIO_LIMITS`."""
    factor = np.where(dominant, 1.0 - contrast, 1.0 + 2.0 * contrast)
    return np.clip(np.asarray(base, float) * factor, *RATIO_LIMITS)


def contrast_step(contrast: float, spread_real: float, spread_twin: float, slope: float = CONTRAST_SLOPE) -> float:
    """The next crown contrast: ``contrast`` moved by the spread still missing over ``slope`` (m of spread
    per unit of contrast), within :data:`CONTRAST_LIMITS`."""
    return float(min(max(contrast + (spread_real - spread_twin) / slope, CONTRAST_LIMITS[0]), CONTRAST_LIMITS[1]))


def spread_slope(before: tuple[float, float], after: tuple[float, float]) -> float:
    """The spread a unit of contrast gave between two renders, each ``(contrast, spread)``: the secant, or
    :data:`CONTRAST_SLOPE` where the contrast hardly moved or the spread did not grow with it."""
    dc = after[0] - before[0]
    if abs(dc) < 0.01 or (after[1] - before[1]) / dc < 0.1 * CONTRAST_SLOPE:
        return CONTRAST_SLOPE
    return float((after[1] - before[1]) / dc)


def _bounded(k: float) -> float:
    return float(min(max(k, SCALE_LIMITS[0]), SCALE_LIMITS[1]))


def _grid(frame) -> tuple[float, float, tuple[int, int]]:
    """The SW corner and shape (ny, nx) of the plot's :data:`CHM_CELL` cells."""
    return frame.offset[0], frame.offset[1], (int(math.ceil(frame.size[1] / CHM_CELL)), int(math.ceil(frame.size[0] / CHM_CELL)))


def _in_cells(x: np.ndarray, y: np.ndarray, frame, cells: np.ndarray | None) -> np.ndarray:
    """(n,) bool: the points in the plot's cells, and in ``cells`` (ny, nx) where given."""
    x0, y0, shape = _grid(frame)
    inside = (x >= x0) & (y >= y0) & (x < x0 + shape[1] * CHM_CELL) & (y < y0 + shape[0] * CHM_CELL)
    if cells is not None:
        row, col = ground.grid_index(x[inside], y[inside], x0, y0, CHM_CELL, shape)
        inside[inside] = cells[row, col]
    return inside


def footprint(x, y, return_number, frame) -> np.ndarray:
    """(ny, nx) bool: the plot's :data:`CHM_CELL` cells that hold a first return of the scan (x, y and
    return_number of shape (n,))."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    x0, y0, shape = _grid(frame)
    first = (np.asarray(return_number) == 1) & _in_cells(x, y, frame, None)
    cells = np.zeros(shape, bool)
    cells[ground.grid_index(x[first], y[first], x0, y0, CHM_CELL, shape)] = True
    return cells


def canopy_state(x, y, z, return_number, dem: np.ndarray, dem_origin, frame, cells: np.ndarray | None = None,
                 counts: np.ndarray | None = None) -> dict:
    """The echoes per pulse, crown gap fraction, canopy cover and canopy spread (:func:`canopy_spread`, of
    all returns) of a scan over the plot ``frame`` (a :class:`~.TwinFrame`), or over its ``cells`` (ny, nx)
    where given (the real scan's :func:`footprint`), heights over ``dem`` (1 m cells from ``dem_origin``).
    With ``counts``, the pulses' numbers of returns, the first returns alone are measured, and the echoes
    per pulse are the mean of their counts: a real scan of first returns only
    (:func:`~mitsuforest.compare.metrics.first_returns_only`), and its twin's render beside it.
    Arrays of shape (n,)."""
    from . import DEM_CELL
    x, y, z = (np.asarray(a, float) for a in (x, y, z))
    if counts is not None:
        kept = np.asarray(return_number) == 1
        x, y, z, return_number, counts = x[kept], y[kept], z[kept], np.ones(int(kept.sum())), np.asarray(counts)[kept]
    h = z - ground.ground_height(dem, dem_origin[0], dem_origin[1], DEM_CELL, x, y)
    first = np.asarray(return_number) == 1
    x0, y0, shape = _grid(frame)
    in_plot = _in_cells(x, y, frame, cells)
    inside = first & in_plot
    chm = detection.canopy_height_model(x[inside], y[inside], h[inside], x0, y0, shape, CHM_CELL)
    row, col = ground.grid_index(x[inside], y[inside], x0, y0, CHM_CELL, shape)
    counted = np.zeros(shape, bool)
    counted[row, col] = True
    gap = foliage.crown_gap_fraction(h[inside], chm[row, col] >= CANOPY_HEIGHT)
    cover = float(np.mean(chm[counted] >= CANOPY_HEIGHT)) if counted.any() else 0.0
    firsts = int(np.count_nonzero(inside))
    if not firsts:
        echoes = None
    elif counts is not None:
        echoes = float(np.mean(counts[inside]))
    else:
        echoes = int(np.count_nonzero(in_plot)) / firsts
    return {"gap_fraction": gap, "cover": cover, "spread": canopy_spread(h[in_plot]), "echoes_per_pulse": echoes}


def converged(real: dict, twin: dict, spread: bool = False) -> bool:
    """The measures within tolerance (the LAI step :func:`leaf_scale` still asks within
    :data:`ECHO_TOLERANCE` or :data:`GAP_TOLERANCE`, :data:`COVER_TOLERANCE` and, with ``spread``,
    :data:`SPREAD_TOLERANCE`)."""
    lai_step = abs(leaf_scale(real, twin) - 1.0)
    tolerance = ECHO_TOLERANCE if leaf_rule(real) == "echoes" else GAP_TOLERANCE
    spread_off = spread and (twin.get("spread") is None or abs(twin["spread"] - real["spread"]) > SPREAD_TOLERANCE)
    return lai_step <= tolerance and abs(twin["cover"] - real["cover"]) <= COVER_TOLERANCE and not spread_off


def read_trees(path: Path) -> list[dict]:
    """The rows of a twin's ``trees.csv``."""
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def base_crown_ratios(rows: list[dict], stand: float | None) -> np.ndarray | None:
    """(k,) the crown ratio of each row of ``trees.csv``: its own, else the ``stand``'s; ``None`` where a
    tree has neither (the template's ratio, which the crown contrast cannot scale)."""
    ratios = np.array([float(r["crown_ratio"]) if r.get("crown_ratio") else np.nan for r in rows], float)
    ratios[np.isnan(ratios)] = np.nan if stand is None else stand
    return None if np.isnan(ratios).any() or not len(ratios) else ratios


def contrast_basis(rows: list[dict], stand: float | None) -> tuple[np.ndarray, np.ndarray] | None:
    """What the crown contrast scales, for the rows of ``trees.csv``: (k,) base crown ratios
    (:func:`base_crown_ratios`) and (k,) which crowns are dominant (:func:`dominant_crowns`); ``None``
    where a tree has no crown ratio."""
    base = base_crown_ratios(rows, stand)
    return None if base is None else (base, dominant_crowns([float(r["crown_radius"]) for r in rows]))


def rescale_trees(path: Path, lai_factor: float, radius_factor: float, crown_ratios=None) -> int:
    """Rewrite ``trees.csv``: each crown radius times ``radius_factor``, each leaf area times
    ``lai_factor · radius_factor²`` (its LAI times the new crown area), at most the
    :data:`MAX_LEAF_AREA` a tree may carry, and, when given, each tree's crown ratio ``crown_ratios`` (k,);
    returns how many trees are at that cap."""
    rows = read_trees(path)
    fields = list(rows[0].keys()) if rows else []
    if crown_ratios is not None and "crown_ratio" not in fields:
        fields.append("crown_ratio")
    capped = 0
    for i, r in enumerate(rows):
        r["crown_radius"] = f"{float(r['crown_radius']) * radius_factor:.3f}"
        if crown_ratios is not None:
            r["crown_ratio"] = f"{crown_ratios[i]:.3f}"
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
    measures, each step's twin measures and factors, the total factors applied and the crown contrast."""
    log = log or (lambda msg: print(msg, file=sys.stderr))
    frame, dem, origin = analysis["frame"], analysis["dem"], analysis["dem_origin"]
    cells = footprint(real_scan.x, real_scan.y, real_scan.return_number, frame)
    first_only = real_scan.first_only
    real = canopy_state(real_scan.x, real_scan.y, real_scan.z, real_scan.return_number, dem, origin, frame, cells,
                        real_scan.number_of_returns if first_only else None)
    record = {"real": real, "leaf_from": leaf_rule(real), "steps": [], "lai_factor": 1.0, "crown_factor": 1.0,
              "crown_contrast": 0.0, "converged": False}
    if real["gap_fraction"] is None:
        record["note"] = "the real scan has no canopy: nothing to calibrate"
        return record
    basis = contrast_basis(read_trees(folder / "trees.csv"), analysis.get("crown_ratio"))
    with_contrast = basis is not None and real["spread"] is not None
    if not with_contrast:
        record["note"] = "no crown contrast: " + ("the real scan's canopy holds too few returns"
                                                  if basis is not None else "the trees have no crown ratio")
    for i in range(iterations):
        twin = _render_state(folder / f"{name}.yaml", variant, analysis, cells, first_only)
        step = {"gap_fraction": twin["gap_fraction"], "cover": twin["cover"], "spread": twin["spread"],
                "echoes_per_pulse": twin["echoes_per_pulse"], "crown_contrast": record["crown_contrast"]}
        if twin["gap_fraction"] is None or converged(real, twin, spread=with_contrast):
            record["steps"].append(step)
            record["converged"] = twin["gap_fraction"] is not None
            log(f"twin: calibration {i + 1}: {_measures(twin, real)}: within tolerance")
            break
        if record["steps"]:          # secant: the exponents the last step showed
            last = record["steps"][-1]
            lai_exp = leaf_exponent(real, last, twin, last["lai_factor"])
            cover_exp = response_exponent(last["cover"], twin["cover"], last["crown_factor"], 2.0)
        else:
            lai_exp, cover_exp = 1.0, 2.0
        k_lai = leaf_scale(real, twin, lai_exp)
        asked = record["lai_factor"] * k_lai
        total = min(max(asked, TOTAL_LEAF_LIMITS[0]), TOTAL_LEAF_LIMITS[1])
        if total != asked:
            log(f"twin: calibration {i + 1}: leaf area per crown area x{asked:.3g} in all asked "
                f"for; held at x{total:g}, the most a calibration takes (see twin.json)")
            record["leaf_held"] = {"asked": asked, "held": total,
                                   "why": "beyond it the twin's echoes or gaps differ for another reason"}
            k_lai = total / record["lai_factor"]
        k_r = crown_scale(real["cover"], twin["cover"], cover_exp)
        step.update(lai_factor=k_lai, crown_factor=k_r, lai_exponent=lai_exp, cover_exponent=cover_exp)
        ratios = None
        if with_contrast and twin["spread"] is not None:
            step["spread_slope"] = _spread_slope(record["steps"], step)
            record["crown_contrast"] = contrast_step(record["crown_contrast"], real["spread"], twin["spread"],
                                                     step["spread_slope"])
            ratios = contrast_ratios(*basis, record["crown_contrast"])
        record["steps"].append(step)
        record["lai_factor"] *= k_lai
        record["crown_factor"] *= k_r
        log(f"twin: calibration {i + 1}: {_measures(twin, real)}: leaf area per crown area x{k_lai:.3f}, "
            f"crown radius x{k_r:.3f}"
            + (f", crown contrast {record['crown_contrast']:.3f}" if ratios is not None else ""))
        step["trees_at_leaf_cap"] = rescale_trees(folder / "trees.csv", k_lai, k_r, ratios)
        if step["trees_at_leaf_cap"]:
            log(f"twin: calibration {i + 1}: {step['trees_at_leaf_cap']} trees at the {MAX_LEAF_AREA:g} m² leaf area "
                "a tree may carry")
    report_file = folder / "twin.json"
    report = json.loads(report_file.read_text())
    report["calibration"] = record
    report_file.write_text(json.dumps(report, indent=1) + "\n")
    return record


def _spread_slope(steps: list[dict], step: dict) -> float:
    """The spread a unit of contrast gave from the last step to this one (:func:`spread_slope`), or
    :data:`CONTRAST_SLOPE` at the first."""
    if not steps or steps[-1]["spread"] is None:
        return CONTRAST_SLOPE
    last = steps[-1]
    return spread_slope((last["crown_contrast"], last["spread"]), (step["crown_contrast"], step["spread"]))


def _render_state(scene_file: Path, variant: str | None, analysis: dict, cells: np.ndarray, first_only: bool) -> dict:
    """Render the twin's scene into a scratch folder beside it and measure it within the real scan's
    footprint ``cells`` (:func:`canopy_state`), on its first returns alone where the real scan holds only
    those (``first_only``)."""
    from ..pipeline import render
    from .points import read_scan
    work = Path(tempfile.mkdtemp(prefix=".calibrate.", dir=scene_file.parent))
    try:
        result = render(scene_file, output_dir=work, variant=variant, overwrite=True, progress=False,
                        log=lambda *_: None)
        twin_scan = read_scan(next(f for f in map(str, result.files) if f.endswith((".laz", ".las"))))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return canopy_state(twin_scan.x, twin_scan.y, twin_scan.z, twin_scan.return_number, analysis["dem"],
                        analysis["dem_origin"], analysis["frame"], cells,
                        twin_scan.number_of_returns if first_only else None)


def _measures(twin: dict, real: dict) -> str:
    text = (f"echoes per pulse {_f(twin['echoes_per_pulse'])} (real {_f(real['echoes_per_pulse'])}), "
            f"gap fraction {_f(twin['gap_fraction'])} (real {real['gap_fraction']:.3f}), "
            f"cover {twin['cover']:.3f} (real {real['cover']:.3f})")
    if real.get("spread") is not None:
        text += f", canopy spread {_f(twin['spread'])} m (real {real['spread']:.3f} m)"
    return text


def _f(value) -> str:
    return "none" if value is None else f"{value:.3f}"
