"""Test scenes: the package's analytic helpers with the repository's sensor files."""

from __future__ import annotations

import time
from pathlib import Path

from mitsuforest.testing.analytic import analytic_scene, bare_scene_file, plane_model, pulses  # noqa: F401

ROOT = Path(__file__).resolve().parents[1]
SENSORS = ROOT / "sensors"


def scene_file(tmp_path, sensor="ideal.yaml", variant="llvm_ad_mono", **sections) -> Path:
    """A bare scene in ``tmp_path`` with a sensor from ``sensors/`` (or an inline mapping)."""
    return bare_scene_file(tmp_path, sensor if isinstance(sensor, dict) else SENSORS / sensor, variant, **sections)


def tiny_scene(trees: int, bushes: int, rocks: int, deadwood: int, stumps: int, thin_beam: bool = True,
               output: str | None = None) -> str:
    """The YAML text of a 12 m plot (seed 3, the VUX-1UAV22 at 100 kHz, lines 6 m apart) with these
    understory counts; ``thin_beam``: one fixed sub-ray on ``llvm_ad_mono``; ``output``: the output
    section as YAML flow text (``{formats: [laz]}``)."""
    lines = ["name: tiny", "seed: 3", "area: {size: [12, 12]}", f"forest: {{type: open, trees: {trees}, min_spacing: 4}}",
             f"understory: {{bushes: {bushes}, rocks: {rocks}, deadwood: {deadwood}, stumps: {stumps}}}",
             f"sensor: {ROOT}/sensors/riegl_vux-1uav22.yaml",
             "survey: {altitude: 30, speed: 20, pulse_frequency: 100000, line_spacing: 6, margin: 2}"]
    if thin_beam:
        lines.append("simulation: {beam_samples: 1, beam_pattern: fixed, variant: llvm_ad_mono}")
    if output is not None:
        lines.append(f"output: {output}")
    return "\n" + "\n".join(lines) + "\n"


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


def settled(items: list, count: int, timeout: float = 10.0, rest: float = 0.3) -> list:
    """A copy of ``items``, a list another thread appends to, once it holds ``count`` entries (or after
    ``timeout`` seconds) and ``rest`` seconds more, in which a thread that should stop there adds none."""
    deadline = time.monotonic() + timeout
    while len(items) < count and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(rest)
    return list(items)
