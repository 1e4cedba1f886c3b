"""The stratified beam: exact cell energies, the Gaussian's moments and half-plane energy in
expectation, the Dr.Jit sampler against its numpy twin; the fixed pattern's staircase beside it."""

import numpy as np
import pytest
from scipy.special import erfc

from mitsuforest import seeds
from mitsuforest.scan.beam import beam_cells, beam_pattern, stratified_offsets
from mitsuforest.scan.sampling import RING_STREAM, device_cells, uniform_pair
from mitsuforest.scan.sampling import stratified_offsets as device_offsets
from mitsuforest.scene.variant import variant_scope

PULSES = 40_000


def _device_offsets(samples, pulses=PULSES, seed=3):
    """(P, S, 2) offsets drawn by the production sampler, and the uniforms it used."""
    import drjit as dr
    import mitsuba as mi
    table = device_cells(beam_cells(samples))
    lane = dr.arange(mi.UInt32, pulses * samples)
    pulse_id = mi.UInt64(lane // samples) + (1 << 33)          # ids past 32 bits use the high word
    sample = lane % samples
    key = seeds.key(seed, "beam")
    ox, oy = device_offsets(table, key, pulse_id, sample)
    radius_u, _ = uniform_pair(key, pulse_id, sample)
    rotation_u, _ = uniform_pair(key, pulse_id, dr.gather(mi.UInt32, table["ring"], sample) + RING_STREAM)
    shape = (pulses, samples)
    return (np.stack([np.array(ox).reshape(shape), np.array(oy).reshape(shape)], -1),
            np.array(radius_u).reshape(shape), np.array(rotation_u).reshape(shape))


@pytest.mark.parametrize("samples", [1, 3, 5, 7, 11, 19, 37, 61])
def test_stratified_weights_are_the_exact_cell_energies(samples):
    cells = beam_cells(samples)
    assert cells.weight.sum() == pytest.approx(1.0, abs=1e-12)
    for ring in np.unique(cells.ring):
        mine = cells.ring == ring
        lo, hi = cells.u_lo[mine][0], cells.u_hi[mine][0]
        assert cells.weight[mine].sum() == pytest.approx(np.exp(-lo) - np.exp(-hi), abs=1e-15)
    fixed_offsets, fixed_weights = beam_pattern(samples)
    assert np.allclose(cells.weight, fixed_weights, atol=1e-15)          # the same cells as the fixed pattern


@pytest.mark.parametrize("samples", [1, 7, 19])
def test_stratified_moments_match_the_gaussian_in_expectation(samples, variant):
    with variant_scope(variant):
        offsets, _, _ = _device_offsets(samples)
    w = beam_cells(samples).weight
    second = (offsets ** 2).sum(-1) @ w                                   # per pulse: Σ w |o|²
    assert second.mean() == pytest.approx(0.5, abs=4 * second.std() / np.sqrt(PULSES))
    assert abs(second.mean() - 0.5) < 0.005
    for axis in range(2):                                                 # E[x²] = E[y²] = 1/4, E[x] = 0
        assert (offsets[..., axis] ** 2 @ w).mean() == pytest.approx(0.25, abs=0.004)
        mean = offsets[..., axis] @ w                                     # per pulse: Σ w x, mean 0
        assert abs(mean.mean()) < 4 * mean.std() / np.sqrt(PULSES)


def test_device_sampler_matches_its_numpy_twin(variant):
    with variant_scope(variant):
        offsets, radius_u, rotation_u = _device_offsets(19, pulses=2000)
    expected = stratified_offsets(beam_cells(19), radius_u.astype(np.float64), rotation_u.astype(np.float64))
    assert np.abs(offsets - expected).max() < 1e-5
    assert len(np.unique(rotation_u[0, beam_cells(19).ring == 2])) == 1  # one rotation per ring and pulse


@pytest.mark.parametrize("samples", [7, 19])
def test_half_plane_energy_is_the_gaussians(samples, variant):
    """Beam energy beyond a straight edge at distance d from the axis: ½ erfc(√2 d / w), averaged over
    pulses, within 1 % for stratified sub-rays; the fixed pattern gives a staircase that misses it."""
    d = np.linspace(-1.5, 1.5, 31)
    exact = 0.5 * erfc(np.sqrt(2) * d)
    with variant_scope(variant):
        offsets, _, _ = _device_offsets(samples)
    w = beam_cells(samples).weight
    stratified = np.array([((offsets[..., 0] > x) @ w).mean() for x in d])
    assert np.abs(stratified - exact).max() < 0.01
    fixed_offsets, fixed_w = beam_pattern(samples)
    staircase = np.array([((fixed_offsets[:, 0] > x) * fixed_w).sum() for x in d])
    assert np.abs(staircase - exact).max() > 0.05                         # the fixed pattern's bias
    assert len(np.unique(np.round(staircase, 12))) <= 2 * samples         # a step function of d
