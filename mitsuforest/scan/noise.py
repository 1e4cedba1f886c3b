"""Ranging noise from a counter-based generator: the same noise for a pulse however pulses are batched.

Each echo's noise is a function of (seed, pulse id, return number) alone: the Tiny Encryption
Algorithm (``mi.sample_tea_32``, 8 rounds) turns that key into two uniform numbers, and Box-Muller
into one standard normal. So a render's bytes do not depend on ``pulses_per_batch``, and llvm and
cuda draw the same numbers (the float32 transcendentals may differ in the last bits).
"""

from __future__ import annotations

import hashlib
import math

TEA_ROUNDS = 8
TWO_PI = 2 * math.pi


def seed_word(seed: int) -> int:
    """A 32-bit key word of a scene seed of any size."""
    return int.from_bytes(hashlib.sha256(f"ranging-noise:{seed}".encode()).digest()[:4], "little")


def standard_normal(dr, mi, key: int, pulse_id, return_number):
    """One N(0, 1) draw per lane, keyed on ``key`` (see :func:`seed_word`), the UInt64 ``pulse_id`` and
    the UInt32 ``return_number``."""
    low = mi.UInt32(pulse_id & 0xFFFFFFFF)
    high = mi.UInt32(pulse_id >> 32)
    u0, u1 = mi.sample_tea_32(low, (high * 0x9E3779B9) ^ (return_number * 0x85EBCA6B) ^ key, TEA_ROUNDS)
    a = (mi.Float(u0 >> 8) + 1.0) * (1.0 / 16777216.0)     # (0, 1]: the log stays finite
    b = mi.Float(u1 >> 8) * (1.0 / 16777216.0)
    return dr.sqrt(-2.0 * dr.log(a)) * dr.cos(TWO_PI * b)
