"""The platform side of a real survey: attitude, mount, flown trajectories, navigation errors and flight
lines, checked on flat ground against the geometry (plan/trajectory.py has the frames)."""

import numpy as np
import pytest
from helpers import SENSORS, scene_file

from mitsuforest.cli import main
from mitsuforest.config import ConfigError, load_scene
from mitsuforest.survey import make_plan
from mitsuforest.plan.trajectory import ENU_FROM_NED, euler_matrix, matrix_euler
from mitsuforest.scan import scan
from mitsuforest.scene import build_scene
from mitsuforest.testing.reference.deflector import rotating

X = 20.0   # the legs fly north along x = 20 m over a flat 40 m plot
NARROW = {**__import__("yaml").safe_load((SENSORS / "ideal.yaml").read_text()), "field_of_view": 40}


def deflector_angle(points):
    """The deflector's angle (rad) of each point's pulse in :func:`flat_scan` (100 Hz mirror, from t = 0);
    the points' ``scan_angle`` is the beam's from the vertical (LAS), which a tilt or a mount turns."""
    return rotating(points["gps_time"], 100, np.pi)[1]


def flat_scan(tmp_path, sensor=NARROW, **survey):
    """Points of a bare flat plot (thin ideal beam, 40° FOV, 10 kHz) and the platform's height above it."""
    path = scene_file(tmp_path, sensor=sensor, survey={
        "altitude": 30, "speed": 10, "pulse_frequency": 10000, "scan_frequency": 100,
        "lines": [[[X, 5.0], [X, 35.0]]], **survey})
    scene = load_scene(path)
    plan = make_plan(scene)
    points = scan(scene, plan, build_scene(plan, {}, scene.sensor, scene.simulation.variant), progress=False).points
    return points, plan.legs[0].start[2] - float(plan.terrain.z.mean()), plan


def test_the_frames_turn_a_level_northbound_body_as_documented():
    """Body x forward, y right, z down, R = Rz(yaw)·Ry(pitch)·Rx(roll) into north-east-down, then ENU."""
    body = ENU_FROM_NED @ euler_matrix(0, 0, 90)[0]            # heading east
    assert np.allclose(body @ [1, 0, 0], [1, 0, 0]) and np.allclose(body @ [0, 1, 0], [0, -1, 0])
    rolled = ENU_FROM_NED @ euler_matrix(10, 0, 0)[0]          # heading north, right wing down
    assert np.allclose(rolled @ [0, 0, 1], [-np.sin(np.radians(10)), 0, -np.cos(np.radians(10))])
    pitched = ENU_FROM_NED @ euler_matrix(0, 10, 0)[0]         # nose up: the nose points up
    assert pitched @ [1, 0, 0] == pytest.approx([0, np.cos(np.radians(10)), np.sin(np.radians(10))])
    angles = np.array([[3.0, -2.0, 350.0], [-1.0, 4.0, 10.0]])
    assert np.allclose(matrix_euler(euler_matrix(*angles.T)), angles)


def test_a_constant_roll_shifts_the_swath_by_h_tan_roll(tmp_path):
    """Right wing down by θ turns the sensor's nadir left: a pulse at deflector angle φ lands H·tan(φ − θ)
    right of the track, so the swath's centre (φ = 0) moves H·tan θ to the left (west on a northbound leg);
    its scan angle (from the vertical, as LAS counts it) is φ − θ."""
    level, H, _ = flat_scan(tmp_path / "level")
    roll = 5.0
    rolled, _, _ = flat_scan(tmp_path / "rolled", attitude={"roll": roll})
    assert H == pytest.approx(30.0)
    for points, theta in ((level, 0.0), (rolled, np.radians(roll))):
        phi = deflector_angle(points)
        assert np.abs(points["x"] - X - H * np.tan(phi - theta)).max() < 2e-3
        assert np.abs(points["scan_angle"] - np.degrees(phi - theta)).max() < 1e-4
        assert np.abs(points["y"] - (5.0 + 10.0 * points["gps_time"])).max() < 2e-3   # pitch 0: below the platform
    def centre(p):   # where the sensor's nadir (φ = 0) lands: a line through the points within 1° of it
        phi = np.degrees(deflector_angle(p))
        near = np.abs(phi) < 1.0
        return np.polyval(np.polyfit(phi[near], p["x"][near], 1), 0.0) - X
    assert centre(level) == pytest.approx(0.0, abs=1e-3)
    assert centre(rolled) == pytest.approx(-H * np.tan(np.radians(roll)), abs=2e-3)   # -2.62 m
    assert len(rolled) == pytest.approx(len(level), rel=0.01)


def _vertical_angle(points, origin, heading_deg):
    """The angle (deg) of the beam from ``origin`` (n, 3) to each point from the local frame's vertical, seen
    from behind along ``heading_deg`` (clockwise from north), positive to the right: LAS 1.4's scan angle
    ("with respect to the vertical of the coordinate system of the data", counter-clockwise seen from the
    rear facing along the track; 1.2: "including the roll of the aircraft", -90 on the left)."""
    h = np.radians(heading_deg)
    v = np.column_stack([points[a] for a in "xyz"]) - origin
    return np.degrees(np.arctan2(v[:, 0] * np.cos(h) - v[:, 1] * np.sin(h), -v[:, 2]))


