"""Navigation errors: where the points are computed, not where the pulses go.

A real survey places each echo with its navigation solution (GNSS position, IMU attitude) and its
calibrated boresight, all slightly wrong, so overlapping strips disagree. The pulses here fly the true
trajectory; each point is then moved from the true beam to the believed one:

    point = p + g(t) + B·E(t)·lever  +  B·E(t)·M·Q·Mᵀ·Bᵀ·(P − O)

with ``P`` the point on the true beam, ``O = p + B·lever`` its true origin, ``p`` and ``B`` the true
platform position and body-to-local rotation, ``M`` the mount's rotation (boresight), ``g(t)`` the
GNSS error, ``E(t)`` the IMU attitude error (a small roll-pitch-yaw rotation in the body frame) and
``Q`` the boresight calibration's error (roll, pitch, yaw about the mounted sensor's axes, in the body
frame's convention: ``M`` here is the boresight rotation alone). So the point
is the believed origin plus the believed direction times the measured range, whatever the echo's range.

The errors are series at ``rate_hz`` epochs over the whole survey, linear between epochs: the GNSS
error is white noise of σ ``gnss_sigma_m`` per axis (east, north, up) plus a random walk whose
increments over ``Δt`` have σ ``gnss_random_walk_m_per_sqrt_s·√Δt`` (zero at the survey's first
epoch); the IMU error is white noise of σ ``imu_sigma_deg`` (roll, pitch, yaw). They are drawn from
the scene's seed alone (its own stream, ``seeds.rng(seed, "navigation-errors")``), so a point's error
does not depend on batches, legs scanned apart or the backend.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .. import seeds
from ..plan.trajectory import ENU_FROM_NED, PoseTable, euler_matrix, matrix_euler
from ..plan.types import Leg

if TYPE_CHECKING:
    from ..config.types import NavigationErrors
    from .platform import Platform


class NavigationModel:
    """The error series of a survey (see module docstring).

    :param errors: the scene's ``survey.navigation_errors``.
    :param span: (first, last) time of the survey's legs (s).
    :param platform: the true motion and mount, whose beams the points are moved from.
    """

    def __init__(self, errors: NavigationErrors, seed: int, span: tuple[float, float], platform: Platform):
        self.platform = platform
        self.step = 1.0 / errors.rate_hz
        self.t0 = float(span[0])
        count = int(np.ceil((span[1] - self.t0) / self.step)) + 2
        rng = seeds.rng(seed, "navigation-errors")
        white, steps, imu = (rng.standard_normal((count, 3)) for _ in range(3))   # always all three: one σ
        steps[0] = 0.0                                                           # leaves the others' draws
        walk = np.cumsum(steps * np.asarray(errors.gnss_random_walk_m_per_sqrt_s) * np.sqrt(self.step), axis=0)
        self.gnss = white * np.asarray(errors.gnss_sigma_m) + walk
        self.imu = imu * np.asarray(errors.imu_sigma_deg)
        error = euler_matrix(*errors.boresight_error_deg)[0]     # about the mounted sensor's body-frame axes
        self.boresight_error = platform.boresight @ error @ platform.boresight.T   # body frame: M·Q·Mᵀ

    def at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """GNSS error (n, 3) m and IMU error (n, 3) roll, pitch, yaw deg at times ``t`` (n,)."""
        u = (np.asarray(t, np.float64) - self.t0) / self.step
        i = np.clip(np.floor(u), 0, len(self.gnss) - 2).astype(np.int64)
        f = (u - i)[:, None]
        out = []
        for series in (self.gnss, self.imu):
            a = np.take(series, i, axis=0)
            out.append(a + f * (np.take(series, i + 1, axis=0) - a))
        return out[0], out[1]

    def believed_pose(self, leg: Leg, table: PoseTable | None, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The navigation solution: platform position (n, 3) and body-to-local rotation (n, 3, 3)."""
        position, body = self.platform.body_pose(leg, table, t)
        gnss, imu = self.at(t)
        return position + gnss, body @ euler_matrix(*imu.T)

    def place(self, points: np.ndarray, leg: Leg, table: PoseTable | None) -> np.ndarray:
        """Move ``points`` (POINT_DTYPE, one leg's, in pulse order) in place from their true beams to the
        believed ones.

        :returns: each pulse's turn from the true beam to the believed one (p, 3, 3), in order (a pulse's
            echoes are the consecutive points of one time).
        """
        if len(points) == 0:
            return np.zeros((0, 3, 3))
        t = points["gps_time"]
        new_pulse = np.r_[True, t[1:] != t[:-1]]             # a pulse's echoes share its time: one transform each
        pulse = np.cumsum(new_pulse) - 1
        turned, shift = self.transform(leg, table, t[new_pulse])
        turn, shift = turned.reshape(-1, 9).T.copy(), shift.T.copy()
        xyz = [points[axis].copy() for axis in "xyz"]
        for r, axis in enumerate("xyz"):
            row = [np.take(turn[3 * r + c], pulse) for c in range(3)]
            points[axis] = row[0] * xyz[0] + row[1] * xyz[1] + row[2] * xyz[2] + np.take(shift[r], pulse)
        return turned

    def transform(self, leg: Leg, table: PoseTable | None, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The affine map from true to believed points at times ``t``: ``A`` (n, 3, 3) and ``b`` (n, 3), with
        ``believed = A·P + b`` (module docstring: ``A = B·E·M·Q·Mᵀ·Bᵀ``, ``b = p + g + B·E·lever − A·O``)."""
        lever = self.platform.lever_arm
        position, body = self.platform.body_pose(leg, table, t)
        gnss, imu = self.at(t)
        believed_body = body @ euler_matrix(*imu.T)
        turn = believed_body @ self.boresight_error @ np.swapaxes(body, 1, 2)
        origin = position + body @ lever
        shift = position + gnss + believed_body @ lever - np.einsum("nij,nj->ni", turn, origin)
        return turn, shift

    def trajectory(self, leg: Leg, table: PoseTable | None, t: np.ndarray) -> np.ndarray:
        """(n, 6) believed x, y, z, roll, pitch, yaw (deg) of the platform at times ``t``."""
        position, body = self.believed_pose(leg, table, t)
        return np.column_stack([position, matrix_euler(ENU_FROM_NED.T @ body)])
