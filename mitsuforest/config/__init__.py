"""Scene and sensor files: loading, defaults and validation (see README, "Configuration").

>>> scene = load_scene("scenes/demo.yaml")                  # doctest: +SKIP
>>> scene.survey.altitude, scene.sensor.name, scene.pulse_frequency  # doctest: +SKIP

A loaded scene is a frozen :class:`~.types.Scene` with every default filled in and every path
absolute; the sensor is resolved into ``scene.sensor``. Any problem raises :class:`ConfigError`
naming the file, the key path and the reason; an edit (``scene.with_(...)``,
``dataclasses.replace``) is checked by the same rules.
"""

from __future__ import annotations

import collections.abc
import dataclasses
import math
from pathlib import Path

import yaml

from ..errors import ConfigError, UserError, amount
from ..fields import POINT_FORMATS
from ..specs.archetypes import (DEFAULT_ARCHETYPES, FAMILY_ARCHETYPES, FIELDS as ARCHETYPE_FIELDS, MAX_UNIQUE, Archetype,
                                 UniqueTrees)
from ..specs.sources import DEFAULT_LEAF_PATTERNS, REPAIR_MODES, UNITS, UP_AXES, MeshTree, QsmTree
from ..specs.understory import CLEARANCE, UNDERSTORY_KEYS
from .schema import REQUIRED, Context, Custom, FilePath, Flag, ListOf, Number, Text, Vector, name_problem, parse_mapping
from .types import (BEAM_PATTERNS, FOREST_BANDS, INTENSITY_SOURCES, OUTPUT_PROFILES, POINT_POSITIONS, Scene, Sensor, display_path,
                    UNDERSTORY_PER_HECTARE, from_mapping, to_mapping, understory_counts)

__all__ = ["load_scene", "load_sensor", "scene_from_mapping", "read_yaml", "validate_scene", "scene_error", "Scene", "Sensor",
           "ConfigError", "FOREST_BANDS"]

MAX_SPECKLE_LOOKS = 64  # scan/noise.py draws one uniform per look for each echo
MAX_BEAM_SAMPLES = 61   # the speed-against-error benchmark stops here; compile time grows faster than linearly
MAX_PLOT_SIDE = 2000.0  # m: the 0.25 m cover raster of a 2 km plot is 64 MB (a 1000 km one would be 14.6 TiB)
MAX_WAVEFORM_SAMPLES = 4096   # a batch's waveforms are 4 bytes x samples x pulses: 1.7 GB at 105,263 pulses
MIN_BATCH = 1000        # time slots per launch: fewer spend their time launching kernels
MAX_RANGE = 1e5         # m: beyond any lidar's reach (the shipped sensors reach 250-10,000 m); the scene's bounds are float32
MAX_RANGE_NOISE = 10.0  # m: 1-sigma ranging noise at short range (data sheets give millimetres to centimetres)
MAX_LEVER_ARM = 100.0   # m: the scanner's offset from the navigation reference point (decimetres on a UAV)
MAX_SCAN_RATE = 1e4     # Hz: scan lines or prism turns a second (polygon mirrors reach about 600)
MIN_BIN = 1e-11         # s: a waveform digitiser's sample, or a pulse (the fastest sample at 0.1 ns, the shortest pulses last 0.3 ns)
MAX_GNSS_SIGMA = 100.0  # m: a navigation solution this far off is no solution
MAX_STEMS_PER_M2 = 10.0  # trees a square metre: young stands regrown after fire hold up to 100,000 a hectare
RSA_JAMMING = 0.547     # random sequential adsorption of discs fills at most this share of a plane
MAX_OFFSET = 1e9   # m: beyond every projected CRS (eastings and northings are below 1e7 m); float64 keeps 0.1 mm to ~1e11 m
MAX_LEGS = 65_535       # a point's point_source_id (16 bits) is its leg's number, from 1
SENSOR_SPEC = {
    "name": Text(REQUIRED),
    "source": Text(""),
    "deflector": Text("rotating", choices=("rotating", "oscillating", "risley")),
    "field_of_view": Number(360.0, gt=0, le=360),
    "pulse_frequencies": ListOf(Number(integer=False, gt=0), REQUIRED, min_length=1),
    "scan_frequency_range": Vector(2, Number(ge=0, le=MAX_SCAN_RATE), [10.0, 200.0]),
    "beam_divergence": Vector(2, Number(ge=0, le=0.3, unit_hint="radians, full angle: 0.5 mrad is 0.5e-3"), REQUIRED,
                              scalar_ok=True),
    "pulse_length": Number(4e-9, ge=MIN_BIN, le=1e-6, unit_hint="seconds: 4 ns is 4e-9"),
    "wavelength": Number(1550e-9, ge=2e-7, le=2e-5, unit_hint="metres: 905 nm is 905e-9"),
    "range_min": Number(0.0, ge=0),
    "range_max": Number(1000.0, gt=0, le=MAX_RANGE),
    "range_precision": Number(0.0, ge=0, le=MAX_RANGE_NOISE),
    "range_accuracy": Number(0.0, ge=0),
    "max_returns": Number(0, integer=True, ge=0),
    "detection_threshold": Number(None, ge=0, nullable=True),
    "echo_separation": Number(None, ge=1e-4, nullable=True),   # m: 0.1 mm; data sheets give decimetres
    "range_precision_per_metre": Number(0.0, ge=0, le=0.1),   # sigma grows by at most a tenth of the range
    "footprint_range_noise": Number(0.0, ge=0, le=10),       # a share of the footprint's range spread
    "speckle_looks": Number(0, integer=True, ge=0, le=MAX_SPECKLE_LOOKS),
    "intensity": {
        "source": Text("amplitude", choices=INTENSITY_SOURCES),
        "gain": Number(1.0e6, gt=0),
        "offset": Number(0.0),
        "saturation": Number(65535, integer=True, ge=1, le=65535),
    },
    "risley": {
        "prism_rates": Vector(2, Number(ge=-MAX_SCAN_RATE, le=MAX_SCAN_RATE), [121.6, -77.7]),
        "prism_deflection": Vector(2, Number(ge=0), [17.6, 17.6]),
    },
    "waveform": {   # scan/waveform.py: samples x pulses per batch x 4 bytes are held per batch
        "bin_size": Number(1.0e-9, ge=MIN_BIN, le=1.0e-6, unit_hint="seconds: 1 ns is 1e-9"),
        "samples": Number(256, integer=True, ge=1, le=MAX_WAVEFORM_SAMPLES),
    },
    "mount": {   # plan/trajectory.py: body frame x forward, y right, z down
        "lever_arm": Vector(3, Number(ge=-MAX_LEVER_ARM, le=MAX_LEVER_ARM), [0.0, 0.0, 0.0]),
        "boresight": Vector(3, Number(ge=-180, le=180), [0.0, 0.0, 0.0]),
    },
}
WAVE_SPEC = {"mean_deg": Number(0.0, ge=-90, le=90), "amplitude_deg": Number(0.0, ge=0, le=90),
             "period_s": Number(10.0, gt=0), "phase_deg": Number(0.0)}


