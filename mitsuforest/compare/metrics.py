"""Metrics of a point cloud and distances between two, as pure functions of numpy arrays.

Coordinates are metres; ``n`` is a cloud's point count. Cells are square, ``cell`` metres on a side,
counted from an ``origin`` (the lower-left corner of the cloud's x-y bounds, floored to the metre,
unless given), so that two calls on one cloud agree on its cells.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

CELL_M = 1.0              # covered ground, canopy cover, the ground model's grid
CANOPY_M = 2.0            # a first return this high above the ground is canopy
GROUND_REACH_M = 0.2      # a return at most this high above the ground model reached the ground (any class)
SPACING_QUERIES = 200_000  # nearest-neighbour queries of the spacing: every k-th point beyond this many
FILTER_CELL_M = 2.0       # the fallback ground filter: lowest point per cell of this size ...
FILTER_WINDOW = 5         # ... kept when within FILTER_RISE_M of the lowest in this many cells square ...
FILTER_RISE_M = 1.5
FILTER_BAND_M = 0.3       # ... and points within this of the surface through the kept points are ground
PROFILE_RANGE_M = (-20.0, 200.0)  # the vertical profile's bins span at most this
HEIGHT_DIGITS = 6         # heights above the ground are rounded to the micrometre (the float noise of z less ground)
MAX_GRID_CELLS = 4_000_000  # the ground model's grid coarsens beyond this many cells (a very wide file)
ISOLATION_CELL_M = 5.0    # a point is isolated when the 3 x 3 x 3 cubes of this size around it ...
ISOLATION_OTHERS = 6      # ... hold fewer than this many other points (lidR's isolated voxel filter)
STRAY_POINTS = 20         # a cluster of such cubes apart from the scan, of fewer than this many points, ...
STRAY_REACH_M = 20.0      # ... above or below the scan within this horizontal distance (or away from it) is stray


def grid_origin(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """The lower-left corner of the (n,) points' bounds, floored to the metre."""
    return float(np.floor(np.min(x))), float(np.floor(np.min(y)))


def cell_keys(x: np.ndarray, y: np.ndarray, cell: float = CELL_M, origin=None) -> np.ndarray:
    """(n,) int64 key of each point's cell: one number per cell, the same for any subset of the points
    given the same ``origin`` (which must lie below and left of them)."""
    x0, y0 = grid_origin(x, y) if origin is None else origin
    ix = np.floor((np.asarray(x, np.float64) - x0) / cell).astype(np.int64)
    iy = np.floor((np.asarray(y, np.float64) - y0) / cell).astype(np.int64)
    return (ix << 32) | iy


def _cube_grid(x: np.ndarray, y: np.ndarray, z: np.ndarray, cell: float):
    """The occupied ``cell`` m cubes of the (n,) points: their (m, 3) int64 indices (from 1, counted from the
    points' lowest corner), their (m,) sorted keys, the (n,) cube of each point and the (m,) points in each."""
    v = np.floor(np.column_stack([x - np.min(x), y - np.min(y), z - np.min(z)]) / cell).astype(np.int64) + 1
    v = np.minimum(v, (1 << 21) - 2)      # 21 bits an axis: beyond 10,000 km, all in the last cube
    keys, first, inverse, count = np.unique(_cube_key(v), return_index=True, return_inverse=True,
                                            return_counts=True)
    return v[first], keys, inverse.ravel(), count


def _cube_key(c: np.ndarray) -> np.ndarray:
    """(m,) int64 key of the (m, 3) cube indices (each 0 to 2²¹ - 1), sorted as the indices (x, then y, then z)."""
    return (c[:, 0] << 42) | (c[:, 1] << 21) | c[:, 2]


