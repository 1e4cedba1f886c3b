"""Pure physics: beam pattern, deflectors, pulse timing, radiometry and the waveform model; the
Dr.Jit twins against their numpy references on every variant the machine has."""

import dataclasses
from fractions import Fraction

import numpy as np
import pytest
from helpers import SENSORS

from mitsuforest.config import load_sensor
from mitsuforest.plan import Leg
from mitsuforest.scan.beam import beam_pattern, footprint_radius, ring_counts
from mitsuforest.scan.radiometry import received_power
from mitsuforest.testing.reference.deflector import oscillating, risley, rotating
from mitsuforest.testing.reference.echoes import pulse_echoes as detect_echoes
from mitsuforest.testing.reference.pulses import reaching_pulses, reaches_box
from mitsuforest.scene.variant import variant_scope

IDEAL = load_sensor(SENSORS / "ideal.yaml")


def resolving_distance(pulse_length):
    return dataclasses.replace(IDEAL, pulse_length=pulse_length).resolving_distance


@pytest.mark.parametrize("samples", [1, 7, 19, 37, 61])
def test_beam_weights_integrate_the_gaussian(samples):
    offsets, weights = beam_pattern(samples)
    assert len(weights) == samples
    assert weights.sum() == pytest.approx(1.0, abs=1e-12)
    assert np.allclose(weights.reshape(-1) @ offsets, 0, atol=1e-12)  # centred
    if samples >= 7:
        # Second moment of I ∝ exp(-2r²/w²) is w²/2: the pattern's RMS footprint is the 1/e² radius.
        rms = np.sqrt(2 * weights @ (offsets ** 2).sum(1))
        assert rms == pytest.approx(1.0, rel=0.05 if samples < 19 else 0.005)
    assert ring_counts(19) == [1, 6, 12]


def test_footprint_radius():
    assert footprint_radius(30.0, 0.5e-3) == pytest.approx(0.0075)
    # Sub-ray directions scaled by β/2 land at the 1/e² radius R·β/2 on a plane at range R.
    offsets, w = beam_pattern(61)
    spots = 30.0 * np.tan(offsets * 0.5e-3 / 2)
    assert np.sqrt(2 * w @ (spots ** 2).sum(1)) == pytest.approx(0.0075, rel=0.005)


def test_rotating_deflector_angles_and_field_of_view():
    t = np.arange(0, 0.02, 1e-5)
    d, theta, fired = rotating(t, 50.0, np.deg2rad(330.0) / 2)
    assert np.allclose(np.linalg.norm(d, axis=1), 1)
    assert np.allclose(np.diff(np.unwrap(theta)), 2 * np.pi * 50 * 1e-5)
    assert fired.mean() == pytest.approx(330 / 360, abs=1e-3)
    assert np.allclose(d[0], [0, 0, -1])  # starts at nadir


def test_oscillating_and_risley_patterns():
    t = np.arange(0, 1, 1e-4)
    _, theta, fired = oscillating(t, 10.0, np.deg2rad(30.0))
    assert fired.all() and theta.max() == pytest.approx(np.deg2rad(30), rel=1e-3)
    # 10 Hz: ten sweeps there and back a second (as HELIOS++'s scanFreq_hz), so twenty scan lines,
    # each across the full field of view at a constant rate, and the same angle 0.1 s later.
    turns = np.flatnonzero(np.diff(np.sign(np.diff(theta))) != 0)
    assert len(turns) == 2 * 10 - 1
    assert np.allclose(np.abs(np.diff(theta))[np.abs(np.diff(theta)) < 1e-2], 4 * np.deg2rad(30) * 10 * 1e-4)
    assert np.allclose(theta[:9000], theta[1000:], atol=1e-9)
    d, off, fired = risley(t, [121.57, -77.73], [17.6, 17.6], np.deg2rad(35.2))
    assert fired.all() and off.max() <= np.deg2rad(35.2) + 1e-9
    assert np.allclose(np.linalg.norm(d, axis=1), 1)
    # Non-repetitive: pulses 1 s apart do not retrace the same directions.
    assert np.abs(d[:5000] - d[5000:]).max() > 0.1


def test_pulse_timing_and_platform():
    leg = Leg((0, 0, 30), (0, 100, 30), 10.0, 60.0)
    assert leg.pulse_count(200000) == 50 * 200000
    p = leg.position(np.array([10.0, 35.0, 60.0]))
    assert np.allclose(p, [[0, 0, 30], [0, 50, 30], [0, 100, 30]])
    assert leg.heading == 0.0 and Leg((0, 0, 30), (10, 0, 30), 0, 5).heading == 90.0
    sensor = dataclasses.replace(IDEAL, deflector="rotating", field_of_view=360.0)
    pulses, _ = reaching_pulses(leg, sensor, 1000, 10, 0, 1000)
    assert np.allclose(np.diff(pulses.time), 1e-3) and pulses.time[0] == 10.0
    assert np.allclose(np.einsum("ij,ij->i", pulses.direction, pulses.across), 0, atol=1e-12)


