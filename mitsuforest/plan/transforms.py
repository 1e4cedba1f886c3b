"""Rigid placements: rotation about z, then tilt about x and y, then translation (see PlacedObject.matrix)."""

from __future__ import annotations

import numpy as np


def rotation(yaw_deg: float, tilt_x_deg: float = 0.0, tilt_y_deg: float = 0.0) -> np.ndarray:
    """3×3 rotation ``Rx(tilt_x) @ Ry(tilt_y) @ Rz(yaw)`` (degrees)."""
    a, b, c = np.deg2rad([tilt_x_deg, tilt_y_deg, yaw_deg])
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    return rx @ ry @ rz


def apply(m: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Transform (n, 3) points by a 4×4 matrix."""
    return points @ m[:3, :3].T + m[:3, 3]
