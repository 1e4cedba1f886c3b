"""Beam deflection patterns in Dr.Jit: where each pulse points in the sensor frame, and whether it fires.

Sensor frame: x across track (right of the flight direction), y along track, z up. Angles in
radians, times in float64. The numpy twin, :mod:`mitsuforest.testing.reference.deflector`, is the
tests' reference.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi

# Pulses this close outside FOV/2 still fire: far above the rounding of θ (~1e-12 rad after 10 min of
# flight), so both twins fire the same pulses.
FOV_TOLERANCE = 1e-9
TWO_PI = 2 * math.pi   # constants are Python floats: a numpy scalar times a Dr.Jit array would become numpy


def deflect(sensor, t: mi.Float64, scan_frequency: float) -> tuple[tuple[mi.Float64, mi.Float64, mi.Float64],
                                                                  mi.Float64, mi.Bool]:
    """Sensor-frame directions, scan angles and fired mask of pulses at times ``t``.

    :param sensor: a :class:`~mitsuforest.config.types.Sensor` (its deflector, field of view, prisms).
    :param t: Float64 (P,) pulse times (s).
    :returns: the direction as 3 Float64 arrays, the scan angle θ (Float64: from nadir across track for
        a line scanner, off-nadir for a Risley pair) and the fired mask (Bool).
    """
    half_fov = sensor.half_fov
    Float64 = type(t)
    n = dr.width(t)
    if sensor.deflector == "rotating":          # θ = 2π f t, wrapped into [-π, π); fired while |θ| ≤ FOV/2
        a = TWO_PI * scan_frequency * t + math.pi
        theta = a - TWO_PI * dr.floor(a / TWO_PI) - math.pi
        s, c = dr.sincos(theta)
        return (s, dr.zeros(Float64, n), -c), theta, dr.abs(theta) <= half_fov + FOV_TOLERANCE
    if sensor.deflector == "oscillating":       # a triangle wave sweeping ±FOV/2, f times a second
        x = t * scan_frequency
        x = x - dr.floor(x)
        theta = (4 * dr.abs(x - 0.5) - 1) * half_fov
        s, c = dr.sincos(theta)
        return (s, dr.zeros(Float64, n), -c), theta, dr.full(dr.mask_t(Float64), True, n)
    # Two Risley prisms (first order): their deviations add as vectors.
    d1, d2 = (math.radians(x) for x in sensor.risley.prism_deflection)
    w1, w2 = (TWO_PI * float(x) for x in sensor.risley.prism_rates)
    s1, c1 = dr.sincos(w1 * t)
    s2, c2 = dr.sincos(w2 * t)
    ax, ay = d1 * c1 + d2 * c2, d1 * s1 + d2 * s2
    off = dr.sqrt(ax * ax + ay * ay)
    s, c = dr.sincos(off)
    scale = s / dr.select(off > 0, off, 1.0)
    return (ax * scale, ay * scale, -c), off, off <= half_fov + FOV_TOLERANCE
