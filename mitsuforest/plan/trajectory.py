"""The platform's motion: trajectory files, attitude, and the pose table pulses are fired from.

Frames (see README, "Trajectories and navigation errors"):

- **Local frame** (the scene's): x east, y north, z up (ENU), metres.
- **Body frame**: x forward, y right, z down (the aerospace convention). Its attitude is
  ``R = Rz(yaw)·Ry(pitch)·Rx(roll)`` (intrinsic z-y'-x''), mapping body vectors into north-east-down;
  ``yaw`` is the heading, degrees clockwise from north (+y), ``pitch`` positive nose up, ``roll``
  positive right wing down. :data:`ENU_FROM_NED` then turns north-east-down into the local frame.
- **Sensor frame** (the deflector's, scan/deflector.py): x right, y forward, z up;
  :data:`BODY_FROM_SENSOR` maps it into the body frame before the mount's boresight rotation.

So a sensor-frame direction ``d`` points along ``ENU_FROM_NED · R · B · BODY_FROM_SENSOR · d`` in the local
frame, where ``B`` is the boresight rotation (same Euler convention, sensor.mount.boresight), and the beam
leaves from the platform position plus ``ENU_FROM_NED · R · lever_arm``.

A :class:`PoseTable` samples a leg's pose every :data:`TABLE_STEP` seconds (positions smoothly by a cubic
spline through a file's rows, attitude by quaternion slerp); pulses interpolate it linearly, on the
device (scan/platform.py) and in numpy (:meth:`PoseTable.pose`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError, display_path
from ..textfiles import SEMICOLONS, NotTextError, read_text, repeated, semicolon_separated

ENU_FROM_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
BODY_FROM_SENSOR = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
TABLE_STEP = 0.005        # s: the pose table's spacing (200 Hz, an INS's rate); linear between rows
COLUMNS = ("time", "x", "y", "z", "roll", "pitch", "yaw")
SLOWEST_SPEED = 0.05      # m/s: a line going further than SLOW_DISTANCE slower than this has its time in ms
SLOW_DISTANCE = 5.0       # m: (a UAV flies 1-20 m/s, a walker 1: in milliseconds 0.001-0.02 m/s)


def euler_matrix(roll, pitch, yaw) -> np.ndarray:
    """(n, 3, 3) ``Rz(yaw)·Ry(pitch)·Rx(roll)`` of angles in degrees (arrays of n, or scalars: (1, 3, 3))."""
    r, p, y = (np.radians(np.atleast_1d(np.asarray(a, float))) for a in np.broadcast_arrays(roll, pitch, yaw))
    (sr, cr), (sp, cp), (sy, cy) = ((np.sin(a), np.cos(a)) for a in (r, p, y))
    out = np.empty((len(r), 3, 3))
    out[:, 0, 0], out[:, 0, 1], out[:, 0, 2] = cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr
    out[:, 1, 0], out[:, 1, 1], out[:, 1, 2] = sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr
    out[:, 2, 0], out[:, 2, 1], out[:, 2, 2] = -sp, cp * sr, cp * cr
    return out


def matrix_euler(matrix: np.ndarray) -> np.ndarray:
    """(n, 3) roll, pitch, yaw (deg; yaw in [0, 360)) of body-to-NED rotations (n, 3, 3)."""
    from scipy.spatial.transform import Rotation
    yaw, pitch, roll = Rotation.from_matrix(matrix).as_euler("ZYX", degrees=True).T
    return np.column_stack([roll, pitch, yaw % 360.0])


@dataclass(frozen=True, eq=False)
class Track:
    """One flight line of a trajectory file: its rows, flown as they are."""

    file: str
    first_line: int          # the file's line of the first row (from 1, the header is line 1)
    time: np.ndarray         # (n,) s, increasing
    position: np.ndarray     # (n, 3) local frame (m)
    attitude: np.ndarray     # (n, 3) roll, pitch, yaw (deg)

    def summary(self) -> dict:
        """What the plan's JSON says of it (its rows stay in the file)."""
        return {"file": self.file, "first_line": self.first_line, "rows": len(self.time)}


