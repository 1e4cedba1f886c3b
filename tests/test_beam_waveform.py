"""The beam pattern's moments, the waveform rule's documented behaviour and the Risley pattern,
each against a closed form."""

import numpy as np
import pytest

from mitsuforest.scan.beam import beam_pattern, ring_counts

# Beam pattern ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("samples", [2, 3, 4, 5, 7, 8, 9, 11, 19, 20, 37, 61])
def test_beam_second_moment_is_the_gaussians(samples):
    """I ∝ exp(-2r²/w²) has E[r²] = w²/2; offsets are in units of w."""
    offsets, weights = beam_pattern(samples)
    assert len(weights) == samples and (weights > 0).all()
    assert weights.sum() == pytest.approx(1.0, abs=1e-12)
    assert np.abs(weights @ offsets).max() < 1e-12                             # centred
    assert weights @ (offsets ** 2).sum(1) == pytest.approx(0.5, rel=1e-6)
    if samples >= 3:
        # Every ring has >= 3 equally spaced rays: the moment is isotropic, E[x²] = E[y²] = 1/4.
        moment = np.einsum("k,ki,kj->ij", weights, offsets, offsets)
        assert np.allclose(moment, np.eye(2) / 4, rtol=0, atol=1e-12)


@pytest.mark.parametrize("samples", [1, 7, 19, 37, 61])
def test_beam_weights_are_the_cell_energies(samples):
    """Ring k of K spans r in [(k-1/2)/K, (k+1/2)/K): its energy is exp(-2 r_in²) - exp(-2 r_out²)."""
    counts = ring_counts(samples)
    _, weights = beam_pattern(samples)
    rings = len(counts) - 1
    edges = np.concatenate([[0.0], (np.arange(1, rings + 1) - 0.5) / max(rings, 1), [np.inf]])
    energy = np.exp(-2 * edges[:-1] ** 2) - np.exp(-2 * edges[1:] ** 2)
    per_ring = np.add.reduceat(weights, np.cumsum([0] + counts[:-1]))
    assert np.allclose(per_ring, energy, rtol=1e-12)


def test_ring_counts():
    assert ring_counts(1) == [1]
    assert ring_counts(7) == [1, 6] and ring_counts(19) == [1, 6, 12] and ring_counts(61) == [1, 6, 12, 18, 24]
    assert ring_counts(11) == [1, 6, 4]
    # A remainder of 1 or 2 joins the ring before it.
    assert ring_counts(2) == [2] and ring_counts(3) == [3] and ring_counts(8) == [1, 7] and ring_counts(21) == [1, 6, 14]


def test_thin_beam_is_one_centre_ray():
    offsets, weights = beam_pattern(1)
    assert offsets.tolist() == [[0.0, 0.0]] and weights.tolist() == [1.0]


@pytest.mark.parametrize("samples", [7, 19, 61])
def test_footprint_rms_radius_is_the_one_over_e2_radius(samples):
    """Sub-rays scaled by β/2 (per axis) onto a plane at range R: sqrt(2 Σ w |spot|²) = R·β/2, and
    per axis sqrt(4 Σ w x²) = R·β_x/2 for an elliptical beam. The tracer uses tan(angle)
    (tracer.py); tan θ/θ - 1 ≈ θ²/3 < 1e-7 here."""
    offsets, w = beam_pattern(samples)
    R, beta = 30.0, 0.5e-3
    spots = R * np.tan(offsets * beta / 2)
    assert np.sqrt(2 * w @ (spots ** 2).sum(1)) == pytest.approx(R * beta / 2, rel=1e-6)
    betas = np.array([1.6e-3, 0.5e-3])
    spots = R * np.tan(offsets * betas / 2)
    assert np.sqrt(4 * w @ spots ** 2) == pytest.approx(R * betas / 2, rel=1e-6)
