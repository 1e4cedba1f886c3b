"""The platform in Dr.Jit: where each pulse leaves from and which way the sensor points, from a leg's
pose table (plan/trajectory.py), with the sensor's mount.

A level straight leg with a zero mount needs no table: :meth:`Platform.table` is then ``None`` and
pulses take the leg's fixed frame (scan/pulses.py), as they always did. Otherwise the leg's
:class:`~mitsuforest.plan.trajectory.PoseTable` is uploaded once per leg as beam origins and
sensor-to-local rotations, and each pulse interpolates it linearly between its two rows (float64).
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..plan.trajectory import BODY_FROM_SENSOR, ENU_FROM_NED, PoseTable, euler_matrix, pose_table
from .kernel import aligned


@dataclass
class DeviceTable:
    """A pose table on the device: beam ``origin`` (3 Float64 columns) and ``rotation`` (9 Float64
    columns, row-major sensor-to-local), one row every ``step`` seconds from ``t0``."""

    t0: float
    step: float
    rows: int
    origin: list[mi.Float64]
    rotation: list[mi.Float64]


class Platform:
    """The platform's motion and the sensor's mount of a scene (see plan/trajectory.py for the frames).

    :param scene: a :class:`~mitsuforest.config.types.Scene` (its ``sensor.mount`` and ``survey.attitude``).
    """

    def __init__(self, scene):
        mount = scene.sensor.mount
        self.attitude = scene.survey.attitude
        self.lever_arm = np.asarray(mount.lever_arm, float)
        self.boresight = euler_matrix(*mount.boresight)[0]       # body axes: the sensor's mounted attitude
        self.sensor_to_body = self.boresight @ BODY_FROM_SENSOR
        self.still = mount.zero and self.attitude.zero

    def table(self, leg) -> PoseTable | None:
        """The leg's pose table, or ``None`` for a level straight leg with a zero mount."""
        if self.still and leg.track is None:
            return None
        return pose_table(leg, None if self.attitude.zero else self.attitude)

    def beam(self, table: PoseTable, t) -> tuple[np.ndarray, np.ndarray]:
        """Beam origin (n, 3) and sensor-to-local rotation (n, 3, 3) at times ``t`` (numpy twin of
        :func:`table_pose`)."""
        position, body = table.pose(t)
        return position + body @ self.lever_arm, body @ self.sensor_to_body

    @staticmethod
    def body_pose(leg, table: PoseTable | None, t) -> tuple[np.ndarray, np.ndarray]:
        """Platform position (n, 3) and body-to-local rotation (n, 3, 3) at times ``t``, with or without
        a pose table (level flight along the leg's heading)."""
        if table is not None:
            return table.pose(t)
        t = np.asarray(t, np.float64)
        body = ENU_FROM_NED @ euler_matrix(0.0, 0.0, leg.heading)[0]
        return leg.position(t), np.broadcast_to(body, (len(t), 3, 3))

    def scan_angles(self, leg, table: PoseTable | None, t: np.ndarray, angle: np.ndarray,
                    turn: np.ndarray | None = None) -> np.ndarray:
        """LAS scan angles (deg) of line-scanner pulses at times ``t`` (n,) whose deflector angles are
        ``angle`` (n,) deg: the beam's angle from the local frame's vertical, seen from behind along the
        platform's heading, positive to the right (LAS 1.4: the pulse's rotational position "with respect
        to the vertical of the coordinate system of the data"; so the platform's roll and the mount's
        boresight are in it). With navigation errors, ``turn`` (n, 3, 3), each pulse's turn from the true
        beam to the believed one (:meth:`~mitsuforest.scan.navigation.NavigationModel.place`): the believed
        beam's angle, along which the points are placed."""
        _, body = self.body_pose(leg, table, t)
        phi = np.radians(np.asarray(angle, np.float64))
        sensor = np.column_stack([np.sin(phi), np.zeros_like(phi), -np.cos(phi)])
        d = np.einsum("nij,nj->ni", body, sensor @ self.sensor_to_body.T)
        if turn is not None:
            d = np.einsum("nij,nj->ni", turn, d)
        forward = body[:, :, 0]                                  # the body's x axis in the local frame
        across = d[:, 0] * forward[:, 1] - d[:, 1] * forward[:, 0]
        return np.degrees(np.arctan2(across / np.maximum(np.hypot(forward[:, 0], forward[:, 1]), 1e-12), -d[:, 2]))

    def upload(self, table: PoseTable) -> DeviceTable:
        """``table`` as beam origins and rotations on the device (call under the scene's variant)."""
        origin = table.position + table.body @ self.lever_arm
        rotation = (table.body @ self.sensor_to_body).reshape(-1, 9)
        return DeviceTable(table.t0, table.step, len(origin),
                           [mi.Float64(aligned(origin[:, k].copy())) for k in range(3)],
                           [mi.Float64(aligned(rotation[:, k].copy())) for k in range(9)])


def table_pose(table: DeviceTable, t: mi.Float64) -> tuple[list[mi.Float64], list[mi.Float64]]:
    """Beam origins (3 Float64) and sensor-to-local rotations (9 Float64, row-major) at Float64 times ``t``,
    linear between the table's rows."""
    t0 = dr.opaque(mi.Float64, table.t0)      # opaque: a new leg must not compile a new kernel
    inv_step = dr.opaque(mi.Float64, 1.0 / table.step)
    last = dr.opaque(mi.UInt32, table.rows - 2)
    u = dr.maximum((t - t0) * inv_step, 0.0)
    i = dr.minimum(mi.UInt32(dr.floor(u)), last)
    f = u - mi.Float64(i)

    def lerp(column: mi.Float64) -> mi.Float64:
        a, b = dr.gather(mi.Float64, column, i), dr.gather(mi.Float64, column, i + 1)
        return a + f * (b - a)

    return [lerp(c) for c in table.origin], [lerp(c) for c in table.rotation]
