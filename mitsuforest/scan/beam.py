"""A Gaussian beam sampled by sub-rays whose weights integrate its irradiance exactly.

Irradiance across the beam at range R is ``I(r) ∝ exp(-2 r² / w²)`` with the 1/e² radius
``w = R·β/2`` (β the full divergence). The beam is cut into a centre disc and rings of 6, 12, 18 ...
cells (hexagonal packing); each sub-ray sits at its cell's RMS radius and carries the
exact energy of its cell, the outermost ring running to infinity. So the weights sum to 1 for any
number of samples, the pattern's second moment equals the beam's (so its RMS footprint is exact),
and ``beam_samples = 1`` is the ideal thin beam (centre ray, weight 1).
"""

from __future__ import annotations

import numpy as np


def ring_counts(samples: int) -> list[int]:
    """Sub-rays per ring: 1, 6, 12, 18, ... with the remainder in the last ring."""
    counts, k = [1], 1
    while sum(counts) < samples:
        counts.append(min(6 * k, samples - sum(counts)))
        k += 1
    return counts


def beam_pattern(samples: int) -> tuple[np.ndarray, np.ndarray]:
    """Sub-ray offsets and weights.

    :returns: offsets (S, 2) in units of the 1/e² radius w (multiply by β/2 for angles),
        weights (S,) summing to 1.
    """
    counts = ring_counts(samples)
    rings = len(counts) - 1
    if rings == 0:
        return np.zeros((1, 2)), np.ones(1)
    # Cell boundaries at (k - 1/2)·Δ with the last finite boundary inside the 1/e² radius.
    delta = 1.0 / rings
    edges = np.concatenate([[0.0], (np.arange(1, rings + 1) - 0.5) * delta, [np.inf]])
    u = 2 * edges ** 2                                   # power beyond radius r is exp(-u)
    energy_below = 1 - np.exp(-u)
    offsets, weights = [], []
    for k, n in enumerate(counts):
        e0, e1 = energy_below[k], energy_below[k + 1]
        radius = np.sqrt(0.5 * _mean_u(u[k], u[k + 1])) if k else 0.0
        phase = np.pi * k / max(n, 1)  # stagger neighbouring rings
        angle = phase + 2 * np.pi * np.arange(n) / n
        offsets.append(radius * np.column_stack([np.cos(angle), np.sin(angle)]))
        weights.append(np.full(n, (e1 - e0) / n))
    return np.vstack(offsets), np.concatenate(weights)


def _mean_u(a: float, b: float) -> float:
    """Mean of u ~ Exp(1) restricted to [a, b] (b may be inf): the cell's mean of 2r²/w²."""
    if np.isinf(b):
        return a + 1.0
    ea, eb = np.exp(-a), np.exp(-b)
    return (a * ea - b * eb) / (ea - eb) + 1.0


def footprint_radius(range_m, divergence: float):
    """1/e² footprint radius ``R·β/2`` (m) at ``range_m`` for full divergence ``β`` (rad)."""
    return np.asarray(range_m) * divergence / 2
