"""The typed scene: frozen dataclasses that every stage reads.

A :class:`Scene` holds what its file says (defaults filled in, paths absolute); settings that follow
from others are properties, so they follow every edit: ``scene.pulse_frequency`` (the survey's, or the
sensor's rate nearest 200 kHz), ``scene.scan_frequency``, ``scene.forest.target_cover``,
``sensor.detection_threshold``, ``sensor.resolving_distance``, ``sensor.half_fov``.

Every Scene is validated when it is made, with the messages of the YAML files, so an edit is checked
like the file::

    scene = load_scene("scenes/demo.yaml")
    scene = scene.with_({"survey.altitude": 40, "sensor": load_sensor("sensors/ideal.yaml")})
    scene = dataclasses.replace(scene, seed=3)
    scene.with_({"simulation.beam_samples": 0})   # ConfigError: scenes/demo.yaml: simulation.beam_samples: must be >= 1, got 0

Fields are named as the YAML keys, except where a key's value is a default that a property resolves
(``detection_threshold``: the field is ``detection_threshold_setting``).
"""

from __future__ import annotations

import dataclasses
import math
import typing
from dataclasses import dataclass, field

import numpy as np

from ..errors import display_path  # noqa: F401 (re-exported: config uses it from here)
from ..specs.archetypes import Archetype, UniqueTrees
from ..specs.sources import MeshTree, QsmTree

# Australia's National Forest Inventory crown cover classes.
FOREST_BANDS = {"woodland": (0.20, 0.50), "open": (0.50, 0.80), "closed": (0.80, 1.00)}
BEAM_PATTERNS = ("stratified", "fixed")   # see scan/beam.py
POINT_POSITIONS = ("beam_axis", "surface")  # see scan/tracer.py
INTENSITY_SOURCES = ("amplitude", "reflectance", "reflectance_db")   # see scan/radiometry.py
OUTPUT_PROFILES = ("ours", "for-instance", "forestformer3d", "treelearn")   # write/output_profiles.py PROFILES, and ours
SPEED_OF_LIGHT = 299_792_458.0


def _yaml(key: str | None):
    """Field metadata: the field's YAML key (``None``: not a YAML key)."""
    return {"yaml": key}


@dataclass(frozen=True)
class Risley:
    prism_rates: tuple[float, float]          # rotations per second of the two prisms
    prism_deflection: tuple[float, float]     # deviation of each prism (deg)


@dataclass(frozen=True)
class IntensityMapping:
    """How a sensor writes an echo's strength as 16-bit LAS intensity (scan/radiometry.py,
    :func:`~mitsuforest.scan.radiometry.intensity_counts`)."""

    source: str = "amplitude"                 # amplitude | reflectance (linear, 1 = white Lambertian) | reflectance_db
    gain: float = 1.0e6                       # counts per unit of the source
    offset: float = 0.0                       # counts added
    saturation: int = 65535                   # counts: stronger returns clip here


@dataclass(frozen=True)
class WaveformSampling:
    """How a sensor digitises its received waveform (scan/waveform.py; written with ``output.waveforms``)."""

    bin_size: float = 1.0e-9                  # s of two-way time per sample (1 ns: 0.15 m of range)
    samples: int = 256                        # samples per pulse: the window (256 ns, 38.4 m of range)

    @property
    def bin_range(self) -> float:
        """One bin on the range axis (m): ``c·bin_size/2``."""
        return SPEED_OF_LIGHT * self.bin_size / 2


@dataclass(frozen=True)
class Mount:
    """How the sensor sits on the platform (plan/trajectory.py has the frames)."""

    lever_arm: tuple[float, float, float] = (0.0, 0.0, 0.0)    # m, body frame: forward, right, down
    boresight: tuple[float, float, float] = (0.0, 0.0, 0.0)    # deg: roll, pitch, yaw of the sensor in the body

    @property
    def zero(self) -> bool:
        return not any(self.lever_arm) and not any(self.boresight)


