"""How a real scan was flown, estimated from its points (pure functions).

* Flight lines: one per ``point_source_id`` where the file has several, else the GPS time split at
  gaps of more than ``LINE_GAP`` s.
* Trajectory: the returns of one pulse lie on its beam, so the line through a pulse's first and last
  returns points at the scanner (Gatziolis & McGaughey 2019; lidR's ``track_sensor``). Each line's
  track is the straight, constant-speed path ``p(t) = p0 + v (t - t_mid)`` nearest all its pulses' beam
  lines (linear least squares): altitude above the ground, speed and heading follow.
* Scan rate: a rotating or oscillating mirror crosses the plot once per scan line, so the returns come
  in bursts one scan period apart: the period is the median spacing of burst starts.
* Pulse rate: one over the median spacing of first returns in a burst; where GPS times are too coarse
  to tell pulses apart, they are stamps a fixed step apart, and a stamp inside a burst holds every pulse
  fired in it: the fullest stamps hold the pulse rate times the step (:func:`stamped_pulse_rate`).
* Field of view: at least twice the largest scan angle seen.

What cannot be estimated (no GPS time, no pulse with two returns, too few bursts) is left ``None``
and named in ``missing`` with the reason.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

LINE_GAP = 1.0          # s: a pause this long between returns starts a new flight line
MIN_BEAM_LENGTH = 1.0   # m between a pulse's first and last returns for its beam direction to count
MIN_RAYS = 20           # pulses with two returns a line needs for its track
GOOD_TRACK = 0.5        # m: RMS miss of the beams below which a track is trusted
BURST_GAP = 0.5e-3      # s: returns further apart than this (and 20 median spacings) start a new burst


@dataclass(frozen=True)
class Track:
    """One flight line's straight track: position at ``t_mid`` (file coordinates, m), velocity (m/s)."""

    position: tuple[float, float, float]
    velocity: tuple[float, float, float]
    t_mid: float
    t_span: tuple[float, float]
    rays: int                                  # pulses whose beams fixed it
    residual: float                            # RMS distance (m) of the track from those beams


@dataclass(frozen=True)
class SurveyEstimate:
    """What could be estimated; ``None`` where it could not (``missing`` says why)."""

    lines: int
    tracks: tuple[Track, ...] = ()
    line_positions: tuple[tuple[float, float], ...] = ()   # a point each placed line passes through (file frame)
    line_sources: tuple[str, ...] = ()         # per file line: track, scan angle or not placed
    altitude: float | None = None              # m above the mean ground
    speed: float | None = None                 # m/s
    heading: float | None = None               # deg clockwise from +y, of the line axis (0-180)
    scan_frequency: float | None = None        # Hz
    pulse_frequency: float | None = None       # Hz
    field_of_view: float | None = None         # deg, a lower bound
    missing: dict = field(default_factory=dict)   # quantity: reason


def line_groups(point_source_id, gps_time) -> list[np.ndarray]:
    """Point indices of each flight line."""
    if point_source_id is not None and len(np.unique(point_source_id)) > 1:
        return [np.nonzero(point_source_id == p)[0] for p in np.unique(point_source_id)]
    if gps_time is None:
        return []
    order = np.argsort(gps_time, kind="stable")
    cuts = np.nonzero(np.diff(gps_time[order]) > LINE_GAP)[0] + 1
    return [np.sort(g) for g in np.split(order, cuts)]


