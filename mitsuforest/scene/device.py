"""The scene's hit table on the device: where a ray hit, and the class and normal of what it hit.

The echo kernel (scan) locates every sub-ray's hit by an object row and a triangle row of
:attr:`HitTable.located <mitsuforest.scene.HitTable.located>` (the ground is one more object row, its
triangles after the models'), reads the triangle's class (for its reflectance) and world-frame normal
(for the incidence), and keeps each echo's rows; the labels stage turns those rows into ids
(:func:`mitsuforest.labels.label_points`). Its numpy twin is
:func:`mitsuforest.testing.reference.labels.label_hits`. A hit the table does not know is flagged in
``unknown``.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from . import HitTable


class DeviceHitTable:
    """Dr.Jit copies of the arrays of a :class:`~mitsuforest.scene.HitTable` that locate a hit (call under
    the scene's variant)."""

    def __init__(self, table: HitTable):
        # One padding element each: Dr.Jit cannot gather from an empty array (a scene without objects).
        def u32(a):
            return mi.UInt32(np.append(np.asarray(a, np.uint32).reshape(-1), np.uint32(0)))

        def f32(a):
            return mi.Float(np.append(np.asarray(a, np.float32).reshape(-1), np.float32(0)))

        arrays = table.located
        self.ground_row = len(table.object_instance)
        self.ground_registry = int(table.ground_registry)
        registry = np.asarray(table.object_of_registry)
        parts = np.asarray(table.part_of_registry)
        self.registry_size = len(registry)
        self.object_of_registry = u32(np.where(registry >= 0, registry, self.ground_row + 1))   # unknown: past the rows
        self.part_of_registry = u32(np.where(parts >= 0, parts, len(arrays["part_base"])))     # not a part: past them
        self.parts = len(arrays["part_base"])
        for name in ("object_rotation", "triangle_normal"):
            setattr(self, name, f32(arrays[name]))
        for name in ("object_part_row", "part_base", "triangle_class"):
            setattr(self, name, u32(arrays[name]))

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
