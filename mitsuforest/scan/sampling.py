"""Counter-based random numbers in Dr.Jit: the same numbers for a pulse however pulses are batched.

A draw is a function of (key, pulse id, stream) alone: the Tiny Encryption Algorithm
(``mi.sample_tea_32``, 8 rounds) turns that triple into two 32-bit words. So a render's bytes do not
depend on ``pulses_per_batch``, and llvm and cuda draw the same numbers (the float32 functions
applied to them may differ in the last bits). Uses: ranging noise (noise.py) and the stratified beam
(:func:`stratified_offsets`, the twin of :func:`mitsuforest.scan.beam.stratified_offsets`), each with
its own key ``seeds.key(seed, purpose)`` (mitsuforest/seeds.py).
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

TEA_ROUNDS = 8
TWO_PI = 2 * math.pi
RING_STREAM = 1 << 16          # streams of ring rotations start here (sub-ray streams are 0 .. S-1)


def uniform_pair(key: int, pulse_id: mi.UInt64, stream: mi.UInt32) -> tuple[mi.Float, mi.Float]:
    """Two uniforms in [0, 1) (Float, 24 bits each) per lane, keyed on ``key``, the UInt64 ``pulse_id``
    and the UInt32 ``stream``."""
    low = mi.UInt32(pulse_id & 0xFFFFFFFF)
    high = mi.UInt32(pulse_id >> 32)
    a, b = mi.sample_tea_32(low, (high * 0x9E3779B9) ^ (stream * 0x85EBCA6B) ^ key, TEA_ROUNDS)
    return mi.Float(a >> 8) * (1.0 / 16777216.0), mi.Float(b >> 8) * (1.0 / 16777216.0)


def device_cells(cells) -> dict:
    """The columns of :class:`~mitsuforest.scan.beam.BeamCells` that :func:`stratified_offsets` reads,
    as Dr.Jit arrays (call under the scene's variant)."""
    from .kernel import aligned
    table = {k: mi.UInt32(aligned(np.asarray(getattr(cells, k), np.uint32))) for k in ("ring", "index", "size")}
    table["u_lo"] = mi.Float(aligned(cells.u_lo.astype(np.float32)))
    table["span"] = mi.Float(aligned(cells.span.astype(np.float32)))
    return table


def stratified_offsets(cells: dict, key: int, pulse_id: mi.UInt64, sample: mi.UInt32) -> tuple[mi.Float, mi.Float]:
    """Offsets (two Float arrays, units of the 1/e² radius) of the stratified beam, one per lane.

    :param cells: the beam's cells as :func:`device_cells` uploads them.
    :param pulse_id: UInt64 per lane; ``sample``: UInt32 per lane, the sub-ray.
    """
    ring = dr.gather(mi.UInt32, cells["ring"], sample)
    radius_u, _ = uniform_pair(key, pulse_id, sample)
    rotation_u, _ = uniform_pair(key, pulse_id, ring + RING_STREAM)
    u = dr.gather(mi.Float, cells["u_lo"], sample) - dr.log(1.0 - radius_u * dr.gather(mi.Float, cells["span"], sample))
    radius = dr.sqrt(0.5 * u)
    index = mi.Float(dr.gather(mi.UInt32, cells["index"], sample))
    size = mi.Float(dr.gather(mi.UInt32, cells["size"], sample))
    s, c = dr.sincos(TWO_PI * (index + rotation_u) / size)
    return radius * c, radius * s
