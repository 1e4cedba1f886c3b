"""A Gaussian beam sampled by sub-rays whose weights are its exact cell energies and whose second
moment is exactly the beam's.

Irradiance across the beam at range R is ``I(r) ∝ exp(-2 r² / w²)`` with the 1/e² radius
``w = R·β/2`` (β the full divergence). Offsets below are in units of w. With ``u = 2 r²`` the
energy is distributed as ``u ~ Exp(1)``: the energy beyond radius r is ``exp(-u)`` and the beam's
second moment is ``E[r²] = E[u] / 2 = 1/2`` (so the RMS radius is ``w/√2``, and ``E[x²] = E[y²] = 1/4``).

Cells. The beam is cut into a centre disc ``u < u₁`` and rings of 6, 12, 18 ... cells (hexagonal
packing, :func:`ring_counts`); ring k spans ``r ∈ [(k - ½)/K, (k + ½)/K)`` with K rings, so the
last finite edge lies inside the 1/e² radius and the outermost ring runs to infinity; ``u₁ = 1/(2K²)``.
Each sub-ray carries the exact energy of its cell, so the weights sum to 1 for any number of samples.

Radii, and why the pattern is dilated. The centre sub-ray sits at ``r = 0`` (it must, for a single
ray to keep the pattern centred); a ring sub-ray sits at its cell's RMS radius, ``ρ_k² = E[u | cell k] / 2``.
A ring cell then contributes its cell's second moment exactly, ``E_k ρ_k² = ½ ∫_cell u e^{-u} du``,
and the rings together contribute

    ½ ∫_{u₁}^∞ u e^{-u} du = ½ (1 + u₁) e^{-u₁},

short of ``½`` by the centre disc's moment ``½ ∫_0^{u₁} u e^{-u} du`` (4.6 % of the RMS radius at
7 samples, 0.4 % at 19). Dilating every offset by ``s`` with

    s² = e^{u₁} / (1 + u₁)

restores it exactly: ``Σ w_k |o_k|² = s² · ½ (1 + u₁) e^{-u₁} = ½``. A dilation is the one change
that keeps the weights, the centring and each ring's angular layout; ``s`` is 1.048 for one ring
(4 to 9 samples), 1.0036 for two (10 to 21), → 1 as rings are added, and every sub-ray stays inside
its cell.
Only the second moment is matched: higher radial moments of the pattern are not the Gaussian's.

Every ring has at least 3 equally spaced rays of equal weight (a remainder of 1 or 2 rays joins the
ring before it, see :func:`ring_counts`), so the pattern is centred (``Σ w o = 0``) and its second
moment is isotropic, ``Σ w o oᵀ = I/4``: for an elliptical beam (two divergences) both footprint
axes are exact. The exceptions are ``samples = 1``, the ideal thin beam (the centre ray, weight 1),
and ``samples = 2``: two opposite rays at ``r = 1/√2`` (the whole beam as one cell, no centre ray),
whose total second moment is exact but lies on one axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def ring_counts(samples: int) -> list[int]:
    """Sub-rays per ring: 1, 6, 12, 18, ... with the remainder in the last ring.

    A remainder of 1 or 2 rays joins the ring before it (a lone ray is not centred; two rays have an
    anisotropic second moment): 8 -> [1, 7], 9 -> [1, 8], 3 -> [3], 2 -> [2].
    """
    counts, k = [1], 1
    while sum(counts) < samples:
        counts.append(min(6 * k, samples - sum(counts)))
        k += 1
    if len(counts) > 1 and counts[-1] < 3:
        last = counts.pop()
        counts[-1] += last
    return counts


def beam_pattern(samples: int) -> tuple[np.ndarray, np.ndarray]:
    """Sub-ray offsets and weights (see the module docstring for the construction).

    :returns: offsets (S, 2) in units of the 1/e² radius w (multiply by β/2 for angles),
        weights (S,) summing to 1, with ``Σ w |o|² = 1/2`` for S ≥ 2.
    """
    counts = ring_counts(samples)
    if samples == 1:
        return np.zeros((1, 2)), np.ones(1)
    u = _cell_edges_u(counts)
    energy_below = -np.expm1(-u)                                  # 1 - exp(-u), exp(-inf) = 0
    has_centre = counts[0] == 1
    scale = np.sqrt(np.exp(u[1]) / (1 + u[1])) if has_centre else 1.0
    offsets, weights = [], []
    for k, n in enumerate(counts):
        radius = 0.0 if (k == 0 and has_centre) else scale * np.sqrt(0.5 * _mean_u(u[k], u[k + 1]))
        phase = np.pi * k / n  # stagger neighbouring rings
        angle = phase + 2 * np.pi * np.arange(n) / n
        offsets.append(radius * np.column_stack([np.cos(angle), np.sin(angle)]))
        weights.append(np.full(n, (energy_below[k + 1] - energy_below[k]) / n))
    return np.vstack(offsets), np.concatenate(weights)


@dataclass(frozen=True)
class BeamCells:
    """The beam's cells, one row per sub-ray: what the stratified pattern draws from.

    Ring k holds ``size`` sub-rays that share the annulus ``u_lo <= u < u_hi`` (``u = 2r²/w²``; the
    centre cell is the disc from 0); each carries ``weight``, the annulus' exact energy over its size.
    """

    ring: np.ndarray      # (S,) int: the sub-ray's ring
    index: np.ndarray     # (S,) int: its place in the ring, 0 .. size-1
    size: np.ndarray      # (S,) int: sub-rays in its ring
    u_lo: np.ndarray      # (S,) float
    u_hi: np.ndarray      # (S,) float, inf for the outermost ring
    weight: np.ndarray    # (S,) float, summing to 1

    @property
    def span(self) -> np.ndarray:
        """(S,) the share of ``u ~ Exp(1)`` beyond ``u_lo`` that lies below ``u_hi``: ``1 - exp(-(u_hi - u_lo))``."""
        return -np.expm1(-(self.u_hi - self.u_lo))


def beam_cells(samples: int) -> BeamCells:
    """The cells of :func:`beam_pattern`'s rings (see :func:`stratified_offsets`)."""
    counts = ring_counts(samples)
    u = _cell_edges_u(counts)
    energy = -np.diff(np.exp(-u))                                  # exact energy of each annulus
    ring = np.repeat(np.arange(len(counts)), counts)
    index = np.concatenate([np.arange(n) for n in counts])
    size = np.repeat(counts, counts)
    return BeamCells(ring, index, size, u[ring], u[ring + 1], energy[ring] / size)