def test_the_las_scan_angle_includes_the_roll_and_reads_back_so(tmp_path):
    """A rolled platform (4° right wing down) with a mount turned 1° more in roll: the pulse that lands
    below the track is aimed 5° right by the deflector, and LAS counts the scan angle from the data's
    vertical, so it must be 0 there, not 5°. Every point's angle (PCD and LAS) is the angle of the beam it
    lies on from the vertical (x = X + H·tan α on flat ground); a level scan's are the deflector's, as before."""
    import laspy

    from mitsuforest.write.las import las_header, las_points
    sensor = {**NARROW, "mount": {"boresight": [1.0, 0.0, 0.0]}}
    rolled, H, plan = flat_scan(tmp_path, sensor=sensor, attitude={"roll": 4.0})
    origin = np.column_stack([np.full(len(rolled), X), 5.0 + 10.0 * rolled["gps_time"], np.full(len(rolled), H)])
    truth = _vertical_angle(rolled, origin, 0.0)
    assert np.abs(rolled["scan_angle"] - truth).max() < 1e-4
    assert np.abs(rolled["x"] - X - H * np.tan(np.radians(rolled["scan_angle"].astype(float)))).max() < 2e-3
    las_points(las_header([0, 0, 0]), rolled).write(tmp_path / "p.las")
    written = np.asarray(laspy.read(tmp_path / "p.las").scan_angle) * 0.006
    assert np.abs(written - truth).max() < 0.0031                              # the 0.006° unit
    level, _, _ = flat_scan(tmp_path / "level")
    assert np.abs(level["scan_angle"] - np.degrees(deflector_angle(level))).max() < 1e-5


def test_a_sinusoidal_pitch_moves_points_along_track_and_the_trajectory_says_so(tmp_path):
    wave = {"amplitude_deg": 3.0, "period_s": 1.0, "phase_deg": 30.0}
    points, H, plan = flat_scan(tmp_path, attitude={"pitch": wave})
    t = points["gps_time"]
    pitch = np.radians(3.0 * np.sin(2 * np.pi * t + np.radians(30)))
    phi = deflector_angle(points)
    # Nose up by ψ tilts the beam forward: the along-track offset is H·tan ψ / cos φ (to first order in ψ of
    # the exact ray-plane intersection, which the test computes exactly here).
    d = np.column_stack([np.sin(phi), np.zeros_like(phi), -np.cos(phi)])           # sensor frame: x right, y fwd, z up
    body = np.column_stack([d[:, 1], d[:, 0], -d[:, 2]])                           # forward, right, down
    local = np.einsum("nij,nj->ni", ENU_FROM_NED @ euler_matrix(0, np.degrees(pitch), 0), body)
    ground = local * (H / -local[:, 2])[:, None]
    assert np.abs(points["y"] - (5.0 + 10.0 * t) - ground[:, 1]).max() < 2e-3
    assert np.abs(ground[:, 1]).max() > 1.0


def _paired(a, b):
    """Rows of ``b`` in the order of ``a``'s (pulse_id, return_number)."""
    key = lambda p: p["pulse_id"].astype(np.int64) * 64 + p["return_number"]   # noqa: E731
    order = np.argsort(key(b))
    at = np.searchsorted(key(b)[order], key(a))
    assert np.array_equal(key(b)[order][at], key(a))
    return b[order][at]


def test_a_boresight_roll_error_makes_opposite_lines_disagree_by_2h_sin_delta(tmp_path):
    """The pulses fly the true mount; the points are placed with a boresight believed δ off in roll (about
    the sensor's forward axis). A pulse at scan angle φ meets flat ground at range H/cos φ; placed along
    the believed direction φ − δ (a roll right turns the beam left) it lands H·sin(φ − δ)/cos φ right of
    the track and H·cos(φ − δ)/cos φ below it. For the nadir pulse that is H·sin δ to the left of each
    line: two opposite lines over the same ground disagree by 2·H·sin δ across the track."""
    delta = 0.5
    lines = [[[X, 5.0], [X, 35.0]], [[X, 35.0], [X, 5.0]]]
    true, H, _ = flat_scan(tmp_path / "true", lines=lines)
    placed, _, _ = flat_scan(tmp_path / "err", lines=lines, navigation_errors={"boresight_error_deg": [delta, 0, 0]})
    placed = _paired(true, placed)
    assert np.array_equal(placed["point_source_id"], true["point_source_id"])
    assert set(np.unique(true["point_source_id"])) == {1, 2}
    phi = np.radians(true["scan_angle"].astype(float))
    d = np.radians(delta)
    right = np.where(true["point_source_id"] == 1, 1.0, -1.0)                   # east on leg 1, west on leg 2
    assert np.abs(placed["x"] - X - right * H * np.sin(phi - d) / np.cos(phi)).max() < 2e-3
    assert np.abs(placed["z"] - (H - H * np.cos(phi - d) / np.cos(phi)) - true["z"]).max() < 2e-3
    assert np.abs(placed["y"] - true["y"]).max() < 1e-3
    assert np.abs(placed["scan_angle"] - np.degrees(phi - d)).max() < 1e-4      # the believed beam's, from the vertical
    nadir = np.abs(phi) < np.radians(1)
    shift = [np.mean(placed["x"][nadir & (true["point_source_id"] == k)] - true["x"][nadir & (true["point_source_id"] == k)])
             for k in (1, 2)]
    assert shift[1] - shift[0] == pytest.approx(2 * H * np.sin(d), rel=0.01)      # 0.52 m


