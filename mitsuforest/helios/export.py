"""``mitsuforest export``: the planned scene as meshes and as a HELIOS++ survey that runs as it is.

Writes, in the local frame (the georeference offset is listed in the tables' first line):

- ``<name>_models/<model>_c<k>_<kind>.obj``: each model's components once, one OBJ each (a tree's
  stem, each first-order branch, its leaves; a rock ...), with ``<name>_models/materials.mtl`` (one
  material per class at the sensor's wavelength);
- ``<name>_models/ground.obj``;
- ``<name>_transforms.csv``: one row per placed object: ids and its 3×4 model-to-local matrix;
- ``<name>_helios_parts.csv``: one row per HELIOS++ part: its id (= our ``object_id``), instance,
  treeid, class, kind, model and OBJ file;
- ``<name>_helios_scene.xml``, ``<name>_helios_survey.xml``, ``<name>_helios_platform.xml``,
  ``<name>_helios_scanner.xml``: ``helios++ <name>_helios_survey.xml`` flies our survey over the scene.

A HELIOS++ part is one component of one placed object, its id our object_id, so HELIOS++'s
``hitObjectId`` is our object_id and its classification ours (from the materials). The meshes'
folder is named after the scene: two scenes exported into one folder share model names (``tree01``,
``bush01``, ``ground``) but not their meshes. Paths in the
documents are absolute (HELIOS++ then finds each file once, from any working folder, with or
without ``--assets``): export again after moving the folder.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from ..classes import CLASS_NAMES, GROUND
from ..write import Staging
from ..write.atomic import atomic_path, naming_errors, write_text
from ..write.tables import component_treeid, csv_text
from .documents import (PartFile, helios_path, materials_mtl, platform_xml, scanner_notes, scanner_xml, scene_xml,
                        survey_xml)

MATERIALS = "materials.mtl"


def export_scene(scene, plan, models: dict, folder, log=print) -> list[Path]:
    """Write the meshes, tables and HELIOS++ documents of a planned scene into ``folder``.

    Everything is written into a staging folder in ``folder`` and moved into place at the end (the
    meshes' folder replacing an earlier export's): a failing write (a full disk, named in the error) or
    Ctrl-C leaves ``folder`` as it was."""
    folder = Path(folder).absolute()
    helios_path(folder / f"{scene.name}_helios_scene.xml")       # refusals first: nothing half-written
    scanner = scanner_xml(scene.sensor, scene.pulse_frequency)
    staging = Staging(folder, f"{scene.name}_export")
    done = {}
    staging.commit_or_discard(lambda: done.update(_write_export(scene, plan, models, scanner, folder, staging.path)),
                              [f"{scene.name}_models"])
    log(f"exported {len(plan.objects)} objects of {done['models']} models as {done['parts']} HELIOS++ parts to "
        f"{folder}; fly them with: helios++ {folder / f'{scene.name}_helios_survey.xml'}")
    for note in scanner_notes(scene.sensor):
        log(f"note: {note}")
    if unexported := _unexported_platform(scene):
        log(f"note: the HELIOS++ survey flies level straight legs between each leg's ends; {unexported} "
            "not exported")
    return done["written"]


def _write_export(scene, plan, models: dict, scanner: str, folder: Path, stage: Path) -> dict:
    """Write the export's files under ``stage`` as they will lie in ``folder`` (the documents name their
    final paths); returns their final paths (``written``) and the numbers of ``models`` and ``parts``."""
    def at(path: Path) -> Path:
        return stage / path.relative_to(folder)

    meshes = folder / f"{scene.name}_models"
    at(meshes).mkdir()
    write_text(at(meshes / MATERIALS), materials_mtl(scene.sensor.wavelength))
    written = [meshes / MATERIALS]
    files = {}   # (model, component) -> OBJ path
    for name in sorted({o.model for o in plan.objects}):
        model = models[name]
        for k, (vertices, faces) in component_meshes(model).items():
            comp = model.components[k]
            files[name, k] = meshes / f"{name}_c{k:03d}_{comp.kind}.obj"
            write_obj(at(files[name, k]), vertices, faces, CLASS_NAMES[comp.classification])
            written.append(files[name, k])
    ground = meshes / "ground.obj"
    write_obj(at(ground), *plan.terrain.mesh(), CLASS_NAMES[GROUND])
    written.append(ground)
    parts, rows = _parts(plan, models, files, ground)
    names = {k: folder / f"{scene.name}_helios_{k}.xml" for k in ("scene", "survey", "platform", "scanner")}
    texts = {
        "scene": scene_xml(scene.name, parts),
        "survey": survey_xml(scene, plan, names["scene"], names["platform"], names["scanner"]),
        "platform": platform_xml(),
        "scanner": scanner,
    }
    offset = scene.origin.offset
    for name, (header, table) in {"transforms": _transform_rows(plan), "helios_parts": (PART_HEADER, rows)}.items():
        path = folder / f"{scene.name}_{name}.csv"
        _write_table(at(path), header, table, offset)
        written.append(path)
    for key, text in texts.items():
        write_text(at(names[key]), text)
        written.append(names[key])
    return {"written": written, "models": len({m for m, _ in files}), "parts": len(parts)}


def _unexported_platform(scene) -> str:
    """The platform settings a HELIOS++ survey of straight legs leaves out, as text ('' when none)."""
    survey = scene.survey
    names = [key for key, unused in (("survey.trajectory", not survey.trajectory), ("survey.attitude", survey.attitude.zero),
                                     ("sensor.mount", scene.sensor.mount.zero),
                                     ("survey.navigation_errors", survey.navigation_errors.zero)) if not unused]
    return (", ".join(names) + (" are" if len(names) > 1 else " is")) if names else ""


def component_meshes(model) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """``{component: (vertices (n, 3), faces (m, 3))}`` of a model, gathered over its parts, each with
    only the vertices its faces use (components without triangles are left out)."""
    out = {}
    for k in range(len(model.components)):
        pieces = [(p.vertices, p.faces[p.component == k]) for p in model.parts]
        pieces = [(v, f) for v, f in pieces if len(f)]
        if not pieces:
            continue
        vertices, faces, base = [], [], 0
        for v, f in pieces:
            used, inverse = np.unique(f, return_inverse=True)
            vertices.append(v[used])
            faces.append(inverse.reshape(f.shape) + base)
            base += len(used)
        out[k] = (np.vstack(vertices), np.vstack(faces).astype(np.uint32))
    return out


def write_obj(path: Path, vertices, faces, material: str) -> None:
    """An OBJ whose faces use ``material`` from the ``materials.mtl`` beside it."""
    text = trimesh.exchange.obj.export_obj(trimesh.Trimesh(vertices, faces, process=False), include_normals=False,
                                           include_texture=False, include_color=False, digits=9)
    body = "\n".join(line for line in text.splitlines() if not line.startswith("#"))
    with atomic_path(path) as tmp, naming_errors(path):
        tmp.write_text(f"mtllib {MATERIALS}\nusemtl {material}\n{body}\n")


PART_HEADER = ["part_id", "object_id", "instance", "treeid", "classification", "class", "kind", "model", "file"]


def _parts(plan, models, files, ground) -> tuple[list[PartFile], list[list]]:
    """The HELIOS++ parts (ground first) and their table rows."""
    parts = [PartFile(plan.ground_object_id, ground)]
    rows = [[plan.ground_object_id, plan.ground_object_id, 0, 0, GROUND, "ground", "ground", "", _rel(ground)]]
    for obj in plan.objects:
        tilt_x, tilt_y = obj.tilt
        rotations = tuple((a, d) for a, d in (("z", obj.rotation), ("y", tilt_y), ("x", tilt_x)) if d)
        for k, comp in enumerate(models[obj.model].components):
            path = files.get((obj.model, k))
            if path is None:
                continue
            object_id = obj.object_id + k
            parts.append(PartFile(object_id, path, rotations, tuple(obj.position)))
            rows.append([object_id, object_id, obj.instance, component_treeid(obj, comp), comp.classification,
                         CLASS_NAMES[comp.classification], comp.kind, obj.model, _rel(path)])
    return parts, rows


def _rel(path: Path) -> str:
    return f"{path.parent.name}/{path.name}"


def _transform_rows(plan) -> tuple[list[str], list[list]]:
    header = ["instance", "object_id", "components", "kind", "model", "treeid"] + \
        [f"m{r}{c}" for r in range(3) for c in range(4)]
    rows = [[obj.instance, obj.object_id, obj.components, obj.kind, obj.model, obj.treeid]
            + [f"{v:.12g}" for v in obj.matrix[:3].ravel()] for obj in plan.objects]
    return header, rows


def _write_table(path: Path, header, rows, offset) -> Path:
    comment = f"# local frame; add origin offset {offset[0]:.3f},{offset[1]:.3f},{offset[2]:.3f} for the georeference\n"
    write_text(path, comment + csv_text(header, rows))
    return path
