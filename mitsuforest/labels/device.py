"""The hit table on the device: :func:`~mitsuforest.labels.label_hits` for Dr.Jit arrays.

Used by the echo kernel, which labels sub-ray hits without copying them back to numpy. The lookups
are those of ``label_hits``; a hit the table does not know is flagged in ``unknown``.
"""

from __future__ import annotations

import numpy as np

from ..classes import GROUND

_INDEX_ARRAYS = ("object_instance", "object_id_base", "object_treeid", "object_part_row", "object_class_row",
                 "part_base", "triangle_component", "component_class")
_VECTOR_ARRAYS = ("object_rotation", "triangle_normal", "ground_normal")  # flattened: row * 9 or row * 3


class DeviceHitTable:
    """Dr.Jit copies of a :class:`~mitsuforest.scene.HitTable`'s arrays (the variant must be set)."""

    def __init__(self, table):
        import drjit as dr
        import mitsuba as mi
        self.dr, self.mi = dr, mi

        # One padding element each: Dr.Jit cannot gather from an empty array (a scene without objects).
        def u32(a):
            return mi.UInt32(np.append(np.asarray(a, np.uint32).reshape(-1), np.uint32(0)))

        def f32(a):
            return mi.Float(np.append(np.asarray(a, np.float32).reshape(-1), np.float32(0)))

        registry = np.asarray(table.object_of_registry)
        self.registry_size = len(registry)
        self.known = u32(registry >= 0)
        self.object_of_registry = u32(np.maximum(registry, 0))
        parts = np.asarray(table.part_of_registry)
        self.is_part = u32(parts >= 0)
        self.part_of_registry = u32(np.maximum(parts, 0))
        self.ground_registry = int(table.ground_registry)
        self.ground_object_id = int(table.ground_object_id)
        for name in _INDEX_ARRAYS:
            setattr(self, name, u32(getattr(table, name)))
        for name in _VECTOR_ARRAYS:
            setattr(self, name, f32(getattr(table, name)))

    def _hit(self, instance, shape, active):
        dr, mi = self.dr, self.mi
        on_object = active & (instance > 0)
        in_table = on_object & (instance < self.registry_size)
        known = in_table & (dr.gather(mi.UInt32, self.known, instance, in_table) > 0)
        row = dr.gather(mi.UInt32, self.object_of_registry, instance, known)
        unknown = (on_object & ~known) | (active & ~on_object & (shape != self.ground_registry))
        return on_object, row, unknown

    def _triangle(self, row, shape, shape_index, prim, on_object):
        dr, mi = self.dr, self.mi
        # OptiX reports the mesh hit inside an instance, Embree its index in the shapegroup.
        reported = on_object & (shape < self.registry_size)
        reported &= dr.gather(mi.UInt32, self.is_part, shape, reported) > 0
        part = dr.select(reported, dr.gather(mi.UInt32, self.part_of_registry, shape, reported),
                         dr.gather(mi.UInt32, self.object_part_row, row, on_object) + shape_index)
        tri = dr.gather(mi.UInt32, self.part_base, part, on_object) + prim
        return tri, dr.gather(mi.UInt32, self.triangle_component, tri, on_object)

    def _class(self, row, component, on_object):
        dr, mi = self.dr, self.mi
        cls = dr.gather(mi.UInt32, self.component_class,
                        dr.gather(mi.UInt32, self.object_class_row, row, on_object) + component, on_object)
        return dr.select(on_object, cls, GROUND)

    def classes_and_normals(self, instance, shape, shape_index, prim, active):
        """Class (UInt32) and world-frame unit normal (Vector3f) of each hit, and the ``unknown`` mask."""
        dr, mi = self.dr, self.mi
        on_object, row, unknown = self._hit(instance, shape, active)
        tri, component = self._triangle(row, shape, shape_index, prim, on_object)
        cls = self._class(row, component, on_object)
        local = mi.Vector3f([dr.gather(mi.Float, self.triangle_normal, tri * 3 + a, on_object) for a in range(3)])
        m = [dr.gather(mi.Float, self.object_rotation, row * 9 + a, on_object) for a in range(9)]
        rotated = mi.Vector3f(m[0] * local.x + m[1] * local.y + m[2] * local.z,
                              m[3] * local.x + m[4] * local.y + m[5] * local.z,
                              m[6] * local.x + m[7] * local.y + m[8] * local.z)
        ground = mi.Vector3f([dr.gather(mi.Float, self.ground_normal, prim * 3 + a, active & ~on_object) for a in range(3)])
        return cls, dr.select(on_object, rotated, ground), unknown

    def identities(self, instance, shape, shape_index, prim, active):
        """``instance``, ``object_id``, ``treeid`` and ``classification`` (UInt32 each) of each hit."""
        dr, mi = self.dr, self.mi
        on_object, row, _ = self._hit(instance, shape, active)
        _, component = self._triangle(row, shape, shape_index, prim, on_object)
        return {
            "instance": dr.select(on_object, dr.gather(mi.UInt32, self.object_instance, row, on_object), 0),
            "object_id": dr.select(on_object, dr.gather(mi.UInt32, self.object_id_base, row, on_object) + component,
                                   self.ground_object_id),
            "treeid": dr.select(on_object, dr.gather(mi.UInt32, self.object_treeid, row, on_object), 0),
            "classification": self._class(row, component, on_object),
        }
