"""Full-waveform output and pulse records (README, "Waveforms and pulse records") against analytic answers."""

import dataclasses
import math

import numpy as np
import pytest
from helpers import analytic_scene, plane_model, pulses, scene_file

from mitsuforest.classes import ROCK
from mitsuforest.cli import main
from mitsuforest.pipeline import render
from mitsuforest.scan import PulseTracer
from mitsuforest.scan.waveform import echo_energy, pulse_sigma, sample_waveforms

C = 299_792_458.0
PULSE = 4e-9                      # s: ΔR = c·τ/2 = 0.60 m
BIN = 1e-9                        # s: h = 0.1499 m
H = C * BIN / 2


def _records(setup, p, samples=1, divergence=0.0, **sensor_changes):
    """Points, the PulseBatch of hand-made pulses and its waveforms (sampled on the device)."""
    scene, _, _, scan_scene = setup
    sensor = dataclasses.replace(scene.sensor, pulse_length=PULSE, beam_divergence=(divergence, divergence),
                                 **sensor_changes)
    points, _, batch = PulseTracer(scan_scene, sensor, samples, waveforms=True).trace_pulse_records(p)
    sigma = pulse_sigma(sensor.resolving_distance)
    assert sensor.waveform.bin_range == pytest.approx(H)
    cast = batch.cast
    return points, batch, sigma, cast["first_bin"].astype(np.int64), cast["samples"], cast["complete"]


def _peaks(wave: np.ndarray, share: float = 0.05) -> np.ndarray:
    """Bins of the local maxima of one waveform above ``share`` of its largest sample."""
    inner = (wave[1:-1] > wave[:-2]) & (wave[1:-1] >= wave[2:]) & (wave[1:-1] > share * wave.max())
    return np.flatnonzero(inner) + 1


def test_single_return_integral_and_window_are_analytic():
    """One return of power p at r: the bins integrate to p·σ·√(2π) (its echo energy), the window starts
    at the bin holding r - 5σ, and the peak is in the bin holding r."""
    sigma = pulse_sigma(C * PULSE / 2)
    ranges = np.array([[25.0, np.inf], [40.03, 41.7]])
    powers = np.array([[2e-4, 0.0], [1e-4, 3e-4]])
    first_bin, wave, complete = sample_waveforms(ranges, powers, sigma, H, 64)
    assert first_bin.tolist() == [math.floor((25 - 5 * sigma) / H), math.floor((40.03 - 5 * sigma) / H)]
    integral = wave.sum(axis=1, dtype=np.float64) * H
    assert integral == pytest.approx(echo_energy([2e-4, 4e-4], sigma), rel=1e-5)
    assert (first_bin[0] + np.argmax(wave[0])) == math.floor(25 / H)
    assert complete.all()
    _, short, complete = sample_waveforms(ranges, powers, sigma, H, 8)    # 1.2 m: the far return is cut
    assert complete.tolist() == [False, False] and short.sum() * H < integral.sum()


def test_device_sampling_is_its_numpy_twin(variant):
    """Random returns (a fifth missing, one pulse without any): the device's float32 waveforms are the
    numpy twin's within 5e-5 of each pulse's peak (float32 differences of erf: 1.7e-5 here), their
    integrals within 1e-5, with the same windows."""
    import mitsuba as mi
    from mitsuforest.scan.waveform import device_waveforms
    from mitsuforest.scene.variant import variant_scope
    rng = np.random.default_rng(3)
    pulses_, subs = 300, 7
    ranges = rng.uniform(2.0, 60.0, (pulses_, subs))
    ranges[rng.random(ranges.shape) < 0.2] = np.inf
    ranges[5] = np.inf
    powers = np.where(np.isfinite(ranges), rng.uniform(0, 1e-3, ranges.shape), 0.0)
    sigma = pulse_sigma(C * PULSE / 2)
    with variant_scope(variant):
        made = device_waveforms(mi.Float(ranges.ravel().astype(np.float32)),
                                mi.Float(powers.ravel().astype(np.float32)), subs, sigma, H, 128)
        rows, first, wave, complete = (np.array(made[k]) for k in ("rows", "first_bin", "waveform", "complete"))
    keep = np.isfinite(ranges).any(axis=1)
    assert rows.tolist() == np.flatnonzero(keep).tolist() and 5 not in rows
    twin_first, twin, twin_complete = sample_waveforms(ranges[keep].astype(np.float32), powers[keep].astype(np.float32),
                                                       sigma, H, 128)
    assert first.tolist() == twin_first.tolist() and complete.tolist() == twin_complete.tolist()
    wave = wave.reshape(-1, 128)
    assert (np.abs(wave - twin).max(axis=1) <= 5e-5 * twin.max(axis=1)).all()
    assert wave.sum(axis=1, dtype=np.float64) == pytest.approx(twin.sum(axis=1, dtype=np.float64), rel=1e-5)
    assert (~complete).any() and complete.any()


