"""The twin's calibration: the Beer-Lambert and cover update rules and the canopy measures, on analytic cases."""

import math

import numpy as np
import pytest

from mitsuforest.twin import TwinFrame
from mitsuforest.twin.calibrate import (CONTRAST_LIMITS, CONTRAST_SLOPE, base_crown_ratios, canopy_spread, canopy_state,
                                        contrast_ratios, contrast_step, converged, crown_scale, dominant_crowns,
                                        echo_scale, footprint, lai_scale, leaf_exponent, leaf_rule, leaf_scale, rescale_trees,
                                        spread_slope)


@pytest.mark.parametrize("lai_twin, lai_real, zenith", [(1.5, 4.2, 30.0), (6.0, 2.0, 0.0), (3.0, 3.0, 15.0)])
def test_beer_lambert_rescale_hits_the_target_gap_fraction_in_one_step(lai_twin, lai_real, zenith):
    def gap(lai):       # random leaves, spherical angles: P = exp(-0.5 LAI / cos theta)
        return math.exp(-0.5 * lai / math.cos(math.radians(zenith)))
    k = lai_scale(gap(lai_real), gap(lai_twin))
    assert k == pytest.approx(lai_real / lai_twin, rel=1e-12)
    assert gap(lai_twin * k) == pytest.approx(gap(lai_real), rel=1e-12)


def test_the_twin_s_measured_34_percent_against_the_real_9_percent_asks_for_2_27_times_the_leaf():
    assert lai_scale(0.089, 0.345) == pytest.approx(math.log(0.089) / math.log(0.345), rel=1e-12)
    assert lai_scale(0.089, 0.345) == pytest.approx(2.27, abs=0.01)


def test_steps_are_bounded_and_an_opaque_or_empty_canopy_does_not_divide_by_zero():
    assert lai_scale(0.05, 0.0) == pytest.approx(math.log(0.05) / math.log(0.005))   # P clipped at MIN_GAP
    assert lai_scale(0.5, 0.0) == 0.25                                               # at most /4 a step
    assert lai_scale(0.001, 0.999) == 4.0                                           # at most x4 a step
    assert crown_scale(0.9, 0.0) == 4.0


def test_crown_scale_gives_discs_the_target_cover():
    # n discs of radius r on an area A, not overlapping: cover n pi r^2 / A; the factor on r hits the target
    n, r, area = 10, 2.0, 1000.0
    cover = n * math.pi * r ** 2 / area
    k = crown_scale(0.3, cover)
    assert n * math.pi * (k * r) ** 2 / area == pytest.approx(0.3, rel=1e-12)


def test_a_circular_clip_is_measured_within_its_footprint():
    """A real clip of radius 10 m, canopy everywhere in it (a first return 10 m up in each 0.5 m spot), and
    a twin rendered over the clip's 20 x 20 m rectangle, its canopy the same circle and its corners bare
    ground: over the whole plot the twin's cover would be the share of the circle's cells, 0.83, against
    the real 1.0 (and its crowns widened to close the gap); within the real footprint both are 1.0."""
    frame = TwinFrame((0.0, 0.0, 90.0), (20.0, 20.0))
    dem = np.full((22, 22), 100.0)
    x, y = (a.ravel() + 0.25 for a in np.mgrid[0:20:0.5, 0:20:0.5])
    in_circle = np.hypot(x - 10, y - 10) <= 10
    real = (x[in_circle], y[in_circle], np.full(in_circle.sum(), 110.0), np.ones(in_circle.sum(), int))
    twin = (x, y, np.where(in_circle, 110.0, 100.0), np.ones(len(x), int))
    cells = footprint(real[0], real[1], real[3], frame)
    assert math.pi * 100 < cells.sum() < math.pi * 100 + 2 * math.pi * 10 * 0.5   # the circle and its edge's cells
    whole = canopy_state(*twin, dem, (-1.0, -1.0), frame)
    assert whole["cover"] == pytest.approx(cells.sum() / 400, abs=1e-12) and whole["cover"] < 0.85
    within = canopy_state(*twin, dem, (-1.0, -1.0), frame, cells)
    assert within["cover"] == canopy_state(*real, dem, (-1.0, -1.0), frame, cells)["cover"] == 1.0


