"""Test scenes: the package's analytic helpers with the repository's sensor files."""

from __future__ import annotations

from pathlib import Path

from mitsuforest.scene.analytic import analytic_scene, bare_scene_file, plane_model, pulses  # noqa: F401

ROOT = Path(__file__).resolve().parents[1]
SENSORS = ROOT / "sensors"


def scene_file(tmp_path, sensor="ideal.yaml", variant="llvm_ad_mono", **sections) -> Path:
    """A bare scene in ``tmp_path`` with a sensor from ``sensors/`` (or an inline mapping)."""
    return bare_scene_file(tmp_path, sensor if isinstance(sensor, dict) else SENSORS / sensor, variant, **sections)