@pytest.mark.parametrize("pulse_length", [1e-9, 4e-9])
def test_device_sampling_keeps_its_precision_at_the_sensors_far_ranges(pulse_length, variant):
    """One return at ranges up to the ideal sensor's range_max (10 km), stepped through a bin: the
    device's float32 samples are the numpy twin's (float64) within 5e-5 of the peak, as near the sensor.
    Bin edges taken as k·h - r in float32 at 10 km keep ~1e-3 m, 1 % of a 1 ns pulse's σ (6.4e-2 m):
    the samples were off by 6.4e-3 of the peak there, 3e-4 at 1 km, and 1.1e-4 at 250 m."""
    import mitsuba as mi
    from mitsuforest.scan.waveform import device_waveforms
    from mitsuforest.scene.variant import variant_scope
    sigma = pulse_sigma(C * pulse_length / 2)
    ranges = (np.array([250.0, 1000.0, 6000.0, 9999.0])[:, None] + np.linspace(0, H, 13)).astype(np.float32)
    ranges = ranges.reshape(-1, 1)
    powers = np.full(ranges.shape, 3e-9)
    with variant_scope(variant):
        made = device_waveforms(mi.Float(ranges.ravel()), mi.Float(powers.ravel().astype(np.float32)), 1, sigma, H, 64)
        first, wave = np.array(made["first_bin"]), np.array(made["waveform"]).reshape(-1, 64)
    twin_first, twin, _ = sample_waveforms(ranges, powers, sigma, H, 64)
    assert first.tolist() == twin_first.tolist()
    mid = 39 + np.argmin(np.abs((ranges[39:, 0] / H) % 1 - 0.5))           # at 10 km, mid-bin: peaks there
    assert first[mid] + np.argmax(wave[mid]) == math.floor(float(ranges[mid, 0]) / H)
    assert (np.abs(wave - twin).max(axis=1) <= 5e-5 * twin.max(axis=1)).all()


def test_a_return_within_five_sigma_of_the_sensor_is_not_complete(variant):
    """A return at 0.5 m (4 ns: σ = 0.255 m): its shape starts before emission, where the window (from
    range 0) cannot hold it, so 2.5 % of its energy is outside and the waveform is not ``complete``;
    at 1.3 m (beyond 5σ = 1.27 m) it is, and the window's integral is the echo's energy."""
    import mitsuba as mi
    from mitsuforest.scan.waveform import device_waveforms
    from mitsuforest.scene.variant import variant_scope
    sigma = pulse_sigma(C * PULSE / 2)
    ranges, powers = np.array([[0.5], [1.3]]), np.array([[1.0], [1.0]])
    first_bin, wave, complete = sample_waveforms(ranges, powers, sigma, H, 64)
    integral = wave.sum(axis=1, dtype=np.float64) * H
    assert first_bin.tolist() == [0, 0]
    assert integral[0] == pytest.approx(echo_energy([1.0], sigma)[0] * 0.5 * (1 + math.erf(0.5 / (sigma * math.sqrt(2)))),
                                        rel=1e-5)
    assert integral[1] == pytest.approx(echo_energy([1.0], sigma)[0], rel=1e-5)
    assert complete.tolist() == [False, True]
    with variant_scope(variant):
        made = device_waveforms(mi.Float(ranges.ravel().astype(np.float32)), mi.Float(powers.ravel().astype(np.float32)),
                                1, sigma, H, 64)
        assert np.array(made["complete"]).tolist() == [False, True]