def test_canopy_state_counts_gap_and_cover_of_a_constructed_cloud():
    # 10 x 10 m plot, flat DEM at 100 m; the west 6 m are crowns (a first return at 10 m in each cell),
    # under which 5 of every 20 first returns reach the ground; the east 4 m is bare ground.
    frame = TwinFrame((0.0, 0.0, 90.0), (10.0, 10.0))
    dem = np.full((12, 12), 100.0)
    xs, ys, zs = [], [], []
    for i in range(10):
        for j in range(10):
            for k in range(20):
                x, y = i + 0.05 + 0.045 * k, j + 0.5
                z = 100.0 if (i >= 6 or k < 5) else 110.0
                xs.append(x), ys.append(y), zs.append(z)
    state = canopy_state(np.array(xs), np.array(ys), np.array(zs), np.ones(len(xs), int), dem, (-1.0, -1.0), frame)
    assert state["cover"] == pytest.approx(0.6)
    assert state["gap_fraction"] == pytest.approx(5 / 20)
    assert state["spread"] == 0.0                 # every return in the canopy at 10 m
    assert state["echoes_per_pulse"] == 1.0 and leaf_rule(state) == "gap fraction"
    second = np.where(np.arange(len(xs)) % 4 == 0, 2, 1)          # a quarter of the points are second returns
    with_seconds = canopy_state(np.array(xs), np.array(ys), np.array(zs), second, dem, (-1.0, -1.0), frame)
    assert with_seconds["echoes_per_pulse"] == pytest.approx(4 / 3)
    assert converged(state, state) and converged(state, state, spread=True)
    assert not converged(state, {**state, "spread": 0.6}, spread=True)
    assert converged(state, {**state, "spread": 0.6})
    assert not converged(state, {"gap_fraction": 0.5, "cover": 0.6})
    assert not converged(state, {"gap_fraction": 0.25, "cover": 0.5})


def test_a_scan_of_first_returns_only_and_its_twin_are_measured_on_their_first_returns():
    """A 10 x 10 m plot under a 10 m canopy, a first return in each 0.5 m spot, every third pulse returning
    again 4 m lower. A file of its first returns only (each with its pulse's count) and the whole scan
    measured with the counts agree: echoes per pulse 4/3 (the counts' mean), the spread of the first
    returns, 0 m. Without the counts the file of first returns gave 1 echo a pulse (the gap fraction
    would set its leaf) and the whole scan a spread of 4 m, so a twin was calibrated against nothing."""
    frame = TwinFrame((0.0, 0.0, 90.0), (10.0, 10.0))
    dem = np.full((12, 12), 100.0)
    x, y = (a.ravel() + 0.25 for a in np.mgrid[0:10:0.5, 0:10:0.5])
    again = np.arange(len(x)) % 3 == 0
    counts = np.where(again, 2, 1)
    first_only = (x, y, np.full(len(x), 110.0), np.ones(len(x), int))
    whole = (np.r_[x, x[again]], np.r_[y, y[again]], np.r_[np.full(len(x), 110.0), np.full(again.sum(), 106.0)],
             np.r_[np.ones(len(x), int), np.full(again.sum(), 2)])
    whole_counts = np.r_[counts, np.full(again.sum(), 2)]
    measured = canopy_state(*first_only, dem, (-1.0, -1.0), frame, None, counts)
    assert measured == canopy_state(*whole, dem, (-1.0, -1.0), frame, None, whole_counts)
    assert measured["echoes_per_pulse"] == pytest.approx(again.sum() / len(x) + 1) == pytest.approx(4 / 3, abs=0.01)
    assert measured["spread"] == 0.0 and measured["cover"] == 1.0
    assert canopy_state(*first_only, dem, (-1.0, -1.0), frame)["echoes_per_pulse"] == 1.0
    assert canopy_state(*whole, dem, (-1.0, -1.0), frame)["spread"] > 1.0


def test_rescale_trees_widens_crowns_and_keeps_leaf_area_per_crown_area(tmp_path):
    f = tmp_path / "trees.csv"
    f.write_text("x,y,height,crown_radius,species,leaf_area\n1.000,2.000,20.000,2.000,pinus_radiata,50.27\n")
    assert rescale_trees(f, lai_factor=2.0, radius_factor=1.5) == 0
    rows = f.read_text().splitlines()
    assert rows[0] == "x,y,height,crown_radius,species,leaf_area"
    assert rows[1] == "1.000,2.000,20.000,3.000,pinus_radiata,226.22"    # 50.27 x 2 x 1.5^2
    assert rescale_trees(f, lai_factor=10.0, radius_factor=1.0) == 1
    assert f.read_text().splitlines()[1].endswith(",2000.00")              # a tree carries at most 2,000 m²


