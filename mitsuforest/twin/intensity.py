"""What a real scan's intensity measures (pure functions): an echo's amplitude falls with range as 1/R²
(the Lambertian lidar equation, :mod:`mitsuforest.scan.radiometry`), a reflectance does not.

Each first return's range is ``(h - z) / cos(angle)`` from the sensor's height ``h`` (the survey
estimate's) over a flat flight, and the least-squares slope of ``ln I`` on ``ln R`` tells the two
apart: -2 for an amplitude, 0 for a reflectance (UAS_Clip: +0.17 over ranges of 113-273 m, a
reflectance; MixedConifer's span 5 %, which says nothing).
"""

from __future__ import annotations

import numpy as np

RANGE_SPAN = 1.5            # the first returns' 95th over 5th percentile range under which the slope says nothing
REFLECTANCE_SLOPE = -1.0    # d ln I / d ln R above which the intensity is a reflectance


def first_return_ranges(z: np.ndarray, angle: np.ndarray, sensor_z: float) -> np.ndarray:
    """(n,) ranges (m) of returns at heights ``z`` seen at scan angles ``angle`` (deg) from ``sensor_z``."""
    return (sensor_z - z) / np.cos(np.deg2rad(angle))


def range_slope(intensity: np.ndarray, range_m: np.ndarray) -> float | None:
    """The least-squares slope of ``ln intensity`` on ``ln range`` over the (n,) echoes with both positive;
    ``None`` where their ranges span less than :data:`RANGE_SPAN` (5th to 95th percentile) or fewer than
    100 echoes are left."""
    keep = (np.asarray(intensity) > 0) & (np.asarray(range_m) > 0)
    if keep.sum() < 100:
        return None
    log_r = np.log(np.asarray(range_m, np.float64)[keep])
    lo, hi = np.percentile(log_r, [5, 95])
    if hi - lo < np.log(RANGE_SPAN):
        return None
    return float(np.polyfit(log_r, np.log(np.asarray(intensity, np.float64)[keep]), 1)[0])


def intensity_unit(scan, sensor_z: float | None) -> tuple[str, str]:
    """``("reflectance", why)`` where the first returns' intensity of the
    :class:`~mitsuforest.twin.points.RealScan` does not fall with range (:data:`REFLECTANCE_SLOPE`),
    else ``("amplitude", why)``: also where the file has no intensity, no scan angle or no sensor height,
    or its ranges are too alike to tell."""
    if scan.intensity is None or scan.scan_angle is None or sensor_z is None:
        missing = "intensity" if scan.intensity is None else "scan angle" if scan.scan_angle is None else "sensor height"
        return "amplitude", f"the file's intensity cannot be placed against range (no {missing})"
    first = scan.return_number == 1
    ranges = first_return_ranges(scan.z[first], scan.scan_angle[first], sensor_z)
    slope = range_slope(np.asarray(scan.intensity)[first], ranges)
    if slope is None:
        return "amplitude", f"its first returns' ranges are too alike (within {RANGE_SPAN:g} times) to tell"
    if slope > REFLECTANCE_SLOPE:
        return "reflectance", f"its first returns' intensity goes as range^{slope:.2f}: a reflectance, not an amplitude (range^-2)"
    return "amplitude", f"its first returns' intensity goes as range^{slope:.2f}, as an amplitude (range^-2)"
