"""Flight legs: a lawnmower pattern over the plot, or the legs a scene lists."""

from __future__ import annotations

import numpy as np

from ..config import lawnmower_lines
from .trajectory import read_trajectory
from .types import Leg


def lawnmower(size, survey) -> list[tuple[np.ndarray, np.ndarray]]:
    """Parallel legs ``line_spacing`` apart covering the plot, alternating direction.

    Legs run along ``heading`` (degrees clockwise from +y) through the plot centre's neighbourhood
    and extend ``margin`` beyond the plot on both ends. Returns [(start_xy, end_xy), ...].
    """
    w, h = size
    centre = np.array([w / 2, h / 2])
    a = np.deg2rad(survey.heading)
    along = np.array([np.sin(a), np.cos(a)])
    across = np.array([along[1], -along[0]])
    corners = np.array([[0, 0], [w, 0], [w, h], [0, h]]) - centre
    half_len = np.abs(corners @ along).max() + survey.margin
    count = int(lawnmower_lines(size, survey.heading, survey.line_spacing))
    offsets = (np.arange(count) - (count - 1) / 2) * survey.line_spacing
    legs = []
    for k, off in enumerate(offsets):
        a0 = centre + off * across - half_len * along
        a1 = centre + off * across + half_len * along
        legs.append((a0, a1) if k % 2 == 0 else (a1, a0))
    return legs


def flight_legs(size, survey, ground_height: float) -> list[Leg]:
    """Timed 3D legs of a :class:`~mitsuforest.config.types.Survey`.

    The platform flies at ``altitude`` above the terrain's mean height at constant ``speed``; a turn
    between legs takes the straight-line distance at the same speed. With ``survey.trajectory`` the
    legs are the file's flight lines, flown as they are (see plan/trajectory.py).
    """
    if survey.trajectory:
        return [Leg(tuple(map(float, tr.position[0])), tuple(map(float, tr.position[-1])), float(tr.time[0]),
                    float(tr.time[-1]), tr) for tr in read_trajectory(survey.trajectory)]
    pairs = survey.lines or lawnmower(size, survey)
    z = ground_height + survey.altitude
    legs, t, last = [], 0.0, None
    with np.errstate(over="ignore", invalid="ignore"):   # legs of 1e300 m: refused by their pulse count, in one line
        for a, b in pairs:
            a, b = np.append(np.asarray(a, float), z), np.append(np.asarray(b, float), z)
            if last is not None:
                t += np.linalg.norm(a - last) / survey.speed
            duration = np.linalg.norm(b - a) / survey.speed
            legs.append(Leg(tuple(a.tolist()), tuple(b.tolist()), float(t), float(t + duration)))
            t += duration
            last = b
    return legs
