"""Ranging noise: one N(0, σ²) draw per echo, keyed on (seed, pulse id, return number) (sampling.py),
so the same pulse gets the same noise however pulses are batched, on any backend."""

from __future__ import annotations

from .sampling import TWO_PI, key_word, uniform_pair


def noise_key(seed: int) -> int:
    return key_word(seed, "ranging-noise")


def standard_normal(dr, mi, key: int, pulse_id, return_number):
    """One N(0, 1) draw per lane (Box-Muller on two counter-based uniforms)."""
    a, b = uniform_pair(mi, key, pulse_id, return_number)
    return dr.sqrt(-2.0 * dr.log(1.0 - a)) * dr.cos(TWO_PI * b)      # 1 - a in (0, 1]: the log is finite