def _wave(value, ctx: Context, key: str):
    """One attitude angle: a number (a constant, deg) or a sinusoid mapping (WAVE_SPEC)."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = {"mean_deg": value}
    return parse_mapping(WAVE_SPEC, value, ctx, key)


ANGLES = Vector(3, Number(ge=0), [0.0, 0.0, 0.0], scalar_ok=True)


def _field_spec(f):
    """The schema of one archetype field, from its metadata (choices, integer, lo, hi)."""
    if f.metadata["choices"]:
        return Text(f.default, choices=f.metadata["choices"])
    return Number(f.default, integer=f.metadata["integer"], ge=f.metadata["lo"], le=f.metadata["hi"])


def _archetypes(value, ctx: Context, key: str):
    if value == "default":
        return list(DEFAULT_ARCHETYPES)
    if not isinstance(value, (list, tuple)):
        ctx.fail(key, "must be 'default' or a list of archetype mappings ([] for none, beside forest.models)")
    spec = {name: _field_spec(f) for name, f in ARCHETYPE_FIELDS.items()}
    spec["base"] = Number(None, integer=True, ge=1, nullable=True)
    out = []
    for i, item in enumerate(value):
        item = dataclasses.asdict(item) if isinstance(item, (Archetype, UniqueTrees)) else item
        where = f"{key}[{i}]"
        if isinstance(item, dict) and "unique" in item:
            out.append(_unique_entry(item, ctx, where))
            continue
        given = parse_mapping(spec, item, ctx, where)
        base, family = given.pop("base"), FAMILY_ARCHETYPES[given["species"]]
        if base and base > len(family):   # `base: N` counts the archetypes of the entry's species
            ctx.fail(f"{where}.base", f"must be <= {len(family)} (the {given['species']} archetypes), got {base}")
        merged = dataclasses.asdict(family[base - 1]) if base else {}
        explicit = {k: given[k] for k in item if k != "base"}
        out.append(Archetype(**{**{k: given[k] for k in ARCHETYPE_FIELDS}, **merged, **explicit}))
    return out


UNIQUE_SPEC = {"species": _field_spec(ARCHETYPE_FIELDS["species"]),
               "unique": Number(REQUIRED, integer=True, ge=1, le=MAX_UNIQUE),
               "weight": _field_spec(ARCHETYPE_FIELDS["weight"])}


def _unique_entry(item: dict, ctx: Context, where: str) -> UniqueTrees:
    """``{species: S, unique: N, weight: W}``: N trees drawn for each plot (specs/archetypes.py,
    :func:`~mitsuforest.specs.archetypes.drawn_archetype`); their parameters cannot be given."""
    for name in item:
        if name == "base":
            ctx.fail(f"{where}.base", "each unique tree starts from a random built-in archetype of its species; "
                     "give only species, unique and weight")
        if name in ARCHETYPE_FIELDS and name not in UNIQUE_SPEC:
            ctx.fail(f"{where}.{name}", "is drawn for each unique tree; give only species, unique and weight")
    return UniqueTrees(**parse_mapping(UNIQUE_SPEC, item, ctx, where))


MAX_TREE_MODELS = 65_534   # treeid is 16 bits, and deadwood takes the number after the last tree model
_MODEL_COMMON = {"units": Text("m", choices=tuple(UNITS)), "up": Text("z", choices=UP_AXES),
                 "weight": Number(1.0, ge=0, le=1e6)}
MESH_SPEC = {"mesh": FilePath(None, nullable=True), "wood": FilePath(None, nullable=True),
             "leaves": Custom(lambda v, c, k: v, None), "repair": Text("fix", choices=REPAIR_MODES), **_MODEL_COMMON}
QSM_SPEC = {"qsm": FilePath(REQUIRED), **_MODEL_COMMON, "seed": Number(0, integer=True, ge=0, le=2**31 - 1),
            **{k: _field_spec(ARCHETYPE_FIELDS[k])
               for k in ("leaf_area", "leaf_length", "leaf_width", "leaf_inclination", "leaf_clumping")}}


def _models(value, ctx: Context, key: str):
    """``forest.models``: tree meshes (``mesh:``, or ``wood:`` and ``leaves:``) and QSMs (``qsm:``)."""
    if value is None:
        return []
    if not isinstance(value, (list, tuple)):
        ctx.fail(key, "must be a list of model mappings, each with mesh:, wood: or qsm:")
    return [_model_entry(item, ctx, f"{key}[{i}]") for i, item in enumerate(value)]


def _model_entry(item, ctx: Context, where: str):
    if isinstance(item, (MeshTree, QsmTree)):
        item = {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(item).items()
                if v is not None}
    if not isinstance(item, dict):
        ctx.fail(where, "must be a mapping with mesh:, wood: or qsm:")
    given = [k for k in ("mesh", "wood", "qsm") if item.get(k) is not None]
    if len(given) != 1:
        ctx.fail(where, "give exactly one of mesh: (one file), wood: (with a leaves: file) or qsm: (a cylinder table)"
                 + (f", not {' and '.join(given)}" if given else ""))
    if given == ["qsm"]:
        return QsmTree(**parse_mapping(QSM_SPEC, item, ctx, where))
    entry = parse_mapping(MESH_SPEC, item, ctx, where)
    entry["leaves"] = _mesh_leaves(item.get("leaves"), entry["mesh"], ctx, where + ".leaves")
    return MeshTree(**entry)


def _mesh_leaves(value, mesh, ctx: Context, key: str):
    """Name patterns with ``mesh:`` (default :data:`DEFAULT_LEAF_PATTERNS`; ``[]``: no leaves), or the
    leaves file with ``wood:`` (none: a tree without leaves)."""
    if mesh:
        if value is None:
            return DEFAULT_LEAF_PATTERNS
        patterns = [value] if isinstance(value, str) else list(value) if isinstance(value, tuple) else value
        return tuple(ListOf(Text()).parse(patterns, ctx, key))
    if value is None:
        return None
    if not isinstance(value, str):
        ctx.fail(key, "with wood: give the leaves file (name patterns go with mesh:)")
    return FilePath(REQUIRED).parse(value, ctx, key)


BUILTIN_SENSORS = Path(__file__).resolve().parent.parent / "sensors"   # the package's sensors/*.yaml


def builtin_sensors() -> list[str]:
    """The names of the sensors the package ships (``sensor: NAME`` in a scene file)."""
    return sorted(p.stem for p in BUILTIN_SENSORS.glob("*.yaml"))


def _sensor(value, ctx: Context, key: str):
    if isinstance(value, Sensor):
        return _checked_sensor_object(value, ctx, key)
    if isinstance(value, str):
        return load_sensor(_sensor_path(value, ctx, key))
    if isinstance(value, dict):
        return _sensor_from_mapping(value, ctx, key + ".")
    ctx.fail(key, "must be a built-in sensor's name, a sensor file path or a mapping")


def names_builtin_sensor(value: str) -> bool:
    """Whether a scene's ``sensor: VALUE`` is read as a built-in sensor's name rather than a file's path."""
    return "/" not in value and "\\" not in value and not value.endswith((".yaml", ".yml"))