def _found(keys: np.ndarray, wanted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where each of the (k,) ``wanted`` keys is in the (m,) sorted ``keys``: (k,) index (clipped), (k,) bool
    found."""
    at = np.clip(np.searchsorted(keys, wanted), 0, len(keys) - 1)
    return at, keys[at] == wanted


NEIGHBOURS = np.array(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1])).reshape(3, -1).T   # (27, 3) cube steps


def isolated_points(x: np.ndarray, y: np.ndarray, z: np.ndarray, cell: float = ISOLATION_CELL_M,
                    others: int = ISOLATION_OTHERS) -> np.ndarray:
    """(n,) bool: points alone in space, a bird, a multipath echo far below the ground, a stray
    coordinate: the ``cell`` m cube holding the point and the 26 cubes around it hold fewer than
    ``others`` other points (an isolated voxel filter, as lidR's ``ivf(res = 5, n = 6)`` and LAStools'
    ``lasnoise``). A scan samples its ground and crowns densely enough that no surface point is that
    alone (the two real scans: none of 390,877 and 37,657 points). A cluster of ``others`` + 1 or more
    such points is not alone: see :func:`stray_clusters`."""
    cubes, keys, inverse, count = _cube_grid(x, y, z, cell)
    around = np.zeros(len(keys), np.int64)
    for step in NEIGHBOURS:
        at, hit = _found(keys, _cube_key(cubes + step))
        around += np.where(hit, count[at], 0)
    return (around - 1 < others)[inverse]


def cube_components(x: np.ndarray, y: np.ndarray, z: np.ndarray,
                    cell: float = ISOLATION_CELL_M) -> tuple[np.ndarray, np.ndarray]:
    """The connected parts of the (n,) points: (n,) int64 part of each point (0, 1, ...) and (k,) points in
    each part. Two points are in one part when a chain of occupied ``cell`` m cubes, each one of the 26
    around the one before, joins theirs: parts are apart by more than ``cell`` m on some axis, and those
    more than 2 ``cell`` m apart on an axis are always apart. Sparse, over the occupied cubes only (a
    point kilometres away costs one cube)."""
    _, inverse, count, part = _cube_parts(x, y, z, cell)
    return part[inverse], np.bincount(part, weights=count).astype(np.int64)


def _cube_parts(x: np.ndarray, y: np.ndarray, z: np.ndarray, cell: float):
    """:func:`_cube_grid`'s (m, 3) cubes, (n,) cube of each point and (m,) points in each, and the (m,) int64
    part (connected component, 26-neighbourhood) of each cube."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    cubes, keys, inverse, count = _cube_grid(x, y, z, cell)
    steps = NEIGHBOURS[14:]           # 13: one of each pair of opposite steps (13 is the cube itself)
    pairs = [(np.flatnonzero(hit), at[hit]) for at, hit in (_found(keys, _cube_key(cubes + s)) for s in steps)]
    i = np.concatenate([p[0] for p in pairs])
    j = np.concatenate([p[1] for p in pairs])
    graph = coo_matrix((np.ones(len(i), np.int8), (i, j)), shape=(len(keys), len(keys)))
    return cubes, inverse, count, connected_components(graph, directed=False)[1].astype(np.int64)


def stray_clusters(x: np.ndarray, y: np.ndarray, z: np.ndarray, cell: float = ISOLATION_CELL_M,
                   points: int = STRAY_POINTS, reach: float = STRAY_REACH_M) -> np.ndarray:
    """(n,) int64: the stray cluster each point is in (0, 1, ...), -1 for the scan's points. A stray cluster
    is a flock of birds over the canopy, a multipath cluster under the ground, a group of stray coordinates:
    a part of the points (:func:`cube_components`, ``cell`` m cubes) of fewer than ``points`` points that

    - lies wholly above the highest or wholly below the lowest point of the scan within ``reach`` m
      horizontally (the scan's points in the ``cell`` m columns within ceil(``reach`` / ``cell``) columns of
      the cluster's, a square), or
    - has no point of the scan within that reach,

    where the scan is every part of ``points`` points or more, and the largest part always.

    Why both conditions: size alone cannot tell a flock from a lone crown in sparse data. The two real scans
    are one part each (5 m cubes: UAS_Clip 390,877 points in 224 cubes, MixedConifer 37,657 in 1,495), but
    a crown with a gap of more than 2 ``cell`` m under it is a part of its own, and MixedConifer's (4.7
    points/m²) smallest crowns hold as few points as a flock: the upper halves of its 197 segmented trees
    taller than 5 m hold 4, 17, 24, 25, 29, ... points. None of its 206 trees' upper halves lies wholly above
    the other points within 5, 10 or 15 m of it: a crown has neighbours as tall, a flock has none, and
    multipath lies under the ground. Limit: a part of fewer than ``points`` points higher than all within
    ``reach`` (a lone crown of a few points over open ground, with more than ``cell`` to 2 ``cell`` m of
    unseen stem under it) is taken for stray.
    """
    cubes, inverse, count, part = _cube_parts(x, y, z, cell)
    sizes = np.bincount(part, weights=count).astype(np.int64)
    scan = sizes >= points
    scan[np.argmax(sizes)] = True
    if scan.all():
        return np.full(len(x), -1, np.int64)
    top, bottom = np.full(len(cubes), -np.inf), np.full(len(cubes), np.inf)    # each cube's highest, lowest point
    np.maximum.at(top, inverse, z)
    np.minimum.at(bottom, inverse, z)
    in_scan = scan[part]
    # The scan's highest and lowest point in each column of cubes (cubes are sorted by column, then height).
    column = (cubes[:, 0] << 21) | cubes[:, 1]
    columns, first = np.unique(column[in_scan], return_index=True)
    col_top = np.maximum.reduceat(top[in_scan], first)
    col_bottom = np.minimum.reduceat(bottom[in_scan], first)
    # The scan's highest and lowest point in the columns within reach of each cube of a small part.
    small = np.flatnonzero(~in_scan)
    near_top, near_bottom = np.full(len(small), -np.inf), np.full(len(small), np.inf)
    r = int(np.ceil(reach / cell))
    for dx in range(-r, r + 1):
        for dy in range(-r, r + 1):
            cy = cubes[small, 1] + dy
            at, hit = _found(columns, ((cubes[small, 0] + dx) << 21) | cy)
            hit &= (cy >= 0) & (cy < 1 << 21)       # a column off the grid's edge is none
            near_top = np.where(hit, np.maximum(near_top, col_top[at]), near_top)
            near_bottom = np.where(hit, np.minimum(near_bottom, col_bottom[at]), near_bottom)
    k = len(sizes)       # ... and over each small part's cubes
    reach_top, high = np.full(k, -np.inf), np.full(k, -np.inf)
    reach_bottom, low = np.full(k, np.inf), np.full(k, np.inf)
    np.maximum.at(reach_top, part[small], near_top)
    np.minimum.at(reach_bottom, part[small], near_bottom)
    np.minimum.at(low, part[small], bottom[small])
    np.maximum.at(high, part[small], top[small])
    stray = ~scan & (np.isneginf(reach_top) | (low > reach_top) | (high < reach_bottom))
    number = np.where(stray, np.cumsum(stray) - 1, -1)
    return number[part][inverse]


def covered_area(x: np.ndarray, y: np.ndarray, cell: float = CELL_M) -> float:
    """Area (m²) of the cells holding at least one of the (n,) points: the ground the scan covers."""
    if len(x) == 0:
        return 0.0
    return float(len(np.unique(cell_keys(x, y, cell))) * cell * cell)


def median_spacing(x: np.ndarray, y: np.ndarray, queries: int = SPACING_QUERIES) -> float:
    """Median 2-D (x-y) distance from a point to its nearest neighbour among the (n,) points.

    The tree holds every point; when there are more than ``queries``, only every k-th point asks
    (deterministic, and unbiased, unlike thinning the points, which would widen the spacing).
    Coincident points (distance 0) count as they are. nan for fewer than 2 points.
    """
    from scipy.spatial import cKDTree
    if len(x) < 2:
        return float("nan")
    xy = np.column_stack([x - np.min(x), y - np.min(y)])
    step = max(1, -(-len(xy) // queries))
    d, _ = cKDTree(xy).query(xy[::step], k=2)
    return float(np.median(d[:, 1]))


def first_returns(return_number: np.ndarray) -> np.ndarray:
    """(n,) bool: a pulse's first return (return number 1; 0, which LAS forbids, counts as 1)."""
    return np.asarray(return_number) <= 1


def last_returns(return_number: np.ndarray, number_of_returns: np.ndarray) -> np.ndarray:
    """(n,) bool: a pulse's last return (its return number is its number of returns, or above it)."""
    return np.asarray(return_number) >= np.asarray(number_of_returns)


def pulses_by_returns(return_number: np.ndarray, number_of_returns: np.ndarray) -> np.ndarray:
    """(k,) pulses by their number of returns (entry 0: none; k - 1 the most returns of a pulse):
    each pulse is counted once, at its first return, by that point's ``number_of_returns``.

    GPS time is not needed (a file cut from a larger one may hold a pulse's later returns without its
    first: those are left out).
    """
    counts = np.asarray(number_of_returns)[first_returns(return_number)].astype(np.int64)
    return np.bincount(np.maximum(counts, 1), minlength=2)


def first_returns_only(return_number: np.ndarray, number_of_returns: np.ndarray,
                       gps_time: np.ndarray | None) -> bool:
    """Whether the (n,) points are one point a pulse, its first return, with the pulse's count of returns
    kept: every return number 1, some numbers of returns above 1, and no two points at one GPS time (a
    pulse's returns share its time). lidR's MixedConifer.laz is such a file: its points with two or more
    returns are never ground. Without GPS times this cannot be told from a file that left its return
    numbers 1, and is not assumed."""
    rn, nr = np.asarray(return_number), np.asarray(number_of_returns)
    if gps_time is None or len(rn) < 2 or np.any(rn > 1) or not np.any(nr > 1):
        return False
    t = np.asarray(gps_time)
    return bool(np.any(t != t[0]) and len(np.unique(t)) == len(t))


def pulse_count(return_number: np.ndarray, number_of_returns: np.ndarray, first_only: bool = False) -> float:
    """The pulses the (n,) points stand for: their first returns where the return numbers are filled
    (some above 1) or the file holds first returns only (``first_only``, :func:`first_returns_only`), else
    the sum of one over each point's number of returns (a file that numbered none of its returns but
    counted them)."""
    rn = np.asarray(return_number)
    if first_only or np.any(rn > 1):
        return float(np.count_nonzero(first_returns(rn)))
    return float(np.sum(1.0 / np.maximum(np.asarray(number_of_returns, np.float64), 1.0)))


def numbers_of_returns_by_time(return_number: np.ndarray, gps_time: np.ndarray,
                               source: np.ndarray | None = None) -> np.ndarray | None:
    """(n,) each point's number of returns, for a file that filled its return numbers but left its
    numbers of returns 0: the largest return number among the points of its pulse, the points that share
    its GPS time (and flight line ``source``). None where the times do not tell pulses apart: a time
    holding two points of one return number (times stamped coarser than the pulse rate), or a time that
    is not a number (NaN, which is no pulse's time)."""
    t = np.asarray(gps_time, np.float64)
    if len(t) == 0 or np.isnan(t).any():
        return None
    rn = np.asarray(return_number, np.int64)
    source = np.zeros(len(t), np.int64) if source is None else np.asarray(source, np.int64)
    order = np.lexsort((rn, t, source))       # sorts, unlike np.unique on records, at numpy's sort speed
    t, source, rn_sorted = t[order], source[order], rn[order]
    starts = np.flatnonzero(np.r_[True, (t[1:] != t[:-1]) | (source[1:] != source[:-1])])
    pulse = np.repeat(np.arange(len(starts)), np.diff(np.r_[starts, len(t)]))
    if np.any((pulse[1:] == pulse[:-1]) & (rn_sorted[1:] == rn_sorted[:-1])):
        return None
    counts = np.empty(len(t), np.int64)
    counts[order] = np.maximum.reduceat(rn_sorted, starts)[pulse]
    return counts


def shares(counts: np.ndarray) -> np.ndarray:
    """(k,) ``counts`` over their sum (zeros when the sum is 0)."""
    counts = np.asarray(counts, np.float64)
    total = counts.sum()
    return counts / total if total else counts


def total_variation(p: np.ndarray, q: np.ndarray) -> float:
    """Total variation distance between two discrete distributions (shares of the same categories,
    the shorter padded with zeros): half the sum of absolute differences, 0 (same) to 1 (disjoint)."""
    k = max(len(p), len(q))
    p, q = (np.pad(np.asarray(v, np.float64), (0, k - len(v))) for v in (p, q))
    return float(0.5 * np.abs(p - q).sum())


def ks_statistic(a: np.ndarray, b: np.ndarray) -> float:
    """Two-sample Kolmogorov-Smirnov statistic: the largest gap between the empirical distribution
    functions of the samples (m,) and (k,), 0 to 1. nan when either is empty."""
    from scipy.stats import ks_2samp
    if len(a) == 0 or len(b) == 0:
        return float("nan")
    return float(ks_2samp(a, b).statistic)


def earth_movers(a: np.ndarray, b: np.ndarray) -> float:
    """1-D earth mover's (Wasserstein-1) distance between the samples (m,) and (k,), in their unit:
    for a sample shifted by d, exactly d. nan when either is empty."""
    from scipy.stats import wasserstein_distance
    if len(a) == 0 or len(b) == 0:
        return float("nan")
    return float(wasserstein_distance(a, b))


@dataclass(frozen=True)
class GroundModel:
    """Ground heights on a regular grid of nodes: ``z[i, j]`` at x = x0 + (i - 0.5) cell,
    y = y0 + (j - 0.5) cell (the centres of the cells from ``x0, y0``, and a ring of cells around)."""

    x0: float
    y0: float
    cell: float
    z: np.ndarray          # (nx, ny)

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """(n,) ground height under the (n,) points, bilinear between the nodes (held flat beyond)."""
        from scipy.ndimage import map_coordinates
        u = (np.asarray(x, np.float64) - self.x0) / self.cell + 0.5
        v = (np.asarray(y, np.float64) - self.y0) / self.cell + 0.5
        return map_coordinates(self.z, [u, v], order=1, mode="nearest")


def ground_model(x: np.ndarray, y: np.ndarray, gx: np.ndarray, gy: np.ndarray, gz: np.ndarray,
                 cell: float = CELL_M) -> GroundModel:
    """The ground under the (n,) points ``x, y`` from the (g,) ground points ``gx, gy, gz``.

    Each ``cell`` holding ground points gives one node (their mean x, y, z); the grid's nodes take the
    linear interpolation over the Delaunay triangles of these, or beyond their hull the nearest one.
    The grid spans the points' bounds (it coarsens to at most MAX_GRID_CELLS cells for a wide file).
    matplotlib's triangle finder looks the grid up (scipy's ``find_simplex`` walks slowly, by seconds,
    on some regular grids of queries).

    :raises ValueError: no ground points.
    """
    from matplotlib.tri import LinearTriInterpolator, Triangulation
    from scipy.interpolate import NearestNDInterpolator
    if len(gx) == 0:
        raise ValueError("no ground points")
    x0, y0 = grid_origin(x, y)
    span = max(np.max(x) - x0, np.max(y) - y0, cell)
    cell = max(cell, span / np.sqrt(MAX_GRID_CELLS))
    nx, ny = (int(np.floor((np.max(v) - o) / cell)) + 3 for v, o in ((x, x0), (y, y0)))
    keys = cell_keys(gx, gy, cell, (x0, y0))
    _, inverse, count = np.unique(keys, return_inverse=True, return_counts=True)
    local = np.column_stack([np.bincount(inverse, gx - x0), np.bincount(inverse, gy - y0)]) / count[:, None]
    height = np.bincount(inverse, gz) / count
    # local coordinates: Qhull loses precision on UTM's millions of metres
    grid = np.meshgrid((np.arange(nx) - 0.5) * cell, (np.arange(ny) - 0.5) * cell, indexing="ij")
    nearest = NearestNDInterpolator(local, height)
    try:
        linear = LinearTriInterpolator(Triangulation(local[:, 0], local[:, 1]), height)(*grid)
        z = np.where(np.ma.getmaskarray(linear), nearest(*grid), np.ma.getdata(linear))
    except (ValueError, RuntimeError):   # fewer than 3 nodes, or all on a line
        z = nearest(*grid)
    return GroundModel(x0, y0, cell, np.asarray(z, np.float64).reshape(nx, ny))


def heights_above(z: np.ndarray, ground: np.ndarray, digits: int = HEIGHT_DIGITS) -> np.ndarray:
    """(n,) heights of the (n,) points ``z`` above the (n,) ``ground`` under them (:meth:`GroundModel.height`),
    rounded to ``digits`` decimals of a metre: z less a ground model leaves float noise of the datum's size
    (1e-13 m at 2,287 m, UAS_Clip's ground), which split tied heights (a flat ground, a layer) across KS's
    steps and the 2 m and 0.2 m thresholds; no point file stores heights finer than the micrometre."""
    return np.round(np.asarray(z, np.float64) - ground, digits)


def lowest_point_ground(x: np.ndarray, y: np.ndarray, z: np.ndarray, cell: float = FILTER_CELL_M,
                        window: int = FILTER_WINDOW, rise: float = FILTER_RISE_M,
                        band: float = FILTER_BAND_M) -> np.ndarray:
    """(n,) bool: ground points found by a lowest-point filter, for clouds without ground classes.

    The lowest point of each ``cell`` is a ground candidate when it lies within ``rise`` metres of the
    lowest candidate in the ``window`` × ``window`` cells around it (a crown's lowest point, higher than
    the ground beside it, is dropped); the surface through the kept candidates (:func:`ground_model`)
    makes every point within ``band`` metres of it ground. Slopes up to about rise / (window // 2
    cells) pass: 1.5 m over 4 m, 20° with the defaults. The cells grow for a file so wide that they
    would number more than MAX_GRID_CELLS.
    """
    from scipy.ndimage import minimum_filter
    origin = grid_origin(x, y)
    cell = max(cell, max(np.max(x) - origin[0], np.max(y) - origin[1]) / np.sqrt(MAX_GRID_CELLS))
    ix = np.floor((x - origin[0]) / cell).astype(np.int64)
    iy = np.floor((y - origin[1]) / cell).astype(np.int64)
    lowest = np.full((ix.max() + 1, iy.max() + 1), np.inf)
    np.minimum.at(lowest, (ix, iy), z)
    around = minimum_filter(lowest, size=window, mode="constant", cval=np.inf)
    keep = np.isfinite(lowest) & (lowest <= around + rise)
    candidate = keep[ix, iy] & (z == lowest[ix, iy])
    surface = ground_model(x, y, x[candidate], y[candidate], z[candidate])
    return np.abs(z - surface.height(x, y)) <= band


def vertical_profile(height: np.ndarray, bin_m: float = 1.0, within=PROFILE_RANGE_M) -> tuple[np.ndarray, np.ndarray]:
    """The (n,) heights' profile: (lower edges (b,), share of the points in each bin (b,)), bins of
    ``bin_m`` from the floor of the lowest height to past the highest; heights beyond ``within`` (a
    bird, a pit) are counted in its end bins."""
    if len(height) == 0:
        return np.zeros(0), np.zeros(0)
    height = np.clip(height, *within)
    lo = np.floor(np.min(height) / bin_m) * bin_m
    index = np.floor((height - lo) / bin_m).astype(np.int64)
    return lo + bin_m * np.arange(index.max() + 1), shares(np.bincount(index))


def canopy_heights(first_height: np.ndarray, threshold: float = CANOPY_M) -> dict:
    """p50, p95, p99 (m) of the heights above the ground of first returns (f,) at least ``threshold``
    high: the canopy's height distribution (nan values when none is that high)."""
    canopy = first_height[first_height >= threshold]
    if len(canopy) == 0:
        return {"p50": float("nan"), "p95": float("nan"), "p99": float("nan")}
    return {f"p{q}": float(v) for q, v in zip((50, 95, 99), np.percentile(canopy, [50, 95, 99]))}


def canopy_cells(fx: np.ndarray, fy: np.ndarray, first_height: np.ndarray, origin, cell: float = CELL_M,
                 threshold: float = CANOPY_M) -> tuple[np.ndarray, np.ndarray]:
    """(cell keys (c,), canopy (c,) bool) of the cells holding first returns (f,): canopy where the
    highest first return is at least ``threshold`` above the ground."""
    keys = cell_keys(fx, fy, cell, origin)
    unique, inverse = np.unique(keys, return_inverse=True)
    top = np.full(len(unique), -np.inf)
    np.maximum.at(top, inverse, first_height)
    return unique, top >= threshold


def canopy_cover(canopy: np.ndarray) -> float:
    """Share of the cells holding first returns that are canopy (see :func:`canopy_cells`)."""
    return float(np.mean(canopy)) if len(canopy) else float("nan")


def ground_under_canopy(lx: np.ndarray, ly: np.ndarray, last_ground: np.ndarray, origin, cells: np.ndarray,
                        canopy: np.ndarray, cell: float = CELL_M) -> float:
    """Share of the last returns (l,) in canopy cells that reach the ground: how often a pulse that
    meets the canopy still reaches the ground. nan when no last return lies under canopy.

    :param last_ground: (l,) bool, the last returns that reach the ground (at most ``GROUND_REACH_M``
        above the ground model, whatever their class: files under-classify their ground).
    :param cells, canopy: from :func:`canopy_cells` with the same ``origin`` and ``cell``.
    """
    keys = cell_keys(lx, ly, cell, origin)
    at = np.clip(np.searchsorted(cells, keys), 0, max(len(cells) - 1, 0))
    under = (cells[at] == keys) & canopy[at] if len(cells) else np.zeros(len(keys), bool)
    return float(np.mean(last_ground[under])) if under.any() else float("nan")


def normalised_intensity(intensity: np.ndarray, reference: float) -> np.ndarray:
    """(n,) intensity over ``reference`` (the median of first-return ground echoes), so that files
    with other intensity scales (16-bit counts, amplitudes) compare."""
    return np.asarray(intensity, np.float64) / reference


def percentiles(values: np.ndarray, qs=(5, 50, 95)) -> dict:
    """``{"p5": ..., ...}`` of the (n,) values; nan values when empty."""
    if len(values) == 0:
        return {f"p{q}": float("nan") for q in qs}
    return {f"p{q}": float(v) for q, v in zip(qs, np.percentile(values, qs))}
