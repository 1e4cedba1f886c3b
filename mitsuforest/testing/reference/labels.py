"""The numpy twin of the hit lookup: :class:`~mitsuforest.scene.device.DeviceHitTable` locating a hit
and :func:`~mitsuforest.labels.label_points` labelling it, from the raw hit (instance, shape, shape
index, primitive) straight to labels, through the :class:`~mitsuforest.scene.HitTable`'s own arrays.

Every hit decodes to (instance, object_id, treeid, classification) and a world-frame surface normal;
a hit on a shape the table does not know is an error, never a silently unlabelled point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...classes import GROUND


@dataclass
class HitLabels:
    instance: np.ndarray        # (n,) uint32, 0 for the ground
    object_id: np.ndarray       # (n,) uint32
    treeid: np.ndarray          # (n,) uint16
    classification: np.ndarray  # (n,) uint8
    normal: np.ndarray          # (n, 3) float32, world frame, unit


def label_hits(table, instance_registry, shape_registry, shape_index, prim_index) -> HitLabels:
    """Labels and normals of hits.

    :param instance_registry: (n,) registry id of the instance hit (0 when the hit is no instance).
    :param shape_registry: (n,) registry id of the shape hit: the plain shape, or (OptiX) the mesh
        hit inside an instance (Embree gives 0 on instance hits).
    :param shape_index: (n,) index of the shape inside the instance's shapegroup (Embree).
    :param prim_index: (n,) triangle index inside that shape.
    """
    inst = np.asarray(instance_registry, np.int64)
    prim = np.asarray(prim_index, np.int64)
    n = len(inst)
    on_object = inst > 0
    ground = ~on_object
    if np.any(ground & (np.asarray(shape_registry) != table.ground_registry)):
        raise RuntimeError("a ray hit a shape that is neither the ground nor a placed object")
    row = np.full(n, -1, np.int64)
    row[on_object] = table.object_of_registry[inst[on_object]]
    if np.any(row[on_object] < 0):
        raise RuntimeError("a ray hit an instance missing from the hit table")
    r = row[on_object]
    shape = np.asarray(shape_registry, np.int64)[on_object]
    part_of_shape = np.where(shape < len(table.part_of_registry),
                             table.part_of_registry[np.minimum(shape, len(table.part_of_registry) - 1)], -1)
    part = np.where(part_of_shape >= 0, part_of_shape,
                    table.object_part_row[r] + np.asarray(shape_index, np.int64)[on_object])
    tri = table.part_base[part] + prim[on_object]
    component = table.triangle_component[tri].astype(np.int64)
    out = HitLabels(
        instance=np.zeros(n, np.uint32), object_id=np.full(n, table.ground_object_id, np.uint32),
        treeid=np.zeros(n, np.uint16), classification=np.full(n, GROUND, np.uint8),
        normal=np.zeros((n, 3), np.float32))
    out.instance[on_object] = table.object_instance[r]
    out.object_id[on_object] = table.object_id_base[r] + component
    out.treeid[on_object] = table.object_treeid[r]
    out.classification[on_object] = table.component_class[table.object_class_row[r] + component]
    out.normal[on_object] = np.einsum("nij,nj->ni", table.object_rotation[r], table.triangle_normal[tri])
    out.normal[ground] = table.ground_normal[prim[ground]]
    return out
