"""Beam deflection patterns in Dr.Jit: where each pulse points in the sensor frame, and whether it fires.

Sensor frame: x across track (right of the flight direction), y along track, z up. Angles in
radians, times in float64. A pulse's time is given as its leg's start ``t0`` (a Python float: a flown
trajectory's own clock, GPS seconds of about 1e9 say) and the time since then: each mirror's or prism's
phase at ``t0`` is reduced to a fraction of a turn exactly (:func:`turns_at`), as ``2π f t`` at such a
``t`` would keep only some 1e-4 rad. The numpy twin, :mod:`mitsuforest.testing.reference.deflector`, is the
tests' reference.
"""

from __future__ import annotations

import math
from fractions import Fraction

import drjit as dr
import mitsuba as mi

# Pulses this close outside FOV/2 still fire: far above the rounding of θ (~1e-12 rad after a 10 min
# leg), so both twins fire the same pulses.
FOV_TOLERANCE = 1e-9
TWO_PI = 2 * math.pi   # constants are Python floats: a numpy scalar times a Dr.Jit array would become numpy


def turns_at(t0: float, frequency: float) -> float:
    """The fractional part of ``t0 · frequency`` (turns, in [0, 1)), exact: a rotation's phase at ``t0``."""
    return float(Fraction(t0) * Fraction(frequency) % 1)


def deflect(sensor, t0: float, since: mi.Float64, scan_frequency: float) -> tuple[
        tuple[mi.Float64, mi.Float64, mi.Float64], mi.Float64, mi.Bool]:
    """Sensor-frame directions, scan angles and fired mask of pulses at times ``t0 + since``.

    :param sensor: a :class:`~mitsuforest.config.types.Sensor` (its deflector, field of view, prisms).
    :param t0: the leg's start (s).
    :param since: Float64 (P,) pulse times since ``t0`` (s).
    :param scan_frequency: full turns (rotating) or full back-and-forth sweeps, two scan lines
        (oscillating), a second.
    :returns: the direction as 3 Float64 arrays, the scan angle θ (Float64: from nadir across track for
        a line scanner, off-nadir for a Risley pair) and the fired mask (Bool).
    """
    half_fov = sensor.half_fov
    Float64 = type(since)
    n = dr.width(since)

    def phase(frequency: float) -> mi.Float64:   # opaque: a new leg must not compile a new kernel
        return dr.opaque(Float64, turns_at(t0, frequency))

    if sensor.deflector == "rotating":          # θ = 2π f t, wrapped into [-π, π); fired while |θ| ≤ FOV/2
        a = TWO_PI * scan_frequency * since + (TWO_PI * phase(scan_frequency) + math.pi)
        theta = a - TWO_PI * dr.floor(a / TWO_PI) - math.pi
        s, c = dr.sincos(theta)
        return (s, dr.zeros(Float64, n), -c), theta, dr.abs(theta) <= half_fov + FOV_TOLERANCE
    if sensor.deflector == "oscillating":       # a triangle wave sweeping ±FOV/2 and back, f times a second
        x = since * scan_frequency + phase(scan_frequency)
        x = x - dr.floor(x)
        theta = (4 * dr.abs(x - 0.5) - 1) * half_fov
        s, c = dr.sincos(theta)
        return (s, dr.zeros(Float64, n), -c), theta, dr.full(dr.mask_t(Float64), True, n)
    # Two Risley prisms (first order): their deviations add as vectors.
    d1, d2 = (math.radians(x) for x in sensor.risley.prism_deflection)
    r1, r2 = (float(x) for x in sensor.risley.prism_rates)
    s1, c1 = dr.sincos(TWO_PI * r1 * since + TWO_PI * phase(r1))
    s2, c2 = dr.sincos(TWO_PI * r2 * since + TWO_PI * phase(r2))
    ax, ay = d1 * c1 + d2 * c2, d1 * s1 + d2 * s2
    off = dr.sqrt(ax * ax + ay * ay)
    s, c = dr.sincos(off)
    scale = s / dr.select(off > 0, off, 1.0)
    return (ax * scale, ay * scale, -c), off, off <= half_fov + FOV_TOLERANCE
