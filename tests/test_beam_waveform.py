"""The beam pattern's moments, the waveform rule's documented behaviour and the Risley pattern,
each against a closed form."""

import numpy as np
import pytest

from mitsuforest.scan.beam import beam_pattern, ring_counts
from mitsuforest.testing.reference.deflector import risley as risley_half_fov
from mitsuforest.testing.reference.echoes import FWHM_PER_SIGMA, two_maxima_ratio, waveform_maxima
from mitsuforest.testing.reference.echoes import pulse_echoes as detect_echoes

DR = 299_792_458.0 * 4e-9 / 2          # ΔR = c·τ/2 = 0.5996 m
SIGMA = DR / FWHM_PER_SIGMA

def risley(t, rates, deflections_deg, field_of_view):
    return risley_half_fov(t, rates, deflections_deg, np.deg2rad(field_of_view) / 2)


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


# Waveform rule ---------------------------------------------------------------------------------------

def _grid_maxima(ranges, powers):
    """Maxima of Σ p exp(-½((x-r)/σ)²) counted on a fine grid from its values (independent of the
    package's slope-based counter)."""
    x = np.arange(min(ranges) - 3 * SIGMA, max(ranges) + 3 * SIGMA, SIGMA / 2000)
    w = sum(p * np.exp(-0.5 * ((x - r) / SIGMA) ** 2) for r, p in zip(ranges, powers))
    return int(np.count_nonzero((w[1:-1] > w[:-2]) & (w[1:-1] > w[2:])))


def test_unequal_powers_past_resolving_distance_two_echoes_one_maximum():
    """1.03 ΔR apart, powers 1 : 0.3 < a_min = 0.683: the rule splits what the waveform merges."""
    ranges, powers = [20.0, 20.0 + 1.03 * DR], [1.0, 0.3]
    e = detect_echoes(np.array([ranges]), np.array([powers]), DR)
    assert e.number_of_returns.tolist() == [2, 2] and e.range.tolist() == ranges
    assert _grid_maxima(ranges, powers) == 1
    assert waveform_maxima(ranges, powers, DR) == 1
    assert two_maxima_ratio(1.03 * DR, DR) == pytest.approx(0.6828, abs=1e-4)


def test_equal_powers():
    """Past ΔR equal powers give two echoes and two maxima; 0.9 ΔR apart (between 2σ = 0.849 ΔR
    and ΔR) they chain into one echo although the waveform has two maxima."""
    for d, echoes in ((1.03 * DR, 2), (0.9 * DR, 1)):
        ranges, powers = [20.0, 20.0 + d], [1.0, 1.0]
        e = detect_echoes(np.array([ranges]), np.array([powers]), DR)
        assert len(e.range) == echoes
        assert _grid_maxima(ranges, powers) == 2 and waveform_maxima(ranges, powers, DR) == 2
    # Two equal Gaussians part at exactly 2σ.
    assert waveform_maxima([0.0, 1.99 * SIGMA], [1, 1], DR) == 1
    assert waveform_maxima([0.0, 2.01 * SIGMA], [1, 1], DR) == 2
    assert 2 * SIGMA / DR == pytest.approx(0.8493, abs=1e-4)


@pytest.mark.parametrize("separation", [0.9, 1.0, 1.1, 1.25, 1.5, 1.75])
def test_two_maxima_ratio_is_the_waveforms_threshold(separation):
    """Just above a_min(d) the waveform has two maxima, just below one (fine-grid count)."""
    d = separation * DR
    a = float(two_maxima_ratio(d, DR))
    assert 0 < a < 1
    assert _grid_maxima([0.0, d], [1.0, a * 1.01]) == 2
    assert _grid_maxima([0.0, d], [1.0, a * 0.99]) == 1
    assert waveform_maxima([0.0, d], [1.0, a * 1.01], DR) == 2
    assert waveform_maxima([0.0, d], [1.0, a * 0.99], DR) == 1


