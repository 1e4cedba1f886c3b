"""Test scenes: the package's analytic helpers with the repository's sensor files."""

from __future__ import annotations

from pathlib import Path

from mitsuforest.testing.analytic import analytic_scene, bare_scene_file, plane_model, pulses  # noqa: F401

ROOT = Path(__file__).resolve().parents[1]
SENSORS = ROOT / "sensors"


def scene_file(tmp_path, sensor="ideal.yaml", variant="llvm_ad_mono", **sections) -> Path:
    """A bare scene in ``tmp_path`` with a sensor from ``sensors/`` (or an inline mapping)."""
    return bare_scene_file(tmp_path, sensor if isinstance(sensor, dict) else SENSORS / sensor, variant, **sections)


def write_obj(path, pieces, scale: float = 1.0, y_up: bool = False) -> Path:
    """An OBJ with one ``o``/``g`` group and material per piece: ``{name: (vertices, faces, material)}``.

    Vertices are in metres, +z up; they are written times ``scale`` and, with ``y_up``, with +y up.
    """
    import numpy as np
    lines, base = [f"mtllib {Path(path).stem}.mtl"], 1
    materials = []
    for name, (v, f, material) in pieces.items():
        v = np.asarray(v, float) * scale
        if y_up:
            v = np.column_stack([v[:, 0], v[:, 2], -v[:, 1]])
        lines += [f"o {name}", f"g {name}", f"usemtl {material}"]
        lines += [f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in v]
        lines += [f"f {a + base} {b + base} {c + base}" for a, b, c in np.asarray(f)]
        base += len(v)
        materials.append(material)
    Path(path).write_text("\n".join(lines) + "\n")
    Path(path).with_suffix(".mtl").write_text("".join(f"newmtl {m}\nKd 0.5 0.5 0.5\n" for m in dict.fromkeys(materials)))
    return Path(path)
