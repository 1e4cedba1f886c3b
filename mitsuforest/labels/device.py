"""The hit table on the device: :func:`~mitsuforest.labels.label_hits` for Dr.Jit arrays.

Used by the echo kernel, which labels sub-ray hits without copying them back to numpy. The lookups
are those of ``label_hits``, arranged for few gathers per sub-ray: the ground is one more object row
(identity rotation, its triangles after the models'), so every hit is located by an object row and a
triangle row (:meth:`DeviceHitTable.locate`), and each triangle carries its class. A hit the table
does not know is flagged in ``unknown``.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..classes import GROUND


def device_arrays(table) -> dict:
    """The table's arrays as the device uses them (numpy), the ground appended as the last object row
    (instance 0, the ground's object id, identity rotation, its triangles after the models')."""
    triangles, ground = len(table.triangle_component), len(table.ground_normal)
    return {
        "object_instance": np.append(table.object_instance, 0),
        "object_id_base": np.append(table.object_id_base, table.ground_object_id),
        "object_treeid": np.append(table.object_treeid, 0),
        "object_part_row": np.append(table.object_part_row, len(table.part_base)),
        "object_rotation": np.concatenate([table.object_rotation.reshape(-1, 9), np.eye(3).reshape(1, 9)]),
        "part_base": np.append(table.part_base, triangles),
        "triangle_component": np.append(table.triangle_component, np.zeros(ground, np.uint16)),
        "triangle_class": np.append(table.triangle_class, np.full(ground, GROUND, np.uint8)),
        "triangle_normal": np.concatenate([table.triangle_normal, table.ground_normal]),
    }


class DeviceHitTable:
    """Dr.Jit copies of a :class:`~mitsuforest.scene.HitTable`'s arrays (call under the scene's variant)."""

    def __init__(self, table):
        # One padding element each: Dr.Jit cannot gather from an empty array (a scene without objects).
        def u32(a):
            return mi.UInt32(np.append(np.asarray(a, np.uint32).reshape(-1), np.uint32(0)))

        def f32(a):
            return mi.Float(np.append(np.asarray(a, np.float32).reshape(-1), np.float32(0)))

        arrays = device_arrays(table)
        self.ground_row = len(table.object_instance)
        self.ground_registry = int(table.ground_registry)
        registry = np.asarray(table.object_of_registry)
        parts = np.asarray(table.part_of_registry)
        self.registry_size = len(registry)
        self.object_of_registry = u32(np.where(registry >= 0, registry, self.ground_row + 1))   # unknown: past the rows
        self.part_of_registry = u32(np.where(parts >= 0, parts, len(arrays["part_base"])))     # not a part: past them
        self.parts = len(arrays["part_base"])
        for name in ("object_rotation", "triangle_normal"):
            setattr(self, name, f32(arrays.pop(name)))
        for name, values in arrays.items():
            setattr(self, name, u32(values))

    def locate(self, instance: mi.UInt32, shape: mi.UInt32, shape_index: mi.UInt32, prim: mi.UInt32,
               active: mi.Bool) -> tuple[mi.UInt32, mi.UInt32, mi.Bool]:
        """Each hit's object row (the ground's for ground hits) and global triangle row, and the
        ``unknown`` mask (a shape that is neither the ground nor a placed object)."""
        on_object = active & (instance > 0)
        in_registry = on_object & (instance < self.registry_size)
        row = dr.select(in_registry, dr.gather(mi.UInt32, self.object_of_registry, instance, in_registry),
                        self.ground_row + 1)
        row = dr.select(on_object, row, self.ground_row)
        unknown = (on_object & (row > self.ground_row)) | (active & ~on_object & (shape != self.ground_registry))
        known = active & ~unknown
        # OptiX reports the mesh hit inside an instance, Embree its index in the shapegroup.
        reported = on_object & (shape < self.registry_size)
        part = dr.gather(mi.UInt32, self.part_of_registry, shape, reported)
        part = dr.select(reported & (part < self.parts),
                         part, dr.gather(mi.UInt32, self.object_part_row, row, known) + dr.select(on_object, shape_index, 0))
        tri = dr.gather(mi.UInt32, self.part_base, part, known) + prim
        return row, tri, unknown

    def class_and_normal(self, row: mi.UInt32, tri: mi.UInt32, active: mi.Bool) -> tuple[mi.UInt32, mi.Vector3f]:
        """Class (UInt32) and world-frame unit normal (Vector3f) of located hits."""
        cls = dr.gather(mi.UInt32, self.triangle_class, tri, active)
        local = [dr.gather(mi.Float, self.triangle_normal, tri * 3 + a, active) for a in range(3)]
        m = [dr.gather(mi.Float, self.object_rotation, row * 9 + a, active) for a in range(9)]
        normal = mi.Vector3f(m[0] * local[0] + m[1] * local[1] + m[2] * local[2],
                             m[3] * local[0] + m[4] * local[1] + m[5] * local[2],
                             m[6] * local[0] + m[7] * local[1] + m[8] * local[2])
        return cls, normal

    def identities(self, row: mi.UInt32, tri: mi.UInt32, active: mi.Bool) -> dict[str, mi.UInt32]:
        """``instance``, ``object_id``, ``treeid`` and ``classification`` (UInt32 each) of located hits."""
        return {
            "instance": dr.gather(mi.UInt32, self.object_instance, row, active),
            "object_id": dr.gather(mi.UInt32, self.object_id_base, row, active)
            + dr.gather(mi.UInt32, self.triangle_component, tri, active),
            "treeid": dr.gather(mi.UInt32, self.object_treeid, row, active),
            "classification": dr.gather(mi.UInt32, self.triangle_class, tri, active),
        }