@pytest.mark.parametrize("axis", [1, 2], ids=["pitch", "yaw"])
def test_a_boresight_pitch_or_yaw_error_places_each_point_along_the_believed_beam(tmp_path, axis):
    """A 1° boresight error in pitch or yaw (the roll case is above): each point lies at its true range
    along the beam turned by it (nose up tilts the beam forward; yaw turns it clockwise seen from above).
    On a northbound leg at 30 m a pitch error moves the nadir point 30·sin 1° = 0.524 m north; a yaw
    error leaves it and moves a point e east of the track e·sin 1° south."""
    error = [0.0, 0.0, 0.0]
    error[axis] = 1.0
    true, H, _ = flat_scan(tmp_path / "true")
    placed, _, _ = flat_scan(tmp_path / "err", navigation_errors={"boresight_error_deg": error})
    placed = _paired(true, placed)
    origin = np.column_stack([np.full(len(true), X), 5.0 + 10.0 * true["gps_time"], np.full(len(true), H)])
    echo = np.column_stack([true[a] for a in "xyz"])
    phi = np.radians(true["scan_angle"].astype(float))
    body = np.column_stack([np.zeros_like(phi), np.sin(phi), np.cos(phi)])        # forward, right, down
    believed = body @ (ENU_FROM_NED @ euler_matrix(*error)[0]).T
    want = origin + believed * np.linalg.norm(echo - origin, axis=1)[:, None]
    assert np.abs(np.column_stack([placed[a] for a in "xyz"]) - want).max() < 2e-5
    nadir, east = np.abs(phi) < np.radians(1), phi > np.radians(15)
    moved = np.column_stack([placed[a] - true[a] for a in "xyz"])
    if axis == 1:
        assert moved[nadir, 1].mean() == pytest.approx(H * np.sin(np.radians(1)), rel=1e-3)   # 0.524 m north
    else:
        assert np.abs(moved[nadir, :2]).max() < 0.02
        assert moved[east, 1] == pytest.approx(-(true["x"][east] - X) * np.sin(np.radians(1)), abs=1e-3)


def test_a_gnss_random_walk_spreads_overlapping_strips_by_its_sigma(tmp_path):
    """Twenty passes along the same line, each Δ = 6 s after the one before (3 s leg, 3 s back): where two
    consecutive strips overlap, their heights differ by the walk's increment over Δ, N(0, q²·Δ)."""
    q, passes = 0.05, 20
    points, _, plan = flat_scan(tmp_path, lines=[[[X, 5.0], [X, 35.0]]] * passes,
                                navigation_errors={"gnss_random_walk_m_per_sqrt_s": [0, 0, q]})
    gap = plan.legs[1].t0 - plan.legs[0].t0
    assert gap == pytest.approx(6.0)
    cell = np.floor(points["y"]).astype(int)
    heights = np.full((passes, 40), np.nan)
    for k in range(passes):
        mine = points["point_source_id"] == k + 1
        sums = np.bincount(cell[mine], points["z"][mine], minlength=40)
        counts = np.bincount(cell[mine], minlength=40)
        heights[k] = np.where(counts > 20, sums / np.maximum(counts, 1), np.nan)
    differences = np.diff(heights, axis=0)
    differences = differences[np.isfinite(differences)]
    assert len(differences) > 400
    assert np.std(differences) == pytest.approx(q * np.sqrt(gap), rel=0.3)    # 0.122 m
    assert np.abs(points["x"] - X - 30 * np.tan(np.radians(points["scan_angle"]))).max() < 2e-3   # level


def test_gnss_white_noise_and_the_trajectory_file_hold_the_believed_trajectory(tmp_path):
    """White GNSS noise of σ (east, north, up) at 10 Hz epochs: the trajectory file's believed columns
    differ from the true ones by it, and each point by the same error interpolated at its time."""
    import laspy

    from mitsuforest.write.las import las_header, las_points
    from mitsuforest.write.tables import write_trajectory
    sigma = [0.1, 0.2, 0.05]
    points, H, plan = flat_scan(tmp_path, navigation_errors={"gnss_sigma_m": sigma, "rate_hz": 10})
    scene = load_scene(tmp_path / "scene.yaml").with_({"origin.offset": [1000.0, 2000.0, 10.0]})
    write_trajectory(tmp_path / "t.csv", scene, plan)
    header = (tmp_path / "t.csv").read_text().splitlines()[0].split(",")
    assert header == ["time", "x", "y", "z", "roll", "pitch", "yaw", "line", "believed_x", "believed_y", "believed_z",
                      "believed_roll", "believed_pitch", "believed_yaw"]
    table = np.loadtxt(tmp_path / "t.csv", delimiter=",", skiprows=1)
    assert np.allclose(table[:, 1:4] - [1000, 2000, 10], plan.legs[0].position(table[:, 0]), atol=1e-4)
    errors = table[:, 8:11] - table[:, 1:4]                  # believed minus true, at the 10 Hz epochs
    assert np.std(errors, axis=0) == pytest.approx(sigma, rel=0.35)
    assert np.allclose(table[:, 11:14], table[:, 4:7]) and (table[:, 7] == 1).all()
    assert points["gps_time"].max() <= table[-1, 0]           # the table's last row is at the leg's end, 3.0 s
    err = np.column_stack([np.interp(points["gps_time"], table[:, 0], errors[:, k]) for k in range(3)])
    flat = np.column_stack([points["x"] - X - H * np.tan(np.radians(points["scan_angle"].astype(float))),
                            points["y"] - 5.0 - 10.0 * points["gps_time"], points["z"]])
    assert np.abs(flat - err).max() < 2e-4 + 1e-3            # the table's 0.1 mm digits, float32 points
    las = las_points(las_header([0, 0, 0]), points)
    assert (np.asarray(las.point_source_id) == 1).all() and (points["point_source_id"] == 1).all()
    las.write(tmp_path / "p.las")
    assert (np.asarray(laspy.read(tmp_path / "p.las").point_source_id) == 1).all()


def _trajectory_csv(path, rows, header="time,x,y,z,roll,pitch,yaw"):
    path.write_text(header + "\n" + "".join(",".join(f"{v:.17g}" for v in r) + "\n" for r in rows))
    return path


