"""Read a HELIOS++ survey: its legs, scanner, platform and scene parts, as plain data.

>>> survey = read_survey("EXPORT/demo_helios_survey.xml")   # doctest: +SKIP
>>> survey.waypoints[0].position, survey.scanner["name"], len(survey.parts)   # doctest: +SKIP

Paths resolve as HELIOS++ resolves them (see :mod:`mitsuforest.helios`). Every element and attribute
is either taken, or known not to change what a pulse hits (listed in :data:`IGNORED`), or refused
with ``FILE: element: reason``; nothing is skipped silently.
"""

from __future__ import annotations

import dataclasses
import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..config.schema import name_problem
from ..errors import ConfigError
from .documents import OPTICS, sub_rays

# Attributes read elsewhere than in the element itself, or that change no hit: recorded, not used.
IGNORED = {
    "survey": {"name"},
    "platformSettings": {"id", "template", "stopAndTurn", "smoothTurn", "slowdownEnabled", "yawAtDeparture_deg"},
    "scannerSettings": {"id", "template", "headRotateStart_deg", "headRotateStop_deg", "trajectoryTimeInterval_s"},
    "FWFSettings": {"binSize_ns", "winSize_ns", "maxFullwaveRange_ns", "apertureDiameter_m"},
    "platform": {"id", "name", "type", "drag", "engine_max_force", "speedup_magnitude", "slowdown_magnitude",
                 "base_pitch_deg", "roll_speed_deg", "pitch_speed_deg", "yaw_speed_deg", "roll_offset_deg",
                 "pitch_offset_deg", "slowdown_distance"},
    "scanner": {"id", "name", "averagePower_w", "beamQualityFactor", "opticalEfficiency", "receiverDiameter_m",
                "atmosphericVisibility_km", "refrIndex_air", "scanProduct"},
}
PLATFORM_TYPES = ("linearpath", "multicopter")
MAX_BEAM_SAMPLE_QUALITY = 100   # 31,087 HELIOS++ sub-rays; above 5 (62) we cast our maximum anyway
MAX_PART_ID = 2 ** 32 - 1       # a part's id becomes its points' 32-bit object_id


@dataclass(frozen=True)
class Waypoint:
    """One ``<leg>``: where the platform is, and how the scanner runs on the way to the next one."""

    position: tuple[float, float, float]
    speed: float                  # m/s, on the way to the next waypoint
    active: bool
    pulse_frequency: float
    scan_frequency: float
    scan_angle: float             # half the field of view (deg)
    beam_divergence: float | None


@dataclass(frozen=True)
class Part:
    """One scene ``<part>``: its OBJ files and placement ``R · (s · v) + t``."""

    part_id: int
    files: tuple[Path, ...]
    y_up: bool
    rotation: np.ndarray = field(compare=False)   # (3, 3)
    scale: float
    offset: tuple[float, float, float]


@dataclass(frozen=True)
class HeliosSurvey:
    name: str
    file: Path
    scanner: dict                 # our sensor file's keys
    beam_samples: int | None      # from FWFSettings beamSampleQuality
    waypoints: tuple[Waypoint, ...]
    parts: tuple[Part, ...]
    seed: int | None = None       # the survey's seed (None: AUTO)


