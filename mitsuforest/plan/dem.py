"""Reading a GeoTIFF DEM for ``terrain.type: dem``: the cells around the plot, in the local frame.

I/O only (rasterio); :func:`~mitsuforest.plan.terrain.make_terrain` meshes what this returns. Each
refusal is a :class:`~mitsuforest.errors.UserError` whose text the plan reports as
``FILE: terrain.path: reason``.
"""

from __future__ import annotations

import logging
import math
import warnings

import numpy as np

from ..errors import UserError, display_path

log = logging.getLogger(__name__)
_WARNED: set[str] = set()    # DEMs without a CRS already warned of in this process

# No ground lies outside these heights, in metres or in feet (the Dead Sea's shore -430 m, Everest
# 8,849 m or 29,032 ft): a cell beyond them holds a nodata value the file does not declare (-9999,
# -32768, -3.4e38), read as a hole.
LOWEST_GROUND, HIGHEST_GROUND = -1000.0, 30_000.0


def read_dem(path, size, offset=(0.0, 0.0, 0.0), crs: str | None = None):
    """The DEM cells whose centres surround the plot, one extra cell beyond each edge where the DEM has it.

    :param size: the plot's extent (m); the plot is ``[0, size[0]] x [0, size[1]]`` in the local frame.
    :param offset: the scene's ``origin.offset``: local = DEM coordinates - offset (heights too).
    :param crs: the scene's ``origin.crs``; when both it and the DEM name a CRS they must be the same.
    :returns: ``x`` (nx,), ``y`` (ny,) cell centres ascending, local frame; ``z`` (ny, nx) heights.
    """
    import rasterio
    from rasterio.windows import Window

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)   # refused below, in one line
            dataset = rasterio.open(path)
    except rasterio.errors.RasterioIOError as e:
        raise UserError(f"cannot read the DEM {path}: {e}") from None
    with dataset:
        t = dataset.transform
        if t.is_identity and dataset.gcps[0]:    # rasterio's identity: pixel numbers, not the points' places
            raise UserError(f"{path}: the DEM is placed by ground control points, not a geotransform: warp it "
                            "north-up first (gdalwarp)")
        if t.is_identity:
            raise UserError(f"{path}: the DEM has no georeference (no geotransform): give it its corners and CRS "
                            "first (gdal_translate -a_ullr ULX ULY LRX LRY -a_srs EPSG:N)")
        if t.b != 0 or t.d != 0:
            raise UserError(f"{path}: the DEM's grid is rotated or sheared; warp it north-up first (gdalwarp)")
        _check_crs(path, dataset.crs, crs)
        ox, oy, oz = offset
        cols = _cell_span(t.c - ox, t.a, size[0], dataset.width)
        rows = _cell_span(t.f - oy, t.e, size[1], dataset.height)
        if cols is None or rows is None:
            raise UserError(f"{path}: the DEM does not cover the plot: it spans {_extent(t, dataset, ox, oy)} in the "
                            f"local frame (origin.offset subtracted), the plot 0..{size[0]:g} x 0..{size[1]:g} m")
        window = Window(cols[0], rows[0], cols[1] - cols[0], rows[1] - rows[0])
        band = dataset.read(1, window=window, masked=True)
        scale, shift, metres = dataset.scales[0], dataset.offsets[0], _metres_per_unit(path, dataset.units[0])
    x = t.c - ox + (np.arange(cols[0], cols[1]) + 0.5) * t.a
    y = t.f - oy + (np.arange(rows[0], rows[1]) + 0.5) * t.e
    stored = np.ma.filled(band.astype(np.float64), np.nan)
    if t.a < 0:
        x, stored = x[::-1], stored[:, ::-1]
    if t.e < 0:                      # north-up: rows run south
        y, stored = y[::-1], stored[::-1]
    height = stored * scale + shift             # GDAL's band scale and offset (1 and 0 for most DEMs)
    foreign = ~((height >= LOWEST_GROUND) & (height <= HIGHEST_GROUND)) & ~np.isnan(height)
    z = _clamp_outer_holes(x, y, np.where(foreign, np.nan, height) * metres - oz, size)
    holes = ~np.isfinite(z)
    if holes.any():
        j, i = np.argwhere(holes)[0]
        where = f"the first at local x {x[i]:.2f}, y {y[j]:.2f}"
        if foreign[j, i]:
            value = f"{stored[j, i]:.9g}"    # float32 exactly, as stored (before a scale and offset)
            raise UserError(f"{path}: the DEM has {int(holes.sum())} cells over the plot at heights no ground has "
                            f"({value}, {where}): a nodata value the file does not declare? Declare it "
                            f"(gdal_edit.py -a_nodata {value}), then fill the cells (gdal_fillnodata)")
        raise UserError(f"{path}: the DEM has {int(holes.sum())} nodata cells over the plot ({where}); "
                        "fill them first (gdal_fillnodata)")
    return x, y, np.ascontiguousarray(z)


