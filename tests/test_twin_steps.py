"""The twin's pure steps (ground, trees, foliage, understory, survey) against analytic values on
constructed inputs: no render (README, "Twins of real plots")."""

import math

import numpy as np
import pytest
import yaml

from mitsuforest.twin import detection, foliage, ground, survey, understory
from mitsuforest.twin.points import RealScan


# --- trees -------------------------------------------------------------------------------------------

def test_the_chm_cell_holds_about_four_first_returns_in_half_metre_steps():
    """2 / sqrt(density) rounded to 0.5 m within 0.5-2 m: 1 m at MixedConifer's 4.7 first returns/m²,
    0.5 m at UAS_Clip's 326.5, 1.5 m at 2/m² (1.41 m), 2 m at 1/m² and below."""
    assert detection.chm_cell(4.7) == 1.0 and detection.chm_cell(326.5) == 0.5
    assert detection.chm_cell(2.0) == 1.5 and detection.chm_cell(1.0) == 2.0 and detection.chm_cell(0.2) == 2.0


def test_the_window_is_0_6_times_popescu_and_wynnes_pine_crown_width():
    """CW = 2.51503 + 0.00901 h² (pines): 2.5511 m at 2 m, 6.1190 m at 20 m; the window is 0.6 of it."""
    settings = detection.DetectionSettings()
    assert detection.window_diameter([2.0, 20.0], settings) == pytest.approx([0.6 * 2.55107, 0.6 * 6.11903], abs=1e-9)


def test_a_lesser_top_beside_a_taller_one_is_a_tree_only_outside_its_window():
    """An 18 m top's window is 0.6 (2.51503 + 0.00901 · 18²) = 3.26 m across, a radius of 2 cells of 1 m:
    a taller top 3 cells away leaves it a tree, 2 cells away hides it."""
    settings = detection.DetectionSettings()
    for apart, tops in ((3, [[10, 5], [10, 8]]), (2, [[10, 5]])):
        chm = np.zeros((21, 21))
        chm[10, 5], chm[10, 5 + apart] = 20.0, 18.0
        assert detection.tree_tops(chm, settings).tolist() == tops


def test_a_steep_sided_crown_is_found_at_its_cell_at_its_height_with_its_disc_radius():
    """A crown 3 m in radius (29 cells of 1 m within 3 m of its top, 12-15 m high, bare ground around)
    whose top is in row 10, column 20 of a CHM with SW corner (100, 200): the tree stands at the top
    cell's centre (120.5, 210.5), as tall as the raw CHM's top (15 m: the smoothing lowers it), and its
    radius is that of a disc of 29 m², 3.04 m."""
    rows, cols = np.indices((21, 31))
    r = np.hypot(rows - 10, cols - 20)
    trees = detection.detect_trees(np.where(r <= 3.0, 15.0 - r, 0.0), 100.0, 200.0)
    assert trees.x.tolist() == [120.5] and trees.y.tolist() == [210.5] and trees.height.tolist() == [15.0]
    assert trees.crown_radius == pytest.approx([math.sqrt(29 / math.pi)], abs=1e-9)


def test_a_lower_tier_under_half_the_top_s_height_is_not_its_crown():
    """A crown 15 m tall within 2 m of its top (13 cells of 1 m: a disc of 2.03 m), ringed out to 4 m by a
    tier 6.8-7.4 m high, under half its height (7.5 m): the crown is the 13 cells (CHM unsmoothed, so
    that the 7.5 m line is the drawn one), not the 49 within 4 m (3.95 m)."""
    rows, cols = np.indices((21, 31))
    r = np.hypot(rows - 10, cols - 20)
    chm = np.where(r <= 2.0, 15.0 - r, np.where(r <= 4.0, 7.4 - 0.3 * (r - 2.0), 0.0))
    trees = detection.detect_trees(chm, 0.0, 0.0, detection.DetectionSettings(smoothing=0.0))
    assert trees.crown_radius == pytest.approx([math.sqrt(13 / math.pi)], abs=1e-9)


def test_an_isolated_cone_s_crown_is_its_cells_at_least_half_its_height():
    """A cone 15 m tall falling 1.5 m a metre, alone on bare ground: its crown is the cells at least half
    its (smoothed) top's height within the regression's crown width (4.4 m) of it, a radius of about 4.4 m."""
    rows, cols = np.indices((21, 31))
    trees = detection.detect_trees(np.maximum(15.0 - 1.5 * np.hypot(rows - 10, cols - 20), 0.0), 0.0, 0.0)
    assert trees.crown_radius == pytest.approx([4.4], abs=0.3)


def test_two_touching_cones_split_at_their_saddle():
    """Two like cones 8 m apart (15 m falling 1.5 m a metre, the CHM the higher of the two): the flood
    gives each cell off the midline to the nearer top, so the crowns are mirror images of each other."""
    rows, cols = np.indices((21, 41))
    cone = [np.maximum(15.0 - 1.5 * np.hypot(rows - 10, cols - c), 0.0) for c in (16, 24)]
    chm = np.maximum(*cone)
    tops = np.array([[10, 16], [10, 24]])
    labels = detection.crowns(chm, tops, detection.DetectionSettings(smoothing=0.0))
    off_midline = (labels > 0) & (cols != 20)
    nearer = np.where(np.abs(cols - 16) < np.abs(cols - 24), 1, 2)
    assert (labels[off_midline] == nearer[off_midline]).all()
    assert np.count_nonzero(labels[:, :20] == 1) == np.count_nonzero(labels[:, 21:] == 2) > 40


