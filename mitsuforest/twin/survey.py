"""How a real scan was flown, estimated from its points (pure functions).

* Flight lines: one per ``point_source_id`` where the file has several, else the GPS time split at
  gaps of more than ``LINE_GAP`` s.
* Trajectory: the returns of one pulse lie on its beam, so the line through a pulse's first and last
  returns points at the scanner (Gatziolis & McGaughey 2019; lidR's ``track_sensor``). Each line's
  track is the straight, constant-speed path ``p(t) = p0 + v (t - t_mid)`` nearest all its pulses' beam
  lines (linear least squares): altitude above the ground, speed and heading follow.
* Nadir lines, where no line has such a track (a file of first returns only, or of single returns): a
  scan line's points lie along the sweep at ``(h - z) tan(angle)`` from the nadir, so their positions
  along it and their scan angles give the sensor's height ``h`` (least squares in the angles, which a
  file rounds); the flight runs square to the sweeps, its speed the sweeps' progress over time, and each
  line lies where its sweeps' nadirs do at the flight lines' median height (:func:`nadir_line`).
* Scan rate: a rotating mirror crosses the nadir once a turn, at a steady rate: where a line has sweeps,
  each sweep's time at scan angle 0 is its scan line's, and the period is the median spacing of those
  (:func:`crossing_period`); the pieces of one scan line (a crown beyond a clipped plot's ground seen
  apart from it) cross it together. Without sweeps, a mirror crosses the plot once per scan line, so the
  returns come in bursts one scan period apart: the period is the median spacing of burst starts.
* Deflector: a rotating mirror sweeps every scan line one way, an oscillating one there and back; where a
  quarter of the sweeps or more run against the others, the mirror oscillates, its scan lines half the
  spacing of sweeps that run the same way (:func:`deflector_of`).
* Pulse rate: one over the median spacing of first returns in a burst; where GPS times are too coarse
  to tell pulses apart, they are stamps a fixed step apart, and a stamp inside a burst holds every pulse
  fired in it: the fullest stamps hold the pulse rate times the step (:func:`stamped_pulse_rate`).
* Field of view: at least twice the largest scan angle seen.
* A line scanner's sweeps run parallel, across its flight; a line whose sweeps run every way (a Risley
  prism pair's rosette, whose scan angle is off the nadir, never negative) says neither its flight, its
  mirror nor its scan rate (:func:`sweep_alignment`).

What cannot be estimated (no GPS time, no pulse with two returns, too few bursts) is left ``None``
and named in ``missing`` with the reason.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

LINE_GAP = 1.0          # s: a pause this long between returns starts a new flight line
MIN_BEAM_LENGTH = 1.0   # m between a pulse's first and last returns for its beam direction to count
MIN_RAYS = 20           # pulses with two returns a line needs for its track
GOOD_TRACK = 0.5        # m: RMS miss of the beams below which a track is trusted
BURST_GAP = 0.5e-3      # s: returns further apart than this (and 20 median spacings) start a new burst
SWEEP_POINTS = 10       # returns a burst needs to count as a sweep for a nadir line
SWEEP_ANGLES = 2.0      # deg of scan angle a sweep must span (LAS 1.2 stores whole degrees)
NADIR_SWEEPS = 20       # sweeps a flight line needs for its sensor height from scan angles
SWEEP_ITERATIONS = 4    # Gauss-Newton steps of a sweep's fit (:func:`sweep`)
SWEEP_MISS = 1.0        # deg: RMS miss of a sweep's fitted angles above which it is not used (whole degrees: 0.29)
MIN_LINE_SPEED = 0.5    # m/s over the ground a nadir line must make
PARALLEL_SWEEPS = 0.9   # alignment of a line's sweeps (:func:`sweep_alignment`) under which they are no scan lines


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
    line_sources: tuple[str, ...] = ()         # per file line: track, scan angle, scan lines or not placed
    line_headings: tuple[float, ...] = ()      # deg clockwise from +y, per placed line: its direction of flight
    altitude: float | None = None              # m above the mean ground
    speed: float | None = None                 # m/s
    heading: float | None = None               # deg clockwise from +y, of the line axis (0-180)
    scan_frequency: float | None = None        # scan lines a second (a rotating mirror's turns, twice an oscillating one's cycles)
    deflector: str | None = None               # rotating | oscillating, from the sweeps' senses
    pulse_frequency: float | None = None       # Hz
    field_of_view: float | None = None         # deg, a lower bound
    scan_angle_side: str | None = None         # right | left: the side of the flight positive scan angles lie on
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
    t = np.asarray(t, np.float64)
    return [t[b] for b in burst_indices(t)]


def burst_indices(t) -> list[np.ndarray]:
    """Indices of the (n,) times ``t`` in each burst, in time order (:func:`bursts`)."""
    order = np.argsort(t, kind="stable")
    gaps = np.diff(t[order])
    if len(gaps) == 0:
        return [order]
    step = np.median(gaps[gaps > 0]) if (gaps > 0).any() else 0.0
    cuts = np.nonzero(gaps > max(BURST_GAP, 20 * step))[0] + 1
    return np.split(order, cuts)


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


def sweep_parts(t, angle) -> list[np.ndarray]:
    """Indices of the sweeps among a flight line's (n,) returns: its bursts (:func:`burst_indices`), each cut
    where its scan angle turns back (an oscillating mirror's turn inside the plot leaves no pause), kept
    with :data:`SWEEP_POINTS` returns or more over :data:`SWEEP_ANGLES` or more, not all in one GPS stamp."""
    parts = [part for b in burst_indices(t) for part in _one_way(b, t, angle)]
    return [b for b in parts if len(b) >= SWEEP_POINTS and np.ptp(angle[b]) >= SWEEP_ANGLES and np.ptp(t[b]) > 0]


def _one_way(b: np.ndarray, t, angle) -> list[np.ndarray]:
    """The burst ``b`` (indices in time order) cut where its scan angle turns back: between GPS stamps
    whose mean angles step one way and then the other (a stamp may hold many pulses, in any order)."""
    times, first, members = np.unique(t[b], return_index=True, return_inverse=True)
    if len(times) < 3:
        return [b]
    means = np.bincount(members, weights=angle[b]) / np.bincount(members)
    steps = np.sign(np.diff(means))
    moving = np.flatnonzero(steps)
    turns = moving[1:][steps[moving[1:]] != steps[moving[:-1]]]      # a step against the one before it
    return np.split(b, first[turns]) if len(turns) else [b]


def sweep_senses(t, angle) -> list[tuple[float, int]]:
    """(start time, sense) of each sweep (:func:`sweep_parts`) among a flight line's (n,) returns: +1 where
    its scan angle grows with time, -1 where it falls."""
    slopes = [(float(t[b].min()), np.polyfit(t[b] - t[b].mean(), angle[b], 1)[0]) for b in sweep_parts(t, angle)]
    return [(start, 1 if slope > 0 else -1) for start, slope in slopes]


def crossing_period(t, angle) -> float | None:
    """The scan-line period (s) of a flight line's (n,) returns with GPS times ``t`` and scan angles ``angle``
    (deg) from a rotating mirror: each sweep (:func:`sweep_parts`) crosses the nadir at its mean time less
    its mean angle over the line's sweep rate (the median of its sweeps' ``|d angle / dt|``: a mirror turns
    at one rate), and crossings within :data:`BURST_GAP` are one scan line's (its pieces, where a stretch of its
    returns is lost: a crown beyond the clipped plot's ground, seen apart from it, had made the bursts of a
    rotating mirror's 40 scan lines a second say 566). :func:`scan_period` of the crossings; ``None`` with
    fewer than 4 sweeps. UAS_Clip's five lines with sweeps say 83.04 Hz each, its bursts 82.75-83.06 Hz.
    (An oscillating mirror's sweep off the nadir, not linear in time, misses its crossing by a part of its
    period that alternates with its sense: MixedConifer's crossings are 6.7 and 9.0 ms apart in turn.)"""
    parts = sweep_parts(t, angle)
    if len(parts) < 4:
        return None
    slopes = np.array([np.polyfit(t[b] - t[b].mean(), angle[b], 1)[0] for b in parts])
    rate = float(np.median(np.abs(slopes)))
    if not rate > 0:
        return None
    crossings = np.sort([t[b].mean() - np.mean(angle[b]) / (rate * np.sign(s)) for b, s in zip(parts, slopes) if s])
    crossings = crossings[np.r_[True, np.diff(crossings) > BURST_GAP]]
    return scan_period([np.array([c]) for c in crossings])


def sweep_alignment(x, y, t, angle) -> float | None:
    """How parallel a flight line's sweeps (:func:`sweep_parts`) run, from 0 (every way) to 1: the mean
    resultant length of their principal directions (doubled angles: a direction is an axis), weighted by
    their returns; ``None`` with fewer than 3 sweeps. A line scanner's are 0.99 or more (UAS_Clip,
    MixedConifer, renders of the VUX-1UAV22 and ALS50-II); a render of a Livox Mid-70's rosette 0.1-0.3."""
    parts = sweep_parts(t, angle)
    if len(parts) < 3:
        return None
    directions = []
    for b in parts:
        q = np.column_stack([x[b], y[b]]) - [np.mean(x[b]), np.mean(y[b])]
        directions.append(np.linalg.eigh(q.T @ q)[1][:, 1])
    return axial_alignment(directions, [len(b) for b in parts])


def axial_alignment(directions, weights) -> float:
    """The mean resultant length, 0 to 1, of the (k, 2) ``directions`` taken as axes (their doubled angles)
    with the (k,) ``weights``: 1 where they all run one way, whichever sense."""
    d = np.asarray(directions, float).reshape(-1, 2)
    w = np.asarray(weights, float)
    return float(abs(np.sum(w * np.exp(2j * np.arctan2(d[:, 1], d[:, 0])))) / np.sum(w))


def deflector_of(senses: list[list[tuple[float, int]]]) -> tuple[str | None, list[float]]:
    """The deflector that the flight lines' sweeps (:func:`sweep_senses`, one list a line) say, and for an
    oscillating one the scan-line periods (s) of its lines with 4 sweeps each way or more: half the period
    of the sweeps that run one way (:func:`scan_period` of their starts). Each line with 6 sweeps or more
    votes, oscillating where a quarter of its sweeps or more run against the rest (a file whose lines
    count their scan angles from opposite sides still has each line's sweeps run one way), and the
    deflector is the one of most sweeps; ``None`` without a line that votes."""
    votes = {"rotating": 0, "oscillating": 0}
    for line in senses:
        ways = [sense for _, sense in line]
        if len(ways) >= 6:
            votes["oscillating" if min(ways.count(1), ways.count(-1)) >= 0.25 * len(ways) else "rotating"] += len(ways)
    if not any(votes.values()):
        return None, []
    if votes["rotating"] >= votes["oscillating"]:
        return "rotating", []
    periods = []
    for line in senses:
        for way in (1, -1):
            starts = [np.array([start]) for start, sense in line if sense == way]
            if (p := scan_period(starts)) is not None:
                periods.append(p / 2)
    return "oscillating", periods


@dataclass(frozen=True)
class Sweep:
    """One scan line's points seen from above: their centroid (x, y), the unit direction of the sweep
    towards larger scan angles, and the height (file z) of the sensor that their positions and angles say."""

    centroid: np.ndarray
    direction: np.ndarray
    sensor_z: float
    miss: float = 0.0          # deg: RMS of the scan angles less those the fit gives
    top: float = 0.0           # the highest of its points (file z)

    @property
    def usable(self) -> bool:
        """Fitted within :data:`SWEEP_MISS` with the sensor above its points (a file that keeps absolute
        or random scan angles fits neither)."""
        return self.miss <= SWEEP_MISS and self.sensor_z > self.top


def sweep(x, y, z, angle) -> Sweep:
    """The :class:`Sweep` of one scan line's (k,) points with scan angles ``angle`` (deg). Along the
    sweep's principal direction a point lies at ``s = s0 + (h - z) tan(angle)``. The positions are exact
    and the angles rounded (LAS 1.2: whole degrees), so ``tan(angle) = (s - s0) / (h - z)`` is fitted in
    ``s0`` and ``h`` (Gauss-Newton from the fit of ``s``, whose slope the rounding flattens: 2.7 % low
    over a 6° sweep of whole degrees)."""
    p = np.column_stack([x, y])
    centroid = p.mean(axis=0)
    q = p - centroid
    direction = np.linalg.eigh(q.T @ q)[1][:, 1]
    tan = np.tan(np.deg2rad(angle))
    s = q @ direction
    if np.dot(tan - tan.mean(), s) < 0:
        direction, s = -direction, -s
    (s0, height), *_ = np.linalg.lstsq(np.column_stack([np.ones_like(tan), tan]), s + z * tan, rcond=None)
    for _ in range(SWEEP_ITERATIONS):
        depth = np.maximum(height - z, 1e-3)
        jacobian = np.column_stack([-1 / depth, -(s - s0) / depth ** 2])
        step, *_ = np.linalg.lstsq(jacobian, tan - (s - s0) / depth, rcond=None)
        s0, height = s0 + step[0], height + step[1]
    fitted = np.rad2deg(np.arctan((s - s0) / np.maximum(height - z, 1e-3)))
    miss = float(np.sqrt(np.mean((np.asarray(angle, np.float64) - fitted) ** 2)))
    return Sweep(centroid, direction, float(height), miss if np.isfinite(miss) else np.inf, float(np.max(z)))


def nadir_offset(sw: Sweep, x, y, z, angle, sensor_z: float) -> np.ndarray:
    """The nadir point (x, y) of the sweep ``sw`` for a sensor at ``sensor_z``: the median over its points of
    where ``s - (sensor_z - z) tan(angle)`` puts it on the sweep's line."""
    s = (np.column_stack([x, y]) - sw.centroid) @ sw.direction
    s0 = np.median(s - (sensor_z - z) * np.tan(np.deg2rad(angle)))
    return sw.centroid + s0 * sw.direction


@dataclass(frozen=True)
class NadirLine:
    """A flight line found from its sweeps (see the module docstring)."""

    sweeps: int
    sensor_z: float                      # median over its sweeps (file z)
    heading: float                       # deg clockwise from +y: the direction of flight
    speed: float                         # m/s over the ground
    position: tuple[float, float] = (np.nan, np.nan)   # its nadir track at the middle sweep, at the lines' height


def nadir_line(x, y, z, t, angle) -> tuple[NadirLine, list] | None:
    """The flight line of (n,) points with GPS times ``t`` and scan angles ``angle`` (deg), and its sweeps'
    point indices and :class:`Sweep`; ``None`` with fewer than three usable sweeps (:func:`sweep_parts`,
    :attr:`Sweep.usable`), sweeps that do not run parallel (:data:`PARALLEL_SWEEPS`) or a progress under
    :data:`MIN_LINE_SPEED`. The flight is square to the sweeps'
    mean direction; its sense and speed are the sweeps' centroids' progress along it over time (a
    least-squares slope)."""
    found = [(b, sweep(x[b], y[b], z[b], angle[b])) for b in sweep_parts(t, angle)]
    found = [(b, sw) for b, sw in found if sw.usable]
    if len(found) < 3:
        return None
    parts, sweeps = [b for b, _ in found], [sw for _, sw in found]
    if axial_alignment([sw.direction for sw in sweeps], [len(b) for b in parts]) < PARALLEL_SWEEPS:
        return None
    across = np.sum([sw.direction * len(b) for sw, b in zip(sweeps, parts)], axis=0)
    if np.linalg.norm(across) == 0:
        return None
    across /= np.linalg.norm(across)
    along = np.array([-across[1], across[0]])
    times = np.array([np.mean(t[b]) for b in parts])
    progress = np.polyfit(times - times.mean(), np.array([sw.centroid for sw in sweeps]) @ along, 1)[0]
    if not abs(progress) >= MIN_LINE_SPEED:
        return None
    along = along if progress >= 0 else -along
    line = NadirLine(len(sweeps), float(np.median([sw.sensor_z for sw in sweeps])),
                     float(np.rad2deg(np.arctan2(along[0], along[1])) % 360), float(abs(progress)))
    return line, list(zip(parts, sweeps))


def place_nadir_line(line: NadirLine, parts: list, x, y, z, angle, sensor_z: float) -> NadirLine:
    """``line`` with its position: across the flight, the median of its sweeps' nadirs for a sensor at
    ``sensor_z``; along it, its middle sweep's centroid."""
    along, across = flight_axes(line.heading)
    nadirs = np.array([nadir_offset(sw, x[b], y[b], z[b], angle[b], sensor_z) for b, sw in parts])
    centroids = np.array([sw.centroid for _, sw in parts])
    point = np.median(centroids @ along) * along + np.median(nadirs @ across) * across
    return dataclasses.replace(line, position=(float(point[0]), float(point[1])))


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
    its median scan angle says at the sensor's height: ``(z_sensor - z_points) · tan(angle)``. Where no line
    has a track that fits its beams well, each line with sweeps is placed on its nadir line
    (:func:`nadir_line`), flown its own way.
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
    aligned = [sweep_alignment(scan.x[g], scan.y[g], t[g], scan.scan_angle[g]) for g in groups] \
        if scan.scan_angle is not None else []
    scanned = [g for g, a in zip(groups, aligned) if a is not None and a >= PARALLEL_SWEEPS]
    senses = [sweep_senses(t[g], scan.scan_angle[g]) for g in scanned]
    deflector, line_periods = deflector_of(senses)
    every_way = None
    if not scanned and any(a is not None for a in aligned):
        why = every_way = (f"the file's sweeps run every way (aligned {max(a for a in aligned if a is not None):.2f}, a line "
               f"scanner's {PARALLEL_SWEEPS:g} or more): not a mirror's scan lines (a Risley prism pair's rosette?)")
        missing.update({"deflector": why, "scan_frequency": why})
        periods = []
    elif deflector == "oscillating":      # burst spacings of a mirror there and back are not its scan lines'
        periods = line_periods
        if not periods and t is not None:
            missing["scan_frequency"] = "an oscillating mirror with no line of 4 sweeps each way"
    elif crossed := [p for g in scanned if (p := crossing_period(t[g], scan.scan_angle[g])) is not None]:
        periods = crossed               # a turn's nadir crossings: its bursts may be pieces of one scan line
    lines = [_line(scan, g, xyz) for g in groups]
    tracks = [ln.track for ln in lines if ln.track is not None]
    good = [tr for tr in tracks if tr.residual <= GOOD_TRACK]
    nadir = _nadir_lines(scan, groups) if t is not None and not good and scan.scan_angle is not None else None
    good = good or tracks          # without sweeps, tracks that fit their beams badly are still the best guess
    if t is not None and not tracks and nadir is None:
        why = (f"no flight line has {MIN_RAYS} pulses with a first and a last return {MIN_BEAM_LENGTH:g} m apart "
               "(return numbers and GPS times of one pulse are needed), nor "
               + (f"{NADIR_SWEEPS} sweeps (bursts of {SWEEP_POINTS} returns or more over {SWEEP_ANGLES:g}° of scan "
                  f"angle or more, fitted within {SWEEP_MISS:g}°) moving at {MIN_LINE_SPEED:g} m/s or more"
                  if scan.scan_angle is not None else "scan angles")) + (f"; {every_way}" if every_way else "")
        missing.update({k: why for k in ("lines", "altitude", "speed")})
    if t is not None and not periods and "scan_frequency" not in missing:
        missing["scan_frequency"] = "too few scan-line bursts in the GPS times"
    if t is not None and not rates:
        missing["pulse_frequency"] = "no scan-line burst of 10 pulses in the GPS times"
    fov = None
    if scan.scan_angle is not None:
        fov = float(2 * np.max(np.abs(scan.scan_angle)))
    else:
        missing["field_of_view"] = "the file has no scan angle"
    common = dict(lines=len(groups), tracks=tuple(tracks), field_of_view=fov, missing=missing, deflector=deflector,
                  scan_frequency=1.0 / float(np.median(periods)) if periods else None,
                  pulse_frequency=float(np.median(rates)) if rates else None)
    if nadir is not None:
        placed, sensor_z, side = nadir
        strong = [ln for ln in placed if ln is not None and ln.sweeps >= NADIR_SWEEPS]
        return SurveyEstimate(
            **common, line_positions=tuple(ln.position for ln in placed if ln is not None),
            line_sources=tuple("scan lines" if ln is not None else "not placed" for ln in placed),
            line_headings=tuple(ln.heading for ln in placed if ln is not None),
            altitude=sensor_z - ground_height, speed=float(np.median([ln.speed for ln in strong])), scan_angle_side=side,
            heading=_axis([ln.heading for ln in strong], [ln.sweeps for ln in strong]))
    heading = _heading(good) if good else None
    sensor_z = float(np.median([tr.position[2] for tr in good])) if good else None
    positions, sources, headings = _line_positions(lines, good, heading, sensor_z)
    return SurveyEstimate(
        **common, line_positions=positions, line_sources=sources, line_headings=headings,
        altitude=sensor_z - ground_height if good else None,
        speed=float(np.median([np.hypot(*tr.velocity[:2]) for tr in good])) if good else None,
        heading=heading)


def _nadir_lines(scan, groups: list[np.ndarray]) -> tuple[list, float, str] | None:
    """Each flight line placed from its sweeps (``None`` where it has too few), the sensor's height (file
    z): the median of the lines with :data:`NADIR_SWEEPS` sweeps, and :func:`scan_angle_side`; ``None``
    without such a line."""
    cols = (scan.x, scan.y, scan.z, scan.gps_time, scan.scan_angle)
    found = [nadir_line(*(c[g] for c in cols)) for g in groups]
    strong = [f[0] for f in found if f is not None and f[0].sweeps >= NADIR_SWEEPS]
    if not strong:
        return None
    sensor_z = float(np.median([ln.sensor_z for ln in strong]))
    placed = [None if f is None else place_nadir_line(*f, scan.x[g], scan.y[g], scan.z[g], scan.scan_angle[g], sensor_z)
              for f, g in zip(found, groups)]
    return placed, sensor_z, scan_angle_side([f for f in found if f is not None])


def scan_angle_side(found: list) -> str:
    """Which side of the flight a file's positive scan angles lie on, ``right`` (as LAS counts them) or
    ``left``: the vote, by returns, of the sweeps of each :func:`nadir_line` (``found``: its line and its
    sweeps' indices and :class:`Sweep` s), each sweep's direction towards larger angles against the right of
    its line's flight."""
    votes = 0.0
    for line, parts in found:
        right = flight_axes(line.heading)[1]
        votes += sum(len(b) * np.sign(sw.direction @ right) for b, sw in parts)
    return "right" if votes >= 0 else "left"


def _line_positions(lines: list[_Line], good: list[Track], heading, sensor_z) -> tuple[tuple, tuple, tuple]:
    """A point (x, y) each placed line passes through, how it was placed (see :func:`estimate`) and its
    heading: the lines' axis ``heading`` the way its track flew (a line placed by scan angle has no track
    to say which way: the axis as it is)."""
    if heading is None:
        return (), (), ()
    along, across = flight_axes(heading)
    positions, sources, headings = [], [], []
    for ln in lines:
        if ln.track is not None and ln.track in good:
            positions.append(tuple(map(float, ln.track.position[:2])))
            sources.append("track")
            headings.append(heading if np.dot(ln.track.velocity[:2], along) >= 0 else (heading + 180.0) % 360)
        elif ln.towards_scanner is not None and ln.scan_angle is not None:
            side = 1.0 if ln.towards_scanner @ across >= 0 else -1.0
            distance = max(sensor_z - ln.centroid[2], 0.0) * np.tan(np.deg2rad(ln.scan_angle))
            positions.append(tuple(map(float, ln.centroid[:2] + side * distance * across)))
            sources.append("scan angle")
            headings.append(heading)
        else:
            sources.append("not placed")
    return tuple(positions), tuple(sources), tuple(headings)


def _heading(tracks) -> float:
    """The flight lines' common axis (deg clockwise from +y, 0-180), the ray-weighted mean of the tracks'."""
    return _axis([np.rad2deg(np.arctan2(tr.velocity[0], tr.velocity[1])) for tr in tracks], [tr.rays for tr in tracks])


def flight_axes(heading: float) -> tuple[np.ndarray, np.ndarray]:
    """The (2,) unit vectors along a flight ``heading`` (deg clockwise from +y) and to its right."""
    h = np.deg2rad(heading)
    return np.array([np.sin(h), np.cos(h)]), np.array([np.cos(h), -np.sin(h)])


def _axis(headings, weights) -> float:
    """The weighted axial mean (deg, 0-180) of ``headings`` (deg): a line flown either way counts alike."""
    doubled = np.angle(np.sum(np.asarray(weights, float) * np.exp(2j * np.deg2rad(headings)))) / 2
    return float(np.rad2deg(doubled) % 180)


def leg_ends(position, heading: float, bounds, margin: float) -> tuple[tuple[float, float], tuple[float, float]]:
    """A leg through ``position`` (x, y) along ``heading`` (deg), over the plot ``bounds``
    (xmin, ymin, xmax, ymax) projected on it, ``margin`` m beyond each end."""
    axis = flight_axes(heading)[0]
    centre = np.array(position[:2], float)
    corners = np.array([[bounds[0], bounds[1]], [bounds[2], bounds[1]], [bounds[0], bounds[3]], [bounds[2], bounds[3]]])
    along = (corners - centre) @ axis
    a, b = centre + (along.min() - margin) * axis, centre + (along.max() + margin) * axis
    return (float(a[0]), float(a[1])), (float(b[0]), float(b[1]))
