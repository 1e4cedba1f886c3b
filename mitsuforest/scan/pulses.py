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

    def select(self, which) -> Pulses:
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
    return reaching_pulses(leg, sensor, survey, first, count)[0]


def reaching_pulses(leg: dict, sensor: dict, survey: dict, first: int, count: int, box: np.ndarray | None = None,
                    range_max: float = np.inf) -> tuple[Pulses, int]:
    """The fired pulses among time slots ``first .. first+count-1`` that can reach ``box`` (2, 3) within
    ``range_max`` (all fired pulses without a box), and how many pulses were fired."""
    k = np.arange(first, first + count, dtype=np.int64)
    t, direction, angle, fired = _slot_beams(leg, sensor, survey, k)
    k, t, direction, angle = k[fired], t[fired], direction[fired], angle[fired]
    origin = platform_position(leg, t)
    if box is not None:
        keep = np.flatnonzero(reaches_box(origin, direction, box, range_max))
        k, t, angle, direction, origin = k[keep], t[keep], angle[keep], direction[keep], origin[keep]
    return Pulses(k, t, origin, direction, _across(leg_frame(leg), direction), angle), int(np.count_nonzero(fired))


def slot_pulses(leg: dict, sensor: dict, survey: dict, slots: np.ndarray) -> Pulses:
    """The pulses of the given time slots of a leg (fired or not)."""
    k = np.asarray(slots, np.int64)
    t, direction, angle, _ = _slot_beams(leg, sensor, survey, k)
    return Pulses(k, t, platform_position(leg, t), direction, _across(leg_frame(leg), direction), angle)


def _slot_beams(leg: dict, sensor: dict, survey: dict, k: np.ndarray):
    """Times, beam axes (local frame), scan angles and fired mask of the time slots ``k`` of a leg."""
    t = leg["t0"] + k / survey["pulse_frequency"]
    d_sensor, angle, fired = deflect(sensor, t, survey["scan_frequency"])
    return t, d_sensor @ leg_frame(leg), angle, fired


def _across(frame: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Unit ``along × direction`` (the scan plane's normal in the beam frame); ``frame[0]`` at nadir-parallel."""
    a = frame[1]
    dx, dy, dz = direction.T
    across = np.empty_like(direction)
    across[:, 0] = a[1] * dz - a[2] * dy
    across[:, 1] = a[2] * dx - a[0] * dz
    across[:, 2] = a[0] * dy - a[1] * dx
    norm = np.sqrt(np.einsum("ij,ij->i", across, across))
    degenerate = norm <= 1e-9
    across /= np.where(degenerate, 1.0, norm)[:, None]
    across[degenerate] = frame[0]
    return across


def reaches_box(origin: np.ndarray, direction: np.ndarray, box: np.ndarray, range_max: float) -> np.ndarray:
    """Whether each ray meets the axis-aligned box (2, 3) within ``range_max`` (slab test)."""
    n = len(origin)
    lo, hi = np.zeros(n), np.full(n, float(range_max))
    for k in range(3):
        o, d = origin[:, k], direction[:, k]
        parallel = d == 0
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / np.where(parallel, 1.0, d)
        t0, t1 = (box[0, k] - o) * inv, (box[1, k] - o) * inv
        inside = (o >= box[0, k]) & (o <= box[1, k])   # a parallel ray meets this slab everywhere or nowhere
        lo = np.maximum(lo, np.where(parallel, np.where(inside, -np.inf, np.inf), np.minimum(t0, t1)))
        hi = np.minimum(hi, np.where(parallel, np.where(inside, np.inf, -np.inf), np.maximum(t0, t1)))
    return lo <= hi