def _unknown_sensor(name: str) -> str:
    return (f"unknown built-in sensor {name!r}; built-in sensors: {', '.join(builtin_sensors())} "
            "(or give a sensor file's path)")


def sensor_file(value) -> Path:
    """The file of a command line's sensor (``--sensor``): a built-in sensor's name (``leica_als50-ii``) or
    a sensor file's path; a name that is neither is refused listing the built-in sensors."""
    names = builtin_sensors()
    if names_builtin_sensor(str(value)) and not Path(value).exists():
        if str(value) not in names:
            raise UserError(f"--sensor: {_unknown_sensor(str(value))}")
        return BUILTIN_SENSORS / f"{value}.yaml"
    return Path(value)


def _sensor_path(value: str, ctx: Context, key: str) -> Path:
    """A built-in sensor by its name (``livox_mid-70``), or a sensor file's path relative to the scene file."""
    names = builtin_sensors()
    if names_builtin_sensor(value):
        if value not in names:
            ctx.fail(key, _unknown_sensor(value))
        return BUILTIN_SENSORS / f"{value}.yaml"
    path = (ctx.folder / Path(value).expanduser()).resolve()
    if not path.exists() and Path(value).stem in names:
        ctx.fail(key, f"file not found: {path} (relative paths are read from the scene file's folder); the "
                      f"built-in sensor of that name is named without a path: sensor: {Path(value).stem}")
    return Path(FilePath(REQUIRED).parse(value, ctx, key))