@dataclass(frozen=True)
class Sensor:
    """A sensor file (``sensors/*.yaml``)."""

    name: str
    source: str
    deflector: str                            # rotating | oscillating | risley
    field_of_view: float                      # full angle (deg)
    pulse_frequencies: tuple[float, ...]      # Hz
    scan_frequency_range: tuple[float, float]  # Hz
    beam_divergence: tuple[float, float]      # full angle at 1/e² (rad), across track (in the scan plane), along track
    pulse_length: float                       # FWHM (s)
    wavelength: float                         # m
    range_min: float
    range_max: float
    range_precision: float                    # 1-σ ranging noise (m)
    range_accuracy: float                     # reported, not simulated (m)
    max_returns: int                          # 0 = unlimited
    detection_threshold_setting: float | None = field(metadata=_yaml("detection_threshold"))
    risley: Risley
    file: str | None = field(default=None, metadata=_yaml(None))   # the sensor file, if any
    echo_separation: float | None = None      # m: nearest two returns are told apart; None: c·τ/2
    range_precision_per_metre: float = 0.0    # k_R: ranging σ grows as sqrt(σ₀² + (k_R·R)² + ...) (scan/noise.py)
    footprint_range_noise: float = 0.0        # f: share of the footprint's range spread on inclined surfaces
    speckle_looks: int = 0                    # L: amplitude × Gamma(L, 1/L); 0: no speckle
    intensity: IntensityMapping = IntensityMapping()
    mount: Mount = Mount()                    # lever arm and boresight (a sensor file's or an inline sensor's)
    waveform: WaveformSampling = WaveformSampling()   # bin size and window of the sampled waveform

    @property
    def detection_threshold(self) -> float:
        """Minimum echo amplitude (unit: see scan/radiometry.py). By default a full-footprint 20 %
        Lambertian target at normal incidence is just detected at ``range_max``."""
        if self.detection_threshold_setting is not None:
            return self.detection_threshold_setting
        return 0.2 / self.range_max ** 2

    @property
    def resolving_distance(self) -> float:
        """Range separation below which two returns merge into one echo (m): the sensor's
        ``echo_separation`` where its data sheet gives one, else the pulse-shape value ``c·τ/2``."""
        if self.echo_separation is not None:
            return self.echo_separation
        return SPEED_OF_LIGHT * self.pulse_length / 2

    @property
    def half_fov(self) -> float:
        """Half the field of view (rad)."""
        return math.radians(self.field_of_view) / 2

    def reach(self, depth: float) -> float:
        """How far from the track (m) pulses reach at ``depth`` below the sensor: the field of view's
        edge there, never beyond ``range_max``; all of ``range_max`` for a field of view of 180° or
        more, or at or above the sensor."""
        if self.half_fov >= math.pi / 2 or depth <= 0:
            return self.range_max
        return min(self.range_max, depth * math.tan(self.half_fov))


@dataclass(frozen=True)
class Area:
    size: tuple[float, float]


@dataclass(frozen=True)
class Origin:
    crs: str | None
    offset: tuple[float, float, float]        # added to local coordinates on output (float64)


@dataclass(frozen=True)
class TerrainSettings:
    type: str                                 # flat | noise | mesh | dem
    amplitude: float
    wavelength: float
    path: str | None


@dataclass(frozen=True)
class Forest:
    type: str                                 # woodland | open | closed
    canopy_cover: float | None
    trees: int | None
    min_spacing: float
    tilt: float
    archetypes: tuple[Archetype | UniqueTrees, ...]   # unique entries: drawn per plot by the plan
    models: tuple[MeshTree | QsmTree, ...] = ()   # imported trees (specs/sources.py), treeids after the archetypes
    trees_file: str | None = None             # a tree list (plan/tree_list.py): one procedural model per row
    surround: float = 0.0                     # m: with a tree list, its trees repeated around the plot this far (plan)

    @property
    def target_cover(self) -> float | None:
        """The canopy cover to reach: the given one, the middle of the type's band when neither a
        cover nor a tree count is given, ``None`` with a tree count or a tree list."""
        if self.canopy_cover is not None or self.trees is not None or self.trees_file is not None:
            return self.canopy_cover
        return sum(FOREST_BANDS[self.type]) / 2


@dataclass(frozen=True)
class Grass:
    cover: float                              # share of the plot under grass patches (0: none)
    height: float                             # mean blade length (m)


@dataclass(frozen=True)
class Litter:
    cover: float                              # share of the plot under leaf-litter patches (0: none)


UNDERSTORY_PER_HECTARE = {"bushes": 200, "rocks": 40, "deadwood": 25, "stumps": 15}   # the paper's 1 ha plots


def understory_counts(given, size) -> dict[str, int]:
    """Bushes, rocks, deadwood and stumps by key: the ``given`` count (a mapping), or where it is None
    UNDERSTORY_PER_HECTARE over the plot's ``size`` (w, h) m, rounded."""
    area_ha = size[0] * size[1] / 10_000
    return {key: given[key] if given[key] is not None else int(round(per_ha * area_ha))
            for key, per_ha in UNDERSTORY_PER_HECTARE.items()}