def test_device_waveforms_are_the_same_bytes_on_any_number_of_threads(variant):
    """Each bin is summed in the same order whatever the threads: 2,000 pulses of 19 returns sampled
    on one Dr.Jit thread and on four give the same bytes (lanes that added into shared bins at once
    differed from run to run in the last bits)."""
    import drjit as dr
    import mitsuba as mi
    from mitsuforest.scan.waveform import device_waveforms
    from mitsuforest.scene.variant import variant_scope
    rng = np.random.default_rng(5)
    ranges = 30.0 + rng.normal(0, 0.3, (2000, 19))                  # returns overlapping in shared bins
    powers = rng.uniform(0, 1e-3, ranges.shape)
    sigma, threads = pulse_sigma(C * PULSE / 2), dr.thread_count()
    made = []
    try:
        for count in (1, 4):
            dr.set_thread_count(count)
            with variant_scope(variant):
                out = device_waveforms(mi.Float(ranges.ravel().astype(np.float32)),
                                       mi.Float(powers.ravel().astype(np.float32)), 19, sigma, H, 64)
                made.append(np.array(out["waveform"]))
    finally:
        dr.set_thread_count(threads)
    assert made[0].tobytes() == made[1].tobytes() and made[0].max() > 0


def test_flat_plate_gives_one_peak_at_its_range_and_its_echo_energy(tmp_path, variant):
    """A plate 25 m below the sensor, face-on, a 7-sub-ray beam: one echo, one peak in the bin holding
    25 m, and the waveform's integral is the echo's energy (within 1 %)."""
    setup = analytic_scene(scene_file(tmp_path, variant=variant),
                           [(plane_model("plate", 10.0, ROCK), (20.0, 20.0, 5.0), 0.0, (0, 0), 0)])
    points, batch, sigma, first_bin, wave, complete = _records(setup, pulses([[20.0, 20.0, 30.0]], [0, 0, -1]),
                                                               samples=7, divergence=2e-3)
    assert len(points) == 1 and points["range"][0] == pytest.approx(25.0, abs=1e-3)
    peaks = _peaks(wave[0])
    assert len(peaks) == 1 and first_bin[0] + peaks[0] == math.floor(25.0 / H)
    energy = echo_energy(batch.echoes["energy"], sigma)
    assert wave[0].sum(dtype=np.float64) * H == pytest.approx(energy[0], rel=0.01)
    # face-on, the chain's power is the plate's ρ / R² (beam weights sum to 1), amplitude the same
    assert batch.echoes["energy"][0] == pytest.approx(points["intensity"][0], rel=1e-4)
    assert complete.all()


def test_two_plates_give_two_peaks_two_echoes_and_their_energies(tmp_path, variant):
    """A plate covering x < 20, 5 m above the ground, under a beam straddling its edge: echoes at 25 m
    and 30 m, two waveform peaks in their bins, and the integral is the sum of both energies."""
    setup = analytic_scene(scene_file(tmp_path, variant=variant),
                           [(plane_model("half", 20.0, ROCK), (10.0, 20.0, 5.0), 0.0, (0, 0), 0)])
    points, batch, sigma, first_bin, wave, _ = _records(setup, pulses([[20.0, 20.0, 30.0]], [0, 0, -1]),
                                                        samples=19, divergence=0.05)
    assert len(points) == 2
    assert points["range"] == pytest.approx([25.0, 30.0], abs=0.05)
    peaks = first_bin[0] + _peaks(wave[0])
    assert len(peaks) == 2
    assert np.abs((peaks + 0.5) * H - points["range"]).max() <= H
    energies = echo_energy(batch.echoes["energy"], sigma)
    assert wave[0].sum(dtype=np.float64) * H == pytest.approx(energies.sum(), rel=0.01)
    assert batch.echo_counts(batch.cast["pulse_id"]).tolist() == [2]