def _sensor_from_mapping(data, ctx: Context, prefix: str, file: str | None = None) -> Sensor:
    parsed = parse_mapping(SENSOR_SPEC, data, ctx, prefix.rstrip("."))
    _check_sensor(parsed, ctx, prefix)
    return from_mapping(Sensor, parsed, file=file)


def _checked_sensor_object(sensor: Sensor, ctx: Context, key: str) -> Sensor:
    """An edited sensor, checked as its file (or the scene's inline mapping) would be."""
    if sensor.file:
        return _sensor_from_mapping(to_mapping(sensor), Context(display_path(sensor.file)), "", sensor.file)
    return _sensor_from_mapping(to_mapping(sensor), ctx, key + ".")


def _crs(value, ctx: Context, key: str):
    """A coordinate reference system pyproj knows (written as the LAS WKT CRS record)."""
    if value is None:
        return None
    if not isinstance(value, str):
        ctx.fail(key, f"must be a string such as 'EPSG:7855', got {value!r}")
    from ..crs import crs_wkt
    try:
        crs_wkt(value)
    except UserError as e:
        ctx.fail(key, str(e).removeprefix("origin.crs: "))
    return value


def _legs(value, ctx: Context, key: str):
    if value is None:
        return None
    end = Vector(2, Number(ge=-MAX_OFFSET, le=MAX_OFFSET))   # local metres: legs of 1e300 m overflow their timing
    leg = Custom(lambda v, c, k: [end.parse(p, c, f"{k}[{j}]") for j, p in enumerate(_pair(v, c, k))])
    return ListOf(leg, min_length=1).parse(value, ctx, key)


def _pair(v, ctx, key):
    if not isinstance(v, list) or len(v) != 2:
        ctx.fail(key, f"a leg must be [[x0, y0], [x1, y1]], got {v!r}")
    if v[0] == v[1]:
        ctx.fail(key, f"a leg needs two distinct ends, got {v!r}")
    return v