# GDAL's band unit type as DEMs write it (lower case), and the metres in one unit.
HEIGHT_UNITS = {**dict.fromkeys(("", "m", "metre", "metres", "meter", "meters"), 1.0),
                **dict.fromkeys(("ft", "foot", "feet", "international foot"), 0.3048),
                **dict.fromkeys(("us survey foot", "us-ft", "ftus", "us_survey_foot", "survey foot"), 1200 / 3937)}


def _metres_per_unit(path, unit: str | None) -> float:
    """Metres in one unit of the DEM's heights, from its band's unit type (none: metres).

    :raises UserError: a unit that is neither metres nor feet."""
    try:
        return HEIGHT_UNITS[(unit or "").strip().lower()]
    except KeyError:
        raise UserError(f"{path}: the DEM's heights are in {unit!r}, not metres or feet: convert them to metres "
                        "first (gdal_calc.py), or name their unit where they are (gdal_edit.py -units m)") from None


def _clamp_outer_holes(x: np.ndarray, y: np.ndarray, z: np.ndarray, size) -> np.ndarray:
    """``z`` (ny, nx) with nodata (NaN) in a cell centred beyond the plot's edge (read only to interpolate
    the heights along the edge) replaced by the height of the cell inside next to it, as if the DEM
    ended there. ``x``, ``y`` ascending."""
    z = z.copy()
    for grid, centres, length in ((z.T, x, size[0]), (z, y, size[1])):    # columns, then rows
        if len(centres) < 2:
            continue
        for outer, inner in ((0, 1), (-1, -2)):
            if centres[outer] < 0 or centres[outer] > length:
                holes = np.isnan(grid[outer])
                grid[outer][holes] = grid[inner][holes]
    return z


def _cell_span(start: float, step: float, length: float, count: int) -> tuple[int, int] | None:
    """Cells ``[first, stop)`` of one axis that cover ``[0, length]``, with one more centre beyond each end
    where the raster has it; ``None`` when the raster's cells do not reach both ends (1e-6 m tolerance)."""
    lo, hi = sorted(((0.0 - start) / step, (length - start) / step))   # the plot's ends in cell units
    tolerance = 1e-6 / abs(step)
    if lo < -tolerance or hi > count + tolerance:
        return None
    first = max(math.floor(lo - 0.5), 0)
    stop = min(math.ceil(hi - 0.5) + 1, count)
    return first, max(stop, first + 1)


def _extent(t, dataset, ox, oy) -> str:
    xs = sorted((t.c - ox, t.c - ox + dataset.width * t.a))
    ys = sorted((t.f - oy, t.f - oy + dataset.height * t.e))
    return f"x {xs[0]:.2f}..{xs[1]:.2f}, y {ys[0]:.2f}..{ys[1]:.2f}"


def _check_crs(path, dem_crs, scene_crs: str | None) -> None:
    if scene_crs is not None and dem_crs is None and str(path) not in _WARNED:
        _WARNED.add(str(path))
        log.warning("mitsuforest: %s: the DEM names no CRS; its coordinates are taken to be in origin.crs (%s)",
                    display_path(path), scene_crs)
    if dem_crs is None:
        return
    from pyproj import CRS
    if scene_crs is None:        # no origin.crs to be the same as: its x and y must be in the scene's metres
        problem = _not_in_metres(dem_crs.to_wkt())
        if problem:
            theirs = CRS.from_user_input(dem_crs.to_wkt())
            raise UserError(f"{path}: the DEM's CRS ({theirs.to_string()}) {problem}; the scene is in metres: "
                            "reproject it to a projected CRS in metres (gdalwarp -t_srs)")
        return
    ours, theirs = CRS.from_user_input(scene_crs), CRS.from_user_input(dem_crs.to_wkt())
    if not ours.equals(theirs, ignore_axis_order=True):
        raise UserError(f"{path}: the DEM's CRS ({theirs.to_string()}) is not origin.crs ({ours.to_string()}); "
                        "reproject it (gdalwarp -t_srs) or fix origin.crs")


def _not_in_metres(wkt: str) -> str | None:
    """Why x and y in the CRS ``wkt`` are not metres (degrees, feet), or None: a projected CRS in metres, or a
    local grid in metres (which origin.crs could not be, but a DEM without one may)."""
    from ..crs import length_units
    try:
        _, words, across, _ = length_units(wkt)
    except ValueError:
        return "is geographic, in degrees"
    return None if across == 1.0 else f"has its axes in {words}"
