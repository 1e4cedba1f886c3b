"""The plan's parts: flight legs, placed objects and the models they place (frozen dataclasses;
:class:`~mitsuforest.specs.ModelSpec`, what the trees stage builds, is shared)."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass

import numpy as np

from ..classes import GROUND, GROUND_OBJECT_ID
from ..specs import ModelSpec
from .terrain import MeshGround, Terrain
from .trajectory import Track
from .transforms import rotation


@dataclass(frozen=True)
class Leg:
    """A straight flight leg flown at constant speed from ``start`` at ``t0`` to ``end`` at ``t1``, or a
    flight line of a trajectory file (``track``: flown as the file says, from its first to its last row)."""

    start: tuple[float, float, float]   # local frame (m)
    end: tuple[float, float, float]
    t0: float                           # s
    t1: float
    track: Track | None = None

    def positions(self) -> np.ndarray:
        """(n, 3) points along the leg: its ends, or every row of its track."""
        if self.track is not None:
            return self.track.position
        return np.array([self.start, self.end], float)

    def frame(self) -> np.ndarray:
        """(3, 3) rows: across-track (right), along-track, up unit vectors."""
        along = np.array(self.end, float) - np.array(self.start, float)
        along[2] = 0.0
        along /= np.linalg.norm(along)
        return np.array([[along[1], -along[0], 0.0], along, [0.0, 0.0, 1.0]])

    def position(self, t) -> np.ndarray:
        """(n, 3) platform positions at times ``t`` (s), linear from start to end."""
        f = (np.asarray(t, np.float64) - self.t0) / (self.t1 - self.t0)
        a, b = np.array(self.start, float), np.array(self.end, float)
        return a + f[:, None] * (b - a)

    def pulse_count(self, pulse_frequency: float) -> int:
        """Time slots of the leg: ``floor(duration · pulse_frequency)``."""
        return int(np.floor((self.t1 - self.t0) * pulse_frequency + 1e-9))

    @property
    def heading(self) -> float:
        """Direction of flight, degrees clockwise from +y (north)."""
        along = self.frame()[1]
        return float(np.rad2deg(np.arctan2(along[0], along[1])) % 360)


@dataclass(frozen=True)
class PlacedObject:
    """One placed copy of a model: rotation about z, then tilt about x and y, then translation."""

    kind: str
    model: str
    treeid: int
    position: tuple[float, float, float]
    rotation: float                      # deg about z
    tilt: tuple[float, float]            # deg about x and y
    instance: int = 0                    # 1.. (0 until ids are assigned)
    object_id: int = 0                   # the first of its ``components`` object ids
    components: int = 1

    @property
    def matrix(self) -> np.ndarray:
        """4×4 model-to-local-frame matrix."""
        m = np.eye(4)
        m[:3, :3] = rotation(self.rotation, *self.tilt)
        m[:3, 3] = self.position
        return m


@dataclass(frozen=True)
class Plan:
    """Everything placed in a scene, and how it is flown. :meth:`to_json` is byte-stable."""

    scene: str
    seed: int
    area: tuple[float, float]
    forest_type: str
    canopy_cover: float
    terrain: Terrain | MeshGround         # a grid, or a mesh alone (a HELIOS++ scene's ground)
    models: dict[str, ModelSpec]
    objects: tuple[PlacedObject, ...]
    legs: tuple[Leg, ...]
    ground_object_id: int = GROUND_OBJECT_ID
    ground_class: int = GROUND

    @property
    def trees(self) -> list[PlacedObject]:
        return [o for o in self.objects if o.kind == "tree"]

    def to_json(self) -> str:
        """The plan as canonical JSON text (stable key order and float formatting)."""
        data = {
            "scene": self.scene, "seed": self.seed, "area": list(self.area), "forest_type": self.forest_type,
            "canopy_cover": self.canopy_cover,
            "terrain": {"type": self.terrain.type, "mean_height": self.terrain.mean_height},
            "ground": {"instance": 0, "object_id": self.ground_object_id, "treeid": 0,
                       "classification": self.ground_class},
            "models": {name: _plain(spec) for name, spec in self.models.items()},
            "objects": [_plain(o) for o in self.objects],
            "legs": [_leg_json(leg) for leg in self.legs],
        }
        return json.dumps(data, indent=1, sort_keys=True, default=_jsonable) + "\n"


def _leg_json(leg: Leg) -> dict:
    out = {k: v for k, v in dataclasses.asdict(dataclasses.replace(leg, track=None)).items() if v is not None}
    if leg.track is not None:
        out["track"] = leg.track.summary()
    return out


def _plain(obj) -> dict:
    return {k: v for k, v in dataclasses.asdict(obj).items() if v is not None}


def _jsonable(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(type(x))