SCENE_SPEC = {
    "name": Text(None, nullable=True),
    "seed": Number(0, integer=True, ge=0),
    "area": {"size": Vector(2, Number(ge=1, le=MAX_PLOT_SIDE), [100.0, 100.0])},   # smaller holds nothing (no cover cell)
    "origin": {"crs": Custom(_crs, None), "offset": Vector(3, Number(), [0.0, 0.0, 0.0])},
    "terrain": {
        "type": Text("flat", choices=("flat", "noise", "mesh", "dem")),
        "amplitude": Number(1.5, ge=0),
        "wavelength": Number(25.0, gt=0),
        "path": FilePath(None, nullable=True),
    },
    "forest": {
        "type": Text("open", choices=tuple(FOREST_BANDS)),
        "canopy_cover": Number(None, gt=0, le=1, nullable=True),
        "trees": Number(None, integer=True, ge=0, nullable=True),
        "min_spacing": Number(3.0, ge=0),
        "tilt": Number(5.0, ge=0, le=45),
        "archetypes": Custom(_archetypes, "default"),
        "models": Custom(_models, None),
        "trees_file": FilePath(None, nullable=True),
        "surround": Number(0.0, ge=0, le=500),
    },
    "understory": {**{k: Number(None, integer=True, ge=0, nullable=True) for k in UNDERSTORY_PER_HECTARE},
                   "grass": {"cover": Number(0.0, ge=0, le=1), "height": Number(0.3, gt=0, le=1.0)},
                   "litter": {"cover": Number(0.0, ge=0, le=1)}},
    "sensor": Custom(_sensor, REQUIRED),
    "survey": {
        "altitude": Number(30.0, gt=0),
        "speed": Number(2.0, gt=0),
        "pulse_frequency": Number(None, gt=0, nullable=True),
        "scan_frequency": Number(None, gt=0, nullable=True),
        "line_spacing": Number(12.0, gt=0, le=MAX_OFFSET),
        "heading": Number(0.0),
        "margin": Number(10.0, ge=0, le=MAX_OFFSET),
        "lines": Custom(_legs, None),
        "trajectory": FilePath(None, nullable=True),
        "attitude": {axis: Custom(_wave, {}) for axis in ("roll", "pitch", "yaw")},
        "navigation_errors": {
            "gnss_sigma_m": Vector(3, Number(ge=0, le=MAX_GNSS_SIGMA), [0.0, 0.0, 0.0], scalar_ok=True),
            "gnss_random_walk_m_per_sqrt_s": Vector(3, Number(ge=0, le=MAX_GNSS_SIGMA), [0.0, 0.0, 0.0], scalar_ok=True),
            "imu_sigma_deg": Vector(3, Number(ge=0, le=180), [0.0, 0.0, 0.0], scalar_ok=True),
            "boresight_error_deg": Vector(3, Number(ge=-10, le=10), [0.0, 0.0, 0.0]),
            "rate_hz": Number(10.0, gt=0, le=1000),
        },
    },
    "simulation": {
        "beam_samples": Number(19, integer=True, ge=1, le=MAX_BEAM_SAMPLES),   # see README, "Choosing beam_samples"
        "beam_pattern": Text("stratified", choices=BEAM_PATTERNS),
        "variant": Text("auto"),
        "pulses_per_batch": Number(None, integer=True, ge=MIN_BATCH, nullable=True),
        "point_position": Text("beam_axis", choices=POINT_POSITIONS),
    },
    "output": {
        "dir": FilePath(None, nullable=True, must_exist=False),
        "formats": ListOf(Text(choices=tuple(POINT_FORMATS)), ["pcd", "laz"], min_length=1, unique=True),
        "profile": Text("ours", choices=OUTPUT_PROFILES),
        "waveforms": Flag(False),
        "pulses": Flag(False),
        "pictures": Flag(True),
    },
}


MAX_YAML_DEPTH = 100   # nesting levels; a scene needs about 6. PyYAML composes recursively: 1,000 levels overflow


class _TooDeep(yaml.YAMLError):
    def __init__(self, mark):
        super().__init__()
        self.problem_mark, self.problem = mark, f"nested deeper than {MAX_YAML_DEPTH} levels"


class _UniqueKeys:
    """Refuses a mapping with a key given twice (PyYAML keeps the last silently)."""

    def construct_mapping(self, node, deep=False):
        seen = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if not isinstance(key, collections.abc.Hashable):   # a list or mapping as a key: PyYAML's own error
                raise yaml.constructor.ConstructorError(None, None, "found unhashable key", key_node.start_mark)
            if key in seen:
                raise yaml.constructor.ConstructorError(None, None, f"duplicate key {key!r}", key_node.start_mark)
            seen.add(key)
        return super().construct_mapping(node, deep)


class _CheckedLoader(_UniqueKeys, yaml.SafeLoader):
    """PyYAML's safe loader in Python, refusing duplicate keys and nesting deeper than
    :data:`MAX_YAML_DEPTH` (a RecursionError otherwise): the authority on what a file means and on the
    line and column of its first error."""

    _depth = 0

    def compose_node(self, parent, index):
        if self._depth >= MAX_YAML_DEPTH:
            raise _TooDeep(self.peek_event().start_mark)
        self._depth += 1
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


_FastLoader = type("_FastLoader", (_UniqueKeys, yaml.CSafeLoader), {}) if yaml.__with_libyaml__ else None


def _integer(loader, node):
    """YAML's integer, refused in the file's terms where Python will not convert it (over 4,300 digits)."""
    try:
        return yaml.SafeLoader.construct_yaml_int(loader, node)
    except ValueError:
        raise yaml.constructor.ConstructorError(None, None, f"an integer of {len(node.value):,} digits is too long",
                                                node.start_mark) from None


for _loader in (_CheckedLoader, _FastLoader):
    if _loader is not None:
        _loader.add_constructor("tag:yaml.org,2002:int", _integer)


