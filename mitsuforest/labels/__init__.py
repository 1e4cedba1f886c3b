"""Stage 5: the labels of scanned points, from what each echo hit.

The scan records, for each echo, the object row and triangle row of its strongest sub-ray's hit in
the scene's :attr:`HitTable.located <mitsuforest.scene.HitTable.located>` (``HIT_DTYPE``); here those
rows become the point's ``instance``, ``object_id`` (the object's first id plus the triangle's
component), ``treeid``, ``classification`` (the triangle's component's class) and ``species``. The
lookups are gathers from small tables, done on the host's threads a batch at a time.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..threads import on_row_ranges

if TYPE_CHECKING:
    from ..scene import HitTable

__all__ = ["LABEL_FIELDS", "label_points", "labelled"]

LABEL_FIELDS = ("instance", "object_id", "treeid", "classification", "species")


def label_points(points: np.ndarray, hits: np.ndarray, table: HitTable) -> None:
    """Fill the :data:`LABEL_FIELDS` of ``points`` in place.

    :param points: (n,) POINT_DTYPE, as the scan made them.
    :param hits: (n,) ``HIT_DTYPE`` (``object_row``, ``triangle``) of the same echoes.
    :param table: the hit table of the scene the points were scanned in.
    """
    if len(points) != len(hits):
        raise ValueError(f"{len(points)} points but {len(hits)} hits")
    on_row_ranges(len(points), _label_rows, points, hits, table.located)


def labelled(points: np.ndarray, hits: np.ndarray, table: HitTable) -> np.ndarray:
    """:func:`label_points`, returning ``points``."""
    label_points(points, hits, table)
    return points


def _label_rows(points: np.ndarray, hits: np.ndarray, located: dict, start: int, stop: int) -> None:
    """Rows ``start:stop`` of :func:`label_points`."""
    rows, out = hits[start:stop], points[start:stop]
    obj, tri = rows["object_row"], rows["triangle"]
    out["instance"] = located["object_instance"][obj]
    out["treeid"] = located["object_treeid"][obj]
    out["species"] = located["object_species"][obj]
    out["object_id"] = located["object_id_base"][obj] + located["triangle_component"][tri]
    out["classification"] = located["triangle_class"][tri]