def test_box_reach():
    box = np.array([[0, 0, 0], [10, 10, 5]], float)
    o = np.array([[5, 5, 30], [5, 5, 30], [50, 5, 30]], float)
    d = np.array([[0, 0, -1], [0, 0, 1], [0, 0, -1]], float)
    assert reaches_box(o, d, box, 1000).tolist() == [True, False, False]
    assert reaches_box(o[:1], d[:1], box, 20).tolist() == [False]


def test_received_power():
    assert received_power(1.0, 0.5, 1.0, 10.0) == pytest.approx(0.005)
    assert received_power(1.0, 0.5, -0.5, 20.0) == pytest.approx(0.000625)


def test_waveform_merges_within_resolving_distance_and_numbers_returns():
    dr = resolving_distance(4e-9)
    assert dr == pytest.approx(0.5996, abs=1e-4)
    inf = np.inf
    ranges = np.array([[10.0, 10.2, 12.0, inf], [5.0, 5.0 + 0.9 * dr, 5.0 + 1.8 * dr, inf], [inf] * 4])
    power = np.full(ranges.shape, 0.25)
    e = detect_echoes(ranges, power, dr)
    assert e.pulse.tolist() == [0, 0, 1]
    assert e.return_number.tolist() == [1, 2, 1] and e.number_of_returns.tolist() == [2, 2, 1]
    assert e.range[0] == pytest.approx(10.1)
    # A chain of returns each within ΔR of the next is one broad echo.
    assert e.range[2] == pytest.approx(5.0 + 0.9 * dr)


def test_threshold_and_max_returns():
    ranges = np.array([[10.0, 20.0, 30.0, 40.0]])
    power = np.array([[1e-3, 1e-6, 1e-3, 1e-3]])
    e = detect_echoes(ranges, power, 0.6, threshold=1e-5)
    assert e.range.tolist() == [10.0, 30.0, 40.0]
    e = detect_echoes(ranges, power, 0.6, threshold=1e-5, max_returns=2)
    assert e.range.tolist() == [10.0, 30.0] and e.number_of_returns.tolist() == [2, 2]
    e = detect_echoes(ranges, power, 0.6, range_min=15.0)
    assert e.range.tolist() == [20.0, 30.0, 40.0]


def test_echo_amplitude_and_dominant_subray():
    ranges = np.array([[10.0, 10.0, 10.0]])
    power = np.array([[0.1, 0.5, 0.2]])
    e = detect_echoes(ranges, power, 0.6)
    assert e.amplitude[0] == pytest.approx(0.8)  # coincident returns add up
    assert e.dominant[0] == 1
    assert e.weighted_mean(np.array([[0.0], [1.0], [2.0]]))[0, 0] == pytest.approx((0.5 + 0.4) / 0.8)


@pytest.mark.parametrize("samples", [1, 7, pytest.param(19, marks=pytest.mark.slow)])
def test_device_waveform_matches_the_numpy_reference(samples, variant):
    """echoes.py (Dr.Jit, one lane per pulse) against its numpy twin on returns built to be hard: ties,
    chains across several sub-rays, misses, zero-power (grazing) returns, more echoes than max_returns."""
    with variant_scope(variant):
        _device_waveform_matches_the_numpy_reference(samples)


