"""``mitsuforest export``: the planned scene as meshes, so other tools can open or scan the same scene.

Writes, in the local frame (the georeference offset is listed in the transforms table header):

- ``models/<model>_<part>.obj``: each model's parts once (tree wood, tree leaves, a rock, ...);
- ``ground.obj``;
- ``<name>_transforms.csv``: one row per placed object: ids and its 3×4 model-to-local matrix;
- ``<name>_helios_scene.xml``: a HELIOS++ scene with one part per object, ``id`` = our ``instance``
  (so HELIOS's ``hitObjectId`` is our instance id), loading that object's model files and applying
  our rotation (about z, then y, then x) and translation as HELIOS filters, in that order.
"""

from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import quoteattr

import trimesh

from .atomic import atomic_path, write_text
from .tables import csv_text


def _write_obj(path: Path, vertices, faces) -> None:
    with atomic_path(path) as tmp:
        trimesh.Trimesh(vertices, faces, process=False).export(tmp, file_type="obj", include_normals=False)


def export_scene(scene, plan, models: dict, folder, log=print) -> list[Path]:
    """Write the meshes, transforms table and HELIOS++ scene XML of a planned scene into ``folder``."""
    folder = Path(folder)
    (folder / "models").mkdir(parents=True, exist_ok=True)
    written = []
    for name in sorted({o.model for o in plan.objects}):
        for part in models[name].parts:
            path = folder / "models" / f"{name}_{part.name}.obj"
            _write_obj(path, part.vertices, part.faces)
            written.append(path)
    ground_v, ground_f = plan.terrain.mesh()
    _write_obj(folder / "ground.obj", ground_v, ground_f)
    written.append(folder / "ground.obj")
    written.append(_write_transforms(folder / f"{scene.name}_transforms.csv", plan, scene.origin.offset))
    written.append(_write_helios(folder / f"{scene.name}_helios_scene.xml", scene, plan, models))
    log(f"exported {len(plan.objects)} objects of {len({o.model for o in plan.objects})} models to {folder}")
    return written


def _write_transforms(path: Path, plan, offset) -> Path:
    header = ["instance", "object_id", "components", "kind", "model", "treeid"] + \
        [f"m{r}{c}" for r in range(3) for c in range(4)]
    rows = [[obj.instance, obj.object_id, obj.components, obj.kind, obj.model, obj.treeid]
            + [f"{v:.12g}" for v in obj.matrix[:3].ravel()] for obj in plan.objects]
    comment = f"# local frame; add origin offset {offset[0]:.3f},{offset[1]:.3f},{offset[2]:.3f} for the georeference\n"
    write_text(path, comment + csv_text(header, rows))
    return path


def _write_helios(path: Path, scene, plan, models: dict) -> Path:
    parts = ['    <part id="0">\n'
             '      <filter type="objloader">\n'
             '        <param type="string" key="filepath" value="ground.obj"/>\n'
             '        <param type="string" key="up" value="z"/>\n'
             '      </filter>\n'
             '    </part>']
    for obj in plan.objects:
        names = [p.name for p in models[obj.model].parts]
        pattern = f"models/{obj.model}_({'|'.join(names)})\\.obj"
        x, y, z = obj.position
        tilt_x, tilt_y = obj.tilt
        rotations = "".join(
            f'      <filter type="rotate"><param type="rotation" key="rotation">'
            f'<rot axis="{axis}" angle_deg="{angle:.9g}"/></param></filter>\n'
            for axis, angle in (("z", obj.rotation), ("y", tilt_y), ("x", tilt_x)) if angle)
        parts.append(
            f'    <part id="{obj.instance}">\n'
            f'      <filter type="objloader">\n'
            f'        <param type="string" key="efilepath" value={quoteattr(pattern)}/>\n'
            f'        <param type="string" key="up" value="z"/>\n'
            f'      </filter>\n'
            f'{rotations}'
            f'      <filter type="translate"><param type="vec3" key="offset" value="{x:.9g};{y:.9g};{z:.9g}"/></filter>\n'
            f'    </part>')
    text = ('<?xml version="1.0" encoding="UTF-8"?>\n'
            f'<!-- mitsuforest export of {quoteattr(scene.name)}: part id = mitsuforest instance (0 = ground);'
            ' see the _ids.csv of a render for object ids, classes and tree ids -->\n'
            '<document>\n'
            f'  <scene id={quoteattr(scene.name)} name={quoteattr(scene.name)}>\n'
            + "\n".join(parts) + "\n  </scene>\n</document>\n")
    write_text(path, text)
    return path