class _Reader:
    """Documents by path (cached) and HELIOS++'s path lookup; errors name the survey file."""

    def __init__(self, survey_file: Path, assets):
        self.survey_file = Path(survey_file)
        # As the helios++ command of HELIOS++ 2.x (pyhelios) passes them: the user's --assets, then the
        # working folder; the binary adds assets/ (its data folders hold no files of ours).
        self.assets = [Path(a) for a in assets] + [Path("."), Path("assets")]
        self.docs = {}

    def fail(self, element: str, reason: str):
        raise ConfigError(self.survey_file, element, reason)

    def document(self, path: Path, element: str) -> ET.Element:
        path = path.resolve()
        if path not in self.docs:
            named = "" if path == self.survey_file.resolve() else f"{path}: "   # the error names the survey
            if not path.is_file():
                self.fail(element, f"{named}{_not_a_file(path)}")
            try:
                self.docs[path] = ET.parse(path).getroot()
            except ET.ParseError as e:
                self.fail(element, f"{named}not valid XML ({e})")
            except OSError as e:   # unreadable (permissions): bad input, not a failing write
                self.fail(element, f"{named}cannot be read ({e.strerror or e})")
        return self.docs[path]

    def locate_document(self, text: str) -> Path:
        """A document named in an attribute: absolute, else the first assets folder holding it, else
        the working folder (HELIOS++'s ``locateAssetFile``)."""
        path = Path(text)
        if path.is_absolute():
            return path
        return next((a / path for a in self.assets if (a / path).exists()), path)

    def element(self, location: str, tag: str, where: str, here: Path) -> tuple[ET.Element, Path]:
        """The ``<tag id=...>`` at ``PATH#id`` (or ``#id`` / ``id`` in the document ``here``)."""
        path_text, _, ident = location.rpartition("#") if "#" in location else ("", "", location)
        path = self.locate_document(path_text) if path_text else here
        root = self.document(path, where)
        for node in root.iter(tag):
            if node.get("id") == ident:
                return node, path
        self.fail(where, f"no <{tag} id={ident!r}> in {path}")

    def mesh_files(self, params: dict, where: str) -> tuple[Path, ...]:
        if "efilepath" in params:
            pattern = params["efilepath"]
            found = []
            for base in self.assets:   # the working folder is one of them
                full = base / pattern if not Path(pattern).is_absolute() else Path(pattern)
                folder = full.parent
                if folder.is_dir():
                    rx = re.compile(full.name)
                    found += [p.resolve() for p in sorted(folder.iterdir()) if p.is_file() and rx.fullmatch(p.name)]
            unique = tuple(dict.fromkeys(found))
            if not unique:
                self.fail(where, f"efilepath {pattern!r} matches no file")
            return unique
        if "filepath" not in params:
            self.fail(where, "objloader needs a filepath or efilepath")
        path = Path(params["filepath"])
        if path.is_absolute():
            if not path.is_file():
                self.fail(where, f"{_not_a_file(path)}: {path}")
            return (path,)
        for a in self.assets:
            if (a / path).is_file():
                return ((a / path).resolve(),)
        self.fail(where, f"{path} is in no assets folder ({', '.join(map(str, self.assets))}); HELIOS++ "
                         "reads a relative filepath only from its assets folders")


def _not_a_file(path: Path) -> str:
    """Why a path a survey names is not read: a folder, or nothing there."""
    return "a folder, not a file" if path.is_dir() else "file not found"