def test_an_empty_chm_cell_takes_its_lowest_neighbour():
    """A cell without returns amid cells 3-10 m high takes 3 m, the lowest around it: a gap stays a gap."""
    x, y, h = [], [], []
    for k, (i, j) in enumerate((i, j) for i in range(3) for j in range(3) if (i, j) != (1, 1)):
        x.append(i + 0.5), y.append(j + 0.5), h.append(3.0 + k)
    chm = detection.canopy_height_model(np.array(x), np.array(y), np.array(h), 0.0, 0.0, (3, 3), 1.0)
    assert chm[1, 1] == 3.0


def test_f1_is_the_harmonic_mean_of_precision_and_recall():
    """Four trees found, two of them on the two true trees: precision 0.5, recall 1, F1 2/3."""
    found = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0], [30.0, 0.0]])
    s = detection.scores(found, np.array([[0.5, 0.0], [10.0, 0.5]]), 2.0)
    assert (s["matched"], s["precision"], s["recall"]) == (2, 0.5, 1.0)
    assert s["f1"] == pytest.approx(2 / 3)


# --- foliage -----------------------------------------------------------------------------------------

def test_crown_lai_is_minus_cos_theta_ln_p_over_one_half():
    """LAI = -cos θ · ln P / 0.5 (spherical leaves, G = 0.5): a gap fraction of 1/e is LAI 2 seen at
    nadir, 1 at 60°; a crown that no pulse passes is clipped at P = 0.005, LAI 10.6, not infinite."""
    assert foliage.effective_lai(math.exp(-1.0), 0.0) == pytest.approx(2.0, rel=1e-12)
    assert foliage.effective_lai(math.exp(-1.0), 60.0) == pytest.approx(1.0, rel=1e-12)
    assert foliage.effective_lai(0.0, 0.0) == pytest.approx(-math.log(0.005) / 0.5, rel=1e-12)


def test_a_cone_holds_half_its_volume_in_the_top_0_781_of_its_length():
    """Crown radius going as depth^0.9: the volume above depth s goes as s^2.8, half of it at 0.5^(1/2.8)
    = 0.7807. Returns of exact quantiles (no random draw) of cone crowns give their ratio back within 0.002."""
    assert foliage.CONE_MEDIAN_DEPTH == pytest.approx(0.7807, abs=1e-4)
    n = 200_000
    stopped_at = -np.log(1 - (np.arange(n) + 0.5) / n)       # foliage passed before a hit: exponential quantiles
    for ratio in (0.3, 0.42, 0.8):
        rel = np.where(stopped_at < 2.0, 1.0 - ratio * (np.minimum(stopped_at, 2.0) / 2.0) ** (1 / 2.8), 0.0)
        assert foliage.crown_ratio(rel) == pytest.approx(ratio, abs=0.002)


def test_a_tree_with_1000_returns_gets_its_own_crown_ratio_and_one_with_999_the_stand_s():
    """README: a tree with at least 1,000 returns under its crown gets its own ratio."""
    n = 1000
    stopped_at = -np.log(1 - (np.arange(n) + 0.5) / n)
    rel = np.where(stopped_at < 2.0, 1.0 - 0.6 * (np.minimum(stopped_at, 2.0) / 2.0) ** (1 / 2.8), 0.0)
    h = np.r_[rel, rel[:999]] * 20.0
    x = np.r_[np.zeros(1000), np.full(999, 10.0)]
    ratios = foliage.tree_crown_ratios(x, np.zeros(1999), h, np.array([0.0, 10.0]), np.zeros(2),
                                       np.full(2, 20.0), np.full(2, 2.0), stand=0.42)
    assert ratios[0] == pytest.approx(0.6, abs=0.02) and ratios[1] == 0.42


def test_returns_beyond_a_crown_s_radius_are_not_under_it():
    """A tree of crown radius 2 m: returns 1.9 m from its stem are under its crown, 2.1 m and 3 m not."""
    rel = foliage.relative_heights_under_crowns([1.9, 2.1, 3.0], [0.0, 0.0, 0.0], [10.0, 10.0, 10.0],
                                                [0.0], [0.0], [20.0], [2.0])
    assert rel.tolist() == [0.5]


# --- ground ------------------------------------------------------------------------------------------

