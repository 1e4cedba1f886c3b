"""Leaves: lanceolate blades of two triangles, clumped at twig ends and hanging at an angle."""

from __future__ import annotations

import numpy as np


def leaf_count(leaf_area: float, length: float, width: float) -> int:
    """Leaves needed for a one-sided ``leaf_area``: a blade is a rhombus of area length·width/2."""
    return int(round(leaf_area / (0.5 * length * width)))


INCLINATION_SPREAD = 15.0   # deg, sd of the blades' angle below horizontal


def _clipped_mean(location: float, sd: float, lo: float, hi: float) -> float:
    """Mean of ``clip(N(location, sd), lo, hi)``."""
    from math import erf, exp, pi, sqrt
    a, b = (lo - location) / sd, (hi - location) / sd
    cdf = lambda x: 0.5 * (1 + erf(x / sqrt(2)))            # noqa: E731
    pdf = lambda x: exp(-0.5 * x * x) / sqrt(2 * pi)        # noqa: E731
    return lo * cdf(a) + hi * (1 - cdf(b)) + location * (cdf(b) - cdf(a)) + sd * (pdf(a) - pdf(b))


def dip_location(inclination: float, sd: float = INCLINATION_SPREAD) -> float:
    """Where to centre the normal of blade angles (deg) so that, clipped to 0-90°, they average
    ``inclination`` (by bisection; 76.5° for 75°). Clipping about ``inclination`` itself pulled the mean
    towards 45°, by 6° at the bounds."""
    lo, hi = -10 * sd, 90 + 10 * sd
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if _clipped_mean(mid, sd, 0.0, 90.0) < inclination else (lo, mid)
    return 0.5 * (lo + hi)


def leaf_blades(anchors: np.ndarray, length: float, width: float, inclination: float, rng) -> tuple[np.ndarray, np.ndarray]:
    """Blades hanging from ``anchors``.

    :param anchors: (k, 3) petiole points on twigs.
    :param inclination: mean blade angle below horizontal (deg); spread ±15° within 0-90° (:func:`dip_location`).
    Blade sizes vary by ±20 % about ``length`` × ``width``, scaled so that the k blades hold exactly k
    times a blade's area, ``length · width / 2`` (one-sided).
    :returns: vertices (4k, 3) and faces (2k, 3): base, left, tip, right per blade.
    """
    k = len(anchors)
    az = rng.uniform(0, 2 * np.pi, k)
    dip = np.deg2rad(np.clip(rng.normal(dip_location(inclination), INCLINATION_SPREAD, k), 0, 90))
    axis = np.column_stack([np.cos(az) * np.cos(dip), np.sin(az) * np.cos(dip), -np.sin(dip)])
    # The blade's width axis is horizontal-ish and rolled at random about the blade axis.
    side = np.column_stack([-np.sin(az), np.cos(az), np.zeros(k)])
    roll = rng.normal(0, 0.5, k)[:, None]
    side = side * np.cos(roll) + np.cross(axis, side) * np.sin(roll)
    scale = rng.uniform(0.8, 1.2, k)[:, None]
    scale /= np.sqrt(np.mean(scale ** 2)) if k else 1.0   # sizes vary, their area sums to k · length · width / 2
    base = anchors + axis * 0.01
    tip = base + axis * length * scale
    mid = base + axis * 0.4 * length * scale
    left, right = mid - side * width * scale / 2, mid + side * width * scale / 2
    vertices = np.stack([base, left, tip, right], axis=1).reshape(-1, 3)
    i = 4 * np.arange(k)[:, None]
    faces = np.concatenate([i + [0, 1, 3], i + [1, 2, 3]], axis=1).reshape(-1, 3)
    return vertices, faces


def lowered_under(vertices: np.ndarray, top: float) -> np.ndarray:
    """Blades (4 vertices each, as :func:`leaf_blades`) that rise above ``top`` moved down, whole, to reach
    it: petioles scattered about the highest twig tips lifted blades over the tree's height."""
    blades = vertices.reshape(-1, 4, 3).copy()
    blades[:, :, 2] -= np.maximum(blades[:, :, 2].max(axis=1) - top, 0.0)[:, None]
    return blades.reshape(-1, 3)


def leaves_on_twigs(twigs, leaf_area: float, length: float, width: float, inclination: float, clumping: float,
                    rng) -> tuple[np.ndarray, np.ndarray]:
    """Blades for a one-sided ``leaf_area`` spread over twigs, denser toward their tips.

    :param twigs: list of (n_i, 3) twig centrelines, base to tip.
    :param clumping: the outer fraction of each twig that carries leaves.
    :returns: vertices (4k, 3) and faces (2k, 3), as :func:`leaf_blades`.
    """
    count = leaf_count(leaf_area, length, width)
    which = rng.integers(0, len(twigs), count)
    s = 1 - clumping * rng.random(count) ** 2   # most leaves in a clump at the twig's tip
    anchors = np.empty((count, 3))
    for k, points in enumerate(twigs):
        sel = which == k
        seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
        cum = np.concatenate([[0.0], np.cumsum(seg)]) / seg.sum()
        for axis in range(3):
            anchors[sel, axis] = np.interp(s[sel], cum, points[:, axis])
    anchors += rng.normal(0, 0.25 * length, anchors.shape)   # a clump of petioles, not a line
    return leaf_blades(anchors, length, width, inclination, rng)
