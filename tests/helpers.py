"""Analytic test scenes: flat ground, planes and hand-made pulses through the real pipeline."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from mitsuforest.config import load_scene
from mitsuforest.plan import make_plan
from mitsuforest.scan.pulses import Pulses
from mitsuforest.scene import build_scene
from mitsuforest.trees.models import Component, Model, Part

ROOT = Path(__file__).resolve().parents[1]
SENSORS = ROOT / "sensors"


def scene_file(tmp_path, sensor="ideal.yaml", **sections) -> Path:
    """A bare scene (no trees, no understory) with ``sections`` merged in; returns its path."""
    data = {
        "name": "test", "seed": 1, "area": {"size": [40, 40]},
        "forest": {"trees": 0}, "understory": {"bushes": 0, "rocks": 0, "deadwood": 0, "stumps": 0},
        "sensor": sensor if isinstance(sensor, dict) else str(SENSORS / sensor),
        "survey": {"altitude": 30, "pulse_frequency": 100000, "scan_frequency": 50},
        "simulation": {"beam_samples": 1, "variant": "llvm_ad_mono"},
        "output": {"dir": str(tmp_path / "out")},
    }
    for key, value in sections.items():
        data[key] = {**data.get(key, {}), **value} if isinstance(value, dict) and isinstance(data.get(key), dict) else value
    tmp_path.mkdir(parents=True, exist_ok=True)
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def plane_model(name: str, size: float, classification: int, kind: str = "rock") -> Model:
    """A square of side ``size`` centred at the origin, facing +z."""
    h = size / 2
    v = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]], np.uint32)
    return Model(name, [Part(kind, v, f, np.zeros(2, np.uint16))], [Component(kind, classification)])


def analytic_scene(path, objects=()):
    """Load a scene file and add ``objects``: (model, position, rotation, tilt, treeid)."""
    scene = load_scene(path)
    plan = make_plan(scene)
    models = {}
    next_id = plan["ground"]["object_id"] + 1
    for k, (model, position, rotation, tilt, treeid) in enumerate(objects, start=1):
        models[model.name] = model
        plan["models"][model.name] = {"kind": "custom"}
        plan["objects"].append({"kind": "custom", "model": model.name, "treeid": treeid, "position": list(position),
                                "rotation": rotation, "tilt": list(tilt), "instance": k, "object_id": next_id,
                                "components": len(model.components)})
        next_id += len(model.components)
    return scene, plan, models, build_scene(plan, models, scene)


def pulses(origins, directions) -> Pulses:
    """Hand-made pulses at time 0 with any beam frame."""
    origins = np.atleast_2d(np.asarray(origins, float))
    d = np.atleast_2d(np.asarray(directions, float))
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    d = np.broadcast_to(d, origins.shape).copy()
    a = np.where(np.abs(d[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    across = np.cross(d, a)
    across /= np.linalg.norm(across, axis=1, keepdims=True)
    n = len(origins)
    return Pulses(np.arange(n), np.zeros(n), origins, d, across, np.zeros(n))