def _flat_plot_with_a_dense_shrub_and_a_pit():
    """30 x 30 m at 0.5 m spacing: ground at 100 m and low returns 0.2 and 0.5 m above it, except a
    4 x 4 m shrub (2 m cells 6-7 in x and y) whose returns, all 0.6 m up, hide the ground; one return
    1 m below the ground (a pit, or a low outlier) in cell (1, 12)."""
    g = np.arange(0.25, 30.0, 0.5)
    x, y = (v.ravel() for v in np.meshgrid(g, g, indexing="ij"))
    shrub = (x >= 12) & (x < 16) & (y >= 12) & (y < 16)
    xs = np.r_[x[~shrub], x[~shrub], x[~shrub], x[shrub], 3.1]
    ys = np.r_[y[~shrub], y[~shrub], y[~shrub], y[shrub], 25.1]
    zs = np.r_[np.full((~shrub).sum(), 100.0), np.full((~shrub).sum(), 100.2), np.full((~shrub).sum(), 100.5),
               np.full(shrub.sum(), 100.6), 99.0]
    return xs, ys, zs


def test_the_fallback_ground_filter_keeps_cell_minima_near_their_neighbourhood_median():
    """README: the lowest return of each 2 m cell is kept where it is within 0.5 m of the median of the
    5 x 5 cell minima around it, and every point within 0.3 m above that surface is ground. The shrub's
    cells (minimum 0.6 m above the median) are dropped and their surface interpolated at 100 m, so the
    shrub is not ground; the returns 0.2 m up are, those 0.5 m up are not; the pit's cell keeps its
    minimum but the median does not let it drag its neighbours' cells down."""
    x, y, z = _flat_plot_with_a_dense_shrub_and_a_pit()
    found = ground.lowest_point_filter(x, y, z)
    pit_cell = (np.floor(x / 2) == 1) & (np.floor(y / 2) == 12)
    assert found[z == 99.0].all()
    assert np.array_equal(found[~pit_cell], z[~pit_cell] <= 100.2)


def test_ground_height_is_bilinear_between_cell_centres():
    """A DEM of 2 m cells from (10, 20) holding the plane z = 2 + 0.1 x + 0.3 y at its cell centres gives
    that plane anywhere between the centres (bilinear is exact on a plane)."""
    ny, nx = 4, 6
    cx = 10.0 + (np.arange(nx) + 0.5) * 2.0
    cy = 20.0 + (np.arange(ny) + 0.5) * 2.0
    grid = 2.0 + 0.1 * cx[None, :] + 0.3 * cy[:, None]
    rng = np.random.default_rng(4)
    x, y = rng.uniform(cx[0], cx[-1], 200), rng.uniform(cy[0], cy[-1], 200)
    assert ground.ground_height(grid, 10.0, 20.0, 2.0, x, y) == pytest.approx(2.0 + 0.1 * x + 0.3 * y, abs=1e-9)


# --- understory --------------------------------------------------------------------------------------

def test_shrubby_cells_hold_a_quarter_of_the_median_cell_s_returns_from_0_5_to_3_m():
    """200 cells of 1 m, 20 ground returns each, in a plot of 600 (400 empty, which do not count); the
    median cell holds 20 returns, so a cell is shrubby with 5 returns 0.5-3 m up. Columns 0-3 hold 10
    (shrubby), column 4 10 at 4 m (branches: no), column 5 3 (no), column 6 5 (yes, exactly a quarter),
    column 7 10 at 0.3 m (litter: no). 50 shrubby m² over a 1.8 m bush crown's 2.54 m²: 20 bushes."""
    xs, ys, hs = [], [], []
    for i in range(10):
        for j in range(20):
            extra = {0: (10, 1.0), 1: (10, 1.0), 2: (10, 1.0), 3: (10, 1.0), 4: (10, 4.0), 5: (3, 1.0),
                     6: (5, 1.0), 7: (10, 0.3)}.get(j, (0, 0.0))
            k = 20 + extra[0]
            xs.append(j + (np.arange(k) + 0.5) / k), ys.append(np.full(k, i + 0.5))
            hs.append(np.r_[np.zeros(20), np.full(extra[0], extra[1])])
    cells = understory.shrub_cells(np.concatenate(xs), np.concatenate(ys), np.concatenate(hs), 0.0, 0.0, (10, 60))
    assert cells.sum(axis=0)[:8].tolist() == [10, 10, 10, 10, 0, 0, 10, 0] and cells.sum() == 50
    assert understory.bush_count(cells) == round(50 / (math.pi * 0.9 ** 2)) == 20


# --- survey ------------------------------------------------------------------------------------------

def _two_line_scan():
    """Line 1: a scanner at 130 m over ground at 500 m (file heights), flying +y at 9 m/s and climbing
    0.3 m/s over x = 0 for 10 s, 1,000 pulses across ±35°, each with a first return 10 m above the
    ground and a last one on it. Line 2: 10 such pulses (too few for a track) from 60 m east, all
    landing 30 m west of it (scan angle atan(30/130) = 13.0°)."""
    cols = {k: [] for k in ("x", "y", "z", "t", "rn", "angle", "source")}

    def pulse(scanner, target_x, t, source):
        s = np.array(scanner)
        g = np.array([target_x, s[1], 500.0])
        angle = math.degrees(math.atan2(target_x - s[0], s[2] - 500.0))
        for rn, point in ((1, s + (g - s) * (s[2] - 510.0) / (s[2] - 500.0)), (2, g)):
            for k, v in zip(("x", "y", "z", "t", "rn", "angle", "source"), (*point, t, rn, angle, source)):
                cols[k].append(v)

    for i in range(1000):
        t = i * 0.01
        z = 630.0 + 0.3 * (t - 5.0)
        pulse((0.0, -45.0 + 9.0 * t, z), (z - 500.0) * math.tan(math.radians(-35.0 + 70.0 * (i % 50) / 49)), t, 1)
    for i in range(10):
        pulse((60.0, 0.5 * i, 630.0), 30.0, 20.0 + 0.01 * i, 2)
    c = {k: np.array(v) for k, v in cols.items()}
    n = len(c["x"])
    return RealScan("synthetic", c["x"], c["y"], c["z"], None, c["rn"].astype(np.int16), np.full(n, 2, np.int16),
                    c["t"], c["angle"], c["source"].astype(np.int32), None, None)