def read_trajectory(path) -> list[Track]:
    """The flight lines of a trajectory CSV (header ``time,x,y,z,roll,pitch,yaw`` in any order, other
    columns ignored but an optional ``line``: consecutive rows with the same ``line`` form one flight
    line; without it the whole file is one).

    :raises ConfigError: ``FILE: line N: reason`` for a missing column, a value that is not a finite
        number, time not increasing within a line, or a line of fewer than two rows.
    """
    shown = display_path(path)
    try:
        text = read_text(path)
    except NotTextError:
        raise ConfigError(shown, "", "not a text file") from None
    rows = [(n, line) for n, line in enumerate(text.splitlines(), start=1) if line.strip()]
    if not rows:
        raise ConfigError(shown, "", f"empty; a trajectory needs the header {','.join(COLUMNS)} and two rows")
    header_line, header = rows[0]
    names = [c.strip().lower() for c in header.split(",")]
    missing = [c for c in COLUMNS if c not in names]
    if missing and semicolon_separated(names):
        raise ConfigError(shown, f"line {header_line}", f"the file is {SEMICOLONS}")
    if missing:
        raise ConfigError(shown, f"line {header_line}", f"the header lacks {', '.join(missing)}: it must name "
                          f"{','.join(COLUMNS)}")
    if twice := repeated(names, (*COLUMNS, "line")):
        raise ConfigError(shown, f"line {header_line}", f"the header names {twice} {names.count(twice)} times; keep one")
    if len(rows) < 3:
        raise ConfigError(shown, f"line {header_line}", "a flight line needs at least two rows after the header")
    wanted = [names.index(c) for c in (*COLUMNS, "line") if c in names]
    values, numbers = np.zeros((len(rows) - 1, len(wanted))), [n for n, _ in rows[1:]]
    for i, (n, line) in enumerate(rows[1:]):
        cells = line.split(",")
        if len(cells) != len(names):
            raise ConfigError(shown, f"line {n}", f"{len(cells)} values, the header names {len(names)} columns")
        try:
            values[i] = [float(cells[k]) for k in wanted]
        except ValueError:
            raise ConfigError(shown, f"line {n}", f"not a number in {line.strip()[:60]!r}") from None
        if not np.isfinite(values[i]).all():
            raise ConfigError(shown, f"line {n}", "a value is not finite")
    numbers = np.asarray(numbers)
    line_ids = values[:, 7] if values.shape[1] > 7 else np.zeros(len(values))
    starts = np.flatnonzero(np.r_[True, line_ids[1:] != line_ids[:-1]])
    tracks = []
    for a, b in zip(starts, np.r_[starts[1:], len(values)]):
        chunk = values[a:b]
        if len(chunk) < 2:
            raise ConfigError(shown, f"line {numbers[a]}", "a flight line needs at least two rows")
        back = np.flatnonzero(np.diff(chunk[:, 0]) <= 0)
        if len(back):
            n = numbers[a + back[0] + 1]
            raise ConfigError(shown, f"line {n}", f"time must increase: {float(chunk[back[0] + 1, 0])} s follows "
                              f"{float(chunk[back[0], 0])} s")   # every digit: GPS seconds differ in the 10th
        if tracks and chunk[0, 0] <= tracks[-1].time[-1]:
            raise ConfigError(shown, f"line {numbers[a]}", "time must increase: this flight line starts before "
                              "the previous one ends")
        _check_speed(chunk[:, 0], chunk[:, 1:4], shown, numbers[a])
        tracks.append(Track(str(path), int(numbers[a]), chunk[:, 0].copy(), chunk[:, 1:4].copy(), chunk[:, 4:7].copy()))
    return tracks


def _check_speed(time: np.ndarray, position: np.ndarray, shown: str, first_line: int) -> None:
    """Refuses a flight line that goes far at a crawl: times in milliseconds plan an hours-long flight.

    :param time: (n,) s. :param position: (n, 3) m.
    """
    distance = float(np.linalg.norm(np.diff(position, axis=0), axis=1).sum())
    duration = float(time[-1] - time[0])
    if distance > SLOW_DISTANCE and distance / duration < SLOWEST_SPEED:
        raise ConfigError(shown, f"line {first_line}", f"the flight line goes {distance:.1f} m in {duration:,.0f} s "
                          f"({distance / duration:.2g} m/s), slower than any platform flies: the time column must "
                          "be seconds (is it milliseconds?)")


@dataclass(frozen=True)
class PoseTable:
    """A leg's pose every ``step`` seconds from ``t0``: platform ``position`` (n, 3) and ``body`` (n, 3, 3),
    the rotation from the body frame to the local frame (``ENU_FROM_NED · R``)."""

    t0: float
    step: float
    position: np.ndarray
    body: np.ndarray

    def rows(self, t) -> tuple[np.ndarray, np.ndarray]:
        """Row ``i`` (n,) and fraction ``f`` (n,) of times ``t``: the pose is row i + f·(row i+1 − row i)."""
        u = (np.asarray(t, np.float64) - self.t0) / self.step
        i = np.clip(np.floor(u), 0, len(self.position) - 2).astype(np.int64)
        return i, u - i

    def pose(self, t) -> tuple[np.ndarray, np.ndarray]:
        """Platform position (n, 3) and body-to-local rotation (n, 3, 3) at times ``t`` (linear between rows)."""
        i, f = self.rows(t)
        a = np.take(self._rows, i, axis=0)               # np.take: 3x faster than fancy indexing here
        pose = a + f[:, None] * (np.take(self._rows, i + 1, axis=0) - a)
        return pose[:, :3], pose[:, 3:].reshape(-1, 3, 3)

    @functools.cached_property
    def _rows(self) -> np.ndarray:
        """(n, 12) position and body rotation (row-major) per row: one gather a row for :meth:`pose`."""
        return np.concatenate([self.position, self.body.reshape(-1, 9)], axis=1)


def pose_table(leg, attitude=None, step: float = TABLE_STEP) -> PoseTable:
    """The pose table of a leg: a file's track (cubic spline through its positions, slerp between its
    attitudes) or a planned straight leg with its heading and ``attitude`` (a
    :class:`~mitsuforest.config.types.Attitude`: roll, pitch and yaw, added to the heading, as functions
    of time; ``None``: level flight)."""
    duration = leg.t1 - leg.t0
    t = leg.t0 + step * np.arange(int(np.ceil(duration / step)) + 2)
    if leg.track is not None:
        from scipy.interpolate import CubicSpline
        from scipy.spatial.transform import Rotation, Slerp
        track = leg.track
        clipped = np.clip(t, track.time[0], track.time[-1])
        position = CubicSpline(track.time, track.position)(clipped)
        roll, pitch, yaw = track.attitude.T
        rotations = Rotation.from_euler("ZYX", np.column_stack([yaw, pitch, roll]), degrees=True)
        ned = Slerp(track.time, rotations)(clipped).as_matrix()
    else:
        position = leg.position(t)
        waves = (attitude.roll, attitude.pitch, attitude.yaw) if attitude is not None else ()
        roll, pitch, yaw = (w(t) for w in waves) if waves else (np.zeros_like(t),) * 3
        ned = euler_matrix(roll, pitch, leg.heading + yaw)
    return PoseTable(float(leg.t0), float(step), position, ENU_FROM_NED @ ned)