def test_sky_pulses_have_no_echo_and_no_waveform(tmp_path, variant):
    setup = analytic_scene(scene_file(tmp_path, variant=variant))
    _, _, batch = PulseTracer(setup[3], setup[0].sensor, 1, waveforms=True).trace_pulse_records(
        pulses([[20.0, 20.0, 30.0], [20.0, 20.0, 30.0]], [[0, 0, -1], [0.3, 0, 1]]))
    assert batch.echo_counts(batch.fired["pulse_id"]).tolist() == [1, 0]
    assert batch.cast["pulse_id"].tolist() == [0]          # a waveform for the pulse with a return only


def _bare_render(tmp_path, variant, **output):
    path = scene_file(tmp_path, variant=variant, survey={"altitude": 30, "pulse_frequency": 100000,
                                                          "scan_frequency": 50, "lines": [[[20, 19], [20, 21]]]},
                      output={"dir": str(tmp_path / "out"), **output})
    return render(path, progress=False, log=lambda *_: None)


def test_render_writes_waveforms_and_every_fired_pulse(tmp_path, variant):
    """Flat ground, the ideal 360° scanner along a 2 m leg: half its pulses go up and have no echo, those
    within 31° of nadir one each (the ground is 40 m wide: 33.7° at 30 m); every fired pulse is in
    ``_pulses.npz`` with its echo count, every pulse with a return has a waveform whose integral is its
    echo's energy, and the echo table joins the points."""
    result = _bare_render(tmp_path, variant, waveforms=True, pulses=True)
    out = tmp_path / "out"
    assert sorted(p.name for p in out.iterdir() if "spool" in p.name or p.name.startswith(".")) == []
    pulse_file, wave_file = np.load(out / "test_pulses.npz"), np.load(out / "test_waveforms.npz")
    manifest = result.manifest
    assert len(pulse_file["pulse_id"]) == manifest["pulses"]["fired"] == manifest["pulse_records"]["fired"]
    up, down = pulse_file["direction"][:, 2] > 0, pulse_file["direction"][:, 2] < -0.85
    assert up.sum() > 0.4 * len(up) and (pulse_file["echoes"][up] == 0).all()
    assert (pulse_file["echoes"][down] == 1).all()
    assert pulse_file["echoes"].sum() == manifest["points"]
    assert np.allclose(pulse_file["origin"][:, 2], 30.0, atol=1e-4)
    # the waveform file: pulses with a return, in pulse order, their echoes
    assert len(wave_file["pulse_id"]) == manifest["waveforms"]["pulses"] == np.count_nonzero(pulse_file["echoes"])
    assert wave_file["samples"].shape == (len(wave_file["pulse_id"]), 256)
    integral = wave_file["samples"].sum(axis=1, dtype=np.float64) * wave_file["bin_range"]
    energy = np.bincount(wave_file["echo_pulse"].astype(np.int64), wave_file["echo_energy"], len(integral))
    assert np.abs(integral / energy - 1).max() < 0.01
    points = _points(out)
    joined = wave_file["pulse_id"][wave_file["echo_pulse"].astype(np.int64)]
    assert np.array_equal(joined, points["pulse_id"])
    assert np.allclose(wave_file["echo_range"], points["range"])
    assert np.allclose(wave_file["echo_amplitude"], points["intensity"])
    # every waveform peaks in the bin holding its echo's range (flat ground, thin beam)
    peak = wave_file["first_bin"].astype(np.int64) + np.argmax(wave_file["samples"], axis=1)
    assert np.array_equal(peak, np.floor(wave_file["echo_range"] / wave_file["bin_range"]).astype(np.int64))


def _points(out):
    from mitsuforest.write import read_pcd
    return read_pcd(out / "test.pcd")