def read_survey(path, assets=()) -> HeliosSurvey:
    """Read the survey in ``path`` and everything it names.

    :param assets: folders searched for relative paths before ``assets/`` and the working folder, as
        HELIOS++'s ``--assets``.
    :raises ConfigError: ``FILE: element: reason`` for anything missing, malformed or unsupported.
    """
    reader = _Reader(Path(path), assets)
    root = reader.document(Path(path), "")
    surveys = list(root.iter("survey"))
    if len(surveys) != 1:
        reader.fail("survey", f"the file must hold one <survey>, it holds {len(surveys)}")
    survey = surveys[0]
    _check_attributes(reader, survey, "survey", {"platform", "scanner", "scene", "seed"} | IGNORED["survey"])
    seed = survey.get("seed", "AUTO")
    if seed != "AUTO" and not seed.isdigit():
        reader.fail("survey.seed", f"must be a whole number >= 0 or AUTO, got {seed!r}")
    name = survey.get("name") or Path(path).stem
    if problem := name_problem(name):
        reader.fail("survey.name", problem)
    for key in ("platform", "scanner", "scene"):
        if not survey.get(key):
            reader.fail("survey", f"attribute {key} is required")
    here = Path(path).resolve()
    platform, _ = reader.element(survey.get("platform"), "platform", "survey.platform", here)
    _check_platform(reader, platform)
    scanner_node, _ = reader.element(survey.get("scanner"), "scanner", "survey.scanner", here)
    scene_node, scene_path = reader.element(survey.get("scene"), "scene", "survey.scene", here)
    beam_samples = None
    for child in survey:
        if child.tag == "FWFSettings":
            _check_attributes(reader, child, "survey.FWFSettings", {"beamSampleQuality"} | IGNORED["FWFSettings"])
            if child.get("beamSampleQuality"):
                beam_samples = _beam_sample_quality(reader, child, "survey.FWFSettings")
        elif child.tag not in ("leg", "platformSettings", "scannerSettings"):
            reader.fail(f"survey.{child.tag}", "element not supported")
    scanner = _scanner(reader, scanner_node)
    if beam_samples is None:
        beam_samples = _scanner_beam_samples(reader, scanner_node)
    waypoints = tuple(_waypoint(reader, leg, i, here) for i, leg in enumerate(survey.findall("leg")))
    if len(waypoints) < 2:
        reader.fail("survey.leg", "a survey needs at least two legs (waypoints)")
    parts = _numbered_parts(reader, list(_scene_parts(reader, scene_node, scene_path)))
    return HeliosSurvey(name, Path(path).resolve(), scanner, beam_samples,
                        waypoints, parts, int(seed) if seed.isdigit() else None)


def _check_attributes(reader, node, where: str, known) -> None:
    for key in node.attrib:
        if key not in known:
            reader.fail(f"{where}.{key}", "attribute not supported")


def _number(reader, node, key: str, where: str, default=None) -> float:
    text = node.get(key)
    if text is None:
        if default is None:
            reader.fail(f"{where}.{key}", "is required")
        return default
    try:
        value = float(text)
    except ValueError:
        reader.fail(f"{where}.{key}", f"must be a number, got {text!r}")
    if not math.isfinite(value):
        reader.fail(f"{where}.{key}", f"must be finite, got {text}")
    return value


def _whole(reader, node, key: str, where: str, default: int | None = None, lo: int = 0, hi: int | None = None) -> int:
    value = _number(reader, node, key, where, None if default is None else float(default))
    if value != int(value) or value < lo or (hi is not None and value > hi):
        bounds = f">= {lo}" if hi is None else f"from {lo} to {hi}"
        reader.fail(f"{where}.{key}", f"must be a whole number {bounds}, got {node.get(key)}")
    return int(value)


def _flag(reader, node, key: str, where: str, default: bool) -> bool:
    text = node.get(key)
    if text is None:
        return default
    if text.lower() not in ("true", "false", "1", "0"):
        reader.fail(f"{where}.{key}", f"must be true or false, got {text!r}")
    return text.lower() in ("true", "1")


def _check_platform(reader, platform) -> None:
    where = f"platform[{platform.get('id')}]"
    if platform.get("type") not in PLATFORM_TYPES:
        reader.fail(f"{where}.type", f"{platform.get('type')!r} is not supported (only {', '.join(PLATFORM_TYPES)}: "
                                     "airborne platforms flown as straight legs)")
    _check_attributes(reader, platform, where, IGNORED["platform"])
    for child in platform:
        if child.tag != "scannerMount":
            reader.fail(f"{where}.{child.tag}", "element not supported")


