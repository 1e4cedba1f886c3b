"""``mitsuforest render SURVEY.xml``: fly a HELIOS++ survey here, writing our usual outputs.

>>> result = render_survey("EXPORT/demo_helios_survey.xml", output_dir="out/h")   # doctest: +SKIP

The survey becomes a :class:`~mitsuforest.config.types.Scene` (its scanner as our sensor, its
settings as our survey) and a :class:`~mitsuforest.plan.types.Plan` whose objects are the scene's
parts, one per part and class, each part's id its points' ``object_id``; the ground parts make the
terrain. Legs are the waypoint pairs whose first waypoint has the scanner on, flown straight at that
waypoint's speed; time runs on through the legs flown with the scanner off.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..classes import CLASS_NAMES, GROUND
from ..config import MAX_BEAM_SAMPLES, scene_from_mapping
from ..errors import ConfigError, UserError, display_path
from ..plan import MAX_LEG_PULSES
from ..plan.terrain import MeshGround
from ..plan.types import Leg, ModelSpec, PlacedObject, Plan
from ..scan.radiometry import reflectance_table
from ..scene import scene_variant
from ..survey import prepare_plan
from ..trees.models import Component, Model, Part, merge
from ..specs.sources import missing_companions
from .parts import class_reflectances, read_obj
from .survey import HeliosSurvey, read_survey


@dataclass(frozen=True)
class PlacedPart(PlacedObject):
    """A placed HELIOS++ part: its rotation and translation as given (``matrix``), not yaw and tilt."""

    transform: tuple = ()   # 4 rows of 4

    @property
    def matrix(self) -> np.ndarray:
        return np.array(self.transform, float)


def render_survey(path, *, assets=(), output_dir=None, seed=None, variant=None, overwrite=False, progress=True,
                  write=True, keep_points=None, log=print):
    """Read the HELIOS++ survey at ``path`` (relative paths resolved as HELIOS++ does, ``assets`` as its
    ``--assets``) and render it with :func:`mitsuforest.pipeline.render`."""
    from ..pipeline import check_output, render
    scene, plan, models, reflectance, notes = survey_scene(read_survey(path, assets), output_dir=output_dir, seed=seed,
                                                           variant=variant)
    for note in notes:
        log(f"note: {note}")
    scene_variant(scene)
    if write:
        check_output(scene, overwrite)     # before the scene is loaded
    prepared = prepare_plan(scene, plan, models, reflectance=reflectance, log=log)
    return render(prepared, overwrite=overwrite, progress=progress, write=write, keep_points=keep_points, log=log)


def survey_scene(survey: HeliosSurvey, output_dir=None, seed=None, variant=None):
    """The scene, plan, models and (256,) class reflectances of a survey, and notes on what was
    approximated."""
    fail = lambda key, reason: ConfigError(display_path(survey.file), key, reason)   # noqa: E731
    legs, flown = _legs(survey, fail)
    first = survey.waypoints[flown[0]]
    meshes, objects, models, ground, notes = _placed_parts(survey, fail)
    ground_v, ground_f, ground_id = ground
    sensor = dict(survey.scanner)
    if first.scan_angle <= 0:
        raise fail(f"survey.leg[{flown[0]}].scannerSettings.scanAngle_deg", "is required (> 0; half the field of view)")
    sensor["field_of_view"] = min(sensor["field_of_view"], 2 * first.scan_angle)
    sensor["pulse_frequencies"] = sorted(set(sensor["pulse_frequencies"]) | {first.pulse_frequency})
    lo, hi = sensor["scan_frequency_range"]
    sensor["scan_frequency_range"] = [min(lo, first.scan_frequency), max(hi, first.scan_frequency)]
    if first.beam_divergence is not None:
        sensor["beam_divergence"] = first.beam_divergence
    samples = survey.beam_samples or 19
    if samples > MAX_BEAM_SAMPLES:
        notes.append(f"beamSampleQuality gives {samples} sub-rays; {MAX_BEAM_SAMPLES} are cast")
        samples = MAX_BEAM_SAMPLES
    lo_xy, hi_xy = ground_v[:, :2].min(0), ground_v[:, :2].max(0)
    altitude = float(np.mean([leg.start[2] for leg in legs])) - float(ground_v[:, 2].mean())
    if altitude <= 0:
        raise fail(f"survey.leg[{flown[0]}].platformSettings.z", "the legs must fly above the ground's mean height")
    data = {
        "name": survey.name, "seed": seed if seed is not None else survey.seed or 0,
        "area": {"size": [max(float(v), 0.01) for v in hi_xy - lo_xy]},
        "forest": {"trees": 0}, "understory": {"bushes": 0, "rocks": 0, "deadwood": 0, "stumps": 0},
        "sensor": sensor,
        "survey": {"altitude": altitude, "speed": first.speed, "pulse_frequency": first.pulse_frequency,
                   "scan_frequency": first.scan_frequency,
                   "lines": [[list(leg.start[:2]), list(leg.end[:2])] for leg in legs]},
        "simulation": {"beam_samples": samples, "variant": variant or "auto"},
        "output": {"dir": str(Path(output_dir or Path("out") / survey.name).resolve())},
    }
    try:
        scene = scene_from_mapping(data, file=display_path(survey.file))
    except ConfigError as e:
        raise fail(_survey_key(e.key, survey, flown[0]), f"{e.reason} (checked as our {e.key})") from None
    table = reflectance_table(scene.sensor.wavelength)
    reflectance, disagreements = class_reflectances(meshes, table)
    plan = Plan(scene=survey.name, seed=scene.seed, area=tuple(data["area"]["size"]), forest_type="open",
                canopy_cover=0.0, terrain=MeshGround(ground_v, ground_f), models={n: ModelSpec("part", 1) for n in models},
                objects=tuple(objects), legs=tuple(legs), ground_object_id=ground_id, ground_class=GROUND)
    return scene, plan, models, reflectance, notes + disagreements


SCANNER_ATTRIBUTES = {"field_of_view": "scanAngleMax_deg", "pulse_frequencies": "pulseFreqs_Hz",
                      "scan_frequency_range": "scanFreqMin_Hz/scanFreqMax_Hz", "beam_divergence": "beamDivergence_rad",
                      "pulse_length": "pulseLength_ns", "wavelength": "wavelength_nm", "range_min": "rangeMin_m",
                      "range_precision": "accuracy_m", "max_returns": "maxNOR", "range_max": "rangeMax_m"}
LEG_ATTRIBUTES = {"speed": "platformSettings.movePerSec_m", "altitude": "platformSettings.z",
                  "pulse_frequency": "scannerSettings.pulseFreq_hz", "scan_frequency": "scannerSettings.scanFreq_hz"}


def _survey_key(key: str, survey: HeliosSurvey, first_leg: int) -> str:
    """The survey element and attribute that a key of the converted scene came from."""
    section, _, rest = key.partition(".")
    field = rest.split("[")[0].split(".")[0]
    scanner = survey.scanner.get("source", "").removeprefix("HELIOS++ scanner ")
    if section == "sensor" and field in SCANNER_ATTRIBUTES:
        return f"scanner[{scanner}].{SCANNER_ATTRIBUTES[field]}"
    if section == "survey" and field in LEG_ATTRIBUTES:
        return f"survey.leg[{first_leg}].{LEG_ATTRIBUTES[field]}"
    if section == "area":
        return "scene (the extent of the ground parts)"
    return f"survey ({key})"


def _legs(survey: HeliosSurvey, fail) -> tuple[list[Leg], list[int]]:
    """Straight legs between consecutive waypoints with the scanner on; one pulse frequency, scan
    frequency, field of view and divergence for all of them."""
    legs, flown, t = [], [], 0.0
    points = survey.waypoints
    for i, (a, b) in enumerate(zip(points, points[1:])):
        length = math.dist(a.position, b.position)
        if a.active:
            if length == 0:
                raise fail(f"survey.leg[{i + 1}].platformSettings", "repeats the previous waypoint: a leg with "
                           "the scanner on needs length")
            if flown:
                ref = points[flown[0]]
                for key, name in (("pulse_frequency", "pulseFreq_hz"), ("scan_frequency", "scanFreq_hz"),
                                  ("scan_angle", "scanAngle_deg"), ("beam_divergence", "beamDivergence_rad")):
                    if getattr(a, key) != getattr(ref, key):
                        raise fail(f"survey.leg[{i}].scannerSettings.{name}",
                                   f"{getattr(a, key)} differs from leg {flown[0]}'s {getattr(ref, key)}; one value "
                                   "for every leg with the scanner on is supported")
            leg = Leg(tuple(map(float, a.position)), tuple(map(float, b.position)), t, t + length / a.speed)
            if (count := leg.pulse_count(a.pulse_frequency)) >= MAX_LEG_PULSES:
                raise fail(f"survey.leg[{i}].scannerSettings.pulseFreq_hz",
                           f"{a.pulse_frequency:g} Hz over the leg's {leg.t1 - leg.t0:,.1f} s is {count:,} pulses, "
                           f"more than the {MAX_LEG_PULSES:,} a leg can number; split the leg or fly faster")
            legs.append(leg)
            flown.append(i)
        t += length / a.speed
    if not legs:
        raise fail("survey.leg", "no leg has the scanner on (active) on the way to a next waypoint")
    return legs, flown


def _placed_parts(survey: HeliosSurvey, fail):
    """Every part's meshes by class as models placed by the part's rotation and translation (the scale is
    in the model); the ground parts' triangles as one mesh in place."""
    all_meshes, objects, models, notes = [], [], {}, []
    ground_meshes, ground_ids = [], []
    keys, missing = {}, []
    for index, part in enumerate(survey.parts):
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = part.rotation, part.offset
        by_class = {}
        for path in part.files:
            missing += missing_companions(path)   # an OBJ's faces are unclassified without its .mtl
            try:
                meshes = read_obj(path, part.y_up)
            except UserError as e:   # name the part of the survey as well as the OBJ
                raise fail(f"scene.part[{index}]", str(e)) from None
            for mesh in meshes:
                all_meshes.append(mesh)
                by_class.setdefault(mesh.classification, []).append((path, mesh))
        for code, group in sorted(by_class.items()):
            if code == GROUND:
                ground_meshes += [((mesh.vertices * part.scale) @ part.rotation.T + part.offset, mesh.faces)
                                  for _, mesh in group]
                ground_ids.append(part.part_id)
                continue
            key = (tuple(str(p) for p, _ in group), part.y_up, part.scale, code)
            if key not in keys:
                name = f"{Path(group[0][0]).stem}_{CLASS_NAMES.get(code, 'unclassified')}_{len(keys):04d}"
                v, f, c = merge([(mesh.vertices * part.scale, mesh.faces) for _, mesh in group], [0] * len(group))
                models[name] = Model(name, [Part("mesh", v, f, c)],
                                     [Component(CLASS_NAMES.get(code, "unclassified"), code)])
                keys[key] = name
            objects.append(PlacedPart(kind="helios_part", model=keys[key], treeid=0,
                                      position=tuple(map(float, part.offset)), rotation=0.0, tilt=(0.0, 0.0),
                                      instance=len(objects) + 1, object_id=part.part_id, components=1,
                                      transform=tuple(map(tuple, m.tolist()))))
    missing = list(dict.fromkeys(missing))
    if missing:
        notes.append(f"material file{'s' if len(missing) > 1 else ''} not found, faces unclassified: "
                     + ", ".join(map(str, missing)))
    if not ground_meshes:
        raise fail("scene", "no part is ground (a material with helios_isGround true or helios_classification 1); "
                            "the ground is needed" + (f"; {notes[-1]}" if missing else ""))
    if len(set(ground_ids)) > 1:
        notes.append(f"ground parts {', '.join(map(str, ground_ids))} form one terrain; its points carry "
                     f"object_id {ground_ids[0]}")
    ground_v, ground_f, _ = merge(ground_meshes, [0] * len(ground_meshes))
    ground = (ground_v, ground_f, ground_ids[0])
    return all_meshes, objects, models, ground, notes