def stratified_offsets(cells: BeamCells, radius_uniform: np.ndarray, rotation_uniform: np.ndarray) -> np.ndarray:
    """Sub-ray offsets of the stratified pattern (numpy twin of the Dr.Jit sampler in scan/sampling.py).

    Each ring is turned by its own uniform rotation, and each sub-ray sits at a radius drawn from its
    annulus' share of the Gaussian (inverse CDF of ``u ~ Exp(1)`` truncated to ``[u_lo, u_hi)``), so
    every sub-ray is an unbiased sample of its annulus: the expected energy on any region of the beam,
    ``E[Σ w 1(o ∈ A)]``, is the Gaussian's, and so is the expected second moment ``E[Σ w |o|²] = 1/2``.

    :param radius_uniform: (P, S) uniforms in [0, 1), one per sub-ray.
    :param rotation_uniform: (P, S) uniforms in [0, 1) of each sub-ray's ring (equal within a ring).
    :returns: offsets (P, S, 2) in units of the 1/e² radius.
    """
    u = cells.u_lo - np.log1p(-radius_uniform * cells.span)
    radius = np.sqrt(0.5 * u)
    angle = 2 * np.pi * (cells.index + rotation_uniform) / cells.size
    return np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=-1)


def _cell_edges_u(counts: list[int]) -> np.ndarray:
    """Cell edges in ``u = 2r²/w²``, (len(counts) + 1,): 0, then ring edges ``(k - ½)/K``, then inf."""
    rings = len(counts) - 1
    if rings == 0:
        return np.array([0.0, np.inf])
    r = (np.arange(1, rings + 1) - 0.5) / rings
    return np.concatenate([[0.0], 2 * r ** 2, [np.inf]])


def _mean_u(a: float, b: float) -> float:
    """Mean of u ~ Exp(1) restricted to [a, b] (b may be inf): the cell's mean of 2r²/w²."""
    if np.isinf(b):
        return a + 1.0
    ea, eb = np.exp(-a), np.exp(-b)
    return (a * ea - b * eb) / (ea - eb) + 1.0


def footprint_radius(range_m, divergence: float):
    """1/e² footprint radius ``R·β/2`` (m) at ``range_m`` for full divergence ``β`` (rad)."""
    return np.asarray(range_m) * divergence / 2
