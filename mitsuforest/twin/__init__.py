"""Twins of real plots: a scene that reproduces a real scan (see README, "Twins of real plots").

>>> report = make_twin("plot.laz", "twin/")   # doctest: +SKIP   writes twin/plot.yaml and its files

The steps are pure functions (:mod:`.ground`, :mod:`.detection`, :mod:`.understory`, :mod:`.survey`);
:mod:`.scene` writes the folder.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import detection, foliage, ground, intensity, survey, understory
from .points import read_scan

__all__ = ["make_twin", "TwinFrame", "DEM_CELL"]

DEM_CELL = 1.0     # m
MAX_CALIBRATIONS = 20   # --calibrate: each is a full render, and the loop converges in 2-4


@dataclass(frozen=True)
class TwinFrame:
    """The twin's plot in the file's coordinates: SW corner ``offset`` (x, y, z) and ``size`` (m)."""

    offset: tuple[float, float, float]
    size: tuple[float, float]

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        return (self.offset[0], self.offset[1], self.offset[0] + self.size[0], self.offset[1] + self.size[1])


def plot_frame(x, y, z_ground) -> TwinFrame:
    """The plot: whole metres around the points, at least 1 m a side; heights offset to a whole metre
    below the lowest ground."""
    x0, y0, z0 = math.floor(float(np.min(x))), math.floor(float(np.min(y))), math.floor(float(np.min(z_ground)))
    w = max(math.ceil(float(np.max(x)) - x0), 1)
    h = max(math.ceil(float(np.max(y)) - y0), 1)
    return TwinFrame((float(x0), float(y0), float(z0)), (float(w), float(h)))


def analyse(scan, settings: detection.DetectionSettings | None = None) -> dict:
    """Everything the twin scene needs from a :class:`~.points.RealScan` (pure): frame, DEM, trees,
    bushes, survey estimate and the notes on what was assumed. Without ``settings``, the detection's
    defaults with a CHM cell for the scan's density (:func:`~.detection.chm_cell`)."""
    notes = list(scan.notes)
    from ..config import MAX_PLOT_SIDE
    size = plot_frame(scan.x, scan.y, scan.z).size      # the plot's sides: all points' x, y extent
    if max(size) > MAX_PLOT_SIDE:      # before any grid, the lowest-point filter's too: a plot a scene cannot hold
        from ..errors import UserError, amount
        raise UserError(f"{scan.path}: its points span {amount(size[0])} x {amount(size[1])} m; a twin's plot "
                        f"is at most {MAX_PLOT_SIDE:,.0f} m a side: clip the file to the plot")
    if scan.ground is not None and scan.ground.any():
        is_ground, ground_source = scan.ground, "the file's ground class"
    else:
        is_ground = ground.lowest_point_filter(scan.x, scan.y, scan.z)
        ground_source = "lowest-point filter (the file has no ground points)"
        notes.append(f"ground: {ground_source}")
    frame = plot_frame(scan.x, scan.y, scan.z[is_ground])
    x0, y0 = frame.offset[0] - DEM_CELL, frame.offset[1] - DEM_CELL
    shape = (int(frame.size[1] / DEM_CELL) + 2, int(frame.size[0] / DEM_CELL) + 2)
    dem = ground.dem(scan.x[is_ground], scan.y[is_ground], scan.z[is_ground], x0, y0, shape, DEM_CELL)
    h = scan.z - ground.ground_height(dem, x0, y0, DEM_CELL, scan.x, scan.y)
    if settings is None:
        first_density = np.count_nonzero(scan.return_number == 1) / (frame.size[0] * frame.size[1])
        settings = detection.DetectionSettings(cell=detection.chm_cell(first_density))
    cx, cy = frame.offset[0], frame.offset[1]
    chm_shape = (int(math.ceil(frame.size[1] / settings.cell)), int(math.ceil(frame.size[0] / settings.cell)))
    chm = detection.canopy_height_model(scan.x, scan.y, h, cx, cy, chm_shape, settings.cell)
    trees = detection.detect_trees(chm, cx, cy, settings)
    first = scan.return_number == 1
    row, col = ground.grid_index(scan.x[first], scan.y[first], cx, cy, settings.cell, chm_shape)
    gap = foliage.crown_gap_fraction(h[first], chm[row, col] >= settings.min_height)
    angle = float(np.median(np.abs(scan.scan_angle[first]))) if scan.scan_angle is not None else 0.0
    lai = foliage.effective_lai(gap, angle) if gap is not None else None
    ratio = foliage.crown_ratio(foliage.relative_heights_under_crowns(scan.x, scan.y, h, trees.x, trees.y, trees.height,
                                                                      trees.crown_radius))
    tree_ratios = foliage.tree_crown_ratios(scan.x, scan.y, h, trees.x, trees.y, trees.height, trees.crown_radius, ratio)
    cells = understory.shrub_cells(scan.x, scan.y, h, cx, cy,
                                   (int(frame.size[1] / understory.CELL), int(frame.size[0] / understory.CELL)))
    estimate = survey.estimate(scan, float(np.mean(dem)))
    if estimate.scan_angle_side == "left":
        notes.append("scan angles: the file's grow to the left of the flight, where LAS counts them positive to "
                     "the right; the twin's follow LAS, so compare shows them mirrored")
    unit = intensity.intensity_unit(scan, None if estimate.altitude is None else estimate.altitude + float(np.mean(dem)))
    from ..compare.metrics import pulse_count
    pulses = pulse_count(scan.return_number, scan.number_of_returns, scan.first_only)
    return {"frame": frame, "dem": dem, "dem_origin": (x0, y0), "ground_source": ground_source, "trees": trees,
            "crown_gap_fraction": gap, "scan_angle": angle, "crown_lai": lai, "crown_ratio": ratio, "tree_crown_ratios": tree_ratios,
            "bushes": understory.bush_count(cells), "shrub_area_m2": float(cells.sum() * understory.CELL ** 2),
            "survey": estimate, "intensity_unit": unit, "pulse_density": pulses / (frame.size[0] * frame.size[1]), "notes": notes,
            "settings": settings}