def test_a_secant_step_hits_a_power_law_the_first_step_missed():
    """Clumped foliage: -ln P = 0.3 LAI^0.4. The Beer-Lambert step falls short; the exponent it shows
    (0.4) makes the next step land on the target."""
    from mitsuforest.twin.calibrate import response_exponent

    def gap(lai):
        return math.exp(-0.3 * lai ** 0.4)
    target, lai = gap(5.0), 1.0
    k1 = lai_scale(target, gap(lai))
    exponent = response_exponent(-math.log(gap(lai)), -math.log(gap(lai * k1)), k1, 1.0)
    assert exponent == pytest.approx(0.4, rel=1e-9)
    lai *= k1
    assert gap(lai) > target * 1.01                        # Beer-Lambert alone falls short
    lai *= lai_scale(target, gap(lai), exponent)
    assert gap(lai) == pytest.approx(target, rel=1e-9)
    assert response_exponent(0.5, 0.7, 1.0, 2.0) == 2.0     # no step: the default


def test_a_measure_that_moved_against_its_step_keeps_the_default_exponent():
    """MixedConifer's twin, second step: leaf area per crown area × 1.058 (with crowns × 1.158) and its
    excess echoes rose 0.432 -> 0.467, against the rule that they fall as leaf rises. That step says nothing
    of the exponent: the default 1 stands, and the next step asks 0.467 / 0.345 = × 1.35 leaf (before: the
    exponent clipped to 0.1 and × 4 leaf, the most a step may ask)."""
    from mitsuforest.twin.calibrate import echo_scale, leaf_exponent, response_exponent
    real, last, twin = {"echoes_per_pulse": 1.345}, {"echoes_per_pulse": 1.432}, {"echoes_per_pulse": 1.467}
    exponent = leaf_exponent(real, last, twin, 1.058)
    assert exponent == 1.0
    assert echo_scale(1.345, 1.467, exponent) == pytest.approx(0.467 / 0.345)
    assert response_exponent(0.7, 0.6, 1.2, 2.0) == 2.0     # cover fell as crowns widened: the default
    assert response_exponent(0.6, 0.7, 1.2, 2.0) == pytest.approx(math.log(0.7 / 0.6) / math.log(1.2))


def test_a_step_too_small_to_measure_keeps_the_default_exponent():
    """MixedConifer's twin (36° swaths), third render: the second step, leaf area × 1.029 with crowns
    × 1.084, left its echoes per pulse at 1.387 (1.3875 -> 1.3865): a secant exponent of 0.09, clipped to
    0.1, asked for × 3.1 the leaf where the miss (0.387 / 0.345) asks × 1.12. A step under 5 % says nothing
    of the exponent; a larger one is held to a quarter of the default or more."""
    from mitsuforest.twin.calibrate import echo_scale, leaf_exponent, response_exponent
    real, last, twin = {"echoes_per_pulse": 1.345}, {"echoes_per_pulse": 1.3875}, {"echoes_per_pulse": 1.3865}
    assert leaf_exponent(real, last, twin, 1.029) == 1.0
    assert echo_scale(1.345, 1.3865, 1.0) == pytest.approx(0.3865 / 0.345)
    assert leaf_exponent(real, last, twin, 1.2) == 0.25                 # the measure hardly moved: at least 1/4
    assert echo_scale(1.345, 1.3865, 0.25) == pytest.approx((0.3865 / 0.345) ** 4)
    assert response_exponent(0.6, 0.7, 1.04, 2.0) == 2.0


def test_crown_ratio_recovers_a_cone_s_length_from_the_foliage_profile_of_its_returns():
    """Layers of a cone's crown of uniform leaf density (crown ratio 0.42: the foliage within relative
    depth s of the top goes as F (s / 0.42)^2.8, F = 2): a pulse stops at the first leaf, so the depth it
    reaches is where the foliage above it is an exponential draw, and one in e² reaches the ground.
    MacArthur-Horn's inversion gives the profile back, and half of it lies 0.781 crown lengths down."""
    from mitsuforest.twin.foliage import crown_ratio, foliage_profile
    rng = np.random.default_rng(3)
    ratio, total = 0.42, 2.0
    stopped_at = rng.exponential(1.0, 400_000)                   # foliage each pulse passes before a hit
    hit = stopped_at < total
    rel = np.where(hit, 1.0 - ratio * (np.minimum(stopped_at, total) / total) ** (1 / 2.8), 0.0)
    assert crown_ratio(rel) == pytest.approx(ratio, abs=0.01)
    z, foliage = foliage_profile(rel, 0.1)
    expected = total * np.clip((1 - z) / ratio, 0, 1) ** 2.8
    assert np.abs(foliage - expected).max() < 0.03
    assert crown_ratio([]) is None and crown_ratio([0.0, 0.0]) is None
    assert crown_ratio(np.r_[np.full(1000, 0.99), np.zeros(100)]) == 0.2      # within the range