def test_two_maxima_ratio_table():
    """The table in the docstring of testing/reference/echoes.py."""
    d = np.array([0.85, 0.9, 1.0, 1.03, 1.1, 1.25, 1.5, 2.0]) * DR
    assert np.allclose(two_maxima_ratio(d, DR), [1, 0.946, 0.749, 0.683, 0.532, 0.271, 0.061, 0.0009],
                       atol=6e-4, rtol=0)
    assert two_maxima_ratio(0.5 * DR, DR) == 1.0


def test_chain_amplitude_is_its_gaussian_weighted_power():
    """Amplitude = Σ p_i exp(-½((r_i - m)/σ)²) with m the energy-weighted mean range."""
    r1, r2, p1, p2 = 20.0, 20.0 + 0.7 * DR, 2e-3, 5e-4
    e = detect_echoes(np.array([[r1, r2]]), np.array([[p1, p2]]), DR)
    m = (p1 * r1 + p2 * r2) / (p1 + p2)
    expected = p1 * np.exp(-0.5 * ((r1 - m) / SIGMA) ** 2) + p2 * np.exp(-0.5 * ((r2 - m) / SIGMA) ** 2)
    assert len(e.range) == 1
    assert e.range[0] == pytest.approx(m, rel=1e-12)
    assert e.amplitude[0] == pytest.approx(expected, rel=1e-9)
    assert expected < 0.85 * (p1 + p2)  # the weighting is not a plain sum here


def test_chain_amplitude_leaves_out_a_neighbour_chain():
    """A neighbour 1.03 ΔR away adds 0.3·exp(-½(1.03·2.3548)²) ≈ 1.6 % to the waveform at the first
    echo, but not to its amplitude: each amplitude is its own chain's power."""
    ranges, powers = np.array([[20.0, 20.0 + 1.03 * DR]]), np.array([[1.0, 0.3]])
    e = detect_echoes(ranges, powers, DR)
    assert e.amplitude.tolist() == [1.0, 0.3]
    waveform_at_first = 1.0 + 0.3 * np.exp(-0.5 * (1.03 * DR / SIGMA) ** 2)
    assert waveform_at_first == pytest.approx(1.0158, abs=1e-4)


def test_device_kernel_follows_the_same_rule(llvm_mono):
    """echoes.py on the documented cases: 1 : 0.3 at 1.03 ΔR gives two echoes, equal at 0.9 ΔR one."""
    import mitsuba as mi

    from mitsuforest.scan.echoes import pulse_echoes
    ranges = np.array([[20.0, 20.0 + 1.03 * DR], [20.0, 20.0 + 0.9 * DR]], np.float32)
    powers = np.array([[1.0, 0.3], [1.0, 1.0]], np.float32)
    t = [mi.Float(np.ascontiguousarray(ranges[:, k])) for k in range(2)]
    p = [mi.Float(np.ascontiguousarray(powers[:, k])) for k in range(2)]
    offset = [[mi.Float(np.zeros(2, np.float32)) for _ in range(3)] for _ in range(2)]
    slots, returns = pulse_echoes(t, p, offset, DR, 0.0, 0)
    assert np.array(returns).tolist() == [2, 1]
    assert np.array(slots[0]["amplitude"])[0] == pytest.approx(1.0, rel=1e-6)


def test_waveform_maxima_edge_cases():
    assert waveform_maxima([np.inf, np.inf], [1.0, 1.0], DR) == 0
    assert waveform_maxima([10.0, 12.0], [0.0, 0.0], DR) == 0
    assert waveform_maxima([10.0], [1.0], DR) == 1
    # Far apart: the waveform underflows to 0 between them and is still counted right.
    assert waveform_maxima([10.0, 30.0, 50.0, np.inf], [1.0, 1e-3, 1.0, 1.0], DR) == 3


# Risley pattern ----------------------------------------------------------------------------------------

RATES = [121.57, -77.73]


