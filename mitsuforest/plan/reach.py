"""Where a leg's pulses can go (its swath), for leaving out the objects no pulse of some legs can reach
(:func:`~mitsuforest.scene.reachable`) and refusing a leg that cannot reach the plot.

A pulse leaves within FOV/2 of the sensor's nadir; the platform's attitude, a trajectory file's, and the
mount's boresight tilt that nadir from the vertical, and the beam's sub-rays spread beyond its axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .trajectory import BODY_FROM_SENSOR, euler_matrix, pose_table


@dataclass(frozen=True)
class Swath:
    """Where a leg's pulses can go: from beam origins at most ``margin`` m (horizontally) from ``path``
    (n, 2; straight between rows) and at most ``top`` m high, each inside a cone about the vertical of
    ``half_angle`` (rad)."""

    path: np.ndarray
    top: float
    half_angle: float
    margin: float = 0.0

    def reach(self, depth, range_max: float) -> np.ndarray:
        """How far (m, horizontally) from an origin its pulses reach at ``depth`` (m, array) below it:
        ``depth·tan(half_angle)``, never beyond ``range_max``; all of ``range_max`` at or above the origin,
        or for a half angle of 90° or more."""
        depth = np.asarray(depth, np.float64)
        if self.half_angle >= np.pi / 2:
            return np.full(depth.shape, float(range_max))
        return np.where(depth <= 0, range_max, np.minimum(range_max, np.maximum(depth, 0.0) * np.tan(self.half_angle)))


BEAM_SPREAD = 3.0   # the widest sub-ray's angle from the beam axis, in half divergences (scan/tracer.py's)
PATH_STEP = 40      # a trajectory's pose rows (5 ms apart) per row of its swath's path


def leg_swaths(legs, sensor, attitude=None, beam: bool = True) -> list[Swath]:
    """The :class:`Swath` of each leg: its pulses leave within FOV/2 of the sensor's nadir, which the
    platform's attitude (``survey.attitude``, or a trajectory file's) and the mount's boresight tilt
    from the vertical, and their sub-rays spread by the beam's divergence beyond that (``beam``; else
    the beam axes' swath); the lever arm moves their origins by up to its length."""
    mount = sensor.mount
    spread = float(np.arctan(BEAM_SPREAD * max(sensor.beam_divergence) / 2)) if beam else 0.0
    level = attitude is None or attitude.zero
    sensor_to_body = euler_matrix(*mount.boresight)[0] @ BODY_FROM_SENSOR
    lever = float(np.linalg.norm(mount.lever_arm))
    out = []
    for leg in legs:
        ends = leg.positions()
        if leg.track is None and level and mount.zero:
            out.append(Swath(ends[:, :2], float(ends[:, 2].max()), sensor.half_fov + spread))
            continue
        table = pose_table(leg, None if level else attitude)
        nadir_cos = (table.body @ sensor_to_body)[:, 2, 2]     # the sensor's -z against the local -z
        tilt = float(np.arccos(np.clip(nadir_cos, -1.0, 1.0)).max())
        # a planned leg flies straight between its ends; a trajectory's spline, coarsened within `bend` m
        path, bend = (ends[:, :2], 0.0) if leg.track is None else _coarse_path(table.position[:, :2])
        top = float(max(ends[:, 2].max(), table.position[:, 2].max())) + lever
        out.append(Swath(path, top, sensor.half_fov + tilt + spread, lever + bend))
    return out


def _coarse_path(path: np.ndarray, step: int = PATH_STEP) -> tuple[np.ndarray, float]:
    """Every ``step``-th row of a path (n, 2) and its last, and how far (m) the path strays from the
    straight lines between the rows kept."""
    keep = np.unique(np.append(np.arange(0, len(path), step), len(path) - 1))
    if len(keep) < 2:
        return path[keep], 0.0
    segment = np.minimum(np.searchsorted(keep, np.arange(len(path)), side="right") - 1, len(keep) - 2)
    a, ab = path[keep][segment], path[keep][segment + 1] - path[keep][segment]
    f = np.clip(np.einsum("nk,nk->n", path - a, ab) / np.maximum(np.einsum("nk,nk->n", ab, ab), 1e-12), 0, 1)
    return path[keep], float(np.linalg.norm(path - a - f[:, None] * ab, axis=1).max())


def path_distance(points: np.ndarray, path: np.ndarray, pairs: int = 1 << 22) -> np.ndarray:
    """(m,) horizontal distance of each point (m, 2) to a path (n, 2) straight between its rows, taking
    at most about ``pairs`` (point, segment) pairs at once (a trajectory's path has a row every 5 ms)."""
    a, b = (path[:-1], path[1:]) if len(path) > 1 else (path, path)
    best = np.full(len(points), np.inf)
    block = max(1, pairs // max(len(points), 1))
    for k in range(0, len(a), block):
        sa, ab = a[k:k + block], b[k:k + block] - a[k:k + block]
        rel = points[:, None, :] - sa[None]
        f = np.clip(np.einsum("mnk,nk->mn", rel, ab) / np.maximum(np.einsum("nk,nk->n", ab, ab), 1e-12), 0, 1)
        best = np.minimum(best, np.linalg.norm(rel - f[..., None] * ab[None], axis=2).min(axis=1))
    return best
