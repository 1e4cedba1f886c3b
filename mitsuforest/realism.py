"""How a render compares with real Australian eucalypt forests: a table for the manifest and README.

Leaf and wood area indices come from the meshes placed in the plan; the first-return ground share
(a gap fraction), the class shares and the vertical profile from the points. Beside them stand the
published ranges in :data:`REFERENCE`, each with its source, or ``None`` where no source was found.
"""

from __future__ import annotations

import numpy as np

from .classes import GROUND, TREE_LEAVES, TREE_WOOD, class_name

# Published ranges: (low, high, source). None: no published figure was found (see README).
_WOODLAND_PFC = ("NVIS Major Vegetation Group 5, Eucalypt Woodlands fact sheet: crown cover 20-50 %, "
                 "projective foliage cover 10-30 % (https://docslib.org/doc/5026620/mvg-5-eucalypt-woodlands); "
                 "gap fraction taken as 1 - foliage cover")
_OPEN_PFC = ("Australian open forests: eucalypt foliage cover 30-70 % (http://austhrutime.com/open_forest.htm); "
             "gap fraction taken as 1 - foliage cover")
_OPEN_LAI = ("O'Grady et al. 2000, Aust. J. Bot. 48:629-638, E. miniata-E. tetrodonta open forest near Darwin: "
             "LAI at most about 1.0, 30-40 % less late in the dry season (http://www.publish.csiro.au/bt/BT99022); "
             "Whitford et al. 1995, Agric. For. Meteorol. 74:237-249, sparse jarrah forest: L = 1-2")
_FOREST_LAI = ("Pook, Gill and Moore 1997, Aust. J. Bot. 45:737-755, E. maculata forest, Kioloa NSW, 15 years: "
               "LAI 0.7-5 (https://publish.csiro.au/BT/BT95063)")
REFERENCE = {
    "woodland": {"leaf_area_index": None, "wood_area_index": None,
                 "gap_fraction": (0.70, 0.90, _WOODLAND_PFC)},
    "open": {"leaf_area_index": (0.6, 2.0, _OPEN_LAI), "wood_area_index": None,
             "gap_fraction": (0.30, 0.70, _OPEN_PFC)},
    "closed": {"leaf_area_index": (0.7, 5.0, _FOREST_LAI), "wood_area_index": None, "gap_fraction": None},
}


def triangle_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m,) areas of the triangles ``faces`` (m, 3) of ``vertices`` (n, 3)."""
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


def model_area_by_class(model) -> np.ndarray:
    """(256,) mesh surface area (m², one side of each triangle) of a model by point class."""
    classes = np.array([c.classification for c in model.components], np.int64)
    out = np.zeros(256)
    for part in model.parts:
        np.add.at(out, classes[part.component], part.of_mesh(triangle_areas))
    return out


def area_indices(plan, models) -> dict:
    """Leaf and wood area index of the trees placed in ``plan``: their classes ``tree_leaves`` and
    ``tree_wood`` (the understory is left out).

    LAI is the one-sided area of the leaf blades (each blade is one sheet of triangles) over the plot
    area; WAI is half the bark area (the hemi-surface, as for a flat leaf) over the plot area.
    """
    per_model = {name: model_area_by_class(models[name]) for name in {o.model for o in plan.objects}}
    placed = sum((per_model[o.model] for o in plan.objects), np.zeros(256))
    plot = float(plan.area[0] * plan.area[1])
    leaf, bark = placed[TREE_LEAVES], placed[TREE_WOOD]
    return {"leaf_area_m2": float(leaf), "bark_area_m2": float(bark), "plot_area_m2": plot,
            "leaf_area_index": float(leaf / plot), "wood_area_index": float(bark / 2 / plot)}


def realism_table(plan, models, classes: np.ndarray, counts) -> dict:
    """The realism table of one render (manifest key ``realism``).

    :param classes: (256,) points by class; ``counts`` a :class:`~mitsuforest.write.profile.ReturnCounts`.
    """
    first = counts.first
    total = int(classes.sum())
    edges = counts.bin_edges
    rows = np.flatnonzero(counts.by_height.sum(1))
    lo, hi = (int(rows[0]), int(rows[-1]) + 1) if len(rows) else (0, 0)
    profile = {class_name(c): counts.by_height[lo:hi, c].tolist()
               for c in np.flatnonzero(counts.by_height.sum(0))}
    return {
        **area_indices(plan, models),
        "first_return_ground_share": float(first[GROUND] / first.sum()) if first.sum() else None,
        "class_shares": {class_name(c): float(classes[c] / total)
                         for c in np.flatnonzero(classes)} if total else {},
        "vertical_profile": {"height_above_ground_m": edges[lo:hi + 1].tolist() if hi else [], "returns": profile},
        "reference": {"forest_type": plan.forest_type, **_reference(plan.forest_type)},
    }


def _reference(forest_type: str) -> dict:
    ranges = REFERENCE.get(forest_type, {})
    return {key: None if value is None else {"low": value[0], "high": value[1], "source": value[2]}
            for key, value in ranges.items()}
