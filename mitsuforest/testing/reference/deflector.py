"""numpy twin of :mod:`mitsuforest.scan.deflector`: beam deflection patterns (tests' reference).

Sensor frame: x across track (right of the flight direction), y along track, z up. Angles in radians.
"""

from __future__ import annotations

import numpy as np

from ...scan.deflector import FOV_TOLERANCE, turns_at


def wrap(angle):
    """Angle wrapped into [-π, π) (the same formula as the Dr.Jit twin)."""
    a = np.asarray(angle) + np.pi
    return a - 2 * np.pi * np.floor(a / (2 * np.pi)) - np.pi


def rotating(t, scan_frequency: float, half_fov: float, t0: float = 0.0):
    """Rotating mirror (line scanner): the beam turns in the across-track plane.

    ``θ = 2π f (t0 + t)`` from nadir; pulses with ``|θ| > half_fov`` (rad) are not fired.

    :param t: (n,) pulse times since ``t0`` (s), float64.
    :param t0: the leg's start (s); its phase is taken exactly (``turns_at``), however large.
    :returns: directions (n, 3), scan angles θ (n,), fired mask (n,).
    """
    theta = wrap(2 * np.pi * scan_frequency * np.asarray(t, np.float64) + 2 * np.pi * turns_at(t0, scan_frequency))
    d = np.column_stack([np.sin(theta), np.zeros_like(theta), -np.cos(theta)])
    return d, theta, np.abs(theta) <= half_fov + FOV_TOLERANCE


def oscillating(t, scan_frequency: float, half_fov: float, t0: float = 0.0):
    """Oscillating mirror: a triangle wave sweeping ±``half_fov`` across track and back ``scan_frequency``
    times a second (two scan lines each), ``t`` (n,) s since ``t0``."""
    x = (np.asarray(t, np.float64) * scan_frequency + turns_at(t0, scan_frequency)) % 1.0
    tri = 4 * np.abs(x - 0.5) - 1                       # -1 .. 1 .. -1
    theta = tri * half_fov
    d = np.column_stack([np.sin(theta), np.zeros_like(theta), -np.cos(theta)])
    return d, theta, np.ones(len(theta), bool)


def risley(t, rates, deflections_deg, half_fov: float, t0: float = 0.0):
    """Two rotating Risley prisms (first-order model): the deviations of both prisms add as vectors.

    Deviation ``δ₁(cos ω₁t, sin ω₁t) + δ₂(cos ω₂t, sin ω₂t)`` with ``ω = 2π·rate``; the beam points
    along nadir tilted by that deviation, ``t`` (n,) s after ``t0``. The scan angle is the off-nadir angle.
    """
    t = np.asarray(t, np.float64)
    d1, d2 = np.deg2rad(deflections_deg)
    a1, a2 = (2 * np.pi * float(r) * t + 2 * np.pi * turns_at(t0, float(r)) for r in rates)
    ax = d1 * np.cos(a1) + d2 * np.cos(a2)
    ay = d1 * np.sin(a1) + d2 * np.sin(a2)
    off = np.hypot(ax, ay)
    s = np.sin(off) / np.where(off > 0, off, 1)
    d = np.column_stack([ax * s, ay * s, -np.cos(off)])
    return d, off, off <= half_fov + FOV_TOLERANCE


def deflect(sensor, t0: float, since, scan_frequency: float):
    """Directions, scan angles and fired mask of pulses at times ``t0 + since`` (``since`` (n,) s) for a
    :class:`~mitsuforest.config.types.Sensor`."""
    if sensor.deflector == "rotating":
        return rotating(since, scan_frequency, sensor.half_fov, t0)
    if sensor.deflector == "oscillating":
        return oscillating(since, scan_frequency, sensor.half_fov, t0)
    return risley(since, sensor.risley.prism_rates, sensor.risley.prism_deflection, sensor.half_fov, t0)
