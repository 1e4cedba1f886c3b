"""numpy twin of :mod:`mitsuforest.scan.pulses`: the pulses of one leg's time slots (tests' reference)."""

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


def reaching_pulses(leg, sensor, pulse_frequency: float, scan_frequency: float, first: int, count: int,
                    box: np.ndarray | None = None, platform=None, table=None) -> tuple[Pulses, int]:
    """The fired pulses among time slots ``first .. first+count-1`` that can reach ``box`` (2, 3) within
    the sensor's ``range_max`` (all fired pulses without a box), and how many pulses were fired.

    :param platform, table: a :class:`~mitsuforest.scan.platform.Platform` and the leg's pose table
        (``Platform.table``); without a table, level flight along the leg's straight line."""
    k = np.arange(first, first + count, dtype=np.int64)
    since = k / pulse_frequency
    t = leg.t0 + since
    d_sensor, angle, fired = deflect(sensor, leg.t0, since, scan_frequency)
    k, t, d_sensor, angle = k[fired], t[fired], d_sensor[fired], angle[fired]
    if table is None:
        frame = np.broadcast_to(leg.frame(), (len(t), 3, 3))    # rows: the sensor axes in the local frame
        origin = leg.position(t)
    else:
        origin, rotation = platform.beam(table, t)
        frame = np.swapaxes(rotation, 1, 2)
    direction = np.einsum("ni,nij->nj", d_sensor, frame)
    if box is not None:
        keep = np.flatnonzero(reaches_box(origin, direction, box, sensor.range_max))
        k, t, angle, direction, origin, frame = k[keep], t[keep], angle[keep], direction[keep], origin[keep], frame[keep]
    return Pulses(k, t, origin, direction, _across(frame, direction), angle), int(np.count_nonzero(fired))


def _across(frame: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Unit ``along × direction`` (the scan plane's normal in the beam frame); ``frame[:, 0]`` at nadir-parallel."""
    across = np.cross(frame[:, 1], direction)
    norm = np.linalg.norm(across, axis=1)
    degenerate = norm <= 1e-9
    across /= np.where(degenerate, 1.0, norm)[:, None]
    across[degenerate] = frame[degenerate, 0]
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


def aimed_at(pulses: Pulses, targets: list[tuple[float, np.ndarray]], bounds: np.ndarray, box: np.ndarray,
             range_max: float) -> np.ndarray:
    """(P,) the pulses the tracer casts: those fired inside ``box`` (2, 3), and those whose beam axis meets
    within ``range_max`` one of the boxes (k, 2, 3) of the nearest ``targets`` entry (range, boxes) whose
    range reaches the farthest corner of ``bounds`` (2, 3) from the pulse (the last entry: the rest)."""
    inside = np.all((pulses.origin >= box[0]) & (pulses.origin <= box[1]), axis=1)
    farthest = np.linalg.norm(np.maximum(np.abs(pulses.origin - bounds[0]), np.abs(pulses.origin - bounds[1])), axis=1)
    keep, tested = inside.copy(), inside.copy()
    for i, (reach, boxes) in enumerate(targets):
        use = ~tested if i == len(targets) - 1 else ~tested & (farthest <= reach)
        for target in boxes:
            keep |= use & reaches_box(pulses.origin, pulses.direction, target, range_max)
        tested |= use
    return keep
