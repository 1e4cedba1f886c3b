"""Ranging and amplitude noise, keyed on (seed, pulse id, return number) (sampling.py), so the same
pulse gets the same noise however pulses are batched, on any backend.

Ranging noise is N(0, σ²) with σ growing with range and incidence (:func:`range_sigma`)::

    σ(R, θ)² = σ₀² + (k_R·R)² + (f·σ_fp)²,    σ_fp = (R/4)·sqrt((γ₁·n·e₁)² + (γ₂·n·e₂)²) / max(|n·d|, c_min)

σ₀ is the sensor's ``range_precision``, k_R its ``range_precision_per_metre`` and f its
``footprint_range_noise``. σ_fp is the standard deviation of the ranges inside the footprint of a
Gaussian beam (1/e² full divergences γ₁ across, γ₂ along the scan, beam frame e₁, e₂, axis d) on a
plane of normal n: a lateral offset u across the beam meets the plane ``u·(n·e)/|n·d|`` farther, and
the footprint's irradiance ``exp(-2 u²/w²)``, ``w = R·γ/2``, has ``std(u) = w/2 = R·γ/4`` per axis.
For a round beam it is ``(R·γ/4)·tan θ`` (θ the incidence angle): the stretch of the echo along the
beam that an inclined surface causes, the range error term of Schaer et al. (2007, "Accuracy
estimation for laser point cloud including scanning geometry", 5th Int. Symposium on Mobile Mapping
Technology). ``c_min`` = :data:`MIN_COS` caps tan θ at sin θ / 0.1, at most 10 (from θ = 84.3°). n is
the normal of the triangle the echo's strongest sub-ray hit.

Speckle (:func:`speckle_gain`): the echo's amplitude is multiplied by ``G ~ Gamma(L, 1/L)`` (mean 1,
variance 1/L), the intensity of fully developed speckle averaged over L independent looks (Goodman,
*Speckle Phenomena in Optics*, 2007, ch. 3), ``L`` the sensor's ``speckle_looks`` (0: none).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from .. import seeds
from .sampling import TWO_PI, uniform_pair

MIN_COS = 0.1          # |cos θ| floor in the footprint term: tan θ becomes sin θ / 0.1 <= 10 past 84.3°


def noise_key(seed: int) -> int:
    return seeds.key(seed, "ranging-noise")


def speckle_key(seed: int) -> int:
    return seeds.key(seed, "speckle")


def standard_normal(key: int, pulse_id: mi.UInt64, return_number: mi.UInt32) -> mi.Float:
    """One N(0, 1) draw per lane (Box-Muller on two counter-based uniforms)."""
    a, b = uniform_pair(key, pulse_id, return_number)
    return dr.sqrt(-2.0 * dr.log(1.0 - a)) * dr.cos(TWO_PI * b)      # 1 - a in (0, 1]: the log is finite


def range_sigma(range_m: mi.Float, n_axis: mi.Float, n_across: mi.Float, n_along: mi.Float, sensor) -> mi.Float:
    """σ(R, θ) of the module docstring, per echo.

    :param range_m: (E,) the echo's range R (m).
    :param n_axis, n_across, n_along: (E,) the surface normal's components along the beam axis d and
        the beam frame's e₁ (across, ``beam_divergence[0]``) and e₂ = d × e₁ (``beam_divergence[1]``).
    :param sensor: a :class:`~mitsuforest.config.types.Sensor`.
    """
    g1, g2 = (float(g) for g in sensor.beam_divergence)
    spread = (range_m / 4) * dr.sqrt(dr.square(g1 * n_across) + dr.square(g2 * n_along)) \
        / dr.maximum(dr.abs(n_axis), MIN_COS)
    k, f = float(sensor.range_precision_per_metre), float(sensor.footprint_range_noise)
    return dr.sqrt(float(sensor.range_precision) ** 2 + dr.square(k * range_m) + dr.square(f * spread))


def varies(sensor) -> bool:
    """Whether σ depends on the echo (else it is the constant ``range_precision``)."""
    return bool(sensor.range_precision_per_metre or sensor.footprint_range_noise)


def speckle_gain(key: int, pulse_id: mi.UInt64, return_number: mi.UInt32, looks: int) -> mi.Float:
    """``G ~ Gamma(L, 1/L)`` per lane: the mean of L unit exponentials, ``-Σ log(1 - u_k) / L``, from
    ``ceil(L/2)`` counter-based uniform pairs (streams ``return_number + 256·pair``)."""
    total = 0.0
    for pair in range((looks + 1) // 2):
        a, b = uniform_pair(key, pulse_id, return_number + (pair << 8))
        total = total - dr.log(1.0 - a)
        if 2 * pair + 1 < looks:
            total = total - dr.log(1.0 - b)
    return total * (1.0 / looks)
