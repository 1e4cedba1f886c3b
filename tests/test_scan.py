"""The scan against analytic answers (README, "The physical model"), on every variant the machine has."""

import dataclasses

import numpy as np
import pytest
import yaml
from scipy import stats
from helpers import ROOT, analytic_scene, plane_model, pulses, scene_file

from mitsuforest.classes import GROUND, ROCK
from mitsuforest.labels import label_points, labelled
from mitsuforest.pipeline import render
from mitsuforest.scan import PulseTracer, scan
from mitsuforest.scan.radiometry import reflectance_table
from mitsuforest.testing.reference import reaching_pulses, trace_reference
from mitsuforest.testing.reference.pulses import aimed_at

RNG = np.random.default_rng(0)


@pytest.fixture(scope="module")
def flat(tmp_path_factory, variant):
    """Flat ground at z = 0 over 40 m x 40 m, ideal sensor."""
    return analytic_scene(scene_file(tmp_path_factory.mktemp("flat"), variant=variant))


def _trace(setup, p, samples=1, point_position="beam_axis", **sensor_changes):
    scene, _, _, scan_scene = setup
    sensor = dataclasses.replace(scene.sensor, **sensor_changes)
    tracer = PulseTracer(scan_scene, sensor, samples, point_position=point_position)
    return labelled(*tracer.trace_pulses(p), tracer.table)


def test_range_to_plane_is_exact(flat):
    xy = RNG.uniform(16, 24, (200, 2))
    angles = np.deg2rad(RNG.uniform(-25, 25, 200))  # lands within 16 m of the plot's centre line
    d = np.column_stack([np.sin(angles), np.zeros(200), -np.cos(angles)])
    pts = _trace(flat, pulses(np.column_stack([xy, np.full(200, 30.0)]), d))
    assert len(pts) == 200
    assert np.abs(pts["range"] - 30 / np.cos(angles)).max() < 1e-3
    assert np.abs(pts["z"]).max() < 1e-3
    assert set(pts["classification"]) == {GROUND}


def test_intensity_follows_cosine_and_inverse_square(flat):
    rho = reflectance_table(flat[0].sensor.wavelength)[GROUND]
    theta = np.deg2rad([0, 20, 40, 60, 70])
    d = np.column_stack([np.sin(theta), np.zeros(5), -np.cos(theta)])
    pts = _trace(flat, pulses(np.tile([10.0, 20, 10], (5, 1)), d))
    expected_cos = pts["intensity"] * pts["range"] ** 2 / rho
    assert np.allclose(expected_cos, np.cos(theta), rtol=0.01)
    near, far = (_trace(flat, pulses([[20, 20, h]], [0, 0, -1]))["intensity"][0] for h in (15.0, 30.0))
    assert near / far == pytest.approx(4.0, rel=1e-3)


@pytest.mark.parametrize("samples", [1, 19])
def test_reflectance_in_db_is_the_targets_at_any_range(flat, samples):
    """A Lambertian plate of reflectance ρ reads 10·log10(ρ) dB face-on at any range, and
    10·log10(ρ·cos θ) at incidence θ: the cos-law and 1/R² in dB (a thin beam exactly; a wide one's
    echo on a slope is stretched in range, so its peak reads a little lower)."""
    rho = reflectance_table(flat[0].sensor.wavelength)[GROUND]
    heights = np.array([5.0, 10.0, 30.0, 100.0, 300.0])
    face_on = _trace(flat, pulses(np.column_stack([np.full(5, 20.0), np.full(5, 20.0), heights]), [0, 0, -1]),
                     samples=samples, beam_divergence=(0.5e-3, 0.5e-3))
    assert len(face_on) == 5
    assert np.abs(face_on["reflectance"] - 10 * np.log10(rho)).max() < 0.01
    theta = np.deg2rad([20, 40, 60, 70])
    d = np.column_stack([np.sin(theta), np.zeros(4), -np.cos(theta)])
    tilted = _trace(flat, pulses(np.tile([10.0, 20, 10], (4, 1)), d), samples=samples, beam_divergence=(0.5e-3, 0.5e-3))
    error = tilted["reflectance"] - 10 * np.log10(rho * np.cos(theta))
    if samples == 1:
        assert np.abs(error).max() < 0.01
    else:   # a wide beam on a slope: the echo is stretched in range, its peak a little lower (0.05 dB at 70°)
        assert (error < 0.01).all() and (error > -0.1).all()


def test_grazing_incidence_gives_finite_values(flat):
    theta = np.deg2rad([85, 87, 89, 89.5, 89.9])
    d = np.column_stack([np.sin(theta), np.zeros(5), -np.cos(theta)])
    pts = _trace(flat, pulses(np.tile([0.5, 20, 0.05], (5, 1)), d), samples=19, beam_divergence=(1e-3, 1e-3))
    for name in ("x", "y", "z", "intensity", "range"):
        assert np.isfinite(pts[name]).all()
    assert (pts["intensity"] >= 0).all()