def test_the_survey_of_a_straight_climbing_line_and_a_short_one():
    """Line 1's beams meet on its track: 130 m above the mean ground (at t_mid, 4.995 s), 9 m/s over the
    ground (the climb is not speed), heading 0°; the field of view is twice the largest scan angle, 70°.
    Line 2, without a track, is placed parallel on the side its beams point to (east), as far across as
    its median scan angle says at the sensor's height, which puts it back on x = 60 m."""
    est = survey.estimate(_two_line_scan(), 500.0)
    assert est.lines == 2 and est.line_sources == ("track", "scan angle")
    assert est.altitude == pytest.approx(130.0 + 0.3 * (4.995 - 5.0), abs=1e-6)
    assert est.speed == pytest.approx(9.0, rel=1e-6)
    assert min(est.heading, 180.0 - est.heading) == pytest.approx(0.0, abs=1e-6)
    assert est.field_of_view == pytest.approx(70.0)
    assert est.line_positions[0] == pytest.approx((0.0, -45.0 + 9.0 * 4.995), abs=1e-6)
    assert est.line_positions[1][0] == pytest.approx(60.0, abs=0.01)


def _first_returns_of_an_airborne_line(heading, nadir, oscillating=True, height=800.0, speed=60.0, seed=0):
    """First returns only (one point a pulse, no two at one time) in a 90 x 90 m plot at the origin, from a
    sensor ``height`` m over flat ground (z = 0) flying ``heading`` (deg) at ``speed`` m/s along a line
    through ``nadir`` (x, y) at t = 10 s, sweeping ±20° 60 times a second: an oscillating mirror there and
    back at 50 kHz, or a rotating one firing over 40° of each turn at 450 kHz. Each pulse's return is at a
    random height of 0-20 m (a canopy); scan angles are rounded to whole degrees (LAS 1.2, positive to the
    right of the flight) and GPS times to the microsecond."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 20.0, 1 / (50_000 if oscillating else 450_000))
    phase = (t * 60.0) % 1.0
    theta = np.radians((4 * np.abs(phase - 0.5) - 1) * 20.0 if oscillating else (phase - 0.5) * 360.0)
    fired = np.abs(theta) <= np.radians(20.0) + 1e-12
    t, theta = t[fired], theta[fired]
    h = np.radians(heading)
    along, right = np.array([np.sin(h), np.cos(h)]), np.array([np.cos(h), -np.sin(h)])
    z = rng.uniform(0.0, 20.0, len(t))
    xy = np.asarray(nadir) + np.outer(speed * (t - 10.0), along) + np.outer((height - z) * np.tan(theta), right)
    keep = (np.abs(xy[:, 0]) <= 45) & (np.abs(xy[:, 1]) <= 45)
    n = int(keep.sum())
    ones = np.ones(n, np.int16)
    return RealScan("synthetic", xy[keep, 0], xy[keep, 1], z[keep], None, ones, ones.copy(),
                    np.round(t[keep] + 1e5, 6), np.round(np.degrees(theta[keep])), None, None, None, first_only=True)


@pytest.mark.parametrize("oscillating", [True, False])
def test_a_first_return_file_s_flight_line_from_its_scan_angles(oscillating):
    """An airborne line of first returns only (no beam to fit a track to) over a plot off its nadir: its
    sweeps' positions against their whole-degree scan angles give the sensor's height (800 m), the flight
    square to them its heading (72°) and speed (60 m/s), its nadir line (100 m to the plot's right of the
    line through the origin), and their senses the mirror (there and back: 60 cycles, 120 scan lines a
    second; one way: 60 turns). Rounding the angles to whole degrees moves a point up to 7 m."""
    heading, nadir = 72.0, (-100 * math.cos(math.radians(72.0)), 100 * math.sin(math.radians(72.0)))
    est = survey.estimate(_first_returns_of_an_airborne_line(heading, nadir, oscillating), 0.0)
    assert est.tracks == () and est.line_sources == ("scan lines",)
    assert est.altitude == pytest.approx(800.0, abs=4.0)
    assert est.line_headings[0] == pytest.approx(heading, abs=0.5)
    assert est.speed == pytest.approx(60.0, rel=0.01)
    assert np.asarray(est.line_positions[0]) @ [math.cos(math.radians(72.0)), -math.sin(math.radians(72.0))] \
        == pytest.approx(-100.0, abs=2.0)
    assert est.deflector == ("oscillating" if oscillating else "rotating")
    assert est.scan_frequency == pytest.approx(120.0 if oscillating else 60.0, rel=0.01)
    assert "altitude" not in est.missing


def test_the_side_of_the_flight_a_file_counts_its_scan_angles_positive_on():
    """The airborne line above counts its angles positive to the right of its flight, as LAS does; the
    same line with its angles negated (as some files keep them) counts them to the left. Its geometry
    is the same either way: the sweeps place the line where it flew."""
    heading, nadir = 72.0, (-100 * math.cos(math.radians(72.0)), 100 * math.sin(math.radians(72.0)))
    scan = _first_returns_of_an_airborne_line(heading, nadir)
    mirrored = RealScan(**{**scan.__dict__, "scan_angle": -scan.scan_angle})
    est, flipped = survey.estimate(scan, 0.0), survey.estimate(mirrored, 0.0)
    assert (est.scan_angle_side, flipped.scan_angle_side) == ("right", "left")
    assert np.allclose(est.line_positions, flipped.line_positions, atol=0.5)
    assert flipped.line_headings[0] == pytest.approx(heading, abs=0.5)


@pytest.mark.parametrize("oscillating", [True, False])
def test_a_twin_sensor_has_the_optics_of_a_scanner_with_its_files_mirror(tmp_path, oscillating):
    """The airborne line above: an oscillating mirror's twin gets the Leica ALS50-II's optics (1064 nm,
    0.22 mrad, 10 ns, 4 returns told apart from 2.7 m, where the pulse shape alone says 1.5 m), a rotating
    one's the VUX-1UAV22's (1550 nm, 0.5 mrad, 4 ns, 15 returns); each as in its shipped sensor file, and
    the twin's sensor loads as a sensor. Both reach twice the slant range at the edge of their field of view
    and detect a hundredth of bare ground's echo at nadir at their own wavelength (ground 0.30 at 1064 nm,
    0.33 at 1550 nm)."""
    from mitsuforest.classes import GROUND
    from mitsuforest.config import BUILTIN_SENSORS, load_sensor
    from mitsuforest.scan import radiometry
    from mitsuforest.twin import TwinFrame, scene
    heading, nadir = 72.0, (-100 * math.cos(math.radians(72.0)), 100 * math.sin(math.radians(72.0)))
    est = survey.estimate(_first_returns_of_an_airborne_line(heading, nadir, oscillating), 0.0)
    analysis = {"survey": est, "pulse_density": 4.0, "frame": TwinFrame((-45.0, -45.0, 0.0), (90.0, 90.0)),
                "scan_angle": 7.0, "intensity_unit": ("amplitude", "a test")}
    _, sensor, report = scene.survey_plan(analysis)
    (tmp_path / "twin.yaml").write_text(yaml.safe_dump(sensor))
    twin = load_sensor(tmp_path / "twin.yaml")
    shipped = load_sensor(BUILTIN_SENSORS / ("leica_als50-ii.yaml" if oscillating else "riegl_vux-1uav22.yaml"))
    for key in ("beam_divergence", "pulse_length", "wavelength", "range_precision", "range_accuracy",
                "max_returns", "echo_separation"):
        assert getattr(twin, key) == getattr(shipped, key), key
    assert (twin.wavelength, twin.beam_divergence[0], twin.max_returns) == \
        ((1064e-9, 0.22e-3, 4) if oscillating else (1550e-9, 0.5e-3, 15))
    assert twin.resolving_distance == (2.7 if oscillating else pytest.approx(299_792_458 * 4e-9 / 2))
    assert twin.name == f"twin sensor ({'Leica ALS50-II' if oscillating else 'RIEGL VUX-1UAV22'} optics)"
    assert ("Leica ALS50-II's optics" if oscillating else "VUX-1UAV22's optics") in report["sensor"]["source"]
    assert twin.range_max == 10 * math.ceil(2 * est.altitude / math.cos(math.radians(twin.field_of_view / 2)) / 10)
    ground = radiometry.received_power(1.0, radiometry.reflectance_table(twin.wavelength)[GROUND], 1.0, est.altitude)
    assert 0.0099 * ground < twin.detection_threshold < 0.0101 * ground


def test_an_oscillating_mirror_that_turns_inside_the_plot_still_gives_its_line():
    """A UAV at 60 m sweeping ±20° (±22 m) over the middle of the plot, 8 m/s heading 30°: the mirror turns
    inside the plot, so there is no pause between one sweep and the next. Cut where the angles turn back,
    its 1,829 sweeps (120 a second over the 11 s it takes to cross the plot) give 60 m, 30°, 8 m/s and a
    mirror there and back at 120 scan lines a second; uncut, its bursts held 263 sweeps (those the plot's
    corners cut apart), and before a sweep's fit was checked, a burst of many ran the line 311° at 0.1 m/s."""
    scan = _first_returns_of_an_airborne_line(30.0, (0.0, 0.0), height=60.0, speed=8.0)
    line, _ = survey.nadir_line(scan.x, scan.y, scan.z, scan.gps_time, scan.scan_angle)
    assert line.sweeps >= 1800
    est = survey.estimate(scan, 0.0)
    assert est.line_sources == ("scan lines",) and est.deflector == "oscillating"
    assert est.altitude == pytest.approx(60.0, abs=1.0)
    assert est.line_headings[0] == pytest.approx(30.0, abs=1.0) and est.speed == pytest.approx(8.0, rel=0.02)
    assert est.scan_frequency == pytest.approx(120.0, rel=0.01)
    assert np.hypot(*est.line_positions[0]) < 1.0