def _parse_yaml(text: str):
    """The document in ``text``. libyaml parses it (a tenth of the Python parser's time; a dataset
    worker reads two files a plot); a document it refuses, or nests deeper than allowed, is parsed
    again by :class:`_CheckedLoader`, whose error (or, for a document libyaml alone refuses, whose
    result) stands.

    :raises yaml.YAMLError: from :class:`_CheckedLoader`.
    """
    if _FastLoader is not None:
        loader = _FastLoader(text)
        try:
            node = loader.get_single_node()
            if node is not None and not _nested_too_deep(node):
                return loader.construct_document(node)
        except yaml.YAMLError:
            pass
        finally:
            loader.dispose()
    return yaml.load(text, Loader=_CheckedLoader)


def _nested_too_deep(root: yaml.Node) -> bool:
    """Whether a path from ``root`` (level 1) down through its collections reaches a level past
    :data:`MAX_YAML_DEPTH`, aliases followed (then :class:`_CheckedLoader`, which does not follow them,
    decides). Walked without recursion; a node is walked again only when reached at a deeper level,
    so an alias repeated many times costs at most one walk a level."""
    deepest, stack = {}, [(root, 1)]
    while stack:
        node, level = stack.pop()
        if level > MAX_YAML_DEPTH:
            return True
        if deepest.get(id(node), 0) >= level:
            continue
        deepest[id(node)] = level
        if isinstance(node, yaml.SequenceNode):
            stack.extend((child, level + 1) for child in node.value)
        elif isinstance(node, yaml.MappingNode):
            stack.extend((child, level + 1) for pair in node.value for child in pair)
    return False


def _not_utf8(data: bytes, error: UnicodeDecodeError) -> str:
    """Why a YAML file is not read: binary, or text in another encoding (where, and what to do)."""
    if b"\0" in data:
        return "not a text file"
    line = data.count(b"\n", 0, error.start) + 1
    return (f"not UTF-8 text (line {line} holds the byte 0x{data[error.start]:02x}, as Windows-1252 or Latin-1 "
            "would write an accented letter); save the file as UTF-8")


