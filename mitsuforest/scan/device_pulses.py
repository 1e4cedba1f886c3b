"""Pulse generation on the device: the pulses of a batch of time slots that fire and can reach the scene.

The same model as :func:`~mitsuforest.scan.pulses.reaching_pulses` and the deflectors of
deflector.py (the numpy reference; tests check the two agree), computed in Dr.Jit so that a batch's
time slots never pass through numpy: times and angles in float64, rays in float32.
"""

from __future__ import annotations

import numpy as np

from .deflector import FOV_TOLERANCE
from .pulses import leg_frame

# Constants are Python floats: a numpy scalar times a Dr.Jit array would become a numpy array.
TWO_PI = float(2 * np.pi)


def _deflect(dr, Float64, sensor: dict, t, scan_frequency: float):
    """Sensor-frame direction (3 arrays), scan angle and fired mask at times ``t`` (see deflector.py)."""
    kind, half_fov = sensor["deflector"], float(np.deg2rad(sensor["field_of_view"])) / 2
    if kind == "rotating":
        a = TWO_PI * scan_frequency * t + np.pi
        theta = a - TWO_PI * dr.floor(a / TWO_PI) - np.pi
        s, c = dr.sincos(theta)
        return (s, dr.zeros(Float64, dr.width(t)), -c), theta, dr.abs(theta) <= half_fov + FOV_TOLERANCE
    if kind == "oscillating":
        x = t * scan_frequency
        x = x - dr.floor(x)
        theta = (4 * dr.abs(x - 0.5) - 1) * half_fov
        s, c = dr.sincos(theta)
        return (s, dr.zeros(Float64, dr.width(t)), -c), theta, dr.full(dr.mask_t(Float64), True, dr.width(t))
    d1, d2 = (float(x) for x in np.deg2rad(sensor["risley"]["prism_deflection"]))
    w1, w2 = (TWO_PI * float(x) for x in sensor["risley"]["prism_rates"])
    s1, c1 = dr.sincos(w1 * t)
    s2, c2 = dr.sincos(w2 * t)
    ax, ay = d1 * c1 + d2 * c2, d1 * s1 + d2 * s2
    off = dr.sqrt(ax * ax + ay * ay)
    s, c = dr.sincos(off)
    scale = s / dr.select(off > 0, off, 1.0)
    return (ax * scale, ay * scale, -c), off, off <= half_fov + FOV_TOLERANCE


def _reaches(dr, origin, direction, box, range_max: float):
    """The slab test of pulses.reaches_box."""
    lo, hi = dr.zeros(type(origin[0]), dr.width(origin[0])), dr.full(type(origin[0]), float(range_max), dr.width(origin[0]))
    for k in range(3):
        o, d = origin[k], direction[k]
        parallel = d == 0
        inv = 1.0 / dr.select(parallel, 1.0, d)
        b0, b1 = float(box[0, k]), float(box[1, k])
        t0, t1 = (b0 - o) * inv, (b1 - o) * inv
        inside = (o >= b0) & (o <= b1)
        lo = dr.maximum(lo, dr.select(parallel, dr.select(inside, -dr.inf, dr.inf), dr.minimum(t0, t1)))
        hi = dr.minimum(hi, dr.select(parallel, dr.select(inside, dr.inf, -dr.inf), dr.maximum(t0, t1)))
    return lo <= hi


def device_pulses(leg: dict, sensor: dict, survey: dict, first: int, count: int, box: np.ndarray,
                  range_max: float):
    """The fired pulses among time slots ``first .. first+count-1`` that can reach ``box``.

    :returns: a dict of Dr.Jit arrays, one entry per pulse: ``slot`` (UInt32, the pulse number in the
        leg), ``origin`` (Point3f), ``direction`` and ``across`` (Vector3f, unit; see Pulses), and
        the number of pulses fired (int).
    """
    import drjit as dr
    import mitsuba as mi
    Float64 = mi.Float64

    def leg_value(x, kind=Float64):   # opaque: a new batch or leg must not compile a new kernel
        return dr.opaque(kind, float(x) if kind is not mi.UInt32 else int(x))

    t0, t1 = leg_value(leg["t0"]), leg_value(leg["t1"])
    slot = leg_value(first, mi.UInt32) + dr.arange(mi.UInt32, count)
    t = t0 + Float64(slot) / float(survey["pulse_frequency"])
    d_sensor, _, fired = _deflect(dr, Float64, sensor, t, float(survey["scan_frequency"] or 0.0))
    frame_np = leg_frame(leg)
    frame = [[leg_value(x) for x in row] for row in frame_np]
    direction = [d_sensor[0] * frame[0][k] + d_sensor[1] * frame[1][k] + d_sensor[2] * frame[2][k] for k in range(3)]
    a, b = [leg_value(x) for x in leg["start"]], [leg_value(x) for x in leg["end"]]
    f = (t - t0) / (t1 - t0)
    origin = [a[k] + f * (b[k] - a[k]) for k in range(3)]
    n_fired = dr.count(fired)
    keep = dr.compress(fired & _reaches(dr, origin, direction, box, range_max))
    if dr.width(keep) == 0:
        return {"slot": mi.UInt32(), "origin": mi.Point3f(), "direction": mi.Vector3f(), "across": mi.Vector3f()}, \
            int(n_fired[0])
    direction = mi.Vector3f(*(mi.Float(dr.gather(Float64, c, keep)) for c in direction))
    origin = mi.Point3f(*(mi.Float(dr.gather(Float64, c, keep)) for c in origin))
    along = mi.Vector3f(*(leg_value(x, mi.Float) for x in frame_np[1]))
    across = dr.cross(along, direction)
    norm = dr.norm(across)
    fallback = mi.Vector3f(*(leg_value(x, mi.Float) for x in frame_np[0]))
    across = dr.select(norm > 1e-9, across / dr.select(norm > 1e-9, norm, 1.0), fallback)
    return {"slot": dr.gather(mi.UInt32, slot, keep), "origin": origin, "direction": direction,
            "across": across}, int(n_fired[0])