def _scanner(reader, node) -> dict:
    """The scanner definition as our sensor file's keys."""
    where = f"scanner[{node.get('id')}]"
    known = {"optics", "accuracy_m", "beamDivergence_rad", "pulseFreqs_Hz", "pulseLength_ns", "rangeMin_m",
             "rangeMax_m", "scanAngleMax_deg", "scanAngleEffectiveMax_deg", "scanFreqMin_Hz", "scanFreqMax_Hz",
             "wavelength_nm", "maxNOR"}
    _check_attributes(reader, node, where, known | IGNORED["scanner"])
    for child in node:
        if child.tag not in ("beamOrigin", "headRotateAxis", "FWFSettings"):
            reader.fail(f"{where}.{child.tag}", "element not supported (one channel, one beam origin)")
    optics = node.get("optics")
    if optics not in OPTICS:
        reader.fail(f"{where}.optics", f"{optics!r} is not supported (only {', '.join(OPTICS)})")
    try:
        freqs = [float(f) for f in node.get("pulseFreqs_Hz", "").split(",") if f.strip()]
    except ValueError:
        reader.fail(f"{where}.pulseFreqs_Hz", f"must be comma-separated numbers, got {node.get('pulseFreqs_Hz')!r}")
    if not freqs:
        reader.fail(f"{where}.pulseFreqs_Hz", "is required")
    sensor = {
        "name": node.get("name") or node.get("id"),
        "source": f"HELIOS++ scanner {node.get('id')}",
        "deflector": OPTICS[optics],
        "field_of_view": min(2 * _half_field_of_view(reader, node, where), 360.0),
        "pulse_frequencies": freqs,
        "scan_frequency_range": [_number(reader, node, "scanFreqMin_Hz", where, 0.0),
                                 _number(reader, node, "scanFreqMax_Hz", where, 0.0)],
        "beam_divergence": _number(reader, node, "beamDivergence_rad", where),
        "pulse_length": _number(reader, node, "pulseLength_ns", where, 4.0) * 1e-9,
        "wavelength": _number(reader, node, "wavelength_nm", where, 1064.0) * 1e-9,
        "range_min": _number(reader, node, "rangeMin_m", where, 0.0),
        "range_precision": _number(reader, node, "accuracy_m", where, 0.0),
        "max_returns": _whole(reader, node, "maxNOR", where, 0),
    }
    if node.get("rangeMax_m"):
        sensor["range_max"] = _number(reader, node, "rangeMax_m", where)
    return sensor


def _half_field_of_view(reader, node, where: str) -> float:
    """Half the scanner's field of view (deg): an oscillating mirror's ``scanAngleMax_deg``; a rotating
    mirror's ``scanAngleEffectiveMax_deg`` (HELIOS++ fires only within it), its ``scanAngleMax_deg`` (half
    the sweep of one scan line) 180, a full turn a line as ours."""
    half = _number(reader, node, "scanAngleMax_deg", where)
    if node.get("optics") != "rotating":
        return half
    if half != 180:
        reader.fail(f"{where}.scanAngleMax_deg", f"a rotating mirror sweeping {2 * half:g}° a scan line is not "
                                                 "supported (ours turns 360° a line: scanAngleMax_deg 180)")
    return min(half, _number(reader, node, "scanAngleEffectiveMax_deg", where))


def _scanner_beam_samples(reader, node) -> int | None:
    fwf = node.find("FWFSettings")
    if fwf is None or not fwf.get("beamSampleQuality"):
        return None
    return _beam_sample_quality(reader, fwf, f"scanner[{node.get('id')}].FWFSettings")


def _beam_sample_quality(reader, node, where: str) -> int:
    """The sub-rays of an ``FWFSettings`` element's ``beamSampleQuality``, a whole number from 1 to
    :data:`MAX_BEAM_SAMPLE_QUALITY`."""
    return sub_rays(_whole(reader, node, "beamSampleQuality", where, lo=1, hi=MAX_BEAM_SAMPLE_QUALITY))


def _settings(reader, node, tag: str, where: str, here: Path, seen=()) -> dict:
    """A settings element's attributes over those of its template (``template="id"`` or ``PATH#id``);
    a chain of templates that comes back to one of its own elements is refused."""
    attrs = {}
    if node.get("template"):
        template, path = reader.element(node.get("template"), tag, f"{where}.template", here)
        seen = (*seen, node)
        if template in seen:
            reader.fail(f"{where}.template", f"{node.get('template')!r} leads back to itself (a template cycle)")
        attrs.update(_settings(reader, template, tag, f"{where}.template", path, seen))
    attrs.update(node.attrib)
    return attrs