@pytest.mark.parametrize("pattern", ["fixed", "stratified"])
def test_an_elliptical_beam_has_its_footprint_axes_across_and_along_the_flight_line(flat, pattern):
    """beam_divergence [γ₁, γ₂] = [4, 1] mrad on a leg along +y over flat ground: near nadir, the
    footprint's energy-weighted second moments (beam.py: Σ w o oᵀ = w²/4 per axis, w = R·γ/2) are
    (R·γ₁/4)² across the track (x) and (R·γ₂/4)² along it (y), with no cross term; exact for the
    fixed pattern, in the mean over pulses for the stratified one."""
    scene, plan, _, scan_scene = flat
    gamma = (4e-3, 1e-3)
    sensor = dataclasses.replace(scene.sensor, beam_divergence=gamma)
    leg = next(leg for leg in plan.legs if 15 < leg.start[0] < 25)
    tracer = PulseTracer(scan_scene, sensor, 19, pattern=pattern)
    middle = leg.pulse_count(scene.pulse_frequency) // 2                 # over the plot's centre
    p, _ = reaching_pulses(leg, sensor, scene.pulse_frequency, scene.scan_frequency, middle, 20_000, tracer.box)
    p = p.select(np.abs(np.rad2deg(p.scan_angle)) < 1.0)
    assert np.abs(leg.frame()[1] - [0, 1, 0]).max() < 1e-12 and len(p.time) > 50
    hits = tracer.cast(p)
    assert len(hits["ray"]) == 19 * len(p.time)
    pulse = hits["ray"] // 19
    w = tracer.weights[hits["ray"] % 19]
    axis_hit = p.origin + p.direction * (p.origin[:, 2] / -p.direction[:, 2])[:, None]
    offset = hits["point"] - axis_hit[pulse]
    height = p.origin[pulse, 2]
    moments = {name: np.bincount(pulse, w * a * b / height ** 2) for name, a, b in
               (("xx", offset[:, 0], offset[:, 0]), ("yy", offset[:, 1], offset[:, 1]),
                ("xy", offset[:, 0], offset[:, 1]))}
    for name, expected in (("xx", (gamma[0] / 4) ** 2), ("yy", (gamma[1] / 4) ** 2), ("xy", 0.0)):
        m = moments[name]
        if pattern == "fixed":      # every pulse, to 0.2 % of the larger moment
            assert np.abs(m - expected).max() < 2e-3 * (gamma[0] / 4) ** 2, name
        else:                       # the mean over pulses, within 4 standard errors
            assert abs(m.mean() - expected) < 4 * m.std() / np.sqrt(len(m)), name


def test_hits_closer_than_range_min_give_no_points(flat):
    pts = _trace(flat, pulses(np.tile([20.0, 20, 2.0], (5, 1)), [0, 0, -1]), samples=7, range_min=3.0,
                 beam_divergence=(1e-3, 1e-3))
    assert len(pts) == 0
    assert len(_trace(flat, pulses([[20.0, 20, 3.5]], [0, 0, -1]), range_min=3.0)) == 1


def test_the_range_gates_cut_within_one_percent_of_their_limits(flat):
    """A plane 1 % inside range_min or range_max gives its echo, 1 % outside none: each gate is where
    the sensor says, not merely on the right side of a far target."""
    for limit, key in ((3.0, "range_min"), (30.0, "range_max")):
        for height, kept in ((limit * 0.99, key == "range_max"), (limit * 1.01, key == "range_min")):
            pts = _trace(flat, pulses([[20.0, 20.0, height]], [0, 0, -1]), **{key: limit})
            assert len(pts) == int(kept), (key, height)


def test_edge_and_vertex_hits_are_neither_lost_nor_doubled(tmp_path, variant):
    # A noise terrain of zero amplitude is a flat 1 m grid mesh: shoot through its vertices and edges.
    setup = analytic_scene(scene_file(tmp_path, variant=variant, terrain={"type": "noise", "amplitude": 0.0}))
    grid = np.stack(np.meshgrid(np.arange(5, 35, 1.0), np.arange(5, 35, 1.0)), -1).reshape(-1, 2)
    targets = np.vstack([grid, grid + [0.5, 0.0], grid + [0.5, 0.5]])  # vertices, edges, diagonals
    pts = _trace(setup, pulses(np.column_stack([targets, np.full(len(targets), 30.0)]), [0, 0, -1]))
    assert len(pts) == len(targets)
    assert np.array_equal(np.sort(pts["pulse_id"]), np.arange(len(targets)))
    assert np.abs(pts["z"]).max() < 1e-4


def test_two_half_planes_resolved_by_pulse_length(tmp_path, variant):
    """A plane covering x < 20 at height d over the ground; a 19-sub-ray beam straddles its edge."""
    pulse_length = 4e-9
    delta = 299_792_458.0 * pulse_length / 2  # ΔR = c·τ/2 = 0.60 m
    counts = {}
    for d in (0.3 * delta, 1.5 * delta):
        model = plane_model("half", 20.0, ROCK)
        setup = analytic_scene(scene_file(tmp_path / f"d{d:.2f}", variant=variant),
                               [(model, (10.0, 20.0, d), 0.0, (0, 0), 0)])
        p = pulses([[20.0, 20.0, 30.0]], [0, 0, -1])
        pts = _trace(setup, p, samples=19, beam_divergence=(0.2, 0.2), pulse_length=pulse_length)
        counts[d] = (len(pts), sorted(pts["classification"]))
    assert counts[0.3 * delta][0] == 1
    assert counts[1.5 * delta] == (2, sorted([GROUND, ROCK]))


