"""The meshes of a HELIOS++ survey's scene parts, split by class, ready to place.

A part's OBJ files are read with trimesh, faces grouped by material. A material's class is its
``helios_classification`` when that is one of ours (see :mod:`mitsuforest.classes`), else ground for
``helios_isGround``, else 0 (unclassified); its reflectance is its ``helios_reflectance``, else ours
for the class at the sensor's wavelength.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from ..classes import CLASS_NAMES, GROUND
from ..errors import UserError

UNCLASSIFIED = 0
DEFAULT_REFLECTANCE = 0.5   # a material with neither class nor reflectance


@dataclass
class MaterialMesh:
    """The faces of one file that use one material, in the file's frame (HELIOS++'s up axis applied)."""

    vertices: np.ndarray   # (n, 3) float64
    faces: np.ndarray      # (m, 3) uint32
    material: str
    classification: int
    reflectance: float | None


def read_obj(path: Path, y_up: bool) -> list[MaterialMesh]:
    """The meshes of one OBJ file, one per material."""
    try:
        loaded = trimesh.load(path, process=False, maintain_order=True)
    except Exception as e:   # trimesh raises many kinds for unreadable files
        raise UserError(f"{path}: cannot read the OBJ file: {e}") from None
    geometries = loaded.geometry.values() if isinstance(loaded, trimesh.Scene) else [loaded]
    out = []
    for g in geometries:
        if not isinstance(g, trimesh.Trimesh) or not len(g.faces):
            continue
        v = np.asarray(g.vertices, np.float64)
        if y_up:   # HELIOS++ reads (x, y, z) of a y-up file as (x, -z, y)
            v = np.column_stack([v[:, 0], -v[:, 2], v[:, 1]])
        name, keys = _material(g)
        out.append(MaterialMesh(v, np.asarray(g.faces, np.uint32), name, *_class_and_reflectance(keys)))
    if not out:
        raise UserError(f"{path}: the OBJ file holds no triangles")
    return out


def _material(g) -> tuple[str, dict]:
    material = getattr(getattr(g, "visual", None), "material", None)
    if material is None:
        return "", {}
    return str(getattr(material, "name", "") or ""), {k.lower(): v for k, v in (getattr(material, "kwargs", {}) or {}).items()}


def _first(value):
    return value[0] if isinstance(value, (list, tuple)) else value


def _class_and_reflectance(keys: dict) -> tuple[int, float | None]:
    code = UNCLASSIFIED
    if "helios_classification" in keys:
        try:
            given = int(float(_first(keys["helios_classification"])))
        except ValueError:
            given = UNCLASSIFIED
        code = given if given in CLASS_NAMES else UNCLASSIFIED
    if code == UNCLASSIFIED and str(_first(keys.get("helios_isground", "false"))).lower() in ("true", "1"):
        code = GROUND
    reflectance = None
    if "helios_reflectance" in keys:
        try:
            reflectance = float(_first(keys["helios_reflectance"]))
        except ValueError:
            reflectance = None
    return code, reflectance


def class_reflectances(meshes, table: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """(256,) reflectance by class code: the mean of the materials' ``helios_reflectance`` in each class,
    else ``table`` (ours at the sensor's wavelength), else :data:`DEFAULT_REFLECTANCE`; and a note for
    each class whose materials disagree (a class has one reflectance here)."""
    out = np.full(256, DEFAULT_REFLECTANCE)
    out[:len(table)] = np.where(np.asarray(table) > 0, table, DEFAULT_REFLECTANCE)
    given = {}
    for m in meshes:
        if m.reflectance is not None:
            given.setdefault(m.classification, set()).add(m.reflectance)
    notes = []
    for code, values in given.items():
        out[code] = float(np.mean(sorted(values)))
        if len(values) > 1:
            notes.append(f"class {code} ({CLASS_NAMES.get(code, 'unclassified')}): materials give reflectances "
                         f"{', '.join(f'{v:g}' for v in sorted(values))}; their mean {out[code]:.3g} is used")
    return out, notes
