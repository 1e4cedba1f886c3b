"""The HELIOS++ documents of an exported scene: scene, survey, platform, scanner (XML text) and the
materials (MTL text). Pure functions of the scene and plan; :mod:`mitsuforest.helios.export` writes them.

Every path a document names is absolute, so HELIOS++ resolves each one way only, whatever its
working folder and ``--assets`` (see :mod:`mitsuforest.helios`).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

from ..classes import CLASS_NAMES, GROUND
from ..errors import UserError
from ..scan.radiometry import reflectance_table

PLATFORM_ID = "mitsuforest_uav"
SCANNER_ID = "mitsuforest_scanner"
OPTICS = {"rotating": "rotating", "oscillating": "oscillating"}   # our deflector -> HELIOS++ optics


@dataclass(frozen=True)
class PartFile:
    """One HELIOS++ scene part: its id (our object_id), its OBJ file and its placement."""

    part_id: int
    path: Path                      # absolute
    rotations: tuple = ()           # ((axis, degrees), ...), applied in order
    offset: tuple = (0.0, 0.0, 0.0)


def sub_rays(quality: int) -> int:
    """Sub-rays HELIOS++ casts per pulse at ``beamSampleQuality`` q: ``1 + Σ_{i=1}^{q-1} floor(2π i)``."""
    return 1 + sum(int(2 * math.pi * i) for i in range(1, quality))


def beam_sample_quality(beam_samples: int) -> int:
    """The ``beamSampleQuality`` whose sub-ray count is nearest ours (exact for 1, 7, 19, 37)."""
    return min(range(1, 9), key=lambda q: (abs(sub_rays(q) - beam_samples), q))


def _document(*children) -> str:
    root = ET.Element("document")
    root.extend(children)
    ET.indent(root, "  ")
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def _param(parent, kind: str, key: str, value: str) -> None:
    ET.SubElement(parent, "param", type=kind, key=key, value=value)


def _g(x: float) -> str:
    return f"{x:.10g}"


def scene_xml(scene_id: str, parts: list[PartFile]) -> str:
    """A HELIOS++ scene: one ``objloader`` part per file with an absolute ``filepath``, its rotations
    and its translation."""
    node = ET.Element("scene", id=scene_id, name=scene_id)
    for part in parts:
        p = ET.SubElement(node, "part", id=str(part.part_id))
        loader = ET.SubElement(p, "filter", type="objloader")
        _param(loader, "string", "filepath", helios_path(part.path))
        _param(loader, "string", "up", "z")
        if part.rotations:
            rotate = ET.SubElement(ET.SubElement(p, "filter", type="rotate"), "param", type="rotation", key="rotation")
            for axis, angle in part.rotations:
                ET.SubElement(rotate, "rot", axis=axis, angle_deg=_g(angle))
        if any(part.offset):
            translate = ET.SubElement(p, "filter", type="translate")
            _param(translate, "vec3", "offset", ";".join(_g(v) for v in part.offset))
    return _document(node)


def helios_path(path: Path) -> str:
    """An absolute path as HELIOS++ documents name it; a path holding '#' is refused."""
    text = str(Path(path).absolute())
    if "#" in text:   # HELIOS++ splits asset locations at '#'
        raise UserError(f"{text}: HELIOS++ cannot name a file whose path holds '#'; export to another folder")
    return text


def survey_xml(scene, plan, scene_file: Path, platform_file: Path, scanner_file: Path) -> str:
    """A HELIOS++ survey flying the plan's legs: a waypoint at each leg's start (scanner on) and end
    (scanner off while turning to the next start), at the legs' altitude and the survey's speed,
    pulse and scan frequency and field of view; the scene's seed is the survey's."""
    survey = ET.Element("survey", name=scene.name,
                        platform=f"{helios_path(platform_file)}#{PLATFORM_ID}",
                        scanner=f"{helios_path(scanner_file)}#{SCANNER_ID}",
                        scene=f"{helios_path(scene_file)}#{scene.name}", seed=str(scene.seed))
    ET.SubElement(survey, "FWFSettings", beamSampleQuality=str(beam_sample_quality(scene.simulation.beam_samples)))
    for leg in plan.legs:
        speed = math.dist(leg.start, leg.end) / (leg.t1 - leg.t0)
        for point, active in ((leg.start, True), (leg.end, False)):
            node = ET.SubElement(survey, "leg")
            ET.SubElement(node, "platformSettings", x=_g(point[0]), y=_g(point[1]), z=_g(point[2]),
                          onGround="false", movePerSec_m=_g(speed), stopAndTurn="true", smoothTurn="false",
                          slowdownEnabled="false")
            ET.SubElement(node, "scannerSettings", active="true" if active else "false",
                          pulseFreq_hz=str(int(round(scene.pulse_frequency))),
                          scanFreq_hz=_g(scene.scan_frequency),
                          scanAngle_deg=_g(scene.sensor.field_of_view / 2),
                          headRotatePerSec_deg="0", headRotateStart_deg="0", headRotateStop_deg="0")
    return _document(survey)


def platform_xml() -> str:
    """A straight-line platform whose scanner looks down with its scan plane across the track (HELIOS++'s
    ``copter_linearpath`` mount without its 5° forward tilt, as our sensor model has none)."""
    platform = ET.Element("platform", id=PLATFORM_ID, name="mitsuforest UAV (straight legs)", type="linearpath")
    mount = ET.SubElement(platform, "scannerMount", x="0", y="0", z="0")
    ET.SubElement(mount, "rot", axis="x", angle_deg="180")
    return _document(platform)


def scanner_xml(sensor, pulse_frequency: float) -> str:
    """Our sensor as a HELIOS++ scanner: optics, pulse frequencies, scan frequencies, half field of
    view, divergence, pulse length, wavelength, ranges, ranging noise and returns per pulse.

    A rotating mirror's ``scanAngleMax_deg`` is 180 (a full turn each scan line, as ours) and its half
    field of view ``scanAngleEffectiveMax_deg``: HELIOS++ sweeps 2 x ``scanAngleMax_deg`` a line.

    ``beamDivergence_rad`` is our full angle, as in HELIOS++'s own scanner files; HELIOS++'s energy
    model takes it as the 1/e² half angle, so its footprint is wider than ours (README, "Comparing
    with HELIOS++", has the echo counts this gives)."""
    if sensor.deflector not in OPTICS:
        raise UserError(f"sensor.deflector: {sensor.deflector} is not exported to HELIOS++ (its Risley model takes "
                        "prism angles and refractive indices, not deflections); only rotating and oscillating are")
    across, along = sensor.beam_divergence
    if not math.isclose(across, along, rel_tol=1e-9):
        raise UserError(f"sensor.beam_divergence: HELIOS++ takes one divergence, the sensor has "
                        f"{across:g} x {along:g} rad")
    freqs = sorted({int(round(f)) for f in (*sensor.pulse_frequencies, pulse_frequency)})
    lo, hi = sensor.scan_frequency_range
    half = sensor.field_of_view / 2
    node = ET.Element(
        "scanner", id=SCANNER_ID, name=sensor.name, optics=OPTICS[sensor.deflector],
        accuracy_m=_g(sensor.range_precision), beamDivergence_rad=_g(across),
        pulseFreqs_Hz=",".join(str(f) for f in freqs), pulseLength_ns=_g(sensor.pulse_length * 1e9),
        rangeMin_m=_g(sensor.range_min), rangeMax_m=_g(sensor.range_max),
        scanAngleMax_deg=_g(_mirror_half_sweep(sensor)), scanAngleEffectiveMax_deg=_g(half),
        scanFreqMin_Hz=_g(lo), scanFreqMax_Hz=_g(hi), wavelength_nm=str(int(round(sensor.wavelength * 1e9))),
        maxNOR=str(sensor.max_returns))
    origin = ET.SubElement(node, "beamOrigin", x="0", y="0", z="0")
    ET.SubElement(origin, "rot", axis="x", angle_deg="90")   # HELIOS++'s VUX-1UAV(22) beam origin: the
    ET.SubElement(origin, "rot", axis="z", angle_deg="90")   # beam sweeps the x-z plane of the mount
    ET.SubElement(node, "headRotateAxis", x="0", y="0", z="1")
    return _document(node)


def _mirror_half_sweep(sensor) -> float:
    """HELIOS++'s ``scanAngleMax_deg``: half the angle its mirror sweeps in one scan line. Our rotating
    mirror turns 360° a line (180; the field of view is ``scanAngleEffectiveMax_deg``), an oscillating
    one sweeps the field of view."""
    return 180.0 if sensor.deflector == "rotating" else sensor.field_of_view / 2


def scanner_notes(sensor) -> list[str]:
    """What of ``sensor`` a HELIOS++ scanner cannot hold (the export says so; the survey flies without it)."""
    notes = []
    if sensor.range_precision_per_metre or sensor.footprint_range_noise:
        notes.append(f"HELIOS++ takes one ranging accuracy: accuracy_m is range_precision "
                     f"({sensor.range_precision:g} m), without its growth with range and incidence")
    if sensor.speckle_looks:
        notes.append("HELIOS++ has no speckle: speckle_looks is not exported")
    return notes


def materials_mtl(wavelength: float) -> str:
    """One material per class: ``Kd`` and ``helios_reflectance`` are our reflectance at ``wavelength``,
    ``helios_classification`` our class code; the ground is ``helios_isGround``."""
    reflectance = reflectance_table(wavelength)
    lines = [f"# mitsuforest classes; reflectances at {wavelength * 1e9:.0f} nm (see scan/radiometry.py)"]
    for code, name in CLASS_NAMES.items():
        r = reflectance[code]
        lines += [f"newmtl {name}", f"Kd {r:.4g} {r:.4g} {r:.4g}", "Ka 0 0 0", "Ks 0 0 0", "Ns 0",
                  f"helios_reflectance {r:.4g}", f"helios_classification {code}",
                  f"helios_isGround {'true' if code == GROUND else 'false'}", ""]
    return "\n".join(lines)
