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
CONE_MEDIAN_DEPTH = np.sqrt(0.5) ** (1 / CONE_EXPONENT)   # 0.68: see crown_ratio
CROWN_RATIO_RANGE = (0.2, 0.9)


def crown_ratio(h_first_canopy, tree_heights) -> float | None:
    """The live-crown ratio of conical crowns that puts the median first return as deep into the crowns
    as the scan's: seen from above, a cone of length ``L`` under its top ``H`` is first hit at
    ``H - L · (ρ/R)^(1/0.9)``, and half a disc's area lies within ``ρ/R = √0.5``, so the median hit is
    0.68 ``L`` below the top. ``h_first_canopy``: heights of first returns at least 2 m above the ground;
    ``tree_heights``: the trees found. ``None`` without either; within :data:`CROWN_RATIO_RANGE`."""
    h, tops = np.asarray(h_first_canopy, float), np.asarray(tree_heights, float)
    if not len(h) or not len(tops):
        return None
    ratio = (1.0 - float(np.median(h)) / float(np.median(tops))) / CONE_MEDIAN_DEPTH
    return float(np.clip(ratio, *CROWN_RATIO_RANGE))