def test_off_by_default_no_files(tmp_path, variant):
    result = _bare_render(tmp_path, variant)
    names = {p.name for p in (tmp_path / "out").iterdir()}
    assert "test.pcd" in names and not names & {"test_waveforms.npz", "test_pulses.npz"}
    assert "waveforms" not in result.manifest and "pulse_records" not in result.manifest
    # the pulse records alone: no waveform file, and the same points
    alone = _bare_render(tmp_path / "pulses", variant, pulses=True)
    names = {p.name for p in (tmp_path / "pulses" / "out").iterdir()}
    assert "test_pulses.npz" in names and "test_waveforms.npz" not in names
    assert alone.manifest["pulse_records"]["fired"] == result.manifest["pulses"]["fired"]
    assert (tmp_path / "pulses" / "out" / "test.pcd").read_bytes() == (tmp_path / "out" / "test.pcd").read_bytes()


GOOD = """
name: t
area: {size: [10, 10]}
forest: {trees: 1}
understory: {bushes: 0, rocks: 0, deadwood: 0, stumps: 0}
sensor: SENSOR
survey: {altitude: 30, pulse_frequency: 200000}
"""


@pytest.mark.parametrize(("scene", "sensor", "message"), [
    ("output: {waveforms: 1}", "", "scene.yaml: output.waveforms: must be true or false, got 1"),
    ("output: {pulses: 'yes please'}", "", "scene.yaml: output.pulses: must be true or false, got 'yes please'"),
    ("output: {waveform: true}", "", "scene.yaml: output.waveform: unknown key (did you mean 'waveforms'?)"),
    ("", "waveform: {samples: 0}", "s.yaml: waveform.samples: must be >= 1, got 0"),
    ("", "waveform: {samples: 100000}", "s.yaml: waveform.samples: must be <= 4096, got 100000"),
    ("", "waveform: {bin_size: -1.0e-9}", "s.yaml: waveform.bin_size: must be >= 1e-11, got -1e-09"),
    ("", "waveform: {bins: 3}", "s.yaml: waveform.bins: unknown key (did you mean 'bin_size'?)"),
])
def test_bad_waveform_keys_give_one_line_and_exit_2(tmp_path, monkeypatch, capsys, scene, sensor, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "s.yaml").write_text(f"name: x\nbeam_divergence: 0.5e-3\npulse_frequencies: [200000]\n{sensor}\n")
    (tmp_path / "scene.yaml").write_text(GOOD.replace("SENSOR", "s.yaml") + scene + "\n")
    assert main(["render", "scene.yaml", "-o", "out"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"mitsuforest: {message}"
    assert not (tmp_path / "out").exists()


def test_a_dataset_cannot_split_plots_that_write_waveforms(tmp_path):
    from mitsuforest.config import ConfigError
    from mitsuforest.dataset.spec import load_dataset
    base = scene_file(tmp_path, output={"dir": str(tmp_path / "out"), "waveforms": True})
    (tmp_path / "set.yaml").write_text(f"base: {base}\nplots: 1\nlegs_per_task: 1\n")
    with pytest.raises(ConfigError, match="set.yaml: legs_per_task: cannot split plots whose scene asks for "
                                          "output.waveforms"):
        load_dataset(tmp_path / "set.yaml")
    (tmp_path / "set.yaml").write_text(f"base: {base}\nplots: 1\n")
    assert load_dataset(tmp_path / "set.yaml").plots[0].scene.output.waveforms


def test_a_full_disk_while_spooling_waveforms_names_the_file_and_leaves_nothing(tmp_path, monkeypatch, capsys):
    """A write of the waveform spool that fails (a full disk): one line naming the waveform file, exit 1,
    no staging folder and no spool left."""
    import errno

    from mitsuforest.write import waveforms

    class FullDisk:
        def write(self, data):
            raise OSError(errno.ENOSPC, "No space left on device")

        def close(self):
            pass
    monkeypatch.setattr(waveforms, "open", lambda *a, **k: FullDisk(), raising=False)
    path = scene_file(tmp_path, survey={"altitude": 30, "pulse_frequency": 100000, "scan_frequency": 50,
                                        "lines": [[[20, 19], [20, 21]]]}, output={"waveforms": True})
    out = tmp_path / "out"
    code = main(["render", str(path), "-o", str(out), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 1 and err.count("\n") == 0, err
    assert err.startswith(f"mitsuforest: {out / 'test_waveforms.npz'}: ") and "No space left on device" in err
    assert not out.exists()