def _device_waveform_matches_the_numpy_reference(samples):
    import mitsuba as mi

    from mitsuforest.scan.echoes import pulse_echoes
    rng = np.random.default_rng(samples)
    n, resolving = 4000, 0.6
    ranges = rng.choice([10.0, 10.3, 10.9, 12.0, 12.55, 20.0], (n, samples)) + rng.normal(0, 0.05, (n, samples))
    ranges[rng.random((n, samples)) < 0.1] = 12.0                      # exact ties
    ranges[rng.random((n, samples)) < 0.2] = np.inf                    # misses
    power = rng.uniform(0, 1e-3, (n, samples))
    power[rng.random((n, samples)) < 0.05] = 0.0                       # grazing
    power[: n // 10] = 0.0                                             # whole pulses at grazing incidence
    threshold, max_returns = 2e-4, 3
    ref = detect_echoes(ranges, power, resolving, threshold, max_returns)

    ranges32 = ranges.astype(np.float32)
    col = [mi.Float(np.ascontiguousarray(ranges32[:, k])) for k in range(samples)]
    pcol = [mi.Float(np.ascontiguousarray(power[:, k].astype(np.float32))) for k in range(samples)]
    off = [[mi.Float(np.full(n, k, np.float32)) for _ in range(3)] for k in range(samples)]
    slots, returns = pulse_echoes(col, pcol, off, resolving, threshold, max_returns)
    got = []
    for slot in slots:
        kept = np.array(slot["kept"])
        rows = np.flatnonzero(kept)
        got.append(np.column_stack([rows, np.array(slot["rank"])[rows] + 1, np.array(slot["range"])[rows],
                                    np.array(slot["amplitude"])[rows], np.array(slot["dominant"])[rows]]))
    got = np.vstack(got)
    got = got[np.lexsort((got[:, 1], got[:, 0]))]
    assert len(got) == len(ref.pulse) > n // 2
    assert np.array_equal(got[:, 0], ref.pulse)
    assert np.array_equal(got[:, 1], ref.return_number)
    assert np.array_equal(np.array(returns)[ref.pulse], ref.number_of_returns)
    assert np.allclose(got[:, 2], ref.range, atol=1e-5)
    assert np.allclose(got[:, 3], ref.amplitude, rtol=1e-4, atol=1e-10)
    assert np.array_equal(got[:, 4], ref.dominant % samples)
    assert samples == 1 or (ref.number_of_returns == max_returns).any()


def test_single_chain_shortcut_gives_the_sorted_rule_s_echo(variant):
    """echoes.single_chain (no sort) on pulses whose returns lie within ΔR: the same echo as the numpy
    reference, strongest sub-ray included when powers tie (the lowest sub-ray wins, as in the twin);
    pulses with a gap wider than ΔR are left to the sorting path."""
    with variant_scope(variant):
        import mitsuba as mi

        from mitsuforest.scan.echoes import single_chain
        rng = np.random.default_rng(5)
        n, samples, resolving = 6000, 19, 0.6
        ranges = 20.0 + rng.choice([0.0, 0.25, 0.5, 0.59], (n, samples)) + rng.choice([0.0, 0.003], (n, samples))
        ranges[n // 2:, 0] += rng.choice([0.0, 0.7, 3.0], n - n // 2)              # a second chain in some
        ranges[rng.random((n, samples)) < 0.2] = np.inf
        ranges[: n // 20] = np.inf                                                 # pulses that return nothing
        power = rng.choice([1e-4, 2e-4, 5e-4], (n, samples))                        # many exact ties
        power[n // 20: n // 10] = 0.0                                              # grazing: plain means
        ref = detect_echoes(ranges, power, resolving, 1e-5, 0)
        col = [mi.Float(np.ascontiguousarray(ranges[:, k].astype(np.float32))) for k in range(samples)]
        pcol = [mi.Float(np.ascontiguousarray(power[:, k].astype(np.float32))) for k in range(samples)]
        off = [[mi.Float(np.full(n, k + a, np.float32)) for a in range(3)] for k in range(samples)]
        one, slot = single_chain(col, pcol, off, resolving, 1e-5)
        one, kept = np.array(one), np.array(slot["kept"])
        finite = np.isfinite(ranges)
        spread = np.where(finite, ranges, -np.inf).max(axis=1) - np.where(finite, ranges, np.inf).min(axis=1)
        assert np.array_equal(one, ~(spread > resolving + 1e-6))
        assert 0.3 < one.mean() < 0.8
        first = ref.return_number == 1
        single = one[ref.pulse[first]]
        pulses = ref.pulse[first][single]
        assert np.array_equal(np.flatnonzero(kept & one), pulses)
        assert np.array_equal(ref.number_of_returns[first][single], np.ones(len(pulses)))
        assert np.allclose(np.array(slot["range"])[pulses], ref.range[first][single], atol=1e-5)
        assert np.allclose(np.array(slot["amplitude"])[pulses], ref.amplitude[first][single], rtol=1e-4)
        assert np.array_equal(np.array(slot["dominant"])[pulses], ref.dominant[first][single] % samples)
        assert (np.array(slot["kept"])[n // 20: n // 10] == 0).all()              # zero amplitude: no echo
        w = np.where(finite, power, 0.0)[pulses]
        assert np.allclose(np.array(slot["offset"][1])[pulses], (w * (np.arange(samples) + 1)).sum(1) / w.sum(1),
                           rtol=1e-5)


@pytest.mark.parametrize("deflector", ["rotating", "oscillating", "risley"])
def test_device_pulses_match_the_numpy_reference(deflector, variant):
    """scan/pulses.py against its numpy twin: same fired and cast pulses, times and angles within
    float64 rounding, rays within float32."""
    from mitsuforest.scan import pulses as device
    sensor = dataclasses.replace(
        IDEAL, deflector=deflector, field_of_view={"rotating": 270, "oscillating": 100, "risley": 30}[deflector],
        range_max=200.0, risley=dataclasses.replace(IDEAL.risley, prism_rates=(121.6, -77.7),
                                                    prism_deflection=(8.0, 7.0)))
    leg = Leg((-4.0, -20.0, 30.0), (-4.0, 100.0, 30.0), 12.5, 72.5)  # beside the box
    box = np.array([[0.0, 0.0, 0.0], [100.0, 100.0, 28.0]])
    # Slot 2,000,000 flies at y = 0 exactly, on the box's face, where a fused multiply-add (CUDA) rounds
    # its origin to -4e-15 and outside: start one slot later, off the tie.
    ref, fired = reaching_pulses(leg, sensor, 200_000, 50, 2_000_001, 50_000, box)
    with variant_scope(variant):
        got, got_fired = device.reaching_pulses(leg, sensor, 200_000, 50, 2_000_001, 50_000, box, first_id=7)
        assert got_fired == fired and 1000 < len(ref.index) < fired
        assert np.array_equal(np.array(got.pulse_id), ref.index + 7)
        assert np.abs(np.array(got.time) - ref.time).max() < 1e-9
        assert np.abs(np.array(got.scan_angle) - ref.scan_angle).max() < 1e-6
        for key in ("origin", "direction", "across"):
            xyz = np.column_stack([np.array(getattr(getattr(got, key), a)) for a in "xyz"])
            assert np.abs(xyz - getattr(ref, key)).max() < 1e-5, key


def exact_scan_angle(sensor, t0: float, since: np.ndarray, scan_frequency: float) -> np.ndarray:
    """Scan angles at ``t0 + since`` with the turns taken in exact rational arithmetic."""
    def turns(frequency):
        return np.array([float((Fraction(t0) + Fraction(s)) * Fraction(frequency) % 1) for s in since])
    if sensor.deflector == "rotating":
        return (2 * np.pi * turns(scan_frequency) + np.pi) % (2 * np.pi) - np.pi
    if sensor.deflector == "oscillating":
        return (4 * np.abs(turns(scan_frequency) - 0.5) - 1) * sensor.half_fov
    (d1, d2), angles = np.deg2rad(sensor.risley.prism_deflection), [2 * np.pi * turns(r) for r in sensor.risley.prism_rates]
    return np.hypot(d1 * np.cos(angles[0]) + d2 * np.cos(angles[1]), d1 * np.sin(angles[0]) + d2 * np.sin(angles[1]))


@pytest.mark.parametrize("deflector", ["rotating", "oscillating", "risley"])
def test_scan_angles_keep_their_precision_at_gps_seconds(deflector, variant):
    """A flown trajectory's legs start at its own clock, GPS seconds of about 1.4e9 s: there 2π·f·t in
    float64 keeps only some 4e-4 rad (steps between pulses off by 17 %). Both twins take the phase at the
    leg's start exactly, so every angle is the exact one within 1e-9 rad."""
    from mitsuforest.scan import pulses as device
    sensor = dataclasses.replace(
        IDEAL, deflector=deflector, field_of_view={"rotating": 360, "oscillating": 100, "risley": 40}[deflector],
        range_max=200.0, risley=dataclasses.replace(IDEAL.risley, prism_rates=(121.6, -77.7),
                                                    prism_deflection=(8.0, 7.0)))
    t0 = 1_400_000_000.123
    leg = Leg((0.0, 0.0, 30.0), (0.0, 10.0, 30.0), t0, t0 + 5.0)
    box = np.array([[-1e3, -1e3, -1e3], [1e3, 1e3, 1e3]])
    ref, _ = reaching_pulses(leg, sensor, 550_000, 200, 1000, 20_000, box)
    since = (ref.index / 550_000)
    truth = exact_scan_angle(sensor, t0, since[::97], 200)
    assert len(ref.index) > 10_000
    assert np.abs(ref.scan_angle[::97] - truth).max() < 1e-9
    with variant_scope(variant):
        got, _ = device.reaching_pulses(leg, sensor, 550_000, 200, 1000, 20_000, box)
        assert np.abs(np.array(got.scan_angle)[::97] - truth).max() < 1e-6      # float32 on the device
        assert np.array_equal(np.array(got.pulse_id), ref.index)
