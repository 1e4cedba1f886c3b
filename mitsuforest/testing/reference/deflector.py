"""numpy twin of :mod:`mitsuforest.scan.deflector`: beam deflection patterns (tests' reference).

Sensor frame: x across track (right of the flight direction), y along track, z up. Angles in radians.
"""

from __future__ import annotations

import numpy as np

from ...scan.deflector import FOV_TOLERANCE


def wrap(angle):
    """Angle wrapped into [-π, π) (the same formula as the Dr.Jit twin)."""
    a = np.asarray(angle) + np.pi
    return a - 2 * np.pi * np.floor(a / (2 * np.pi)) - np.pi


def rotating(t, scan_frequency: float, half_fov: float):
    """Rotating mirror (line scanner): the beam turns in the across-track plane.

    ``θ = 2π f t`` from nadir; pulses with ``|θ| > half_fov`` (rad) are not fired.

    :param t: (n,) pulse times (s), float64.
    :returns: directions (n, 3), scan angles θ (n,), fired mask (n,).
    """
    theta = wrap(2 * np.pi * scan_frequency * np.asarray(t, np.float64))
    d = np.column_stack([np.sin(theta), np.zeros_like(theta), -np.cos(theta)])
    return d, theta, np.abs(theta) <= half_fov + FOV_TOLERANCE


def oscillating(t, scan_frequency: float, half_fov: float):
    """Oscillating mirror: a triangle wave sweeping ±``half_fov`` across track ``scan_frequency`` times a second."""
    x = (np.asarray(t, np.float64) * scan_frequency) % 1.0
    tri = 4 * np.abs(x - 0.5) - 1                       # -1 .. 1 .. -1
    theta = tri * half_fov
    d = np.column_stack([np.sin(theta), np.zeros_like(theta), -np.cos(theta)])
    return d, theta, np.ones(len(theta), bool)


def risley(t, rates, deflections_deg, half_fov: float):
    """Two rotating Risley prisms (first-order model): the deviations of both prisms add as vectors.

    Deviation ``δ₁(cos ω₁t, sin ω₁t) + δ₂(cos ω₂t, sin ω₂t)`` with ``ω = 2π·rate``; the beam points
    along nadir tilted by that deviation. The scan angle is the off-nadir angle.
    """
    t = np.asarray(t, np.float64)
    d1, d2 = np.deg2rad(deflections_deg)
    w1, w2 = 2 * np.pi * np.asarray(rates, float)
    ax = d1 * np.cos(w1 * t) + d2 * np.cos(w2 * t)
    ay = d1 * np.sin(w1 * t) + d2 * np.sin(w2 * t)
    off = np.hypot(ax, ay)
    s = np.sin(off) / np.where(off > 0, off, 1)
    d = np.column_stack([ax * s, ay * s, -np.cos(off)])
    return d, off, off <= half_fov + FOV_TOLERANCE


def deflect(sensor, t, scan_frequency: float):
    """Directions, scan angles and fired mask of pulses at times ``t`` for a
    :class:`~mitsuforest.config.types.Sensor`."""
    if sensor.deflector == "rotating":
        return rotating(t, scan_frequency, sensor.half_fov)
    if sensor.deflector == "oscillating":
        return oscillating(t, scan_frequency, sensor.half_fov)
    return risley(t, sensor.risley.prism_rates, sensor.risley.prism_deflection, sensor.half_fov)