def test_relative_heights_are_taken_under_each_tree_s_own_crown():
    from mitsuforest.twin.foliage import relative_heights_under_crowns
    rel = relative_heights_under_crowns([0.5, 10.2, 5.0], [0.0, 0.0, 0.0], [10.0, 15.0, 8.0],
                                        [0.0, 10.0], [0.0, 0.0], [20.0, 30.0], [1.0, 2.0])
    assert rel.tolist() == [0.5, 0.5]                            # the third point is under neither crown
    assert len(relative_heights_under_crowns([1.0], [1.0], [1.0], [], [], [], [])) == 0


def _cone_returns(ratio, n, rng, total=2.0):
    """Relative heights of ``n`` pulses' returns from a cone crown of ``ratio`` and uniform leaf density
    (foliage within relative depth s of the top ``total (s / ratio)^2.8``; see the test above)."""
    stopped_at = rng.exponential(1.0, n)
    hit = stopped_at < total
    return np.where(hit, 1.0 - ratio * (np.minimum(stopped_at, total) / total) ** (1 / 2.8), 0.0)


def test_each_tree_gets_its_own_crown_ratio_where_it_has_returns_enough():
    """Three trees 10 m apart (radius 3 m): a shallow crown (0.3 of its 20 m), a deep one (0.7 of 30 m),
    both with thousands of returns, and one with a few hundred, which takes the stand's ratio."""
    from mitsuforest.twin.foliage import MIN_TREE_RETURNS, tree_crown_ratios
    rng = np.random.default_rng(11)
    trees_x, trees_y, heights = np.array([0.0, 10.0, 20.0]), np.zeros(3), np.array([20.0, 30.0, 25.0])
    x, y, h = [], [], []
    for k, (ratio, n) in enumerate(((0.3, 20_000), (0.7, 20_000), (0.5, MIN_TREE_RETURNS // 2))):
        rel = _cone_returns(ratio, n, rng)
        r, phi = 2.9 * np.sqrt(rng.random(n)), rng.uniform(0, 2 * np.pi, n)
        x.append(trees_x[k] + r * np.cos(phi))
        y.append(r * np.sin(phi))
        h.append(rel * heights[k])
    ratios = tree_crown_ratios(np.concatenate(x), np.concatenate(y), np.concatenate(h), trees_x, trees_y, heights,
                               np.full(3, 3.0), stand=0.42)
    assert ratios[:2] == pytest.approx([0.3, 0.7], abs=0.015)
    assert ratios[2] == 0.42
    assert np.isnan(tree_crown_ratios([50.0], [0.0], [1.0], trees_x, trees_y, heights, np.full(3, 3.0), None)).all()


def test_canopy_spread_is_the_interquartile_range_of_the_heights_in_the_canopy():
    h = np.r_[np.zeros(5000), np.linspace(2.0, 22.0, 10_001)]      # ground, then uniform 2-22 m
    assert canopy_spread(h) == pytest.approx(10.0, abs=1e-9)       # quartiles at 7 and 17 m
    assert canopy_spread(np.r_[np.zeros(5000), np.full(99, 10.0)]) is None    # under 100 canopy returns


def test_the_widest_quarter_of_the_crowns_are_the_dominants_and_the_contrast_moves_both_kinds():
    radius = np.arange(1.0, 9.0)                                   # 1..8 m: the quantile 0.75 is 6.25 m
    dominant = dominant_crowns(radius)
    assert dominant.tolist() == [False] * 6 + [True] * 2
    ratios = contrast_ratios(np.full(8, 0.4), dominant, 0.25)
    assert ratios.tolist() == pytest.approx([0.6] * 6 + [0.3] * 2)   # x 1.5 and x 0.75
    assert contrast_ratios([0.8, 0.8], [False, True], 0.25).tolist() == pytest.approx([0.95, 0.6])  # at most 0.95
    assert contrast_ratios([0.4], [True], 0.0).tolist() == [0.4]
    assert dominant_crowns([]).tolist() == []


def test_a_secant_contrast_step_lands_on_a_linear_spread_the_first_guess_missed():
    def spread(c):                 # the twin's spread answers 14 m per unit of contrast from 5.2 m
        return 5.2 + 14.0 * c
    target, c0 = 8.9, 0.0
    c1 = contrast_step(c0, target, spread(c0))
    assert c1 == pytest.approx((target - 5.2) / CONTRAST_SLOPE)    # the first step assumes 10 m a unit
    slope = spread_slope((c0, spread(c0)), (c1, spread(c1)))
    assert slope == pytest.approx(14.0)
    c2 = contrast_step(c1, target, spread(c1), slope)
    assert spread(c2) == pytest.approx(target)
    assert contrast_step(0.4, 30.0, 5.0) == CONTRAST_LIMITS[1] and contrast_step(0.1, 0.0, 9.0) == CONTRAST_LIMITS[0]
    assert spread_slope((0.2, 6.0), (0.2, 7.0)) == CONTRAST_SLOPE          # no step: the guess
    assert spread_slope((0.0, 6.0), (0.2, 5.0)) == CONTRAST_SLOPE          # spread fell: the guess


def test_crown_ratios_are_the_tree_s_own_or_the_stand_s_and_rescale_writes_them(tmp_path):
    f = tmp_path / "trees.csv"
    f.write_text("x,y,height,crown_radius,species,leaf_area,crown_ratio\n"
                 "1.000,2.000,20.000,2.000,pinus_radiata,50.27,0.300\n3.000,4.000,10.000,1.000,pinus_radiata,12.57,\n")
    rows = [dict(zip(("crown_ratio",), (r,))) for r in ("0.300", "")]
    assert base_crown_ratios(rows, 0.42).tolist() == [0.3, 0.42]
    assert base_crown_ratios(rows, None) is None
    rescale_trees(f, 1.0, 1.0, np.array([0.225, 0.63]))
    assert [r.split(",")[-1] for r in f.read_text().splitlines()] == ["crown_ratio", "0.225", "0.630"]
    g = tmp_path / "plain.csv"
    g.write_text("x,y,height,crown_radius,species\n1.000,2.000,20.000,2.000,pinus_radiata\n")
    rescale_trees(g, 1.0, 1.0, np.array([0.5]))
    assert g.read_text().splitlines() == ["x,y,height,crown_radius,species,crown_ratio",
                                          "1.000,2.000,20.000,2.000,pinus_radiata,0.500"]


@pytest.mark.parametrize("exponent", [1.0, 0.6])
def test_the_echo_rule_lands_on_a_power_law_of_excess_echoes_in_one_step_then_by_secant(exponent):
    """Echoes beyond the first fall as LAI^-exponent: E = 1 + 1.9 LAI^-exponent. The first step (exponent
    1) hits where the law is 1; the secant shows 0.6 where it is not, and the next step lands."""
    def echoes(lai):
        return 1.0 + 1.9 * lai ** -exponent
    real = {"echoes_per_pulse": echoes(3.3), "gap_fraction": 0.1}
    lai = 1.0
    twin = {"echoes_per_pulse": echoes(lai), "gap_fraction": 0.2}
    assert leaf_rule(real) == "echoes"
    k1 = leaf_scale(real, twin)
    assert k1 == pytest.approx((echoes(lai) - 1) / (echoes(3.3) - 1)) == echo_scale(real["echoes_per_pulse"],
                                                                                    twin["echoes_per_pulse"])
    after = {"echoes_per_pulse": echoes(lai * k1), "gap_fraction": 0.15}
    if exponent == 1.0:
        assert lai * k1 == pytest.approx(3.3)
        return
    shown = leaf_exponent(real, twin, after, k1)
    assert shown == pytest.approx(0.6, rel=1e-9)
    assert lai * k1 * leaf_scale(real, after, shown) == pytest.approx(3.3, rel=1e-9)


def test_a_scan_of_single_returns_sets_the_leaf_by_the_gap_fraction():
    real = {"echoes_per_pulse": 1.01, "gap_fraction": 0.1}
    twin = {"echoes_per_pulse": 1.5, "gap_fraction": 0.2}
    assert leaf_rule(real) == "gap fraction" and leaf_rule({"gap_fraction": 0.1}) == "gap fraction"
    assert leaf_scale(real, twin) == lai_scale(0.1, 0.2)
    assert echo_scale(1.5, 1.0) == 0.25            # the excess floored at MIN_EXCESS, the step at /4
    assert converged({**real, "cover": 0.5}, {**twin, "gap_fraction": 0.1, "cover": 0.5})


def _calibrate_a_stand(tmp_path, monkeypatch, real_lai: float, iterations: int = 6) -> dict:
    """A stand of 12 trees standing in for renders: the echoes beyond the first go as LAI^-0.7, the cover
    as radius^1.5, the spread grows 14 m a unit of contrast; the real scan's echoes are those of
    ``real_lai`` times the stand's leaf, its cover that of crowns 1.2 times as wide, its spread 8.5 m."""
    from types import SimpleNamespace

    from mitsuforest.twin import calibrate as c
    radius = np.linspace(1.0, 4.0, 12)
    rows = [f"{10 + i:.3f},5.000,20.000,{r:.3f},pinus_radiata,{20 * np.pi * r ** 2:.2f},0.400"
            for i, r in enumerate(radius)]
    header = "x,y,height,crown_radius,species,leaf_area,crown_ratio\n"
    (tmp_path / "trees.csv").write_text(header + "\n".join(rows) + "\n")
    (tmp_path / "twin.json").write_text("{}")

    def measured(folder):
        t = c.read_trees(folder / "trees.csv")
        r = np.array([float(x["crown_radius"]) for x in t])
        lai = np.mean([float(x["leaf_area"]) / (np.pi * float(x["crown_radius"]) ** 2) for x in t]) / 20.0
        dominant = c.dominant_crowns(r)
        contrast = 1.0 - float(t[int(np.argmax(dominant))]["crown_ratio"]) / 0.4
        return {"echoes_per_pulse": 1.0 + 1.2 * lai ** -0.7, "cover": min(1.0, 0.6 * (r[0] / 1.0) ** 1.5),
                "spread": 5.0 + 14.0 * contrast, "gap_fraction": 0.2}

    monkeypatch.setattr(c, "_render_state", lambda scene, variant, analysis, cells, first_only: measured(scene.parent))
    monkeypatch.setattr(c, "footprint", lambda *args: None)
    real = {"echoes_per_pulse": 1.0 + 1.2 * real_lai ** -0.7, "cover": 0.6 * 1.2 ** 1.5, "spread": 8.5,
            "gap_fraction": 0.1}
    monkeypatch.setattr(c, "canopy_state", lambda *args: real)
    scan = SimpleNamespace(x=None, y=None, z=None, return_number=None, number_of_returns=None, first_only=False)
    analysis = {"frame": None, "dem": None, "dem_origin": None, "crown_ratio": 0.4}
    record = c.calibrate(scan, analysis, tmp_path, "stand", iterations, log=lambda *_: None)
    record["real"] = real
    return record


def test_the_loop_converges_on_a_stand_whose_measures_follow_power_laws(tmp_path, monkeypatch):
    """The stand of :func:`_calibrate_a_stand` with 3 times its leaf in the real scan: the loop's secant
    steps reach all three measures within tolerance, and its factors are the ones the laws ask."""
    from mitsuforest.twin import calibrate as c
    record = _calibrate_a_stand(tmp_path, monkeypatch, 3.0)
    real = record["real"]
    assert record["converged"] and record["leaf_from"] == "echoes" and "leaf_held" not in record
    last = record["steps"][-1]
    assert abs(c.echo_scale(real["echoes_per_pulse"], last["echoes_per_pulse"]) - 1) <= c.ECHO_TOLERANCE
    assert abs(last["cover"] - real["cover"]) <= c.COVER_TOLERANCE
    assert abs(last["spread"] - real["spread"]) <= c.SPREAD_TOLERANCE
    assert len(record["steps"]) <= 4 and record["lai_factor"] == pytest.approx(3.0, rel=0.1)
    assert record["crown_factor"] == pytest.approx(1.2, rel=0.03)
    assert record["crown_contrast"] == pytest.approx(0.25, abs=0.04)


def test_the_loop_holds_the_leaf_at_four_times_the_scan_s(tmp_path, monkeypatch):
    """A real scan whose echoes ask for 8 times the stand's leaf: the steps stop at 4 times in all
    (TOTAL_LEAF_LIMITS), the record says what was asked and held, and the loop does not converge."""
    record = _calibrate_a_stand(tmp_path, monkeypatch, 8.0, iterations=5)
    assert record["lai_factor"] == pytest.approx(4.0, rel=1e-9) and not record["converged"]
    assert record["leaf_held"]["held"] == 4.0 and record["leaf_held"]["asked"] > 4.0