PLATFORM_KEYS = {"x", "y", "z", "onGround", "movePerSec_m"}
SCANNER_KEYS = {"active", "pulseFreq_hz", "scanFreq_hz", "scanAngle_deg", "headRotatePerSec_deg", "beamDivergence_rad"}


def _waypoint(reader, leg, i: int, here: Path) -> Waypoint:
    where = f"survey.leg[{i}]"
    for child in leg:
        if child.tag not in ("platformSettings", "scannerSettings"):
            reader.fail(f"{where}.{child.tag}", "element not supported")
    p_node, s_node = leg.find("platformSettings"), leg.find("scannerSettings")
    if p_node is None or s_node is None:
        reader.fail(where, "a leg needs platformSettings and scannerSettings")
    p = ET.Element("platformSettings", _settings(reader, p_node, "platformSettings", f"{where}.platformSettings", here))
    s = ET.Element("scannerSettings", _settings(reader, s_node, "scannerSettings", f"{where}.scannerSettings", here))
    _check_attributes(reader, p, f"{where}.platformSettings", PLATFORM_KEYS | IGNORED["platformSettings"])
    _check_attributes(reader, s, f"{where}.scannerSettings", SCANNER_KEYS | IGNORED["scannerSettings"])
    if _flag(reader, p, "onGround", f"{where}.platformSettings", False):
        reader.fail(f"{where}.platformSettings.onGround", "true is not supported (airborne legs only)")
    if _number(reader, s, "headRotatePerSec_deg", f"{where}.scannerSettings", 0.0) != 0:
        reader.fail(f"{where}.scannerSettings.headRotatePerSec_deg", "a rotating head is not supported")
    pw, sw = f"{where}.platformSettings", f"{where}.scannerSettings"
    speed = _number(reader, p, "movePerSec_m", pw, 70.0)
    if speed <= 0:
        reader.fail(f"{pw}.movePerSec_m", f"must be > 0, got {speed:g}")
    active = _flag(reader, s, "active", sw, True)
    return Waypoint(
        position=(_number(reader, p, "x", pw, 0.0), _number(reader, p, "y", pw, 0.0), _number(reader, p, "z", pw, 0.0)),
        speed=speed, active=active,
        pulse_frequency=_number(reader, s, "pulseFreq_hz", sw, 0.0),
        scan_frequency=_number(reader, s, "scanFreq_hz", sw, 0.0),
        scan_angle=_number(reader, s, "scanAngle_deg", sw, 0.0),
        beam_divergence=_number(reader, s, "beamDivergence_rad", sw) if s.get("beamDivergence_rad") else None)


def _scene_parts(reader, scene, path: Path):
    for child in scene:
        if child.tag != "part":
            reader.fail(f"scene.{child.tag}", f"element not supported ({path})")
        yield child


def _numbered_parts(reader, nodes) -> tuple[Part, ...]:
    """The scene's parts with HELIOS++'s ids: a part without an id is numbered by a running index, and
    one that loads several files becomes one part a file numbered on from it, the index moving on past
    them (``XmlSceneLoader``, ``ScenePart::splitSubparts``; files in the order :meth:`_Reader.mesh_files`
    lists them)."""
    parts, index = [], 0
    for i, node in enumerate(nodes):
        part = _part(reader, node, i, index)
        if node.get("id") is None and len(part.files) > 1:
            parts += [dataclasses.replace(part, part_id=part.part_id + k, files=(f,)) for k, f in enumerate(part.files)]
            index += len(part.files) - 1
        else:
            parts.append(part)
        index += 1
    return tuple(parts)


