"""The pulse timeline: times, platform positions and beam directions of the pulses of one leg."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .deflector import deflect


@dataclass
class Pulses:
    index: np.ndarray       # (P,) pulse number within the leg (0 = the leg's first time slot)
    time: np.ndarray        # (P,) float64 s
    origin: np.ndarray      # (P, 3) float64, local frame
    direction: np.ndarray   # (P, 3) unit beam axis, local frame
    across: np.ndarray      # (P, 3) beam frame axis in the scan plane (divergence[0] applies here)
    scan_angle: np.ndarray  # (P,) rad

    def select(self, which) -> "Pulses":
        """The pulses picked by a boolean mask, index array or slice."""
        return Pulses(**{k: v[which] for k, v in vars(self).items()})


def leg_pulse_count(leg: dict, pulse_frequency: float) -> int:
    """Time slots of a leg: ``floor(duration · pulse_frequency)``."""
    return int(np.floor((leg["t1"] - leg["t0"]) * pulse_frequency + 1e-9))


def leg_frame(leg: dict) -> np.ndarray:
    """(3, 3) rows: across-track (right), along-track, up unit vectors of a leg."""
    along = np.array(leg["end"], float) - np.array(leg["start"], float)
    along[2] = 0.0
    along /= np.linalg.norm(along)
    return np.array([[along[1], -along[0], 0.0], along, [0.0, 0.0, 1.0]])


def platform_position(leg: dict, t) -> np.ndarray:
    """(n, 3) position on a straight leg at times ``t`` (linear in time from start to end)."""
    f = (np.asarray(t, np.float64) - leg["t0"]) / (leg["t1"] - leg["t0"])
    a, b = np.array(leg["start"], float), np.array(leg["end"], float)
    return a + f[:, None] * (b - a)


def leg_pulses(leg: dict, sensor: dict, survey: dict, first: int, count: int) -> Pulses:
    """The fired pulses among time slots ``first .. first+count-1`` of a leg."""
    f = survey["pulse_frequency"]
    k = np.arange(first, first + count, dtype=np.int64)
    t = leg["t0"] + k / f
    d_sensor, angle, fired = deflect(sensor, t, survey["scan_frequency"])
    frame = leg_frame(leg)
    k, t, d_sensor, angle = k[fired], t[fired], d_sensor[fired], angle[fired]
    direction = d_sensor @ frame
    across = np.cross(frame[1], direction)
    norm = np.linalg.norm(across, axis=1, keepdims=True)
    across = np.where(norm > 1e-9, across / np.maximum(norm, 1e-12), frame[0])
    return Pulses(k, t, platform_position(leg, t), direction, across, angle)


def reaches_box(origin: np.ndarray, direction: np.ndarray, box: np.ndarray, range_max: float) -> np.ndarray:
    """Whether each ray meets the axis-aligned box (2, 3) within ``range_max`` (slab test)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / direction
        t0 = (box[0] - origin) * inv
        t1 = (box[1] - origin) * inv
    lo = np.nanmax(np.minimum(t0, t1), axis=1)
    hi = np.nanmin(np.maximum(t0, t1), axis=1)
    return (hi >= np.maximum(lo, 0.0)) & (lo <= range_max)