def test_a_straight_trajectory_file_reproduces_the_planned_leg(tmp_path):
    planned, H, plan = flat_scan(tmp_path / "planned")
    z = plan.legs[0].start[2]
    t = np.linspace(0.0, 3.0, 7)
    csv = _trajectory_csv(tmp_path / "line.csv", [[s, X, 5.0 + 10 * s, z, 0, 0, 0] for s in t])
    flown, _, flown_plan = flat_scan(tmp_path / "flown", lines=None, trajectory=str(csv))
    assert flown_plan.legs[0].track is not None and (flown_plan.legs[0].t0, flown_plan.legs[0].t1) == (0.0, 3.0)
    assert '"track"' in flown_plan.to_json()
    assert np.array_equal(flown["pulse_id"], planned["pulse_id"])
    for key in ("x", "y", "z"):
        assert np.abs(flown[key] - planned[key]).max() < 1e-3, key
    assert (flown["point_source_id"] == 1).all()


def test_a_trajectory_file_in_gps_seconds_gives_the_points_of_one_timed_from_zero(tmp_path):
    """The same straight trajectory stamped from 0 s and from 1.4e9 s (GPS seconds; a whole number of the
    mirror's 100 Hz turns later): the same pulses at the same places, their times 1.4e9 s later. In
    float64, 2π·f·t at 1.4e9 s keeps only some 4e-4 rad, 12 mm at this range, so the deflector takes the
    mirror's phase at the leg's start exactly."""
    shift = 1_400_000_000.0
    z = 30.0 + float(make_plan(load_scene(scene_file(tmp_path / "p", survey={"altitude": 30}))).terrain.z.mean())
    rows = [[s, X, 5.0 + 10 * s, z, 0, 0, 0] for s in np.linspace(0.0, 3.0, 7)]
    zero, _, _ = flat_scan(tmp_path / "zero", lines=None, trajectory=str(_trajectory_csv(tmp_path / "a.csv", rows)))
    gps, _, plan = flat_scan(tmp_path / "gps", lines=None, trajectory=str(
        _trajectory_csv(tmp_path / "b.csv", [[r[0] + shift, *r[1:]] for r in rows])))
    assert plan.legs[0].t0 == shift and len(zero) > 3000
    assert np.array_equal(gps["pulse_id"], zero["pulse_id"])
    for key in ("x", "y", "z"):
        assert np.abs(gps[key] - zero[key]).max() < 1e-4, key
    assert np.abs(gps["scan_angle"] - zero["scan_angle"]).max() < 1e-4      # degrees
    assert np.abs(gps["gps_time"] - shift - zero["gps_time"]).max() < 1e-6


def test_a_curved_trajectory_file_is_flown_smoothly_with_lines_and_slerped_attitude(tmp_path):
    """A file with two flight lines (the ``line`` column): the second flies a yawed, rolled arc. Its points
    lie where the beam from the spline's position, turned by the slerped attitude, meets the ground."""
    from mitsuforest.plan.trajectory import pose_table
    from mitsuforest.scan import Platform
    _, H, plan = flat_scan(tmp_path / "planned")
    z = plan.legs[0].start[2]
    rows = [[s, X, 5.0 + 10 * s, z, 0, 0, 0, 7] for s in np.linspace(0, 3, 4)]
    rows += [[10 + s, X + 5 * np.sin(s), 5 + 8 * s, z + 0.5 * s, 2 * s, -1.0, 10 * s, 9] for s in np.linspace(0, 3, 13)]
    csv = _trajectory_csv(tmp_path / "two.csv", rows, "time,x,y,z,roll,pitch,yaw,line")
    points, _, flown = flat_scan(tmp_path / "flown", lines=None, trajectory=str(csv))
    assert [(leg.t0, leg.t1) for leg in flown.legs] == [(0.0, 3.0), (10.0, 13.0)]
    second = points[points["point_source_id"] == 2]
    assert len(second) > 1000 and set(np.unique(points["point_source_id"])) == {1, 2}
    scene = load_scene(tmp_path / "flown" / "scene.yaml")
    table = pose_table(flown.legs[1])
    assert np.allclose(table.pose(np.array([10.0, 11.5, 13.0]))[0][:, 1], [5, 17, 29], atol=1e-6)   # through the rows
    origin, rotation = Platform(scene).beam(table, second["gps_time"])
    phi = deflector_angle(second)
    d = np.einsum("nij,nj->ni", rotation, np.column_stack([np.sin(phi), np.zeros_like(phi), -np.cos(phi)]))
    ground = origin + d * ((origin[:, 2] - (z - H)) / -d[:, 2])[:, None]
    assert np.abs(np.column_stack([second["x"], second["y"], second["z"]]) - ground).max() < 2e-3
    # The render's trajectory file flies again: the same two lines, through the same poses.
    from mitsuforest.plan.trajectory import read_trajectory
    from mitsuforest.write.tables import write_trajectory
    write_trajectory(tmp_path / "again.csv", scene, flown)
    again = read_trajectory(tmp_path / "again.csv")
    assert [len(tr.time) for tr in again] == [31, 31]      # 10 a second from 0 and 10 s, and the ends 3 and 13 s
    rows = np.array(rows)[4:]
    at = np.isin(np.round(rows[:, 0], 6), np.round(again[1].time, 6))
    assert at.sum() == 7          # the file's rows at 10.0, 10.5 ... 13.0 s
    assert np.allclose(again[1].position[np.isin(np.round(again[1].time, 6), np.round(rows[at, 0], 6))],
                       rows[at, 1:4], atol=1e-4)
    assert np.allclose(again[1].attitude[np.isin(np.round(again[1].time, 6), np.round(rows[at, 0], 6))],
                       rows[at, 4:7], atol=1e-3)