def test_a_sweep_that_its_angles_do_not_fit_is_not_used():
    """The same airborne line with its scan angles shuffled among its points (a file whose angles are not
    the beams'): no sweep fits within 1°, so no line is placed and the reason says what a sweep needs;
    with every angle 0 or 1° no burst is a sweep either."""
    line = _first_returns_of_an_airborne_line(72.0, (0.0, 100.0))
    shuffled = RealScan(**{**line.__dict__, "scan_angle": np.random.default_rng(1).permutation(line.scan_angle)})
    flat = RealScan(**{**line.__dict__, "scan_angle": (line.scan_angle > 0).astype(float)})
    for scan in (shuffled, flat):
        est = survey.estimate(scan, 0.0)
        assert est.altitude is None and est.line_positions == ()
        assert ("sweeps (bursts of 10 returns or more over 2° of scan angle or more, fitted within 1°)"
                in est.missing["altitude"])


def test_sweeps_place_a_line_whose_beams_fit_no_track():
    """The airborne line with 200 of its pulses given a last return 6 m under the first but up to 4 m aside
    at random (beams that point nowhere in common): their track misses them by metres, over GOOD_TRACK, so
    the sweeps place the line (800 m, 72°) rather than that track."""
    line = _first_returns_of_an_airborne_line(72.0, (-100 * math.cos(math.radians(72.0)), 100 * math.sin(math.radians(72.0))))
    rng = np.random.default_rng(2)
    pick = rng.choice(len(line.x), 200, replace=False)
    twos = np.full(len(line.x), 1, np.int16)
    twos[pick] = 2
    last = {"x": line.x[pick] + rng.uniform(-4, 4, 200), "y": line.y[pick] + rng.uniform(-4, 4, 200),
            "z": line.z[pick] - 6.0}
    scan = RealScan("synthetic", np.r_[line.x, last["x"]], np.r_[line.y, last["y"]], np.r_[line.z, last["z"]], None,
                    np.r_[np.ones(len(line.x), np.int16), np.full(200, 2, np.int16)], np.r_[twos, np.full(200, 2, np.int16)],
                    np.r_[line.gps_time, line.gps_time[pick]], np.r_[line.scan_angle, line.scan_angle[pick]],
                    None, None, None)
    est = survey.estimate(scan, 0.0)
    assert len(est.tracks) == 1 and est.tracks[0].residual > survey.GOOD_TRACK
    assert est.line_sources == ("scan lines",) and est.altitude == pytest.approx(800.0, abs=5.0)
    assert est.line_headings[0] == pytest.approx(72.0, abs=0.5)