@pytest.mark.parametrize("separation", [None, 0.26])
def test_echo_separation_is_a_sensor_property(tmp_path, variant, separation):
    """Two planes d apart under a narrow beam straddling the upper one's edge: one echo just below the
    sensor's separation (its echo_separation, else c·τ/2 = 0.60 m), two just above."""
    sensor = {"pulse_length": 4e-9, "echo_separation": separation}
    expected = separation or 299_792_458.0 * 4e-9 / 2
    assert dataclasses.replace(analytic_scene(scene_file(tmp_path / "s", variant=variant))[0].sensor,
                               **sensor).resolving_distance == pytest.approx(expected)
    for factor, echoes in ((0.9, 1), (1.1, 2)):
        d = factor * expected
        setup = analytic_scene(scene_file(tmp_path / f"d{factor}", variant=variant),
                               [(plane_model("half", 20.0, ROCK), (10.0, 20.0, d), 0.0, (0, 0), 0)])
        pts = _trace(setup, pulses([[20.0, 20.0, 30.0]], [0, 0, -1]), samples=19, beam_divergence=(0.02, 0.02),
                     **sensor)
        assert len(pts) == echoes, (d, pts["range"])


def test_surface_points_lie_on_the_surface_not_on_the_central_ray(tmp_path, variant):
    """point_position: surface. A wide beam on a 45° slope: each point is on the plane, off the beam
    axis; beam_axis puts it on the axis (x = y = 20) at the echo's range instead."""
    model = plane_model("slope", 30.0, ROCK)
    setup = analytic_scene(scene_file(tmp_path, variant=variant), [(model, (20.0, 20.0, 10.0), 0.0, (0, 45), 0)])
    p = pulses([[20.0, 20.0, 30.0]], [0, 0, -1])
    pts = _trace(setup, p, samples=19, beam_divergence=(0.05, 0.05), point_position="surface")
    normal = np.array([np.sin(np.pi / 4), 0, np.cos(np.pi / 4)])
    xyz = np.column_stack([pts["x"], pts["y"], pts["z"]])
    assert np.abs((xyz - [20, 20, 10]) @ normal).max() < 1e-3
    assert np.hypot(pts["x"] - 20, pts["y"] - 20).max() > 0.1            # the outer echoes: off the axis
    axis = _trace(setup, p, samples=19, beam_divergence=(0.05, 0.05))
    assert np.array_equal(axis["range"], pts["range"])
    assert np.abs(axis["x"] - 20).max() < 1e-5 and np.abs(axis["y"] - 20).max() < 1e-5
    assert np.abs(axis["z"] - (30 - axis["range"])).max() < 1e-5


@pytest.mark.parametrize("samples", [7, 19])
def test_beam_axis_points_of_a_plate_lie_on_it_within_the_noise(flat, samples):
    """beam_axis: wide beams at up to 40° incidence on flat ground (z = 0). Without noise each point
    lies on the ground to within the range spread the footprint's curvature leaves (second order: the
    mean range of a tilted footprint is not the axis' range by ~ w²·tan²θ/R); with σ = 2 cm the
    height residuals are N(0, (σ cos θ)²) about that."""
    n = 2000
    theta = np.deg2rad(RNG.uniform(0, 40, n))
    xy = np.column_stack([RNG.uniform(5, 15, n), RNG.uniform(5, 35, n)])
    d = np.column_stack([np.sin(theta), np.zeros(n), -np.cos(theta)])
    origin = np.column_stack([xy, np.full(n, 20.0)])
    p = pulses(origin, d)
    clean = _trace(flat, p, samples=samples, beam_divergence=(2e-3, 2e-3))
    assert len(clean) == n
    on_axis = origin[clean["pulse_id"]] + d[clean["pulse_id"]] * clean["range"][:, None].astype(float)
    assert np.abs(np.column_stack([clean["x"], clean["y"], clean["z"]]) - on_axis).max() < 1e-4
    assert np.abs(clean["z"]).max() < 2e-4
    sigma = 0.02
    noisy = _trace(flat, p, samples=samples, beam_divergence=(2e-3, 2e-3), range_precision=sigma)
    residual = noisy["z"] / np.cos(theta[noisy["pulse_id"]])               # the range error, along the axis
    assert residual.std() == pytest.approx(sigma, rel=0.05)
    assert abs(residual.mean()) < 4 * sigma / np.sqrt(n)


def test_a_pulse_straddling_a_step_lies_between_its_levels_on_the_axis(tmp_path, variant):
    """A plate covering x < 20 at height d = 0.3 ΔR over the ground; a vertical beam at x = 20 puts
    half its footprint on each level: one echo, on the axis, between the levels (rock 0.35 and ground
    0.33 are nearly equally bright, so near their mean); point_position: surface puts the same echo's
    point at the energy-weighted mean of the hit points: the same height but for the sub-rays' slant
    (30 m·(1 - cos 0.01) = 1.5 mm at most), in the air between the two plates too."""
    pulse_length = 4e-9
    d = 0.3 * 299_792_458.0 * pulse_length / 2
    setup = analytic_scene(scene_file(tmp_path, variant=variant),
                           [(plane_model("half", 20.0, ROCK), (10.0, 20.0, d), 0.0, (0, 0), 0)])
    p = pulses([[20.0, 20.0, 30.0]], [0, 0, -1])
    pts = _trace(setup, p, samples=19, beam_divergence=(0.02, 0.02), pulse_length=pulse_length)
    assert len(pts) == 1
    assert 0.2 * d < pts["z"][0] < 0.8 * d
    assert abs(pts["x"][0] - 20) < 1e-5 and abs(pts["y"][0] - 20) < 1e-5
    surface = _trace(setup, p, samples=19, beam_divergence=(0.02, 0.02), pulse_length=pulse_length,
                     point_position="surface")
    assert surface["z"][0] == pytest.approx(pts["z"][0], abs=2e-3)