def test_the_trajectory_file_holds_each_leg_to_its_end_and_flies_the_same_legs_again(tmp_path):
    """The render's trajectory file has a row at each leg's end, where its last pulse is fired (it stopped
    at the last tenth of a second before it, so the points of each leg's last 0.1 s, 1 m at 10 m/s, were
    past the file's end and a render flying the file again flew every leg 0.1 s shorter)."""
    from mitsuforest.plan.trajectory import read_trajectory
    from mitsuforest.write.tables import write_trajectory
    points, _, plan = flat_scan(tmp_path, lines=[[[X, 5.0], [X, 35.0]], [[X + 5, 35.0], [X + 5, 8.0]]])
    write_trajectory(tmp_path / "t.csv", load_scene(tmp_path / "scene.yaml"), plan)
    again = read_trajectory(tmp_path / "t.csv")
    assert len(again) == len(plan.legs) == 2
    for number, (track, leg) in enumerate(zip(again, plan.legs), start=1):
        assert (track.time[0], track.time[-1]) == pytest.approx((leg.t0, leg.t1), abs=1e-6)
        assert np.allclose(track.position[[0, -1]], [leg.position(np.array([leg.t0]))[0], leg.end], atol=1e-4)
        times = points["gps_time"][points["point_source_id"] == number]
        assert track.time[0] - 1e-6 <= times.min() and times.max() <= track.time[-1] + 1e-6
        assert np.allclose(np.diff(track.time)[:-1], 0.1)


def test_a_lever_arm_and_boresight_move_the_beam(tmp_path):
    """A sensor 1 m ahead and 0.5 m right of the reference point, turned 2° in roll: the beam leaves from
    (X + 0.5, y + 1) and every point lands H·tan(φ − 2°) right of it (the roll of the mount as of the body),
    φ the deflector's angle; φ − 2° is its scan angle, from the vertical."""
    sensor = {**NARROW, "mount": {"lever_arm": [1.0, 0.5, 0.0], "boresight": [2.0, 0.0, 0.0]}}
    path = scene_file(tmp_path, sensor=sensor, survey={
        "altitude": 30, "speed": 10, "pulse_frequency": 10000, "scan_frequency": 100, "lines": [[[X, 5.0], [X, 35.0]]]})
    scene = load_scene(path)
    plan = make_plan(scene)
    points = scan(scene, plan, build_scene(plan, {}, scene.sensor, scene.simulation.variant), progress=False).points
    phi = deflector_angle(points)
    assert np.abs(points["x"] - X - 0.5 - 30 * np.tan(phi - np.radians(2))).max() < 2e-3
    assert np.abs(points["scan_angle"] - np.degrees(phi - np.radians(2))).max() < 1e-4
    assert np.abs(points["y"] - 6.0 - 10 * points["gps_time"]).max() < 2e-3