def test_a_file_without_beams_or_scan_angles_says_why_its_line_is_not_placed():
    """The same line without scan angles: no altitude, speed or lines, and the reason names both what a
    track and what a nadir line needs."""
    scan = _first_returns_of_an_airborne_line(90.0, (0.0, 0.0))
    est = survey.estimate(RealScan(**{**scan.__dict__, "scan_angle": None}), 0.0)
    assert est.altitude is None and est.line_positions == () and est.deflector is None
    assert "scan angles" in est.missing["altitude"] and "first and a last return" in est.missing["altitude"]


def test_the_twin_sensor_reads_bare_ground_at_its_ground_counts_and_detects_a_hundredth_of_it():
    """The intensity mapping puts a flat ground's echo at the file's median scan angle (the Lambertian
    radiometry of the scan) at GROUND_COUNTS, for a 127 m UAV survey and an 800 m airborne one. A survey
    within half the VUX-1UAV22's 1000 m keeps its range; an 800 m one at ±20° reaches twice its 851 m
    slant range. The threshold is the data sheet's (0.2 / 1000²) until that is over a hundredth of bare
    ground's echo at nadir (above 128 m), then that hundredth: an echo of 1.01 % of the ground's is
    detected from 800 m, one of 0.99 % is not."""
    from mitsuforest.classes import GROUND
    from mitsuforest.config.types import IntensityMapping
    from mitsuforest.scan import radiometry
    from mitsuforest.twin import scene
    rho = radiometry.reflectance_table(1550e-9)[GROUND]
    for altitude, angle in ((127.0, 56.0), (800.0, 7.0)):
        cos = math.cos(math.radians(angle))
        amplitude = radiometry.received_power(1.0, rho, cos, altitude / cos)
        mapping = IntensityMapping(**scene.intensity_scale(altitude, angle))
        assert int(radiometry.intensity_counts(np.array([amplitude]), np.array([0.0]), mapping)[0]) == \
            pytest.approx(scene.GROUND_COUNTS, abs=2)
    assert scene.sensor_reach(127.0, 140.0) == {"range_max": 1000.0, "detection_threshold": 2e-7}
    far = scene.sensor_reach(800.0, 40.0)
    assert far["range_max"] == 10 * math.ceil(2 * 800 / math.cos(math.radians(20)) / 10) == 1710
    ground = radiometry.received_power(1.0, rho, 1.0, 800.0)
    assert 0.0099 * ground < far["detection_threshold"] < 0.0101 * ground