@dataclass(frozen=True)
class Understory:
    bushes: int | None                        # None: UNDERSTORY_PER_HECTARE for the plot (Scene.understory_counts)
    rocks: int | None
    deadwood: int | None
    stumps: int | None
    grass: Grass
    litter: Litter


@dataclass(frozen=True)
class Wave:
    """One attitude angle of a planned leg: ``mean + amplitude·sin(2π t / period + phase)`` (deg, t in s)."""

    mean_deg: float = 0.0
    amplitude_deg: float = 0.0
    period_s: float = 10.0
    phase_deg: float = 0.0

    def __call__(self, t: np.ndarray) -> np.ndarray:
        return self.mean_deg + self.amplitude_deg * np.sin(2 * math.pi * np.asarray(t) / self.period_s
                                                           + math.radians(self.phase_deg))

    @property
    def zero(self) -> bool:
        return self.mean_deg == 0 and self.amplitude_deg == 0



@dataclass(frozen=True)
class Attitude:
    """A planned leg's attitude disturbance: roll, pitch and yaw (added to the heading) as :class:`Wave` s."""

    roll: Wave = Wave()
    pitch: Wave = Wave()
    yaw: Wave = Wave()

    @property
    def zero(self) -> bool:
        return self.roll.zero and self.pitch.zero and self.yaw.zero


@dataclass(frozen=True)
class NavigationErrors:
    """Errors of the navigation solution the points are computed with (scan/navigation.py); the pulses
    fly the true trajectory."""

    gnss_sigma_m: tuple[float, float, float] = (0.0, 0.0, 0.0)            # white, per epoch: east, north, up
    gnss_random_walk_m_per_sqrt_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    imu_sigma_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)           # white, per epoch: roll, pitch, yaw
    boresight_error_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)     # the calibration's error: roll, pitch, yaw
    rate_hz: float = 10.0                                                # epochs of the solution; linear between

    @property
    def zero(self) -> bool:
        return not any((*self.gnss_sigma_m, *self.gnss_random_walk_m_per_sqrt_s, *self.imu_sigma_deg,
                        *self.boresight_error_deg))


@dataclass(frozen=True)
class Survey:
    altitude: float
    speed: float
    pulse_frequency: float | None             # None: see Scene.pulse_frequency
    scan_frequency: float | None              # None: see Scene.scan_frequency
    line_spacing: float
    heading: float
    margin: float
    lines: tuple | None                       # ((x0, y0), (x1, y1)) per leg, or None (lawnmower)
    trajectory: str | None = None             # a trajectory CSV flown instead of planned legs
    attitude: Attitude = Attitude()           # planned legs' roll, pitch, yaw disturbance
    navigation_errors: NavigationErrors = NavigationErrors()


@dataclass(frozen=True)
class Simulation:
    beam_samples: int
    beam_pattern: str                         # fixed | stratified
    variant: str
    pulses_per_batch: int | None
    point_position: str = "beam_axis"         # beam_axis | surface


@dataclass(frozen=True)
class Output:
    dir: str
    formats: tuple[str, ...]
    profile: str = "ours"                     # one of OUTPUT_PROFILES
    waveforms: bool = False                   # NAME_waveforms.npz: each pulse's sampled waveform and its echoes
    pulses: bool = False                      # NAME_pulses.npz: every fired pulse with its echo count (0: none)
    pictures: bool = True                     # NAME_top/side/profile/returns.png (about 1 CPU s a render)