def beam_rays(xyz, t, return_number, number_of_returns) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pulses with a first and a last return (same GPS time and return count, one of each): anchors (k, 3)
    at the last return, unit directions (k, 3) towards the first (towards the scanner), times (k,)."""
    multi = number_of_returns >= 2
    first = np.nonzero(multi & (return_number == 1))[0]
    last = np.nonzero(multi & (return_number == number_of_returns))[0]
    key_first = np.rec.fromarrays([t[first], number_of_returns[first]])
    key_last = np.rec.fromarrays([t[last], number_of_returns[last]])
    kf, cf = np.unique(key_first, return_counts=True)
    kl, cl = np.unique(key_last, return_counts=True)
    both = np.intersect1d(kf[cf == 1], kl[cl == 1])
    fi = first[np.isin(key_first, both)]
    li = last[np.isin(key_last, both)]
    fi = fi[np.lexsort((number_of_returns[fi], t[fi]))]
    li = li[np.lexsort((number_of_returns[li], t[li]))]
    d = xyz[fi] - xyz[li]
    length = np.linalg.norm(d, axis=1)
    ok = length >= MIN_BEAM_LENGTH
    return xyz[li][ok], d[ok] / length[ok, None], t[li][ok]


def fit_track(anchors, directions, times) -> Track:
    """The constant-velocity track nearest the beam lines (see the module docstring)."""
    t_mid = float(np.median(times))
    dt = times - t_mid
    p = np.eye(3) - directions[:, :, None] * directions[:, None, :]   # (k, 3, 3): drops the part along the beam
    m = np.concatenate([p, p * dt[:, None, None]], axis=2).reshape(-1, 6)
    b = np.einsum("kij,kj->ki", p, anchors).reshape(-1)
    solution, *_ = np.linalg.lstsq(m, b, rcond=None)
    residual = float(np.sqrt(np.mean((m @ solution - b) ** 2) * 3 / 2))
    return Track(tuple(solution[:3]), tuple(solution[3:]), t_mid, (float(times.min()), float(times.max())),
                 len(times), residual)


def bursts(t) -> list[np.ndarray]:
    """Sorted times split into the bursts of one scan line each."""
    t = np.sort(np.asarray(t, np.float64))
    gaps = np.diff(t)
    if len(gaps) == 0:
        return [t]
    step = np.median(gaps[gaps > 0]) if (gaps > 0).any() else 0.0
    cuts = np.nonzero(gaps > max(BURST_GAP, 20 * step))[0] + 1
    return np.split(t, cuts)


def scan_period(groups: list[np.ndarray]) -> float | None:
    """The scan period (s): the median spacing of consecutive burst starts, over the shortest spacings
    (a burst missed doubles a spacing)."""
    spacings = np.concatenate([np.diff([b[0] for b in groups])]) if len(groups) > 2 else np.zeros(0)
    if len(spacings) < 3:
        return None
    short = spacings[spacings <= 1.5 * np.percentile(spacings, 10)]
    return float(np.median(short))


def pulse_rate(groups_first: list[np.ndarray]) -> float | None:
    """Pulses per second inside bursts of first-return times (bursts of at least 10 pulses): one over the
    median spacing of consecutive pulses, which pulses without a return do not bias; where the GPS time
    is too coarse to tell pulses apart (more than 5 % share a time), :func:`stamped_pulse_rate`."""
    bursts_ = [b for b in groups_first if len(b) >= 10 and b[-1] > b[0]]
    if not bursts_:
        return None
    spacing = np.concatenate([np.diff(b) for b in bursts_])
    if np.mean(spacing == 0) <= 0.05:
        return float(1.0 / np.median(spacing[spacing > 0]))
    return stamped_pulse_rate(bursts_)


def stamped_pulse_rate(bursts_: list[np.ndarray]) -> float | None:
    """Pulses per second from bursts of first-return times stamped at a coarse, fixed step (the median
    positive spacing of stamps within bursts). A stamp with a stamp one step before and after it lies
    inside the burst, so it holds every pulse fired in its step that left a first return in the file.
    Pulses are lost in stretches (first returns outside a clipped plot, on the stand around it; sky), which
    only ever empty stamps, so the full stamps are the fullest: those within one pulse of the 90th
    percentile of the inner stamps' counts, and the rate is their mean count over the step. Counting a
    whole burst over its length instead counts each pulse lost, and the burst's partial first and last
    stamps, against the rate (UAS_Clip: 590 kHz, where its full stamps say 820-830 kHz on every line).
    ``None`` without inner stamps, or where the step is not well inside a burst (over :data:`BURST_GAP`)."""
    stamps = [np.unique(b, return_counts=True) for b in bursts_]
    steps = np.concatenate([np.diff(t) for t, _ in stamps])
    if not len(steps):
        return None
    step = float(np.median(steps))
    if step <= 0 or step > BURST_GAP:
        return None
    inner = []
    for t, counts in stamps:
        gaps = np.diff(t)
        one_step = np.abs(gaps - step) <= 0.5 * step
        inner.append(counts[1:-1][one_step[:-1] & one_step[1:]])
    inner = np.concatenate(inner)
    if not len(inner):
        return None
    full = inner[inner >= np.percentile(inner, 90) - 1]
    return float(np.mean(full) / step)


@dataclass(frozen=True)
class _Line:
    """What one flight line's points say: its track (if any), the mean horizontal direction of its beams
    towards the scanner, its points' centroid (x, y, z) and median absolute scan angle (deg)."""

    track: Track | None
    towards_scanner: np.ndarray | None
    centroid: np.ndarray
    scan_angle: float | None


def _line(scan, g: np.ndarray, xyz: np.ndarray) -> _Line:
    t = scan.gps_time
    anchors, directions, times = beam_rays(xyz[g], t[g], scan.return_number[g], scan.number_of_returns[g])
    track = fit_track(anchors, directions, times) if len(times) >= MIN_RAYS and np.ptp(times) > 0 else None
    towards = None
    if len(directions):
        mean = directions[:, :2].mean(axis=0)
        towards = mean / np.linalg.norm(mean) if np.linalg.norm(mean) > 0 else None
    angle = float(np.median(np.abs(scan.scan_angle[g]))) if scan.scan_angle is not None else None
    return _Line(track, towards, xyz[g].mean(axis=0), angle)


