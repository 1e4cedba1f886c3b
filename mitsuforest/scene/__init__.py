"""Stage 3: the Mitsuba scene of a plan, and the table that says what a ray hit.

Each model's meshes are loaded once as a ``shapegroup``; every placed object is an ``instance`` of
it; the ground is a plain mesh. Nothing else is modelled: no emitters, no sensor, no integrator —
the scan kernel only reads hit distances and ids. Each model's proxy (proxies.py) goes with the scene,
for the scan to aim its pulses at. Objects that no pulse of any leg can reach are
left out (see :func:`reachable`); a scene built for some legs loads only the objects in their reach.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import drjit as dr
import mitsuba as mi
import numpy as np

from ..classes import GROUND, SPECIES_CODES
from ..plan.reach import Swath, leg_swaths, path_distance
from ..plan.transforms import apply
from .meshes import face_normals, mitsuba_mesh
from .proxies import model_cells
from .variant import scene_variant, select_variant, variant_scope

__all__ = ["ScanScene", "build_scene", "scene_variant", "select_variant", "variant_scope", "reachable"]


@dataclass
class HitTable:
    """Flat lookup arrays from (instance registry id, shape index, primitive) to labels and normals.

    ``object_of_registry[r]`` is the row of the object whose instance shape has registry id ``r``
    (-1 for none). Rows index the ``object_*`` arrays. A hit's part (a mesh of its model) is
    ``part_of_registry[shape]`` where the backend reports the mesh hit inside an instance (OptiX), else
    ``object_part_row[obj] + shape_index`` (Embree reports the mesh's index in the shapegroup);
    ``part_base[part]`` is the first row of that part's triangles in ``triangle_component`` and
    ``triangle_normal``.
    """

    object_of_registry: np.ndarray   # (R,) int32
    part_of_registry: np.ndarray     # (R,) int32: the part row of a model mesh's registry id, -1 for none
    ground_registry: int
    object_instance: np.ndarray      # (O,) uint32
    object_id_base: np.ndarray       # (O,) uint32
    object_treeid: np.ndarray        # (O,) uint16
    object_rotation: np.ndarray      # (O, 3, 3) float32
    object_part_row: np.ndarray      # (O,) int64: first row of the object's model in part_base
    object_class_row: np.ndarray     # (O,) int64: first row of the model's components in component_class
    part_base: np.ndarray            # (parts,) int64
    triangle_component: np.ndarray   # (T,) uint16
    triangle_class: np.ndarray       # (T,) uint8: the class of the triangle's component
    triangle_normal: np.ndarray      # (T, 3) float32, model frame
    component_class: np.ndarray      # (C,) uint8
    ground_normal: np.ndarray        # (G, 3) float32
    ground_object_id: int
    instance_species: np.ndarray | None = None   # (I,) uint8: species code by instance id (0 the ground)

    @cached_property
    def located(self) -> dict[str, np.ndarray]:
        """The table's arrays as a located hit indexes them: by object row, the ground appended as the
        last row (instance 0, the ground's object id, identity rotation, species 0), and by triangle
        row, the ground's triangles after the models' (component 0, class ground).
        :class:`~mitsuforest.scene.device.DeviceHitTable` locates hits in these rows on the device;
        :func:`~mitsuforest.labels.label_points` turns them into labels."""
        triangles, ground = len(self.triangle_component), len(self.ground_normal)
        species = (np.zeros(len(self.object_instance), np.uint8) if self.instance_species is None
                   else self.instance_species[self.object_instance.astype(np.int64)])
        return {
            "object_instance": np.append(self.object_instance, np.uint32(0)),
            "object_id_base": np.append(self.object_id_base, np.uint32(self.ground_object_id)),
            "object_treeid": np.append(self.object_treeid, np.uint16(0)),
            "object_species": np.append(species, np.uint8(0)),
            "object_part_row": np.append(self.object_part_row, len(self.part_base)),
            "object_rotation": np.concatenate([self.object_rotation.reshape(-1, 9), np.eye(3).reshape(1, 9)]),
            "part_base": np.append(self.part_base, triangles),
            "triangle_component": np.append(self.triangle_component, np.zeros(ground, np.uint16)),
            "triangle_class": np.append(self.triangle_class, np.full(ground, GROUND, np.uint8)),
            "triangle_normal": np.concatenate([self.triangle_normal, self.ground_normal]),
        }

    def species(self, instance: np.ndarray) -> np.ndarray:
        """(n,) uint8 species codes (classes.SPECIES_CODES) of the points of instances ``instance``."""
        if self.instance_species is None:
            return np.zeros(len(instance), np.uint8)
        return self.instance_species[np.asarray(instance, np.int64)]


@dataclass
class ScanScene:
    mitsuba: mi.Scene
    table: HitTable
    bbox: np.ndarray         # (2, 3) local-frame bounds of everything modelled
    variant: str
    objects: int             # placed objects in reach of the survey
    culled: int              # placed objects out of reach of every leg, left out
    triangles: int           # distinct triangles of those objects' models and the ground (instanced copies once)
    loaded: int              # placed objects loaded: those in reach of the legs it was built for
    boxes: np.ndarray        # (k, 2, 3) bounds of every object in reach of the survey, and the ground's
    reflectance: np.ndarray | None = None   # (256,) by class; None: ours at the sensor's wavelength
    placements: list = field(default_factory=list)   # (model name, 4×4 matrix) of every object in reach of the survey
    survey_models: dict = field(default_factory=dict)  # model name -> Model of those objects

    @cached_property
    def cells(self) -> dict:
        """Model name → its proxy's cells (:func:`~.proxies.model_cells`), found when the scan first asks
        (a survey prepared only to write, a dataset's merge, never does)."""
        return {name: model_cells(model) for name, model in self.survey_models.items()}


def reachable(obj_bounds: np.ndarray, swaths: list[Swath], sensor) -> np.ndarray:
    """Whether any pulse of any leg (its :class:`Swath`) can reach each object's bounding box.

    A pulse leaves at most ``half_angle`` from the vertical, so it reaches height z out to
    (origin height - z)·tan(half_angle) horizontally from its origin, never beyond ``range_max``; a half
    angle of 90° or more reaches everything within ``range_max``.

    :param obj_bounds: (m, 2, 3) boxes.
    :returns: (m,) bool.
    """
    obj_bounds = np.asarray(obj_bounds, np.float64).reshape(-1, 2, 3)
    centre = obj_bounds.mean(axis=1)[:, :2]
    radius = np.linalg.norm(obj_bounds[:, 1, :2] - obj_bounds[:, 0, :2], axis=1) / 2
    out = np.zeros(len(obj_bounds), bool)
    for swath in swaths:
        reach = swath.reach(swath.top - obj_bounds[:, 0, 2], sensor.range_max)
        out |= path_distance(centre, np.asarray(swath.path, np.float64)) - radius - swath.margin <= reach
    return out


def build_scene(plan, models: dict, sensor, variant: str, legs: range | None = None,
                reflectance: np.ndarray | None = None, attitude=None) -> ScanScene:
    """Load the plan's objects and ground into Mitsuba under ``variant`` and build the hit table.

    :param sensor: the scene's :class:`~mitsuforest.config.types.Sensor` (objects out of its reach are
        left out).
    :param variant: a Mitsuba variant (see :func:`select_variant`); the global variant is left as it was.
    :param legs: load only the objects in reach of these legs (indices into ``plan.legs``; all by
        default). The box, counts and triangles stay those of the whole survey, so a scan of these legs
        casts the same pulses and makes the same points as over the whole survey's scene.
    :param reflectance: (256,) reflectance by class; None: ours at the sensor's wavelength.
    :param attitude: the planned legs' ``survey.attitude`` (None: level), which turns where pulses go.
    """
    variant = select_variant(variant)
    with variant_scope(variant):
        return _build(plan, models, sensor, variant, legs, reflectance, attitude)


def _placed(plan, models) -> list[tuple]:
    """(object, 4×4 matrix, bounds (2, 3)) of every placed object; a large model (an imported
    2 M-triangle mesh) is bounded by its hull's corners, not transformed whole per placed copy."""
    extremes = {name: models[name].hull_corners() for name in {obj.model for obj in plan.objects}}
    out = []
    for obj in plan.objects:
        m = obj.matrix
        v = apply(m, extremes[obj.model])
        out.append((obj, m, np.array([v.min(0), v.max(0)])))
    return out


def _build(plan, models, sensor, variant, legs, reflectance, attitude) -> ScanScene:
    ground_v, ground_f = plan.terrain.mesh()
    placed = _placed(plan, models)
    swaths = leg_swaths(plan.legs, sensor, attitude)
    bounds = np.array([b for _, _, b in placed]).reshape(-1, 2, 3)
    survey = [p for p, near in zip(placed, reachable(bounds, swaths, sensor)) if near]
    if legs is not None:
        bounds = np.array([b for _, _, b in survey]).reshape(-1, 2, 3)
        near = reachable(bounds, [swaths[i] for i in legs], sensor)
    keep = survey if legs is None else [p for p, n in zip(survey, near) if n]
    used = sorted({obj.model for obj, _, _ in keep})
    d = {"type": "scene"}
    part_meshes = []          # in part-row order, as _hit_table numbers parts
    for name in used:
        meshes = [mitsuba_mesh(f"{name}_{p.name}", p.vertices, p.faces) for p in models[name].parts]
        part_meshes += meshes
        d[f"model_{name}"] = {"type": "shapegroup", **{f"p{i:02d}": m for i, m in enumerate(meshes)}}
    for obj, m, _ in keep:
        d[f"object_{obj.instance:07d}"] = {"type": "instance", "shape": {"type": "ref", "id": f"model_{obj.model}"},
                                               "to_world": mi.ScalarTransform4f(m.tolist())}
    d["ground"] = mitsuba_mesh("ground", ground_v, ground_f)
    mi_scene = mi.load_dict(d)
    table = _hit_table(mi_scene, plan, models, used, keep, ground_v, ground_f, part_meshes)
    all_bounds = [b for _, _, b in survey] + [np.array([ground_v.min(0), ground_v.max(0)])]
    bbox = np.array([np.min([b[0] for b in all_bounds], 0), np.max([b[1] for b in all_bounds], 0)])
    survey_models = {name: models[name] for name in sorted({obj.model for obj, _, _ in survey})}
    triangles = sum(m.triangles for m in survey_models.values()) + len(ground_f)
    dr.sync_thread()     # the scene's buffers complete before kernels on another thread (the scan's) read them
    return ScanScene(mi_scene, table, bbox, variant, len(survey), len(placed) - len(survey), triangles, len(keep),
                     np.array(all_bounds), reflectance, [(obj.model, m) for obj, m, _ in survey], survey_models)


def _registry_ids(shapes: list[mi.Mesh]) -> np.ndarray:
    if not shapes:
        return np.zeros(0, np.int64)
    return np.array(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(shapes)), np.int64)


def _hit_table(mi_scene: mi.Scene, plan, models, used, keep, ground_v, ground_f,
               part_meshes: list[mi.Mesh]) -> HitTable:
    registry = np.array(dr.reinterpret_array(mi.UInt32, mi_scene.shapes_dr()), np.int64)
    part_registry = _registry_ids(part_meshes)
    ids = [s.id() for s in mi_scene.shapes()]
    by_instance = {obj.instance: row for row, (obj, _, _) in enumerate(keep)}
    size = int(max(registry.max(), part_registry.max(initial=0))) + 1
    object_of_registry = np.full(size, -1, np.int32)
    part_of_registry = np.full(size, -1, np.int32)
    part_of_registry[part_registry] = np.arange(len(part_registry))
    ground_registry = -1
    for reg, sid in zip(registry, ids):
        if sid == "ground":
            ground_registry = int(reg)
        elif sid.startswith("object_"):
            object_of_registry[reg] = by_instance[int(sid.split("_")[1])]
    part_row, class_row, part_base, comps, normals, classes, tri_classes = {}, {}, [], [], [], [], []
    tri_count = comp_count = 0
    for name in used:
        model = models[name]
        part_row[name], class_row[name] = len(part_base), comp_count
        model_classes = np.array([c.classification for c in model.components], np.uint8)
        for p in model.parts:
            part_base.append(tri_count)
            comps.append(p.component)
            tri_classes.append(model_classes[p.component])
            normals.append(p.of_mesh(face_normals))
            tri_count += len(p.faces)
        classes += [c.classification for c in model.components]
        comp_count += len(model.components)
    objs = [obj for obj, _, _ in keep]
    return HitTable(
        object_of_registry=object_of_registry,
        part_of_registry=part_of_registry,
        ground_registry=ground_registry,
        object_instance=np.array([o.instance for o in objs], np.uint32),
        object_id_base=np.array([o.object_id for o in objs], np.uint32),
        object_treeid=np.array([o.treeid for o in objs], np.uint16),
        object_rotation=np.array([m[:3, :3] for _, m, _ in keep], np.float32).reshape(-1, 3, 3),
        object_part_row=np.array([part_row[o.model] for o in objs], np.int64),
        object_class_row=np.array([class_row[o.model] for o in objs], np.int64),
        part_base=np.array(part_base, np.int64),
        triangle_component=np.concatenate(comps) if comps else np.zeros(0, np.uint16),
        triangle_class=np.concatenate(tri_classes) if tri_classes else np.zeros(0, np.uint8),
        triangle_normal=np.vstack(normals) if normals else np.zeros((0, 3), np.float32),
        component_class=np.array(classes, np.uint8),
        ground_normal=face_normals(ground_v, ground_f),
        ground_object_id=plan.ground_object_id,
        instance_species=instance_species(plan),
    )


def instance_species(plan) -> np.ndarray:
    """(max instance + 1,) uint8: each instance's species code; trees carry their archetype's family,
    everything else (the ground at 0, understory, deadwood) ``none``."""
    codes = np.zeros(max((o.instance for o in plan.objects), default=0) + 1, np.uint8)
    for o in plan.objects:
        if o.kind == "tree":
            codes[o.instance] = SPECIES_CODES[plan.models[o.model].species]
    return codes