@pytest.mark.parametrize("text, where, reason", [
    ("time,x,y,roll,pitch,yaw\n0,1,2,0,0,0\n", "line 1", "the header lacks z"),
    ("time,x,y,z,roll,pitch,yaw\n0,1,2,30,0,0,0\n1,1,2,30,0,0,0\n1,1,3,30,0,0,0\n", "line 4", "time must increase"),
    ("time,x,y,z,roll,pitch,yaw\n1400000000.25,1,2,30,0,0,0\n1400000000.125,1,3,30,0,0,0\n", "line 3",
     "time must increase: 1400000000.125 s follows 1400000000.25 s"),
    ("time,x,y,z,roll,pitch,yaw\n0,1,2,30,0,0,0\n1,1,nan,30,0,0,0\n", "line 3", "a value is not finite"),
    ("time,x,y,z,roll,pitch,yaw\n0,1,2,30,0,0,0\n1,1,x,30,0,0,0\n", "line 3", "not a number"),
    ("time,x,y,z,roll,pitch,yaw\n0,1,2,30,0,0,0\n", "line 1", "a flight line needs at least two rows"),
    ("time,x,y,z,roll,pitch,yaw,line\n0,1,2,30,0,0,0,1\n1,1,2,30,0,0,0,1\n2,1,2,30,0,0,0,2\n", "line 4",
     "a flight line needs at least two rows"),
    ("time,x,y,z,roll,pitch,yaw\n", "line 1", "a flight line needs at least two rows"),
    ("", "", "empty"),
    ("time,x,y,z,roll,pitch,yaw\n0,20,5,30,0,0,0\n3000,20,35,30,0,0,0\n", "line 2",
     "the flight line goes 30.0 m in 3,000 s (0.01 m/s), slower than any platform flies: the time column must be "
     "seconds (is it milliseconds?)"),
])
def test_a_bad_trajectory_file_is_one_line_and_exit_2(tmp_path, capsys, text, where, reason):
    csv = tmp_path / "bad.csv"
    csv.write_text(text)
    path = scene_file(tmp_path, survey={"trajectory": str(csv)})
    assert main(["plan", str(path), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and (f"bad.csv: {where}: {reason}" if where else f"bad.csv: {reason}") in err
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_a_trajectory_too_long_to_number_its_pulses_is_refused_as_the_files_not_survey_speed(tmp_path, capsys):
    """A flight line of 10^7 s (1 m/s over 10,000 km): the refusal named survey.speed, which a trajectory
    does not fly, and said "fly faster"."""
    csv = _trajectory_csv(tmp_path / "t.csv", [[0, 20, 5, 30, 0, 0, 0], [1e7, 20, 1e7, 30, 0, 0, 0]])
    path = scene_file(tmp_path, survey={"trajectory": str(csv)})
    assert main(["plan", str(path), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "scene.yaml: survey.trajectory: leg 1 lasts 10,000,000 s" in err, err
    assert not (tmp_path / "out").exists()


def test_a_trajectory_below_the_ground_is_refused_as_the_files_not_survey_altitude(tmp_path, capsys):
    """Heights above the datum less an offset gone wrong: the refusal named survey.altitude (not flown with
    a trajectory) and 'the ground rises 0.0 m above its mean height'."""
    csv = _trajectory_csv(tmp_path / "t.csv", [[0, 20, 5, -5, 0, 0, 0], [1, 20, 15, -5, 0, 0, 0]])
    path = scene_file(tmp_path, survey={"trajectory": str(csv)})
    assert main(["plan", str(path), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "scene.yaml: survey.trajectory: the trajectory comes down to z -5.0 m, below " \
        "the ground's highest point at 0.0 m" in err and "in the scene's local frame (origin.offset subtracted)" in err
    assert not (tmp_path / "out").exists()


def test_a_hovering_platform_is_not_taken_for_a_trajectory_in_milliseconds(tmp_path):
    """4.9 m of drift in 100 s, and 30 m in 600 s (0.05 m/s), are flown; the speed check spares them."""
    for rows in ([[0, 20, 5, 30, 0, 0, 0], [100, 20, 9.9, 30, 0, 0, 0]], [[0, 20, 5, 30, 0, 0, 0], [600, 20, 35, 30, 0, 0, 0]]):
        csv = _trajectory_csv(tmp_path / "t.csv", rows)
        plan = make_plan(load_scene(scene_file(tmp_path, survey={"trajectory": str(csv)})))
        assert (plan.legs[0].t0, plan.legs[0].t1) == (0.0, rows[1][0])


def test_trajectory_settings_that_contradict_are_refused(tmp_path, capsys):
    csv = _trajectory_csv(tmp_path / "t.csv", [[0, 20, 5, 30, 0, 0, 0], [1, 20, 15, 30, 0, 0, 0]])
    both = scene_file(tmp_path / "a", survey={"trajectory": str(csv), "lines": [[[0, 0], [1, 1]]]})
    assert main(["plan", str(both)]) == 2
    assert "survey.lines: give either survey.lines or survey.trajectory" in capsys.readouterr().err
    rolled = scene_file(tmp_path / "b", survey={"trajectory": str(csv), "attitude": {"roll": 2}})
    assert main(["plan", str(rolled)]) == 2
    assert "survey.attitude: a trajectory file gives its own attitude" in capsys.readouterr().err


def test_device_pulses_with_a_pose_table_match_the_numpy_reference(tmp_path, variant):
    """scan/pulses.py on a pose table (attitude, mount) against its numpy twin: same pulses, rays within float32."""
    from mitsuforest.scan import Platform
    from mitsuforest.scan import pulses as device
    from mitsuforest.testing.reference.pulses import reaching_pulses
    from mitsuforest.scene.variant import variant_scope
    sensor = {**NARROW, "field_of_view": 100, "mount": {"lever_arm": [0.3, -0.2, 0.1], "boresight": [1.0, -2.0, 3.0]}}
    path = scene_file(tmp_path, sensor=sensor, variant=variant, survey={
        "speed": 5, "lines": [[[X, -5.0], [X + 10, 45.0]]],
        "attitude": {"roll": {"amplitude_deg": 4, "period_s": 2.0}, "pitch": 1.5, "yaw": {"amplitude_deg": 2, "period_s": 3}}})
    scene = load_scene(path)
    leg = make_plan(scene).legs[0]
    platform = Platform(scene)
    table = platform.table(leg)
    box = np.array([[0.0, 0.0, 0.0], [40.0, 40.0, 28.0]])
    ref, fired = reaching_pulses(leg, scene.sensor, 100_000, 50, 300_000, 50_000, box, platform, table)
    with variant_scope(variant):
        got, got_fired = device.reaching_pulses(leg, scene.sensor, 100_000, 50, 300_000, 50_000, box, 0,
                                                platform.upload(table))
        assert got_fired == fired and 1000 < len(ref.index) <= fired
        assert np.array_equal(np.array(got.pulse_id), ref.index)
        for key in ("origin", "direction", "across"):
            xyz = np.column_stack([np.array(getattr(getattr(got, key), a)) for a in "xyz"])
            assert np.abs(xyz - getattr(ref, key)).max() < 1e-5, key
    # The table holds the waves: roll at 3.5 s is 4·sin(2π·3.5/2) = -4°.
    position, body = table.pose(np.array([3.5]))
    assert matrix_euler(ENU_FROM_NED.T @ body)[0, 0] == pytest.approx(-4.0, abs=1e-3)
    assert matrix_euler(ENU_FROM_NED.T @ body)[0, 1] == pytest.approx(1.5, abs=1e-3)


def test_navigation_errors_do_not_depend_on_batches_or_legs_scanned_apart(tmp_path):
    """The error series are drawn from the seed and the survey's span alone: a survey scanned whole, in
    small batches, or leg by leg (as the dataset's workers do) gives the same points."""
    errors = {"gnss_sigma_m": 0.05, "gnss_random_walk_m_per_sqrt_s": 0.02, "imu_sigma_deg": 0.05,
              "boresight_error_deg": [0.1, -0.1, 0.2]}
    path = scene_file(tmp_path, sensor=NARROW, survey={
        "altitude": 30, "speed": 10, "pulse_frequency": 10000, "scan_frequency": 100,
        "lines": [[[X, 5.0], [X, 35.0]], [[X + 5, 35.0], [X + 5, 5.0]]], "navigation_errors": errors,
        "attitude": {"roll": {"amplitude_deg": 2, "period_s": 1.3}}})
    scene = load_scene(path)
    plan = make_plan(scene)
    scan_scene = build_scene(plan, {}, scene.sensor, scene.simulation.variant)
    whole = scan(scene, plan, scan_scene, progress=False).points
    small = scan(scene.with_({"simulation.pulses_per_batch": 1000}), plan, scan_scene, progress=False).points
    apart = np.concatenate([scan(scene, plan, scan_scene, progress=False, legs=range(k, k + 1)).points for k in (0, 1)])
    assert len(whole) > 5000
    assert whole.tobytes() == small.tobytes() == apart.tobytes()
    level = scan(scene.with_({"survey.navigation_errors": {}}), plan, scan_scene, progress=False).points
    assert np.array_equal(level["pulse_id"], whole["pulse_id"])                 # the same pulses ...
    assert 0.01 < np.abs(level["z"] - whole["z"]).mean() < 0.5                 # ... placed elsewhere


def test_the_helios_export_names_the_platform_settings_it_leaves_out(tmp_path):
    from mitsuforest.helios.export import _unexported_platform
    scene = load_scene(scene_file(tmp_path))
    assert _unexported_platform(scene) == ""
    assert _unexported_platform(scene.with_({"survey.attitude.roll": 1})) == "survey.attitude is"
    assert _unexported_platform(scene.with_({"survey.navigation_errors.gnss_sigma_m": 0.1,
                                             "sensor.mount.lever_arm": [0, 0, 1]})) == \
        "sensor.mount, survey.navigation_errors are"


def _navigation(tmp_path, mount=None, **errors):
    """A NavigationModel over 0..400 s for a northbound leg along x = 20 m at 30 m, and that leg."""
    from mitsuforest.config.types import NavigationErrors
    from mitsuforest.scan.navigation import NavigationModel
    from mitsuforest.scan.platform import Platform
    sensor = {**NARROW, **({"mount": mount} if mount else {})}
    scene = load_scene(scene_file(tmp_path, sensor=sensor, survey={"altitude": 30, "lines": [[[X, 5.0], [X, 35.0]]]}))
    platform = Platform(scene)
    leg = make_plan(scene).legs[0]
    return NavigationModel(NavigationErrors(**errors), 11, (0.0, 400.0), platform), leg


def test_the_error_series_have_the_sigmas_they_are_given(tmp_path):
    """20,000 epochs at 50 Hz: white GNSS and IMU noise with the σ given per axis, and a random walk whose
    increments over one epoch have σ q·√Δt, each within 3 % (the σ of a sample σ here is 0.5 %)."""
    white, _ = _navigation(tmp_path / "w", gnss_sigma_m=(0.1, 0.2, 0.05), imu_sigma_deg=(0.01, 0.02, 0.03), rate_hz=50)
    t = white.t0 + white.step * np.arange(20_000)
    gnss, imu = white.at(t)
    assert np.std(gnss, axis=0) == pytest.approx([0.1, 0.2, 0.05], rel=0.03)
    assert np.std(imu, axis=0) == pytest.approx([0.01, 0.02, 0.03], rel=0.03)
    assert np.abs(np.mean(gnss, axis=0)).max() < 0.01
    walk, _ = _navigation(tmp_path / "r", gnss_random_walk_m_per_sqrt_s=(0.02, 0.02, 0.05), rate_hz=50)
    gnss, imu = walk.at(t)
    assert np.std(np.diff(gnss, axis=0), axis=0) == pytest.approx(np.array([0.02, 0.02, 0.05]) * np.sqrt(0.02), rel=0.03)
    assert np.array_equal(gnss[0], [0.0, 0.0, 0.0]) and not imu.any()
    half = walk.at(t[:-1] + walk.step / 2)[0]                                    # linear between epochs
    assert np.allclose(half, (gnss[:-1] + gnss[1:]) / 2)


def test_white_noise_between_epochs_has_its_sigma_interpolated(tmp_path):
    """White GNSS and IMU noise of σ at 50 Hz epochs, read at 200,000 random times (as pulses read it):
    a + u·(b − a) of two independent epochs has variance σ²·((1 − u)² + u²), so over uniform u the
    std is σ·√(2/3) (0.82 σ), not σ, and σ/√2 midway (README, "Navigation errors"). Sampling error of
    the std here: about 0.3 %."""
    sigma, imu = np.array([0.1, 0.2, 0.05]), np.array([0.01, 0.02, 0.03])
    model, _ = _navigation(tmp_path, gnss_sigma_m=tuple(sigma), imu_sigma_deg=tuple(imu), rate_hz=50)
    t = np.random.default_rng(4).uniform(0.0, 400.0, 200_000)
    gnss, attitude = model.at(t)
    assert np.std(gnss, axis=0) == pytest.approx(sigma * np.sqrt(2 / 3), rel=0.02)
    assert np.std(attitude, axis=0) == pytest.approx(imu * np.sqrt(2 / 3), rel=0.02)
    midway, _ = model.at(model.t0 + model.step * (np.arange(19_000) + 0.5))
    assert np.std(midway, axis=0) == pytest.approx(sigma / np.sqrt(2), rel=0.03)


@pytest.mark.parametrize("yaw, moved", [(0.0, "x"), (90.0, "y")])
def test_a_boresight_roll_error_turns_about_the_mounted_sensors_forward_axis(tmp_path, yaw, moved):
    """The calibration's roll error δ is about the mounted sensor's own axis (M·Q·Mᵀ in the body frame).
    Mounted straight, that axis is the body's forward one and a nadir beam's point moves H·sin δ across
    the track (x on a northbound leg); mounted turned 90° in yaw, it is the body's right axis and the
    point moves H·sin δ along the track (y), the other axis untouched."""
    delta, H = 0.5, 30.0
    model, leg = _navigation(tmp_path, mount={"boresight": [0.0, 0.0, yaw]}, boresight_error_deg=(delta, 0.0, 0.0))
    t = np.array([1.0, 2.0])
    table = model.platform.table(leg)
    position, _ = model.platform.body_pose(leg, table, t)
    below = position - [0.0, 0.0, H]                                            # a nadir beam's echo at range H
    turn, shift = model.transform(leg, table, t)
    moved_by = np.einsum("nij,nj->ni", turn, below) + shift - below
    k = "xyz".index(moved)
    assert np.abs(moved_by[:, k]) == pytest.approx(H * np.sin(np.radians(delta)), rel=1e-6)     # 0.262 m
    assert np.abs(moved_by[:, 1 - k]).max() < 1e-9
    assert moved_by[:, 2] == pytest.approx(H * (1 - np.cos(np.radians(delta))), rel=1e-6)


def test_the_believed_origin_carries_the_lever_arm_turned_by_the_imu_error(tmp_path):
    """With a lever arm ℓ, the beam's believed origin is p + g + B·E·ℓ: an IMU yaw error ε turns a 2 m
    forward arm by ε, so the true origin is placed 2·sin ε across the track (0.35 m at 10°)."""
    model, leg = _navigation(tmp_path, mount={"lever_arm": [2.0, 0.0, 0.0]}, imu_sigma_deg=(0.0, 0.0, 10.0))
    t = np.linspace(1.0, 3.0, 5)
    table = model.platform.table(leg)
    position, body = model.platform.body_pose(leg, table, t)
    origin = position + body @ model.platform.lever_arm
    turn, shift = model.transform(leg, table, t)
    placed = np.einsum("nij,nj->ni", turn, origin) + shift
    yaw = np.radians(model.at(t)[1][:, 2])
    assert np.abs(yaw).max() > np.radians(3)
    assert np.allclose(placed - position, np.column_stack([2 * np.sin(yaw), 2 * np.cos(yaw), np.zeros_like(yaw)]),
                       atol=1e-9)


@pytest.mark.parametrize("encoding", ["utf-8-sig", "utf-16", "cp1252"])
def test_a_trajectory_and_a_tree_list_as_spreadsheets_on_windows_save_them_are_read(tmp_path, encoding):
    """Spreadsheets on Windows write CSV with a UTF-8 byte order mark, as UTF-16 ("Unicode text") or as
    Windows-1252 (here with an accented free-text column), with CRLF line ends: read as UTF-8 would be."""
    def save(name, text):
        (tmp_path / name).write_bytes(text.replace("\n", "\r\n").encode(encoding))
    save("t.csv", "time,x,y,z,roll,pitch,yaw,note\n0,20,5,30,0,0,0,départ\n3,20,35,30,0,0,0,fin\n")
    save("trees.csv", "x,y,height,crown_radius,Bemerkung\n10,12,12,2.5,Kiefer ä\n")
    import yaml
    path = scene_file(tmp_path, survey={"trajectory": "t.csv"})
    path.write_text(yaml.safe_dump({**yaml.safe_load(path.read_text()), "forest": {"trees_file": "trees.csv"}}))
    plan = make_plan(load_scene(path))
    assert (plan.legs[0].t0, plan.legs[0].t1) == (0.0, 3.0) and plan.legs[0].start[:2] == (20.0, 5.0)
    assert len(plan.trees) == 1 and plan.trees[0].position[:2] == (10.0, 12.0)


def test_a_semicolon_separated_trajectory_is_refused_saying_so(tmp_path):
    (tmp_path / "t.csv").write_text("time;x;y;z;roll;pitch;yaw\n0;20;5;30;0;0;0\n3;20;35;30;0;0;0\n")
    with pytest.raises(ConfigError, match=r"t.csv: line 1: the file is separated by ';' \(a spreadsheet set to "
                                          r"decimal commas\): save it as CSV with ','"):
        make_plan(load_scene(scene_file(tmp_path, survey={"trajectory": "t.csv"})))


def test_a_trajectory_naming_a_column_twice_is_refused(tmp_path):
    (tmp_path / "t.csv").write_text("time,x,y,z,roll,pitch,yaw,x\n0,20,5,30,0,0,0,1\n3,20,35,30,0,0,0,1\n")
    with pytest.raises(ConfigError, match=r"t.csv: line 1: the header names x 2 times; keep one"):
        make_plan(load_scene(scene_file(tmp_path, survey={"trajectory": "t.csv"})))


def test_a_binary_trajectory_or_tree_list_is_refused_in_one_line(tmp_path):
    from mitsuforest.errors import UserError
    (tmp_path / "t.csv").write_bytes(b"MATLAB 5.0 MAT-file\0\0\x01time,x")
    with pytest.raises(UserError, match=r"t.csv: not a text file"):
        make_plan(load_scene(scene_file(tmp_path, survey={"trajectory": "t.csv"})))
    (tmp_path / "trees.csv").write_bytes(b"x,y\0\0")
    import yaml
    path = scene_file(tmp_path)
    path.write_text(yaml.safe_dump({**yaml.safe_load(path.read_text()), "forest": {"trees_file": "trees.csv"}}))
    with pytest.raises(UserError, match=r"cannot read the tree list .*trees.csv: .*a binary file"):
        make_plan(load_scene(path))
