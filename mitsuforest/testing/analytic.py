"""Analytic test scenes: bare plots, planes and hand-made pulses, run through the real pipeline.

Used by the tests and ``benchmarks/stability.py``; handy for validating a sensor setup too::

    path = bare_scene_file(folder, sensors / "ideal.yaml")
    scene, plan, models, scan_scene = analytic_scene(path, [(plane_model("p", 10, ROCK), (5, 5, 2), 0, (0, 30), 0)])
    tracer = PulseTracer(scan_scene, scene.sensor, 1)
    points = labelled(*tracer.trace_pulses(pulses([[5, 5, 30]], [0, 0, -1])), tracer.table)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

import dataclasses

from ..config import load_scene
from ..plan import ModelSpec, PlacedObject
from ..scene import build_scene
from ..survey import make_plan
from ..trees.models import Component, Model, Part
from .reference.pulses import Pulses


def bare_scene_file(folder, sensor, variant: str = "auto", **sections) -> Path:
    """Write a scene without trees or understory (40 m plot, ideal settings) with ``sections`` merged in.

    :param sensor: a sensor file path or an inline sensor mapping.
    :param variant: the Mitsuba variant it runs on.
    """
    data = {
        "name": "test", "seed": 1, "area": {"size": [40, 40]},
        "forest": {"trees": 0}, "understory": {"bushes": 0, "rocks": 0, "deadwood": 0, "stumps": 0},
        "sensor": sensor if isinstance(sensor, dict) else str(sensor),
        "survey": {"altitude": 30, "pulse_frequency": 100000, "scan_frequency": 50},
        "simulation": {"beam_samples": 1, "variant": variant},
        "output": {"dir": str(Path(folder) / "out")},
    }
    for key, value in sections.items():
        merge = isinstance(value, dict) and isinstance(data.get(key), dict)
        data[key] = {**data[key], **value} if merge else value
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "scene.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def plane_model(name: str, size: float, classification: int, kind: str = "rock") -> Model:
    """A square of side ``size`` centred at the origin, facing +z."""
    h = size / 2
    v = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]], np.uint32)
    return Model(name, [Part(kind, v, f, np.zeros(2, np.uint16))], [Component(kind, classification)])


def analytic_scene(path, objects=()):
    """Load a scene file and place ``objects``: (model, position, rotation, (tilt_x, tilt_y), treeid).

    :returns: scene, plan, models, scan scene.
    """
    scene = load_scene(path)
    plan = make_plan(scene)
    models, specs, placed = {}, dict(plan.models), []
    next_id = plan.ground_object_id + 1
    for k, (model, position, rotation, tilt, treeid) in enumerate(objects, start=1):
        models[model.name] = model
        specs[model.name] = ModelSpec("custom", len(model.components))
        placed.append(PlacedObject("custom", model.name, treeid, tuple(position), rotation, tuple(tilt), k, next_id,
                                   len(model.components)))
        next_id += len(model.components)
    plan = dataclasses.replace(plan, models=specs, objects=plan.objects + tuple(placed))
    return scene, plan, models, build_scene(plan, models, scene.sensor, scene.simulation.variant)


def pulses(origins, directions) -> Pulses:
    """Hand-made pulses at time 0 (any beam frame)."""
    origins = np.atleast_2d(np.asarray(origins, float))
    d = np.atleast_2d(np.asarray(directions, float))
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    d = np.broadcast_to(d, origins.shape).copy()
    a = np.where(np.abs(d[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    across = np.cross(d, a)
    across /= np.linalg.norm(across, axis=1, keepdims=True)
    n = len(origins)
    return Pulses(np.arange(n), np.zeros(n), origins, d, across, np.zeros(n))
