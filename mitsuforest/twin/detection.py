"""Individual trees on a canopy height model (pure functions).

Tree tops are variable-window local maxima (Popescu & Wynne 2004, *Photogrammetric Engineering &
Remote Sensing* 70: 589-604): a CHM cell is a top when it is the highest within a circular window whose
diameter grows with its height, their crown-width regressions
``CW = 2.51503 + 0.00901 h²`` (pines) and ``CW = 3.09632 + 0.00895 h²`` (broadleaves), scaled by
``window_scale``. Crowns are grown from the tops by a marker watershed (a priority flood) on the CHM (cells above
``min_height`` and above ``crown_share`` of their top's height, no farther from it than ``crown_reach``
times the regression's crown width: twice the radius it predicts), as Dalponte & Coomes (2016) do; a
crown's radius is that of the disc of its area.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from .ground import grid_index

WINDOW = {"conifer": (2.51503, 0.00901), "broadleaf": (3.09632, 0.00895)}   # CW = a + b h² (m)


@dataclass(frozen=True)
class DetectionSettings:
    """The detection's parameters (see the module docstring)."""

    cell: float = 1.0               # CHM cell (m); see chm_cell for the one a twin uses
    smoothing: float = 0.5          # Gaussian sigma (m) of the CHM before the maxima are found
    min_height: float = 2.0         # m: lower cells are not canopy
    crown_type: str = "conifer"     # WINDOW's regression
    window_scale: float = 0.6       # times the regression's crown width (tuned on MixedConifer's treeID)
    crown_share: float = 0.5        # a crown cell is at least this share of its top's height
    crown_reach: float = 1.0        # a crown cell is at most this many regression crown widths from its top


def chm_cell(first_returns_per_m2: float) -> float:
    """A CHM cell holding about four first returns (so that few cells are empty), in 0.5 m steps from
    0.5 to 2 m: 1 m at MixedConifer's 4.7 points/m², 0.5 m for UAV scans."""
    if first_returns_per_m2 <= 0:
        return 1.0
    return float(np.clip(np.round(2.0 / np.sqrt(first_returns_per_m2) * 2) / 2, 0.5, 2.0))


@dataclass(frozen=True)
class DetectedTrees:
    """Trees found on a CHM, shapes (k,): top positions (m), heights above ground (m), crown radii (m)."""

    x: np.ndarray
    y: np.ndarray
    height: np.ndarray
    crown_radius: np.ndarray


def canopy_height_model(x, y, h, x0: float, y0: float, shape, cell: float) -> np.ndarray:
    """The highest height above ground in each cell (ny, nx), row 0 south; empty cells take the lowest of
    their neighbours' (so a gap stays a gap), then 0."""
    row, col = grid_index(x, y, x0, y0, cell, shape)
    chm = np.full(shape, -np.inf)
    np.maximum.at(chm, (row, col), np.asarray(h, float))
    for _ in range(3):
        empty = ~np.isfinite(chm)
        if not empty.any():
            break
        neighbours = ndimage.minimum_filter(np.where(empty, np.inf, chm), size=3, mode="nearest")
        chm[empty & np.isfinite(neighbours)] = neighbours[empty & np.isfinite(neighbours)]
    return np.maximum(np.where(np.isfinite(chm), chm, 0.0), 0.0)


def window_diameter(height, settings: DetectionSettings) -> np.ndarray:
    """The search window's diameter (m) at ``height`` (m)."""
    a, b = WINDOW[settings.crown_type]
    return settings.window_scale * (a + b * np.asarray(height, float) ** 2)


def tree_tops(chm: np.ndarray, settings: DetectionSettings) -> np.ndarray:
    """Rows and columns (k, 2) of the CHM's variable-window local maxima above ``min_height``."""
    diameters = window_diameter(chm, settings)
    radii_cells = np.maximum(np.round(diameters / 2 / settings.cell).astype(int), 1)
    tops = np.zeros(chm.shape, bool)
    candidates = chm >= settings.min_height
    for r in np.unique(radii_cells[candidates]):
        yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
        highest = ndimage.maximum_filter(chm, footprint=xx * xx + yy * yy <= r * r, mode="nearest")
        at = candidates & (radii_cells == r)
        tops |= at & (chm >= highest)
    labels, count = ndimage.label(tops, structure=np.ones((3, 3)))   # a flat top counts once
    if count == 0:
        return np.zeros((0, 2), int)
    centres = ndimage.center_of_mass(tops, labels, np.arange(1, count + 1))
    return np.rint(np.array(centres)).astype(int)