def test_risley_equal_prisms_off_nadir_closed_form():
    """|δ e^{iω₁t} + δ e^{iω₂t}| = 2δ|cos(π(f₁ - f₂)t)|."""
    t = np.random.default_rng(1).uniform(0, 10, 20000)
    delta = np.deg2rad(8.0)
    d, off, fired = risley(t, RATES, [8.0, 8.0], 40.0)
    assert np.allclose(off, 2 * delta * np.abs(np.cos(np.pi * (RATES[0] - RATES[1]) * t)), rtol=0, atol=1e-9)
    assert np.allclose(np.linalg.norm(d, axis=1), 1, rtol=0, atol=1e-12)
    assert np.allclose(np.arccos(np.clip(-d[:, 2], -1, 1)), off, rtol=0, atol=1e-7)  # arccos loses digits near 0
    assert np.allclose(np.arctan2(np.hypot(d[:, 0], d[:, 1]), -d[:, 2]), off, rtol=0, atol=1e-12)
    assert fired.all()


def test_risley_extremes():
    """Off-nadir angle is δ₁ + δ₂ when the prisms align, |δ₁ - δ₂| when opposed (nadir for equal)."""
    beat = RATES[0] - RATES[1]
    aligned, opposed = np.arange(5) / beat, (np.arange(5) + 0.5) / beat
    _, off, _ = risley(aligned, RATES, [8.0, 8.0], 40.0)
    assert np.allclose(off, np.deg2rad(16.0), rtol=0, atol=1e-9)
    d, off, _ = risley(opposed, RATES, [8.0, 8.0], 40.0)
    assert np.allclose(off, 0, atol=1e-9) and np.allclose(d, [0, 0, -1], atol=1e-9)
    _, off, _ = risley(opposed, RATES, [8.0, 5.0], 40.0)
    assert np.allclose(off, np.deg2rad(3.0), rtol=0, atol=1e-9)
    t = np.random.default_rng(2).uniform(0, 1, 20000)
    _, off, fired = risley(t, RATES, [8.0, 5.0], 20.0)
    assert off.min() >= np.deg2rad(3.0) - 1e-12 and off.max() <= np.deg2rad(13.0) + 1e-12
    assert np.array_equal(fired, off <= np.deg2rad(10.0) + 1e-9)


def test_risley_azimuth_is_the_deviations_argument():
    """atan2(d_y, d_x) = arg(δ₁e^{iω₁t} + δ₂e^{iω₂t}); for equal prisms (ω₁ + ω₂)t/2, plus π where the
    cosine is negative."""
    t = np.random.default_rng(3).uniform(0, 10, 20000)
    w1, w2 = 2 * np.pi * np.array(RATES)
    d, off, _ = risley(t, RATES, [8.0, 5.0], 40.0)
    deviation = np.deg2rad(8.0) * np.exp(1j * w1 * t) + np.deg2rad(5.0) * np.exp(1j * w2 * t)
    assert np.allclose(off, np.abs(deviation), rtol=0, atol=1e-12)
    gap = np.angle(np.exp(1j * (np.arctan2(d[:, 1], d[:, 0]) - np.angle(deviation))))
    assert np.abs(gap).max() < 1e-9
    d, _, _ = risley(t, RATES, [8.0, 8.0], 40.0)
    half = np.cos((w1 - w2) * t / 2)
    expected = (w1 + w2) * t / 2 + np.where(half < 0, np.pi, 0.0)
    gap = np.angle(np.exp(1j * (np.arctan2(d[:, 1], d[:, 0]) - expected)))
    assert np.abs(gap[np.abs(half) > 1e-6]).max() < 1e-9


def test_risley_period_is_one_over_the_rates_gcd():
    """Rates 30 and -20 Hz repeat after 1/gcd = 0.1 s, and not after half of it."""
    t = np.random.default_rng(4).uniform(0, 1, 1000)
    d0, _, _ = risley(t, [30.0, -20.0], [8.0, 5.0], 40.0)
    d1, _, _ = risley(t + 0.1, [30.0, -20.0], [8.0, 5.0], 40.0)
    d2, _, _ = risley(t + 0.05, [30.0, -20.0], [8.0, 5.0], 40.0)
    assert np.abs(d1 - d0).max() < 1e-9
    assert np.abs(d2 - d0).max() > 0.1