def test_return_numbers_have_no_gaps(demo_result):
    pts = demo_result.points
    order = np.lexsort((pts["return_number"], pts["pulse_id"]))
    p = pts[order]
    _, first, counts = np.unique(p["pulse_id"], return_index=True, return_counts=True)
    expected = np.arange(len(p)) - np.repeat(first, counts) + 1
    assert np.array_equal(p["return_number"], expected)
    assert np.array_equal(p["number_of_returns"], np.repeat(counts, counts))
    assert (np.bincount(p["number_of_returns"])[2:].sum()) > 0  # the forest gives multiple returns


def test_strip_density_and_spacing_on_flat_ground(tmp_path, variant):
    """Line scanner over flat ground: points within |x| <= X of the track = f_p (L/v) atan(X/A) / π."""
    altitude, speed, f_p, f_s = 30.0, 2.0, 100000, 50
    path = scene_file(tmp_path, variant=variant, area={"size": [80, 20]},
                      survey={"lines": [[[40, -5], [40, 25]]], "altitude": altitude, "speed": speed,
                              "pulse_frequency": f_p, "scan_frequency": f_s})
    scene, plan, _, scan_scene = analytic_scene(path)
    result = scan(scene, plan, scan_scene, progress=False)
    pts = result.points
    leg = plan.legs[0]
    assert result.pulses_emitted == int((leg.t1 - leg.t0) * f_p)
    inside = (pts["y"] > 2) & (pts["y"] < 18)
    for half_width in (5.0, 20.0):
        count = np.sum(inside & (np.abs(pts["x"] - 40) <= half_width))
        expected = f_p * (16.0 / speed) * np.arctan(half_width / altitude) / np.pi
        assert count == pytest.approx(expected, rel=0.01)
    # Nadir spacing across track and line spacing along track.
    nadir = pts[np.abs(pts["x"] - 40) < 0.5]
    line = nadir[np.abs(nadir["gps_time"] - nadir["gps_time"][len(nadir) // 2]) < 0.5 / f_s]
    across = np.median(np.diff(np.sort(line["x"])))
    assert across == pytest.approx(altitude * 2 * np.pi * f_s / f_p, rel=0.02)
    first = nadir[np.abs(nadir["x"] - 40) < 0.01]
    along = np.median(np.diff(np.sort(first["y"])))
    assert along == pytest.approx(speed / f_s, rel=0.02)


def test_field_of_view_limits_fired_pulses(tmp_path, variant):
    path = scene_file(tmp_path, sensor="riegl_vux-1uav.yaml", variant=variant, survey={"pulse_frequency": 50000})
    scene, plan, _, scan_scene = analytic_scene(path)
    plan = dataclasses.replace(plan, legs=plan.legs[:1])
    result = scan(scene, plan, scan_scene, progress=False)
    assert result.pulses_fired == pytest.approx(result.pulses_emitted * 330 / 360, rel=1e-3)


def test_origin_offset_changes_nothing_but_the_offset(tmp_path, variant):
    base = scene_file(tmp_path / "a", variant=variant, area={"size": [10, 10]}, understory={"rocks": 3},
                      simulation={"beam_samples": 7}, sensor="riegl_vux-1uav22.yaml",
                      survey={"pulse_frequency": 100000, "line_spacing": 20, "margin": 0})
    offset = [5e5, 6e6, 100.0]
    shifted = scene_file(tmp_path / "b", variant=variant, area={"size": [10, 10]}, understory={"rocks": 3},
                         simulation={"beam_samples": 7}, sensor="riegl_vux-1uav22.yaml",
                         survey={"pulse_frequency": 100000, "line_spacing": 20, "margin": 0},
                         origin={"offset": offset})
    a = render(base, write=False, progress=False, log=lambda *_: None).points
    b = render(shifted, write=False, progress=False, log=lambda *_: None).points
    assert len(a) == len(b) > 1000
    for axis, o in zip("xyz", offset):
        assert np.abs((b[axis] - o) - a[axis]).max() < 1e-3
    assert np.array_equal(a["object_id"], b["object_id"])


def test_rays_at_known_trees_return_their_ids(demo_setup):
    scene, plan, models, scan_scene = demo_setup
    trees = plan.trees
    origins, targets = [], []
    for tree in trees:
        m = tree.matrix
        at = m[:3, :3] @ [0, 0, 1.3] + m[:3, 3]
        origins.append(at + [1.0, 0, 0])
        targets.append(at)
    d = np.array(targets) - np.array(origins)
    tracer = PulseTracer(scan_scene, dataclasses.replace(scene.sensor, range_min=0.0), 1)
    pts = labelled(*tracer.trace_pulses(pulses(origins, d)), tracer.table)
    first = pts[pts["return_number"] == 1]
    assert np.array_equal(first["instance"], [t.instance for t in trees])
    assert np.array_equal(first["treeid"], [t.treeid for t in trees])
    assert np.array_equal(first["object_id"], [t.object_id for t in trees])  # the stem, component 0
    assert set(first["classification"]) == {2}


def test_rays_at_known_leaves_are_leaves(demo_setup):
    """Sub-ray hits on a tree's leaf triangles label as leaves (the part is found on every backend:
    Embree reports a shapegroup index, OptiX the mesh)."""
    scene, plan, models, scan_scene = demo_setup
    tree = plan.trees[0]
    leaves = models[tree.model].parts[1]
    centres = leaves.vertices[leaves.faces].mean(axis=1)[::200]
    targets = centres @ tree.matrix[:3, :3].T + tree.matrix[:3, 3]
    origins = targets + [0.0, 0.0, 0.02]            # 2 cm above each leaf centre, looking down
    tracer = PulseTracer(scan_scene, dataclasses.replace(scene.sensor, range_min=0.0), 1)
    pts = labelled(*tracer.trace_pulses(pulses(origins, [0, 0, -1])), tracer.table)
    first = pts[pts["return_number"] == 1]
    assert len(first) > 0.9 * len(targets)
    assert (first["classification"] == 3).mean() > 0.95
    assert set(first["instance"]) == {tree.instance}


@pytest.mark.parametrize(("samples", "pattern", "position"), [(1, "fixed", "beam_axis"), (7, "fixed", "surface"),
                                                            (7, "stratified", "beam_axis"), (7, "stratified", "surface")])
def test_echo_kernel_matches_the_numpy_reference_in_a_forest(demo_setup, samples, pattern, position):
    """The device path (pulses, rays, labels, radiometry, waveform in Dr.Jit) against the numpy
    reference (pulses in numpy, sub-ray hits copied back, then label_hits, received_power,
    pulse_echoes) over the demo trees. The reference traces every pulse that can reach the scene's box,
    the device only those aimed at an object's proxy (scene/proxies.py): the same points."""
    scene, plan, _, scan_scene = demo_setup
    sensor = dataclasses.replace(scene.sensor, range_precision=0.0, footprint_range_noise=0.0,
                                 range_precision_per_metre=0.0, speckle_looks=0)
    leg, count = plan.legs[0], 100_000
    tree = min(plan.trees, key=lambda t: abs(t.position[0] - leg.start[0]))      # the tree nearest the track
    along = (tree.position[1] - leg.start[1]) / (leg.end[1] - leg.start[1])
    first = int(along * leg.pulse_count(scene.pulse_frequency)) - count // 2       # 1 s of flight over it
    tracer = PulseTracer(scan_scene, sensor, samples, pattern=pattern, point_position=position)
    got, hits, fired, cast = tracer.trace_slots(leg, scene.pulse_frequency, scene.scan_frequency, first, count)
    label_points(got, hits, tracer.table)
    p, ref_fired = reaching_pulses(leg, sensor, scene.pulse_frequency, scene.scan_frequency, first, count, tracer.box)
    ref = trace_reference(tracer, p)
    aimed = aimed_at(p, tracer.targets, tracer.bounds, tracer.box, sensor.range_max)
    # the pulses aimed at no object's box are not cast, nor those that miss its proxy's cells
    assert fired == ref_fired and cast < 0.9 * aimed.sum() and aimed.sum() < 0.8 * len(p.time)
    assert len(got) == len(ref) > 10_000                                     # and every pulse's points are made
    assert (ref["classification"] != GROUND).mean() > 0.2          # the pulses see trees, not just ground
    if samples > 1:
        assert (ref["number_of_returns"] > 1).mean() > 0.02
    for key in ("pulse_id", "return_number", "number_of_returns", "classification", "treeid", "instance", "object_id"):
        assert np.array_equal(got[key], ref[key]), key
    for axis in ("x", "y", "z", "range"):
        assert np.abs(got[axis] - ref[axis]).max() < 1e-4, axis
    assert np.allclose(got["intensity"], ref["intensity"], rtol=1e-4)
    assert np.abs(got["gps_time"] - ref["gps_time"]).max() < 1e-9          # float64 rounding of t0 + k/f
    assert np.abs(got["scan_angle"] - ref["scan_angle"]).max() < 1e-4


def test_only_pulses_aimed_at_an_object_box_are_cast(variant):
    """``box_mesh`` closes each box (volume its own), and ``aimed_at`` keeps a pulse whose axis meets a box
    within range, drops one that passes 1 cm beside it or whose box lies beyond range, and keeps every
    pulse fired from inside the scene's box, whatever its aim. With two sets of boxes, grown by 0 m for
    pulses within 30 m of every corner of the geometry and by 0.5 m for the rest: a pulse 0.2 m beside a
    box is dropped from 10 m up and kept from 40 m up, where the wider boxes test it."""
    import trimesh
    import mitsuba as mi
    from mitsuforest.scan.pulses import aimed_at as cast_only, upload_pulses
    from mitsuforest.scene.proxies import box_mesh
    from mitsuforest.scene.meshes import mitsuba_mesh
    from mitsuforest.scene.variant import variant_scope
    from mitsuforest.testing.reference.pulses import Pulses
    boxes = np.array([[[0, 0, 0], [1, 2, 3]], [[5, 0, 0], [6, 1, 0.5]]], float)
    v, f = box_mesh(boxes)
    for k in range(2):
        mesh = trimesh.Trimesh(v[8 * k:8 * k + 8], f[12 * k:12 * k + 12] - 8 * k)
        assert mesh.is_watertight and abs(mesh.volume) == pytest.approx(np.prod(boxes[k, 1] - boxes[k, 0]))
    down, up = [0, 0, -1], [0, 0, 1]
    origin = np.array([[0.5, 1, 10], [1.01, 1, 10], [5.5, 0.5, 10], [5.5, 0.5, 30], [0.5, 1, 1], [7, 1, 0.2],
                       [1.2, 1, 10], [1.2, 1, 40]], float)
    direction = np.array([down, down, down, down, up, up, down, down], float)
    made = Pulses(np.arange(8), np.zeros(8), origin, direction, np.tile([1.0, 0, 0], (8, 1)), np.zeros(8))
    bounds, scene_box = np.array([[0, 0, 0], [6, 2, 3]], float), np.array([[-1, -1, -1], [8, 3, 4]], float)
    sets = [(30.0, boxes), (50.0, boxes + np.array([[-0.5] * 3, [0.5] * 3]))]
    expected = [0, 2, 3, 4, 5, 7]
    with variant_scope(variant):
        targets = [(r, mi.load_dict({"type": "scene", "boxes": mitsuba_mesh("boxes", *box_mesh(b))})) for r, b in sets]
        kept = cast_only(upload_pulses(made), targets, bounds, scene_box, range_max=50.0)
        assert kept.pulse_id.numpy().tolist() == expected
        one = cast_only(upload_pulses(made), targets[:1], bounds, scene_box, range_max=20.0)
        assert one.pulse_id.numpy().tolist() == [0, 2, 4, 5]     # one set for all; pulse 3 out of its 20 m range
    assert np.flatnonzero(aimed_at(made, sets, bounds, scene_box, 50.0)).tolist() == expected


def test_ranging_noise_is_gaussian_with_the_sensor_sigma(flat):
    """Noise σ = 2 cm on a plane at 30 m: the residuals are N(0, σ²) and move points along the beam."""
    sigma, n = 0.02, 40_000
    xy = RNG.uniform(5, 35, (n, 2))
    pts = _trace(flat, pulses(np.column_stack([xy, np.full(n, 30.0)]), [0, 0, -1]), range_precision=sigma)
    residual = pts["range"] - 30.0
    assert len(pts) == n
    assert residual.std() == pytest.approx(sigma, rel=0.02)
    assert abs(residual.mean()) < 4 * sigma / np.sqrt(n)
    assert np.mean(np.abs(residual) < sigma) == pytest.approx(0.6827, abs=0.01)
    assert np.mean(np.abs(residual) < 2 * sigma) == pytest.approx(0.9545, abs=0.005)
    assert np.abs(pts["z"] + residual).max() < 1e-4             # along the (vertical) beam axis
    again = _trace(flat, pulses(np.column_stack([xy, np.full(n, 30.0)]), [0, 0, -1]), range_precision=sigma)
    assert np.array_equal(again["range"], pts["range"])         # keyed on the pulse, not drawn


@pytest.mark.parametrize(("range_m", "theta_deg"), [(20.0, 0.0), (20.0, 60.0), (50.0, 0.0), (50.0, 60.0),
                                                    (20.0, 80.0), (20.0, 87.0)])
def test_ranging_noise_grows_with_range_and_incidence_as_documented(flat, range_m, theta_deg):
    """σ(R, θ)² = σ₀² + (k_R·R)² + (f·(R·γ/4)·tan θ)² (scan/noise.py) on flat ground, an elliptical
    beam (γ = 1 mrad across, 4 mrad along the beam frame's second axis, the one the tilt lies in):
    the std of n thin-beam ranges matches σ within 4 % (its sampling error is 1/sqrt(2n) = 1.1 %).
    tan θ is capped where |cos θ| falls below 0.1 (sin θ / 0.1, 9.95 to 10, from θ = 84.3°): 80° keeps its
    5.67, 87° (19.1) is cut to 9.99."""
    sigma0, k, f, gamma, n = 0.005, 2e-4, 1.0, (1e-3, 4e-3), 4000
    theta = np.deg2rad(theta_deg)
    d = np.array([np.sin(theta), 0.0, -np.cos(theta)])
    hit = np.column_stack([RNG.uniform(10, 30, n), RNG.uniform(10, 30, n), np.zeros(n)])
    p = pulses(hit - range_m * d, d)
    p.across[:] = [0.0, -1.0, 0.0]                              # so along = d x across lies in the tilt's plane
    pts = _trace(flat, p, range_precision=sigma0, range_precision_per_metre=k,
                 footprint_range_noise=f, beam_divergence=gamma)
    assert len(pts) == n
    tan = np.sin(theta) / max(np.cos(theta), 0.1)
    expected = np.sqrt(sigma0 ** 2 + (k * range_m) ** 2 + (f * range_m * gamma[1] / 4 * tan) ** 2)
    residual = pts["range"].astype(float) - range_m
    assert residual.std() == pytest.approx(expected, rel=0.04)
    assert abs(residual.mean()) < 4 * expected / np.sqrt(n)
    assert np.array_equal(_trace(flat, p, range_precision=sigma0, range_precision_per_metre=k,
                                 footprint_range_noise=f, beam_divergence=gamma)["range"], pts["range"])


@pytest.mark.parametrize("axis", ["across", "along"])
def test_a_render_s_ranging_noise_on_a_slope_is_the_law_across_and_along_the_track(tmp_path, variant, axis):
    """A render's beam frame, not hand-made pulses: a northbound leg 25 m above a plate sloping 40° across
    the track (tilted about y) or along it (about x), an elliptical beam γ = [4, 1] mrad (across, along),
    σ₀ = 0, f = 1. Each point's range error over the ray-plane range R is N(0, σ²) with
    σ = (R/4)·sqrt((γ₁·n·e₁)² + (γ₂·n·e₂)²)/|n·d|, e₁ = (cos φ, 0, sin φ) across the beam in the scan
    plane and e₂ = +y: the z-scores' std is 1 for one fixed sub-ray (the thin beam). One stratified
    sub-ray is a random point of the footprint, whose range spreads by σ_fp already: √2 (README,
    "Ranging noise")."""
    gamma, x, tilt = (4e-3, 1e-3), 20.0, np.radians(40.0)
    normal = np.array([np.sin(tilt), 0, np.cos(tilt)]) if axis == "across" else np.array([0, -np.sin(tilt), np.cos(tilt)])
    sensor = {**yaml.safe_load((ROOT / "sensors" / "ideal.yaml").read_text()), "field_of_view": 40,
              "beam_divergence": list(gamma), "footprint_range_noise": 1.0}
    for pattern, expected in (("fixed", 1.0), ("stratified", np.sqrt(2))):
        path = scene_file(tmp_path / pattern, sensor=sensor, variant=variant,
                          survey={"altitude": 30, "speed": 10, "pulse_frequency": 50000, "scan_frequency": 100,
                                  "lines": [[[x, 15.0], [x, 25.0]]]},
                          simulation={"beam_samples": 1, "beam_pattern": pattern})
        tilts = (0.0, 40.0) if axis == "across" else (40.0, 0.0)
        scene, plan, _, scan_scene = analytic_scene(path, [(plane_model("slope", 30.0, ROCK), (x, 20.0, 5.0), 0.0,
                                                            tilts, 0)])
        result = scan(scene, plan, scan_scene, progress=False)
        pts = result.points[result.hits["object_row"] == 0]                  # on the plate (row 0), not the ground
        assert len(pts) > 4000
        phi = np.radians(pts["scan_angle"].astype(float))
        origin = np.column_stack([np.full(len(pts), x), 15.0 + 10.0 * pts["gps_time"], np.full(len(pts), 30.0)])
        d = np.column_stack([np.sin(phi), np.zeros_like(phi), -np.cos(phi)])
        true_range = ((np.array([x, 20.0, 5.0]) - origin) @ normal) / (d @ normal)
        e1 = np.column_stack([np.cos(phi), np.zeros_like(phi), np.sin(phi)])
        sigma = true_range / 4 * np.hypot(gamma[0] * (e1 @ normal), gamma[1] * normal[1]) / np.abs(d @ normal)
        z = (pts["range"] - true_range) / sigma
        assert z.std() == pytest.approx(expected, rel=0.05), pattern
        assert abs(z.mean()) < 4 * expected / np.sqrt(len(z))


def test_speckle_multiplies_the_amplitude_by_a_gamma_of_the_looks(flat):
    """speckle_looks L: the amplitude of a plate is its noiseless value times G ~ Gamma(L, 1/L): mean
    1 and variance 1/L, and the same for the same pulse."""
    n = 20_000
    xy = RNG.uniform(5, 35, (n, 2))
    p = pulses(np.column_stack([xy, np.full(n, 30.0)]), [0, 0, -1])
    clean = _trace(flat, p)["intensity"].astype(float)
    for looks in (1, 5):
        speckled = _trace(flat, p, speckle_looks=looks)
        gain = speckled["intensity"] / clean
        assert gain.mean() == pytest.approx(1.0, abs=4 / np.sqrt(looks * n))
        assert gain.var() == pytest.approx(1 / looks, rel=0.06)
        assert np.mean(gain < 1) == pytest.approx(stats.gamma.cdf(1, looks, scale=1 / looks), abs=0.015)
        assert np.array_equal(_trace(flat, p, speckle_looks=looks)["intensity"], speckled["intensity"])
        assert np.array_equal(speckled["range"], _trace(flat, p)["range"])      # the amplitude only


@pytest.mark.parametrize("pattern", ["fixed", "stratified"])
def test_same_bytes_for_any_batch_size(tmp_path, variant, pattern):
    """Ranging noise and stratified sub-rays are keyed on the pulse: pulses_per_batch changes nothing
    in the files, nor do the batches sized by the share of slots cast (``None``, the default)."""
    files = []
    for batch in (10_000, 100_000, None):
        path = scene_file(tmp_path / str(batch), sensor="riegl_vux-1uav22.yaml", variant=variant,
                          area={"size": [12, 12]}, understory={"rocks": 3},
                          survey={"pulse_frequency": 100000, "lines": [[[6, -2], [6, 14]]]},
                          simulation={"beam_samples": 7, "pulses_per_batch": batch, "beam_pattern": pattern})
        render(path, progress=False, log=lambda *_: None)
        files.append(tmp_path / str(batch) / "out")
    for suffix in (".pcd", ".laz"):
        a, *others = ((f / f"test{suffix}").read_bytes() for f in files)
        assert len(a) > 100_000 and all(a == b for b in others), suffix


@pytest.mark.parametrize("waveforms, pulse_records", [(True, False), (False, True)])
def test_a_batch_traced_in_launches_makes_the_same_points_and_waveforms(demo_setup, waveforms, pulse_records):
    """A batch's cast pulses traced in launches of at most 1000 (``launch_pulses``, as a render bounds a
    large automatic batch) give the same points, hits, echo records and waveforms (or pulse records
    without waveforms) as one launch."""
    scene, plan, _, scan_scene = demo_setup
    leg = plan.legs[0]
    first = leg.pulse_count(scene.pulse_frequency) // 2
    made = []
    for launch in (None, 1000):
        tracer = PulseTracer(scan_scene, scene.sensor, 7, seed=3, pattern="stratified", waveforms=waveforms,
                             pulse_records=pulse_records, launch_pulses=launch)
        made.append(tracer.trace_slots(leg, scene.pulse_frequency, scene.scan_frequency, first, 60_000))
    (points, hits, fired, cast, batch), (points2, hits2, fired2, cast2, batch2) = made
    assert cast == cast2 > 3000 and fired == fired2
    assert points.tobytes() == points2.tobytes() and hits.tobytes() == hits2.tobytes() and len(points) > 3000
    if pulse_records:
        assert batch.cast is None is batch2.cast and len(batch.fired["pulse_id"]) > 3000
        for key in batch.fired:
            np.testing.assert_array_equal(batch.fired[key], batch2.fired[key], err_msg=key)
    else:
        assert batch.cast.keys() == batch2.cast.keys() and len(batch.cast["samples"]) > 1000
    for key in batch.cast or {}:
        np.testing.assert_array_equal(batch.cast[key], batch2.cast[key], err_msg=key)
    for key in batch.echoes:
        np.testing.assert_array_equal(batch.echoes[key], batch2.echoes[key], err_msg=key)


def test_every_read_back_of_a_batch_waits_for_the_device_first(demo_setup, monkeypatch):
    """Dr.Jit's read-backs (``dr.compress``, ``dr.count(...)[0]``) wait for the device holding Python's
    lock (``tests/test_device_waits.py``): the scan's waits on them come first, from each place it reads."""
    import sys

    import drjit as dr

    from mitsuforest.scan import echo_kernel, pulses, waveform
    scene, plan, _, scan_scene = demo_setup
    callers = set()

    def recorded(*values):
        callers.add(sys._getframe(1).f_code.co_name)
        dr.eval(*values)
    for module in (echo_kernel, pulses, waveform):
        monkeypatch.setattr(module, "evaluate_and_wait", recorded)
    tracer = PulseTracer(scan_scene, scene.sensor, 7, seed=3, pattern="stratified", waveforms=True)
    leg = plan.legs[0]
    tracer.trace_slots(leg, scene.pulse_frequency, scene.scan_frequency, leg.pulse_count(scene.pulse_frequency) // 2,
                       20_000)
    assert callers == {"reaching_pulses", "aimed_at", "_sub_ray_returns", "_ranked_echoes", "device_waveforms"}


def test_the_next_batch_casts_about_a_million_sub_rays_within_its_bounds():
    """``next_batch``: 15 % of 200,000 slots cast at 19 sub-rays → 1e6 / (19 · 0.15) slots; at most twice
    the last batch, never under the default batch nor over the backend's most slots; a batch that cast
    nothing → twice the last, up to the most."""
    from mitsuforest.scan import MAX_BATCH_SLOTS, default_batch, next_batch
    assert next_batch("llvm_ad_mono", 19, 30_000, 200_000) == 1_000_000 * 200_000 // (30_000 * 19) == 350_877
    assert next_batch("llvm_ad_mono", 19, 15_000, 105_263) == 210_526                 # twice the last
    assert next_batch("llvm_ad_mono", 19, 90_000, 100_000) == default_batch("llvm_ad_mono", 19) == 105_263
    assert next_batch("llvm_ad_mono", 1, 100, 400_000) == MAX_BATCH_SLOTS["llvm"]
    assert next_batch("llvm_ad_mono", 19, 0, 105_263) == 210_526
    assert next_batch("cuda_ad_mono", 19, 0, 1_000_000) == MAX_BATCH_SLOTS["cuda"]


def test_variant_scope_puts_back_the_variant_it_found(variant):
    """Nested scopes, and a block that fails, leave the variant they found (this test ends with the
    process's own, whatever it was)."""
    import mitsuba as mi
    from mitsuforest.scene.variant import variant_scope
    with variant_scope("scalar_rgb"):
        with variant_scope(variant):
            assert mi.variant() == variant and mi.Float is getattr(mi, variant).Float
        assert mi.variant() == "scalar_rgb" and mi.Float is mi.scalar_rgb.Float
        with pytest.raises(ZeroDivisionError), variant_scope(variant):
            1 / 0
        assert mi.variant() == "scalar_rgb"


def test_first_variant_scope_of_a_process_leaves_its_variant():
    """Mitsuba 3.9 cannot go back to no variant: a process's first scope leaves its own (documented)."""
    import subprocess
    import sys
    script = ("import mitsuba as mi\nfrom mitsuforest.scene.variant import variant_scope\n"
              "assert mi.variant() is None\nwith variant_scope('scalar_rgb'):\n    pass\nprint(mi.variant())\n")
    proc = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and proc.stdout == "scalar_rgb\n", proc.stderr