@dataclass(frozen=True)
class Scene:
    """A scene file, validated (see module docstring)."""

    name: str
    seed: int
    area: Area
    origin: Origin
    terrain: TerrainSettings
    forest: Forest
    understory: Understory
    sensor: Sensor
    survey: Survey
    simulation: Simulation
    output: Output
    file: str | None = field(default=None, metadata=_yaml(None))   # the scene file, if any

    def __post_init__(self):
        from . import validate_scene
        validate_scene(self)

    @property
    def pulse_frequency(self) -> float:
        """The survey's pulse frequency, or the sensor's nearest to 200 kHz."""
        if self.survey.pulse_frequency is not None:
            return self.survey.pulse_frequency
        return min(self.sensor.pulse_frequencies, key=lambda f: abs(f - 200_000))

    @property
    def understory_counts(self) -> dict[str, int]:
        """Bushes, rocks, deadwood and stumps to place: the file's counts, or the paper's per hectare
        (200, 40, 25, 15) for the plot's area, rounded."""
        return understory_counts(dataclasses.asdict(self.understory), self.area.size)

    @property
    def scan_frequency(self) -> float:
        """The survey's scan frequency, or 50 Hz clamped to the sensor's range."""
        if self.survey.scan_frequency is not None:
            return self.survey.scan_frequency
        lo, hi = self.sensor.scan_frequency_range
        return min(max(50.0, lo), hi)

    def with_(self, changes: dict | None = None, **sections) -> Scene:
        """A copy with ``changes`` applied and validated like the YAML file.

        :param changes: dotted YAML key paths to new values, e.g. ``{"survey.altitude": 40}``; a value
            may be a mapping, a list, or a section (``sensor=load_sensor(...)``).
        :param sections: top-level keys, e.g. ``survey={"altitude": 40}`` (merged into the section).
        """
        from . import scene_from_mapping
        data = to_mapping(self)
        for key, value in sections.items():
            value = _as_value(value)
            current = data.get(key)
            data[key] = {**current, **value} if isinstance(current, dict) and isinstance(value, dict) else value
        for path, value in (changes or {}).items():
            *parents, last = path.split(".")
            node = data
            for p in parents:
                if isinstance(node.get(p), Sensor):     # an edited sensor is no longer its file's
                    node[p] = to_mapping(node[p])
                node = node.setdefault(p, {})           # an unknown section is reported by the parser
                if not isinstance(node, dict):
                    from . import scene_error
                    raise scene_error(self, path, f"{p} is not a section")
            node[last] = _as_value(value)
        return scene_from_mapping(data, file=self.file)

    def describe(self) -> dict:
        """The scene as plain JSON-ready data, derived settings resolved (for the run manifest)."""
        d = to_mapping(self, plain=True)
        d["file"] = self.file
        d["sensor"]["file"] = self.sensor.file
        d["sensor"]["detection_threshold"] = self.sensor.detection_threshold
        d["survey"]["pulse_frequency"] = self.pulse_frequency
        d["survey"]["scan_frequency"] = self.scan_frequency
        d["forest"]["canopy_cover"] = self.forest.target_cover
        d["understory"].update(self.understory_counts)
        return d


SECTIONS = (Wave, Attitude, NavigationErrors, WaveformSampling, Mount, Risley, IntensityMapping, Sensor, Area, Origin, TerrainSettings, Forest, Grass, Litter, Understory, Survey, Simulation, Output, Scene)


def _as_value(value):
    """An edit's value as the parser takes it: sensors and archetypes as they are, other sections as mappings."""
    if isinstance(value, SECTIONS) and not isinstance(value, Sensor):
        return to_mapping(value)
    return value


def _keyed_fields(cls):
    return [(f, f.metadata.get("yaml", f.name)) for f in dataclasses.fields(cls) if f.metadata.get("yaml", f.name)]


def to_mapping(section, plain: bool = False) -> dict:
    """A section as the YAML mapping it came from (lists for tuples).

    A nested sensor and the archetypes stay objects (the parser takes them back as they are), unless
    ``plain`` asks for JSON-ready data.
    """
    if isinstance(section, (Archetype, UniqueTrees, MeshTree, QsmTree)):
        return dataclasses.asdict(section)
    return {key: _nested(getattr(section, f.name), plain) for f, key in _keyed_fields(type(section))}


def _nested(value, plain: bool):
    if isinstance(value, (tuple, list)):
        return [_nested(v, plain) for v in value]
    if isinstance(value, (Sensor, Archetype, UniqueTrees, MeshTree, QsmTree)) and not plain:
        return value
    if dataclasses.is_dataclass(value):
        return to_mapping(value, plain)
    return value


def from_mapping(cls, data: dict, **extra):
    """A section from a parsed (validated, defaults filled) mapping; nested sections recursively."""
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for f, key in _keyed_fields(cls):
        value = data[key]
        hint = hints[f.name]
        if dataclasses.is_dataclass(hint) and isinstance(value, dict):
            value = from_mapping(hint, value)
        kwargs[f.name] = _frozen(value)
    return cls(**kwargs, **extra)


def _frozen(value):
    """Lists (also nested) as tuples, so that a frozen section is immutable all the way down."""
    if isinstance(value, list):
        return tuple(_frozen(v) for v in value)
    return value