def estimate(scan, ground_height: float) -> SurveyEstimate:
    """Estimate the survey of a :class:`~mitsuforest.twin.points.RealScan` whose mean ground height
    (file coordinates) is ``ground_height``.

    A line whose own track fits its beams well (within ``GOOD_TRACK``) is placed on it. Another line
    with beams is placed parallel to the good tracks, on the side its beams point to, as far across as
    its median scan angle says at the sensor's height: ``(z_sensor - z_points) · tan(angle)``.
    """
    missing = {}
    t = scan.gps_time
    groups = line_groups(scan.point_source_id, t) if t is not None else []
    if t is None:
        missing.update({k: "the file has no GPS time" for k in ("lines", "altitude", "speed", "scan_frequency",
                                                                 "pulse_frequency")})
    xyz = np.column_stack([scan.x, scan.y, scan.z])
    periods, rates = [], []
    for g in groups:
        if (p := scan_period(bursts(t[g]))) is not None:
            periods.append(p)
        if (r := pulse_rate(bursts(t[g][scan.return_number[g] == 1]))) is not None:
            rates.append(r)
    lines = [_line(scan, g, xyz) for g in groups]
    tracks = [ln.track for ln in lines if ln.track is not None]
    good = [tr for tr in tracks if tr.residual <= GOOD_TRACK] or tracks
    if t is not None and not tracks:
        why = (f"no flight line has {MIN_RAYS} pulses with a first and a last return {MIN_BEAM_LENGTH:g} m apart "
               "(return numbers and GPS times of one pulse are needed)")
        missing.update({k: why for k in ("lines", "altitude", "speed")})
    if t is not None and not periods:
        missing["scan_frequency"] = "too few scan-line bursts in the GPS times"
    if t is not None and not rates:
        missing["pulse_frequency"] = "no scan-line burst of 10 pulses in the GPS times"
    fov = None
    if scan.scan_angle is not None:
        fov = float(2 * np.max(np.abs(scan.scan_angle)))
    else:
        missing["field_of_view"] = "the file has no scan angle"
    heading = _heading(good) if good else None
    sensor_z = float(np.median([tr.position[2] for tr in good])) if good else None
    positions, sources = _line_positions(lines, good, heading, sensor_z)
    return SurveyEstimate(
        lines=len(groups), tracks=tuple(tracks), line_positions=positions, line_sources=sources,
        altitude=sensor_z - ground_height if good else None,
        speed=float(np.median([np.hypot(*tr.velocity[:2]) for tr in good])) if good else None,
        heading=heading,
        scan_frequency=1.0 / float(np.median(periods)) if periods else None,
        pulse_frequency=float(np.median(rates)) if rates else None,
        field_of_view=fov, missing=missing)


def _line_positions(lines: list[_Line], good: list[Track], heading, sensor_z) -> tuple[tuple, tuple]:
    """A point (x, y) each placed line passes through, and how it was placed (see :func:`estimate`)."""
    if heading is None:
        return (), ()
    across = np.array([np.cos(np.deg2rad(heading)), -np.sin(np.deg2rad(heading))])
    positions, sources = [], []
    for ln in lines:
        if ln.track is not None and ln.track in good:
            positions.append(tuple(map(float, ln.track.position[:2])))
            sources.append("track")
        elif ln.towards_scanner is not None and ln.scan_angle is not None:
            side = 1.0 if ln.towards_scanner @ across >= 0 else -1.0
            distance = max(sensor_z - ln.centroid[2], 0.0) * np.tan(np.deg2rad(ln.scan_angle))
            positions.append(tuple(map(float, ln.centroid[:2] + side * distance * across)))
            sources.append("scan angle")
        else:
            sources.append("not placed")
    return tuple(positions), tuple(sources)


def _heading(tracks) -> float:
    """The flight lines' common axis (deg clockwise from +y, 0-180), the ray-weighted mean of the tracks'."""
    angles = np.array([np.arctan2(tr.velocity[0], tr.velocity[1]) for tr in tracks])
    weights = np.array([tr.rays for tr in tracks], float)
    doubled = np.angle(np.sum(weights * np.exp(2j * angles))) / 2       # axial mean: a line flown either way
    return float(np.rad2deg(doubled) % 180)


def leg_ends(position, heading: float, bounds, margin: float) -> tuple[tuple[float, float], tuple[float, float]]:
    """A leg through ``position`` (x, y) along ``heading`` (deg), over the plot ``bounds``
    (xmin, ymin, xmax, ymax) projected on it, ``margin`` m beyond each end."""
    axis = np.array([np.sin(np.deg2rad(heading)), np.cos(np.deg2rad(heading))])
    centre = np.array(position[:2], float)
    corners = np.array([[bounds[0], bounds[1]], [bounds[2], bounds[1]], [bounds[0], bounds[3]], [bounds[2], bounds[3]]])
    along = (corners - centre) @ axis
    a, b = centre + (along.min() - margin) * axis, centre + (along.max() + margin) * axis
    return (float(a[0]), float(a[1])), (float(b[0]), float(b[1]))