def scene_stem(path) -> str:
    """A point file's name less its format's suffix: ``plot`` of ``plot.laz`` and of ``plot.copc.laz``."""
    from ..fields import POINT_FORMATS
    from ..write.formats import format_of
    name, fmt = Path(path).name, format_of(path)
    return name[:-len(POINT_FORMATS[fmt])] if fmt else Path(path).stem


def _check_variant(variant: str) -> None:
    """Refuse a ``--variant`` the calibration renders could not run, as a scene's ``simulation.variant``
    would be refused, in one line naming the option."""
    from ..errors import UserError
    from ..scene.variant import VariantError, select_variant
    if variant != "auto" and not variant.startswith(("llvm_", "cuda_")):
        raise UserError(f"--variant: must be auto or a Mitsuba llvm_* or cuda_* variant such as llvm_ad_mono, "
                        f"got {variant!r}")
    try:
        select_variant(variant)
    except VariantError as e:
        raise UserError(f"--variant: {e.reason}") from None


def make_twin(path, out_dir, species=(), sensor=None, name: str | None = None, log=None, calibrate: int = 0,
              variant: str | None = None) -> dict:
    """Write the twin of the scan ``path`` into ``out_dir``: ``<name>.yaml``, ``<name>_dem.tif``,
    ``trees.csv`` and ``twin.json``; returns the report (``twin.json``'s content).

    :param species: procedural families drawn for the trees in turn (default ``pinus_radiata``).
    :param sensor: a built-in sensor's name or a sensor file to use instead of the estimated sensor.
    :param name: the scene's name (default: the file's stem, or ``twin`` where that cannot name files).
    :param calibrate: render the twin up to this many times, rescaling its crowns' leaf area, width and
        depth towards the real scan's echoes per pulse (or gap fraction), canopy cover and canopy spread
        after each (:mod:`.calibrate`); ``variant`` is the Mitsuba variant of those renders.
    :raises UserError: one line, before anything is written: an unreadable or empty file, an unknown
        species, a bad name or sensor file, an output folder that cannot be written.
    """
    from ..classes import TREE_SPECIES
    from ..config.schema import name_problem
    from ..errors import UserError
    from .scene import write_twin
    for s in species:
        if s not in TREE_SPECIES:
            raise UserError(f"--species: must be one of {', '.join(TREE_SPECIES)}, got {s!r}")
    if not 0 <= calibrate <= MAX_CALIBRATIONS:
        raise UserError(f"--calibrate: must be within 0-{MAX_CALIBRATIONS} (each is a render of the twin; "
                        f"calibration converges in 2-4), got {calibrate:,}")
    if name is not None and (problem := name_problem(name)):
        raise UserError(f"--name: {problem}")
    if sensor is not None:
        from ..config import load_sensor, sensor_file
        sensor = sensor_file(sensor)
        load_sensor(sensor)                     # a bad sensor file is refused before any work
    if calibrate:           # not once the twin's files are written, naming its scene file; unused without it
        _check_variant("auto" if variant is None else variant)
    scan = read_scan(path)
    stem = scene_stem(path)
    name = name or (stem if name_problem(stem) is None else "twin")
    analysis = analyse(scan)
    report = write_twin(analysis, scan, Path(out_dir), name, tuple(species), sensor, log)
    if calibrate:
        from .calibrate import calibrate as calibrate_crowns
        report["calibration"] = calibrate_crowns(scan, analysis, Path(out_dir), name, calibrate, variant, log)
    return report