def test_the_twin_flies_the_field_of_view_its_file_shows_rounded_up_to_5_degrees():
    """Twice the largest scan angle, rounded up to 5°: MixedConifer's whole-degree angles up to 18 give 40°
    (to the nearest degree, 36°, its lines inside the plot held 11 % more first returns a m² than the
    file's, within 2 % at 40°: the file's swaths were trimmed), UAS_Clip's 69.996° (0.006° steps) 140°;
    within 5-360°, and nothing without scan angles."""
    from mitsuforest.twin.scene import field_of_view_seen
    assert field_of_view_seen(2 * 18.0) == 40
    assert field_of_view_seen(2 * 69.996) == 140
    assert field_of_view_seen(2 * 17.5) == 35 and field_of_view_seen(0.0) == 5
    assert field_of_view_seen(2 * 190.0) == 360 and field_of_view_seen(None) is None


def _returns_seen_from(sensor_z, angles, intensity_of_range, scatter=0.3):
    """First returns at heights 0-20 m seen from ``sensor_z`` at ``angles`` (deg), each with the intensity
    ``intensity_of_range(range)`` times a lognormal scatter (``scatter``: its sigma)."""
    rng = np.random.default_rng(5)
    z = rng.uniform(0.0, 20.0, len(angles))
    r = (sensor_z - z) / np.cos(np.radians(angles))
    counts = np.round(intensity_of_range(r) * rng.lognormal(0.0, scatter, len(r)))
    ones = np.ones(len(r), np.int16)
    return RealScan("synthetic", np.zeros(len(r)), np.zeros(len(r)), z, None, ones, ones.copy(), None, angles,
                    None, counts, None)


def test_an_intensity_that_does_not_fall_with_range_is_a_reflectance_in_db_where_its_band_is_narrow():
    """A UAV at 130 m seeing its returns at 20-70° (ranges 110-380 m): counts going as 1/R² are an
    amplitude; counts that keep their level are a reflectance, in dB where their 5th to 95th percentiles
    span under 10 times (a lognormal scatter of sigma 0.3: 2.7 times), linear where they span more (sigma
    1: 27 times). From 800 m at 5-18° the ranges span 8 %, too alike to tell, so the twin keeps the
    amplitude and says why, as it does for a file without a varying intensity."""
    from mitsuforest.twin import intensity
    angles = np.random.default_rng(6).uniform(20.0, 70.0, 5000)
    amplitude = _returns_seen_from(130.0, angles, lambda r: 4e8 / r ** 2)
    level = _returns_seen_from(130.0, angles, lambda r: np.full(len(r), 40_000.0))
    linear = _returns_seen_from(130.0, angles, lambda r: np.full(len(r), 4_000.0), scatter=1.0)
    assert intensity.range_slope(amplitude.intensity, intensity.first_return_ranges(amplitude.z, angles, 130.0)) \
        == pytest.approx(-2.0, abs=0.05)
    assert intensity.intensity_unit(amplitude, 130.0)[0] == "amplitude"
    assert intensity.intensity_unit(level, 130.0)[0] == "reflectance_db"
    assert intensity.intensity_unit(linear, 130.0)[0] == "reflectance"
    narrow = _returns_seen_from(800.0, angles * 18 / 70, lambda r: 4e8 / r ** 2)
    assert intensity.intensity_unit(narrow, 800.0) == ("amplitude", "its first returns' ranges are too alike "
                                                       "(within 1.5 times) to tell")
    assert intensity.intensity_unit(RealScan(**{**level.__dict__, "intensity": None}), 130.0) == \
        ("amplitude", "the file's intensity cannot be set against range (it has no intensity that varies)")


def test_the_heading_is_the_axial_mean_of_lines_flown_either_way():
    """Tracks heading 28° and 212° (flown back along 32°), clockwise from +y: the lines' axis is 30°."""
    def track(deg, rays):
        v = (9 * math.sin(math.radians(deg)), 9 * math.cos(math.radians(deg)), 0.0)
        return survey.Track((0.0, 0.0, 0.0), v, 0.0, (0.0, 1.0), rays, 0.0)
    assert survey._heading([track(28.0, 100), track(212.0, 100)]) == pytest.approx(30.0, abs=1e-9)


def test_the_scan_period_ignores_spacings_doubled_by_missed_bursts():
    """Bursts every 12 ms, every other one missed over the first 70: 35 spacings of 24 ms, 29 of 12 ms;
    the period is 12 ms, not the median spacing of 24 ms."""
    starts = [0.012 * k for k in range(100) if k >= 70 or k % 2 == 0]
    assert survey.scan_period([np.array([s, s + 0.001]) for s in starts]) == pytest.approx(0.012)