def read_yaml(path) -> tuple[object, Context]:
    """Read one YAML file; a missing file or a syntax error is a :class:`ConfigError`."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(display_path(path), "", "file not found" if not path.exists() else "not a file")
    try:
        data = path.read_bytes()
    except OSError as e:   # unreadable (permissions): bad input, not a failing write
        raise ConfigError(display_path(path), "", f"cannot be read ({e.strerror or e})") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ConfigError(display_path(path), "", _not_utf8(data, e)) from None
    try:
        data = _parse_yaml(text)
    except yaml.reader.ReaderError as e:   # its text runs over two lines
        line = text.count("\n", 0, e.position) + 1
        raise ConfigError(display_path(path), "", f"YAML syntax error: line {line}: unacceptable character "
                          f"#x{e.character:04x}: {e.reason}") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        kind = "" if isinstance(e, _TooDeep) else "YAML syntax error: "
        raise ConfigError(display_path(path), "", f"{kind}{where}{getattr(e, 'problem', None) or e}") from None
    return data, Context(display_path(path))


def load_sensor(path) -> Sensor:
    """Load and validate a sensor file (``sensors/*.yaml``)."""
    data, ctx = read_yaml(path)
    return _sensor_from_mapping(data, ctx, "", str(ctx.file.resolve()))


def _check_sensor(sensor: dict, ctx: Context, prefix: str):
    lo, hi = sensor["scan_frequency_range"]
    if lo > hi:
        ctx.fail(prefix + "scan_frequency_range", f"must be [low, high], got [{lo:g}, {hi:g}]")
    if hi <= 0 and sensor["deflector"] != "risley":   # a Risley deflector's prism rates set its pattern
        ctx.fail(prefix + "scan_frequency_range", f"a {sensor['deflector']} deflector needs a scan frequency above 0: "
                 f"the high end must be > 0, got [{lo:g}, {hi:g}]")
    if sensor["range_max"] <= sensor["range_min"]:
        ctx.fail(prefix + "range_max", f"must be > range_min ({sensor['range_min']:g})")


def load_scene(path, *, seed: int | None = None, variant: str | None = None, output_dir=None) -> Scene:
    """Load, validate and complete a scene file; command-line overrides are applied first and
    checked with the file."""
    data, ctx = read_yaml(path)
    if isinstance(data, dict):
        data = _overridden(data, seed, variant, output_dir)
    return scene_from_mapping(data, file=ctx.file)


def _overridden(data: dict, seed, variant, output_dir) -> dict:
    data = dict(data)
    if seed is not None:
        data["seed"] = seed
    for section, key, value in (("simulation", "variant", variant),
                                ("output", "dir", output_dir and str(Path(output_dir).resolve()))):
        if value is not None:
            current = data.get(section)
            data[section] = {**current, key: value} if isinstance(current, dict) else {key: value}
    return data


def scene_from_mapping(data, file=None) -> Scene:
    """A :class:`Scene` from a mapping of the scene file's form.

    :param file: the file the mapping came from: errors name it and relative paths start from its
        folder (without a file: ``<scene>`` and the working folder).
    """
    parsed = _parsed_scene(data, _scene_context(file))
    return from_mapping(Scene, parsed, file=str(Path(file).resolve()) if file else None)


def scene_error(scene: Scene, key: str, reason: str) -> ConfigError:
    """A problem found after loading (planning, say), reported like the file's own errors."""
    return ConfigError(_scene_context(scene.file).file, key, reason)


def validate_scene(scene: Scene) -> None:
    """Check a scene by the rules of its file (``Scene`` calls this whenever one is made)."""
    _parsed_scene(to_mapping(scene), _scene_context(scene.file))


def _scene_context(file) -> Context:
    """Where a scene's values come from: its file, or ``<scene>`` (relative paths from the working folder)."""
    return Context(display_path(file) if file else Path("<scene>"))


def _parsed_scene(data, ctx: Context) -> dict:
    scene = parse_mapping(SCENE_SPEC, data, ctx)
    if scene["name"] is None:
        scene["name"] = ctx.file.stem if ctx.file.name != "<scene>" else "scene"
    if problem := name_problem(scene["name"]):
        ctx.fail("name", problem)
    if scene["output"]["dir"] is None:
        scene["output"]["dir"] = str(Path("out", scene["name"]).resolve())
    _check_scene(scene, ctx)
    return scene


def lawnmower_lines(size, heading: float, line_spacing: float) -> float:
    """How many parallel legs ``line_spacing`` apart along ``heading`` (degrees clockwise from +y) cover
    a plot of ``size`` (w, h) m: plan/flight.py's lawnmower lays them. A float, as a spacing of 1e-300 m
    calls for more legs than an integer type holds (the scene's check refuses over :data:`MAX_LEGS`)."""
    (w, h), a = size, math.radians(heading)
    half_width = max(abs(x * math.cos(a) - y * math.sin(a)) for x in (-w / 2, w / 2) for y in (-h / 2, h / 2))
    try:
        return math.ceil(2 * half_width / line_spacing) + 1.0
    except OverflowError:   # the quotient is inf
        return math.inf


def most_stems(size) -> int:
    """The most trees a plot of ``size`` (w, h) m may hold, listed or counted: :data:`MAX_STEMS_PER_M2` a
    square metre, at least one."""
    w, h = size
    return max(1, int(MAX_STEMS_PER_M2 * w * h))


def understory_capacity(size, kind: str) -> int:
    """How many understory objects of ``kind`` random placement can fit, alone, in a plot of ``size``
    (w, h) m: their clear discs (``CLEARANCE``) fill at most a share RSA_JAMMING of it, and none fits in a
    plot no wider than one disc."""
    (w, h), clearance = size, CLEARANCE[kind]
    if min(w, h) <= 2 * clearance:
        return 0
    return int(RSA_JAMMING * w * h / (math.pi * clearance ** 2))


def _check_understory_fits(counts: dict, size, ctx: Context) -> None:
    """Refuse understory counts whose clear discs cannot fit in the plot together, before any work (a
    dataset checks every plot's this way); the plan's placement loop stays the exact test."""
    (w, h), used = size, 0.0
    for kind, key in UNDERSTORY_KEYS.items():
        if counts[key] and not understory_capacity((w, h), kind):
            ctx.fail(f"understory.{key}", f"a {w:g} x {h:g} m plot is too small for {key} (each needs "
                     f"{2 * CLEARANCE[kind]:g} m across inside the plot); set it to 0")
        used += counts[key] * math.pi * CLEARANCE[kind] ** 2
        if used > RSA_JAMMING * w * h:
            ctx.fail(f"understory.{key}", f"{counts[key]} {key} do not fit in a {w:g} x {h:g} m plot beside the "
                     "other understory (each keeps a clear disc); lower the counts")


def _check_scene(scene: dict, ctx: Context):
    forest, survey, sensor = scene["forest"], scene["survey"], scene["sensor"]
    for i, value in enumerate(scene["origin"]["offset"]):
        if abs(value) > MAX_OFFSET:
            ctx.fail(f"origin.offset[{i}]", f"{value:g} m is no map coordinate: projected CRSs stay within "
                     f"±{MAX_OFFSET:g} m, and far beyond that float64 cannot keep the points' 0.1 mm")
    ground_layer = scene["understory"]["grass"]["cover"] + scene["understory"]["litter"]["cover"]
    if ground_layer > 1:
        ctx.fail("understory.litter.cover", f"grass and litter patches do not overlap: their covers add up to "
                 f"{ground_layer:g}, more than 1")
    if forest["canopy_cover"] is not None and forest["trees"] is not None:
        ctx.fail("forest.trees", "give either forest.canopy_cover or forest.trees, not both")
    disc = math.pi * (forest["min_spacing"] / 2) * (forest["min_spacing"] / 2)   # inf, not OverflowError, for 1e300
    if forest["trees"] and disc > 0:   # 0 for a spacing under 1e-160 m as for none
        w, h = scene["area"]["size"]
        fit = int(RSA_JAMMING * w * h / disc) + 1
        if forest["trees"] > fit:
            ctx.fail("forest.trees", f"{forest['trees']} trees at min_spacing {forest['min_spacing']:g} m do not fit "
                     f"in a {w:g} x {h:g} m plot (random placement fills at most about {fit})")
    if forest["trees"]:
        w, h = scene["area"]["size"]
        most = most_stems(scene["area"]["size"])
        if forest["trees"] > most:
            ctx.fail("forest.trees", f"{forest['trees']} trees in a {w:g} x {h:g} m plot is more than {MAX_STEMS_PER_M2:g} a "
                     f"square metre (at most {most}; the densest young stands hold about 10)")
    _check_understory_fits(understory_counts(scene["understory"], scene["area"]["size"]), scene["area"]["size"], ctx)
    cover = forest["canopy_cover"]
    lo, hi = FOREST_BANDS[forest["type"]]
    if cover is not None and not lo <= cover <= hi:
        ctx.fail("forest.canopy_cover", f"{cover:g} is outside the {forest['type']} band {lo:g}-{hi:g}")
    if forest["trees_file"] is not None and (forest["trees"] is not None or forest["canopy_cover"] is not None):
        ctx.fail("forest.trees_file", "places the trees it lists: give it without forest.trees or forest.canopy_cover")
    if forest["surround"] and forest["trees_file"] is None:
        ctx.fail("forest.surround", "repeats the trees of forest.trees_file around the plot: give it with one")
    if forest["trees_file"] is not None and forest["models"]:
        ctx.fail("forest.trees_file", "grows procedural trees of the listed sizes: give it without forest.models")
    if forest["trees_file"] is None and not sum(a.weight for a in [*forest["archetypes"], *forest["models"]]) > 0:
        ctx.fail("forest.archetypes", "at least one archetype or model needs weight > 0")
    if sum(getattr(a, "unique", 1) for a in forest["archetypes"]) + len(forest["models"]) > MAX_TREE_MODELS:
        ctx.fail("forest.models", f"at most {MAX_TREE_MODELS:,} archetypes and models together (treeid is 16 bits)")
    if scene["terrain"]["type"] in ("mesh", "dem") and not scene["terrain"]["path"]:
        ctx.fail("terrain.path", f"is required when terrain.type is {scene['terrain']['type']}")
    if scene["terrain"]["type"] not in ("mesh", "dem") and scene["terrain"]["path"]:
        ctx.fail("terrain.path", f"is read only with terrain.type dem (a GeoTIFF) or mesh; terrain.type is "
                 f"{scene['terrain']['type']}")
    freqs = sensor.pulse_frequencies
    if survey["pulse_frequency"] is not None and survey["pulse_frequency"] not in freqs:
        ctx.fail("survey.pulse_frequency", f"{survey['pulse_frequency']:g} Hz is not one of the sensor's "
                 f"pulse frequencies ({', '.join(f'{f:g}' for f in freqs)})")
    lo, hi = sensor.scan_frequency_range
    if survey["scan_frequency"] is not None and not lo <= survey["scan_frequency"] <= hi:
        ctx.fail("survey.scan_frequency", f"{survey['scan_frequency']:g} Hz is outside the sensor's range "
                 f"{lo:g}-{hi:g} Hz")
    if survey["trajectory"] and survey["lines"] is not None:
        ctx.fail("survey.lines", "give either survey.lines or survey.trajectory, not both")
    if survey["trajectory"] is None and survey["lines"] is None:   # before the legs are laid: 1e-6 m would take hours
        lines = lawnmower_lines(scene["area"]["size"], survey["heading"], survey["line_spacing"])
        if lines > MAX_LEGS:
            ctx.fail("survey.line_spacing", f"{survey['line_spacing']:g} m apart, {amount(lines)} flight lines cross the "
                     f"plot, more than the {MAX_LEGS:,} that LAS point_source_id can number")
    waves = survey["attitude"].values()
    if survey["trajectory"] and any(w["mean_deg"] or w["amplitude_deg"] for w in waves):
        ctx.fail("survey.attitude", "a trajectory file gives its own attitude; survey.attitude is for planned legs")
    variant = scene["simulation"]["variant"]
    if variant != "auto" and not (variant.startswith("llvm_") or variant.startswith("cuda_")):
        ctx.fail("simulation.variant", f"must be auto or a Mitsuba llvm_* or cuda_* variant such as llvm_ad_mono, "
                 f"got {variant!r}")