def crowns(chm: np.ndarray, tops: np.ndarray, settings: DetectionSettings) -> np.ndarray:
    """Crown labels (ny, nx): 1..k for the crown of top k, 0 outside every crown.

    A priority flood (scikit-image's ``watershed``) from the tops down the CHM, within the cells above
    ``min_height``: a cell joins the crown whose flood reaches it first, level by level. (scipy's
    ``watershed_ift`` orders by the steps between cells instead, so on a gentle slope the bare ground's
    marker climbed a crown standing alone and left it its top cells.)
    """
    from skimage.segmentation import watershed
    markers = np.zeros(chm.shape, np.int32)
    markers[tops[:, 0], tops[:, 1]] = np.arange(1, len(tops) + 1)
    canopy = chm >= settings.min_height
    labels = watershed(-chm, markers, mask=canopy).astype(np.int64)
    top_height = np.zeros(len(tops) + 1)
    top_height[1:] = chm[tops[:, 0], tops[:, 1]]
    rows, cols = np.indices(chm.shape)
    reach = np.zeros(len(tops) + 1)
    a, b = WINDOW[settings.crown_type]
    reach[1:] = settings.crown_reach * (a + b * top_height[1:] ** 2) / settings.cell
    centre_r, centre_c = np.zeros(len(tops) + 1), np.zeros(len(tops) + 1)
    centre_r[1:], centre_c[1:] = tops[:, 0], tops[:, 1]
    far = np.hypot(rows - centre_r[labels], cols - centre_c[labels]) > reach[labels]
    low = chm < settings.crown_share * top_height[labels]
    labels[far | low | ~canopy] = 0
    return labels


def detect_trees(chm: np.ndarray, x0: float, y0: float, settings: DetectionSettings = DetectionSettings()) -> DetectedTrees:
    """Tree tops and crowns on a CHM whose SW corner is (x0, y0): positions in the CHM's coordinates."""
    smooth = ndimage.gaussian_filter(chm, settings.smoothing / settings.cell) if settings.smoothing > 0 else chm
    tops = tree_tops(smooth, settings)
    if len(tops) == 0:
        empty = np.zeros(0)
        return DetectedTrees(empty, empty, empty, empty)
    labels = crowns(smooth, tops, settings)
    area = np.bincount(labels.ravel(), minlength=len(tops) + 1)[1:] * settings.cell ** 2
    height = _top_heights(chm, tops)
    radius = np.maximum(np.sqrt(area / np.pi), settings.cell)
    return DetectedTrees(x=x0 + (tops[:, 1] + 0.5) * settings.cell, y=y0 + (tops[:, 0] + 0.5) * settings.cell,
                         height=height, crown_radius=radius)


def _top_heights(chm: np.ndarray, tops: np.ndarray) -> np.ndarray:
    """Each top's height on the raw CHM: the highest cell within one cell of it (smoothing lowers peaks)."""
    highest = ndimage.maximum_filter(chm, size=3, mode="nearest")
    return highest[tops[:, 0], tops[:, 1]]


def match(found: np.ndarray, truth: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one matching of found tree positions (k, 2) to true ones (m, 2) within ``radius`` (m), the
    total distance least (Hungarian assignment): index pairs (found, truth), each of shape (p,)."""
    from scipy.optimize import linear_sum_assignment
    if len(found) == 0 or len(truth) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    d = np.hypot(found[:, None, 0] - truth[None, :, 0], found[:, None, 1] - truth[None, :, 1])
    rows, cols = linear_sum_assignment(np.where(d <= radius, d, 1e6))
    keep = d[rows, cols] <= radius
    return rows[keep], cols[keep]


def scores(found: np.ndarray, truth: np.ndarray, radius: float) -> dict:
    """Precision, recall and F1 of found tree positions against true ones, matched one to one within ``radius``."""
    pairs = len(match(found, truth, radius)[0])
    precision = pairs / len(found) if len(found) else 0.0
    recall = pairs / len(truth) if len(truth) else 0.0
    f1 = 2 * precision * recall / (precision + recall) if pairs else 0.0
    return {"found": len(found), "true": len(truth), "matched": pairs, "precision": precision, "recall": recall, "f1": f1}