def test_a_leg_runs_along_its_heading_over_the_plot_and_its_margin():
    """Heading 90° (east) through (0, 5) over a 20 x 10 m plot with 10 m margins: from (-10, 5) to
    (30, 5); heading 0° (north) through (5, 0): from (5, -10) to (5, 20)."""
    east = np.array(survey.leg_ends((0.0, 5.0), 90.0, (0, 0, 20, 10), 10.0))
    north = np.array(survey.leg_ends((5.0, 0.0), 0.0, (0, 0, 20, 10), 10.0))
    assert east == pytest.approx(np.array([[-10.0, 5.0], [30.0, 5.0]]), abs=1e-9)
    assert north == pytest.approx(np.array([[5.0, -10.0], [5.0, 20.0]]), abs=1e-9)


def test_a_rotating_mirror_s_scan_lines_cut_in_pieces_are_counted_once():
    """A UAV at 60 m, its mirror turning 60 times a second, whose returns between -5 and +8° of scan angle
    are lost (0.6 ms of each turn: a crown beyond a clipped plot's ground is seen apart from the rest of its
    scan line): each scan line is two bursts, whose starts had said 786 scan lines a second; the sweeps'
    nadir crossings say 60."""
    line = _first_returns_of_an_airborne_line(72.0, (0.0, 0.0), oscillating=False, height=60.0, speed=8.0)
    lost = (line.scan_angle >= -5) & (line.scan_angle < 8)
    cut = RealScan(**{**line.__dict__, **{k: getattr(line, k)[~lost] for k in
                                          ("x", "y", "z", "return_number", "number_of_returns", "gps_time", "scan_angle")}})
    assert 1 / survey.scan_period(survey.bursts(cut.gps_time)) > 700
    est = survey.estimate(cut, 0.0)
    assert est.deflector == "rotating" and est.scan_frequency == pytest.approx(60.0, rel=0.001)
    assert survey.crossing_period(cut.gps_time, cut.scan_angle) == pytest.approx(1 / 60, rel=0.001)


def test_a_risley_rosette_s_sweeps_say_no_mirror_scan_rate_or_flight():
    """First returns of a Livox Mid-70's rosette (prisms of 17.6° at 121.57 and -77.73 turns a second, the
    scan angle off the nadir: never negative) from 35 m, flying north at 6 m/s over a 24 m plot: cut where
    its angle turns back, its petals are sweeps that fit, but they run every way, not parallel as a line
    scanner's scan lines do (a render of the Mid-70's had its twin flown by an oscillating mirror at 108
    cycles a second, 2 m/s where it flew 6 m/s, one line 7 m off): the mirror, scan rate, line, speed and
    altitude are missing, saying why."""
    t = np.arange(0.0, 8.0, 1e-5)
    a1, a2 = 2 * np.pi * 121.57 * t, -2 * np.pi * 77.73 * t
    ax, ay = np.radians(17.6) * (np.cos(a1) + np.cos(a2)), np.radians(17.6) * (np.sin(a1) + np.sin(a2))
    off = np.hypot(ax, ay)
    z = np.random.default_rng(3).uniform(0.0, 10.0, len(t))
    reach = (35.0 - z) * np.tan(off) / np.maximum(off, 1e-12)
    x, y = 12.0 + reach * ax, -12.0 + 6.0 * t + reach * ay
    keep = (x >= 0) & (x <= 24) & (y >= 0) & (y <= 24)
    ones = np.ones(int(keep.sum()), np.int16)
    scan = RealScan("synthetic", x[keep], y[keep], z[keep], None, ones, ones.copy(), np.round(t[keep], 6),
                    np.round(np.degrees(off[keep]), 3), None, None, None, first_only=True)
    est = survey.estimate(scan, 0.0)
    assert est.deflector is None and est.scan_frequency is None
    assert "sweeps run every way" in est.missing["deflector"] and "sweeps run every way" in est.missing["scan_frequency"]
    assert est.line_positions == () and est.speed is None and est.altitude is None
    assert "sweeps run every way" in est.missing["speed"]
    assert est.pulse_frequency == pytest.approx(100_000, rel=0.01) and est.field_of_view == pytest.approx(70.0, abs=1)


def test_a_line_placed_on_its_track_is_flown_the_way_its_track_flew():
    """The climbing line above turned to head 30° (clockwise from +y) and, flown back, 210°: the line's
    track says which way, and the twin's leg runs that way (lines on tracks had all been flown along the
    lines' axis, 0-180°: a lawnmower's every other line backwards, its scan angles mirrored). Line 2,
    placed by scan angle, has no track to say: it keeps the axis."""
    scan = _two_line_scan()
    for heading in (30.0, 210.0):
        h = np.radians(heading)
        x, y = scan.x * np.cos(h) + scan.y * np.sin(h), -scan.x * np.sin(h) + scan.y * np.cos(h)
        est = survey.estimate(RealScan(**{**scan.__dict__, "x": x, "y": y}), 500.0)
        assert est.heading == pytest.approx(30.0, abs=1e-6)
        assert est.line_headings == pytest.approx((heading, 30.0), abs=1e-6)
        a, b = survey.leg_ends(est.line_positions[0], est.line_headings[0], (-50, -50, 50, 50), 10.0)
        assert np.degrees(np.arctan2(b[0] - a[0], b[1] - a[1])) % 360 == pytest.approx(heading, abs=1e-6)
