"""Pulses in Dr.Jit: the pulses of a batch of time slots that fire and can reach the scene, and those
among them aimed at one of its objects.

A batch's time slots never pass through numpy: times and angles are float64, rays float32. The
numpy twin, :mod:`mitsuforest.testing.reference.pulses`, is the tests' reference.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from .deflector import deflect
from .kernel import aligned, evaluate_and_wait
from .platform import DeviceTable, table_pose


@dataclass
class DevicePulses:
    """A batch of pulses as Dr.Jit arrays, one lane per pulse."""

    pulse_id: mi.UInt64     # the pulse's number in the survey (keys its ranging noise)
    time: mi.Float64        # GPS time (s)
    scan_angle: mi.Float    # rad
    origin: mi.Point3f      # local frame
    direction: mi.Vector3f  # unit beam axis
    across: mi.Vector3f     # unit: the beam's first frame axis (divergence[0] applies along it)

    @property
    def count(self) -> int:
        return dr.width(self.time)

    def take(self, index: mi.UInt32) -> DevicePulses:
        """The pulses at ``index``, in its order."""
        return DevicePulses(dr.gather(mi.UInt64, self.pulse_id, index), dr.gather(mi.Float64, self.time, index),
                            dr.gather(mi.Float, self.scan_angle, index), dr.gather(mi.Point3f, self.origin, index),
                            dr.gather(mi.Vector3f, self.direction, index), dr.gather(mi.Vector3f, self.across, index))


def reaches_box(origin: list[mi.Float64], direction: list[mi.Float64], box: np.ndarray, range_max: float) -> mi.Bool:
    """Whether each ray (origin and direction: 3 Float64 arrays each) meets the axis-aligned box (2, 3)
    within ``range_max`` (slab test)."""
    lo, hi = dr.zeros(type(origin[0]), dr.width(origin[0])), dr.full(type(origin[0]), float(range_max), dr.width(origin[0]))
    for k in range(3):
        o, d = origin[k], direction[k]
        parallel = d == 0
        inv = 1.0 / dr.select(parallel, 1.0, d)
        b0, b1 = float(box[0, k]), float(box[1, k])
        t0, t1 = (b0 - o) * inv, (b1 - o) * inv
        inside = (o >= b0) & (o <= b1)     # a parallel ray meets this slab everywhere or nowhere
        lo = dr.maximum(lo, dr.select(parallel, dr.select(inside, -dr.inf, dr.inf), dr.minimum(t0, t1)))
        hi = dr.minimum(hi, dr.select(parallel, dr.select(inside, dr.inf, -dr.inf), dr.maximum(t0, t1)))
    return lo <= hi


def reaching_pulses(leg, sensor, pulse_frequency: float, scan_frequency: float, first: int, count: int,
                    box: np.ndarray, first_id: int = 0, table: DeviceTable | None = None, keep_fired: bool = False):
    """The fired pulses among time slots ``first .. first+count-1`` of a leg that can reach ``box``
    (2, 3) within the sensor's ``range_max``; call under the scene's Mitsuba variant.

    :param leg: a :class:`~mitsuforest.plan.types.Leg`.
    :param first_id: the survey's pulse number of the leg's first time slot.
    :param table: the leg's :class:`~mitsuforest.scan.platform.DeviceTable` (attitude, mount, a flown
        trajectory), or ``None``: level flight along the leg's straight line.
    :param keep_fired: also return every fired pulse, cast or not, in numpy (``output.pulses``).
    :returns: the pulses, and how many were fired; with ``keep_fired`` a third item, a dict of the
        fired pulses' ``pulse_id``, ``gps_time``, ``scan_angle`` (rad) (F,), ``origin`` and ``direction``
        (F, 3) (local frame).
    """
    Float64 = mi.Float64

    def leg_value(x, kind=Float64):   # opaque: a new batch or leg must not compile a new kernel
        return dr.opaque(kind, int(x) if kind in (mi.UInt32, mi.UInt64) else float(x))

    t0, t1 = leg_value(leg.t0), leg_value(leg.t1)
    slot = leg_value(first, mi.UInt32) + dr.arange(mi.UInt32, count)
    since = Float64(slot) / float(pulse_frequency)
    t = t0 + since
    d_sensor, angle, fired = deflect(sensor, float(leg.t0), since, float(scan_frequency or 0.0))
    if table is None:
        frame_np = leg.frame()
        frame = [[leg_value(x) for x in row] for row in frame_np]
        direction = _turned(d_sensor, frame)
        a, b = [leg_value(x) for x in leg.start], [leg_value(x) for x in leg.end]
        f = (t - t0) / (t1 - t0)
        origin = [a[k] + f * (b[k] - a[k]) for k in range(3)]
    else:
        origin, rotation = table_pose(table, t)
        frame = [[rotation[3 * k + j] for k in range(3)] for j in range(3)]   # rows: the sensor axes, local frame
        direction = _turned(d_sensor, frame)
    reach = fired & reaches_box(origin, direction, box, sensor.range_max)
    evaluate_and_wait(fired, reach)            # one kernel for both masks, then the count and compaction
    n_fired = int(dr.count(fired)[0])
    all_fired = _fired_table(fired, slot, t, angle, origin, direction, first_id) if keep_fired else None
    keep = dr.compress(reach)
    if dr.width(keep) == 0:
        none = DevicePulses(mi.UInt64(), Float64(), mi.Float(), mi.Point3f(), mi.Vector3f(), mi.Vector3f())
        return (none, n_fired, all_fired) if keep_fired else (none, n_fired)
    direction = mi.Vector3f(*(mi.Float(dr.gather(Float64, c, keep)) for c in direction))
    origin = mi.Point3f(*(mi.Float(dr.gather(Float64, c, keep)) for c in origin))
    if table is None:
        along = mi.Vector3f(*(leg_value(x, mi.Float) for x in frame_np[1]))
        fallback = mi.Vector3f(*(leg_value(x, mi.Float) for x in frame_np[0]))   # a beam along the track
    else:
        along, fallback = (mi.Vector3f(*(mi.Float(dr.gather(Float64, c, keep)) for c in frame[j])) for j in (1, 0))
    across = dr.cross(along, direction)
    norm = dr.norm(across)
    across = dr.select(norm > 1e-9, across / dr.select(norm > 1e-9, norm, 1.0), fallback)
    pulse_id = leg_value(first_id, mi.UInt64) + mi.UInt64(dr.gather(mi.UInt32, slot, keep))
    cast = DevicePulses(pulse_id, dr.gather(Float64, t, keep), mi.Float(dr.gather(Float64, angle, keep)),
                        origin, direction, across)
    return (cast, n_fired, all_fired) if keep_fired else (cast, n_fired)


def _fired_table(fired: mi.Bool, slot: mi.UInt32, t: mi.Float64, angle: mi.Float64, origin: list[mi.Float64],
                 direction: list[mi.Float64], first_id: int) -> dict:
    """Every fired pulse of a batch in numpy (see :func:`reaching_pulses`' ``keep_fired``)."""
    keep = dr.compress(fired)
    out = {"pulse_id": np.uint64(first_id) + np.array(dr.gather(mi.UInt32, slot, keep)).astype(np.uint64),
           "gps_time": np.array(dr.gather(mi.Float64, t, keep)),
           "scan_angle": np.array(dr.gather(mi.Float64, angle, keep)).astype(np.float32)}
    for key, value, dtype in (("origin", origin, np.float32), ("direction", direction, np.float32)):
        out[key] = np.column_stack([np.array(dr.gather(mi.Float64, value[k], keep)) for k in range(3)]).astype(dtype)
    return out


def _turned(d_sensor: tuple[mi.Float64, mi.Float64, mi.Float64], frame: list[list[mi.Float64]]) -> list[mi.Float64]:
    """Sensor-frame directions in the local frame: ``frame`` rows are the sensor's axes there."""
    return [d_sensor[0] * frame[0][k] + d_sensor[1] * frame[1][k] + d_sensor[2] * frame[2][k] for k in range(3)]


def upload_pulses(pulses, first_id: int = 0) -> DevicePulses:
    """Hand-made numpy pulses (:class:`~mitsuforest.testing.reference.pulses.Pulses`) on the device."""
    cols = [mi.Float(aligned(a[:, k].astype(np.float32)))
            for a in (pulses.origin, pulses.direction, pulses.across) for k in range(3)]
    return DevicePulses(mi.UInt64(aligned((np.asarray(pulses.index, np.uint64) + np.uint64(first_id)))),
                        mi.Float64(aligned(np.asarray(pulses.time, np.float64))),
                        mi.Float(aligned(np.asarray(pulses.scan_angle, np.float32))),
                        mi.Point3f(*cols[0:3]), mi.Vector3f(*cols[3:6]), mi.Vector3f(*cols[6:9]))


def aimed_at(pulses: DevicePulses, targets: list[tuple[float, mi.Scene]], bounds: np.ndarray, box: np.ndarray,
             range_max: float) -> DevicePulses:
    """The pulses whose beam axis meets a target within ``range_max``, and every pulse fired from inside
    ``box`` (2, 3), where a beam may start inside a target and leave range before its faces; call under
    the scene's Mitsuba variant.

    :param targets: (range, Mitsuba scene of closed surfaces), nearest first, the last at ``range_max``:
        what can be hit, grown by the widest sub-ray's spread at that range (the render's: the objects'
        proxies and the ground's box, :func:`mitsuforest.scene.proxies.proxy_scene`). A pulse is tested
        against the nearest set whose range reaches the farthest corner of ``bounds`` (2, 3; the scene's
        geometry, so every hit lies within that distance); the last set takes the rest.
    :returns: the pulses kept. One that misses every target has no sub-ray that can hit anything: dropping
        it changes no point, only the rays traced.
    """
    if pulses.count == 0:
        return pulses
    ray = mi.Ray3f(pulses.origin, pulses.direction)
    ray.maxt = mi.Float(range_max)
    inside = dr.full(mi.Bool, True, pulses.count)
    farthest = mi.Float(0.0)
    for k in range(3):
        o = pulses.origin[k]
        inside &= (o >= float(box[0, k])) & (o <= float(box[1, k]))
        far = dr.maximum(dr.abs(o - float(bounds[0, k])), dr.abs(o - float(bounds[1, k])))
        farthest += far * far
    farthest = dr.sqrt(farthest)
    keep, tested = inside, mi.Bool(inside)
    for i, (reach, scene) in enumerate(targets):
        use = ~tested if i == len(targets) - 1 else ~tested & (farthest <= reach)
        hit = scene.ray_test(ray, active=use)
        dr.eval(hit)   # OptiX traces one scene per kernel: fused, the second ray test would be dropped
        keep |= hit
        tested |= use
    evaluate_and_wait(keep)
    keep = dr.compress(keep)
    return pulses if dr.width(keep) == pulses.count else pulses.take(keep)