def _part(reader, node, index: int, number: int) -> Part:
    """The ``index``-th part, ``number`` its id when it has none."""
    where = f"scene.part[{index}]"
    _check_attributes(reader, node, where, {"id"})
    part_id = node.get("id", str(number))
    if not part_id.lstrip("-").isdigit() or not 0 <= int(part_id) <= MAX_PART_ID:
        reader.fail(f"{where}.id", f"must be a whole number from 0 to {MAX_PART_ID} (it becomes the points' "
                                   f"object_id), got {part_id!r}")
    files, y_up, rotation, scale, offset = None, False, np.eye(3), 1.0, (0.0, 0.0, 0.0)
    for j, f in enumerate(node):
        fw = f"{where}.filter[{j}]"
        if f.tag != "filter":
            reader.fail(f"{where}.{f.tag}", "element not supported")
        kind = f.get("type")
        params = {p.get("key"): p for p in f.findall("param")}
        values = {k: p.get("value") for k, p in params.items()}
        if kind == "objloader":
            _check_keys(reader, params, fw, kind, {"filepath", "efilepath", "up"})
            files = reader.mesh_files(values, fw)
            if values.get("up", "z") not in ("y", "z"):
                reader.fail(f"{fw}.up", f"must be y or z, got {values['up']!r}")
            y_up = values.get("up") == "y"
        elif kind == "rotate":
            _check_keys(reader, params, fw, kind, {"rotation"})
            if "rotation" in params:
                rotation = rotation_matrix(params["rotation"], reader, fw) @ rotation
        elif kind == "scale":
            _check_keys(reader, params, fw, kind, {"scale"})
            value = _number(reader, params["scale"], "value", f"{fw}.scale")
            scale = value if value != 0 else scale
        elif kind == "translate":
            _check_keys(reader, params, fw, kind, {"offset", "onGround"})
            if "onGround" in values and int(float(values["onGround"])) != 0:
                reader.fail(f"{fw}.onGround", "placing a part on the ground is not supported; give its offset")
            if "offset" in values:
                offset = _vec3(reader, values["offset"], f"{fw}.offset")
        else:
            reader.fail(f"{fw}", f"filter type {kind!r} is not supported (objloader, rotate, scale, translate)")
    if files is None:
        reader.fail(where, "a part needs an objloader filter")
    return Part(int(part_id), files, y_up, rotation, scale, offset)


def _check_keys(reader, params, where, kind, known) -> None:
    for key in params:
        if key not in known:
            reader.fail(f"{where}.{key}", f"{kind} parameter not supported")


def _vec3(reader, text: str, where: str) -> tuple[float, float, float]:
    try:
        values = tuple(float(v) for v in text.split(";"))
    except (ValueError, AttributeError):
        values = ()
    if len(values) != 3 or not all(map(math.isfinite, values)):
        reader.fail(where, f"must be three numbers 'x;y;z', got {text!r}")
    return values


def axis_rotation(axis: str, degrees: float) -> np.ndarray:
    """Right-handed rotation about x, y or z (HELIOS++'s ``<rot>``)."""
    a = math.radians(degrees)
    c, s = math.cos(a), math.sin(a)
    i = "xyz".index(axis.lower())
    j, k = (i + 1) % 3, (i + 2) % 3
    m = np.eye(3)
    m[j, j], m[j, k], m[k, j], m[k, k] = c, -s, s, c
    return m


def rotation_matrix(param, reader, where: str) -> np.ndarray:
    """The ``<rot>`` list of a rotation param: applied in order (global), or composed the other way
    with ``rotations="local"``."""
    local = param.get("rotations") == "local"
    m = np.eye(3)
    for r in param.findall("rot"):
        axis = r.get("axis", "")
        if axis.lower() not in ("x", "y", "z"):
            reader.fail(f"{where}.rot", f"axis must be x, y or z, got {axis!r}")
        step = axis_rotation(axis, _number(reader, r, "angle_deg", f"{where}.rot"))
        m = m @ step if local else step @ m
    return m
