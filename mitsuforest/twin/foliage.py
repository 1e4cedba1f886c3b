"""How much leaf the crowns of a real scan hold, from how few pulses pass them (pure functions).

Beer-Lambert for a canopy of randomly placed leaves with a spherical angle distribution (G = 0.5): the
share of pulses at zenith angle θ that pass the crowns without a hit is ``P = exp(-G · LAI / cos θ)``, so
``LAI = -cos θ · ln P / G`` (as LiDAR LAI estimates do, e.g. Richardson, Moskal & Kim 2009, *Agric. For.
Meteorol.* 149: 1152-1160). ``P`` is the share of first returns under the crowns (CHM at or above its
``min_height``) that reach the ground (within ``GROUND_BAND`` of the DEM), θ their median scan angle. A
crown's leaf area is this LAI times its area. Real crowns are clumped, so this is an effective LAI, a
lower bound of the true one; our shoots are clumped too.
"""

from __future__ import annotations

import numpy as np

G = 0.5              # projection of unit leaf area, spherical leaf angles
GROUND_BAND = 0.5    # m above the DEM: a first return this low passed the crown
MIN_GAP = 0.005      # P is clipped here: an opaque canopy would give an infinite LAI


def crown_gap_fraction(h_first, under_crown) -> float | None:
    """The share of first returns under crowns that reach the ground; ``None`` without any under crowns."""
    under = np.asarray(under_crown, bool)
    if not under.any():
        return None
    return float(np.mean(np.asarray(h_first)[under] < GROUND_BAND))


def effective_lai(gap: float, scan_angle_deg: float) -> float:
    """Leaf area per unit crown area (m²/m², one-sided) from a gap fraction seen at a scan angle (deg)."""
    return float(-np.cos(np.deg2rad(scan_angle_deg)) * np.log(max(gap, MIN_GAP)) / G)


CONE_EXPONENT = 0.9                      # Pinus radiata crown radius ~ (1 - u)^0.9 (trees/skeleton.py)
# Half a cone's volume lies within this share of its length from the top: its cross-section at depth s
# (from the top, in crown lengths) goes as s^(2 · 0.9), so the volume above s as s^2.8.
CONE_MEDIAN_DEPTH = 0.5 ** (1 / (2 * CONE_EXPONENT + 1))   # 0.781
CROWN_RATIO_RANGE = (0.2, 0.9)
# Returns under a crown for its own crown ratio: the median of n returns' relative heights is known to about
# 0.5 / sqrt(n) / (their density there), within 0.02 of the height at 1,000 (a crown a third of the tree deep).
MIN_TREE_RETURNS = 1000


def relative_heights_under_crowns(x, y, h, tree_x, tree_y, tree_height, tree_radius) -> np.ndarray:
    """Each return within its nearest tree's crown radius, its height ``h`` over that tree's height;
    points (n,), trees (k,). Empty without trees."""
    return _under_crowns(x, y, h, tree_x, tree_y, tree_height, tree_radius)[0]


def _under_crowns(x, y, h, tree_x, tree_y, tree_height, tree_radius) -> tuple[np.ndarray, np.ndarray]:
    """(relative heights (m,), their trees' indices (m,)) of the returns within their nearest tree's crown."""
    if not len(tree_x):
        return np.empty(0), np.empty(0, int)
    from scipy.spatial import cKDTree
    d, i = cKDTree(np.column_stack([tree_x, tree_y])).query(np.column_stack([x, y]))
    under = d <= np.asarray(tree_radius)[i]
    return np.asarray(h)[under] / np.asarray(tree_height)[i[under]], i[under]


def tree_crown_ratios(x, y, h, tree_x, tree_y, tree_height, tree_radius, stand: float | None) -> np.ndarray:
    """Each tree's own crown ratio (k,): :func:`crown_ratio` of the returns under its crown where it has
    :data:`MIN_TREE_RETURNS` of them, else the ``stand``'s (nan where that is ``None``). Real stands mix
    high, shallow crowns with deep ones (UAS_Clip's 18 trees: 0.27-0.81 where the stand's is 0.42), and
    one ratio for all piles every crown's widest part, and most of its returns, at one height."""
    rel, tree = _under_crowns(x, y, h, tree_x, tree_y, tree_height, tree_radius)
    out = np.full(len(tree_x), np.nan if stand is None else stand)
    for k in np.unique(tree):
        mine = rel[tree == k]
        if len(mine) >= MIN_TREE_RETURNS and (ratio := crown_ratio(mine)) is not None:
            out[k] = ratio
    return out


def foliage_profile(relative_height, canopy_from: float, step: float = 0.025) -> tuple[np.ndarray, np.ndarray]:
    """The cumulative foliage above each relative height, by MacArthur & Horn (1969): of all returns
    under the crowns (``relative_height``: height over the tree's own height, shape (n,)), the share
    ``n(>z) / n`` above ``z`` were stopped there, so ``-ln(1 - n(>z)/n)`` is the leaf area above ``z``
    in units of the extinction coefficient. Returns the heights from 1 down to ``canopy_from`` in
    ``step`` and that profile; returns below ``canopy_from`` (ground, understory) only count as passed."""
    rel = np.sort(np.asarray(relative_height, float))
    z = np.arange(1.0, canopy_from - 1e-9, -step)
    above = 1.0 - np.searchsorted(rel, z, side="right") / max(len(rel), 1)
    return z, -np.log(np.maximum(1.0 - above, 1e-6))


def crown_ratio(relative_height, canopy_from: float = 0.1) -> float | None:
    """The live-crown ratio of conical crowns of uniform leaf density that hold half their foliage as
    deep as the scan's crowns do: the relative height ``z50`` above which half the foliage lies
    (:func:`foliage_profile`, down to ``canopy_from`` of the tree's height), and a cone holds half its
    volume in its top :data:`CONE_MEDIAN_DEPTH` of its length, so the ratio is
    ``(1 - z50) / 0.781``. ``relative_height``: every return under the detected crowns over its tree's
    height. ``None`` without returns or foliage; within :data:`CROWN_RATIO_RANGE`."""
    if not len(relative_height):
        return None
    z, foliage = foliage_profile(relative_height, canopy_from)
    if foliage[-1] <= 0:
        return None
    z50 = float(np.interp(0.5 * foliage[-1], foliage, z))
    return float(np.clip((1.0 - z50) / CONE_MEDIAN_DEPTH, *CROWN_RATIO_RANGE))
