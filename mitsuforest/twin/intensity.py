"""What a real scan's intensity measures (pure functions): an echo's amplitude falls with range as 1/R²
(the Lambertian lidar equation, :mod:`mitsuforest.scan.radiometry`), a reflectance does not, and a
reflectance in dB spans a narrow band of counts where a linear one spans a wide one.

Each first return's range is ``(h - z) / cos(angle)`` from the sensor's height ``h`` (the survey
estimate's) over a flat flight, and the least-squares slope of ``ln I`` on ``ln R`` tells the two
apart: -2 for an amplitude, 0 for a reflectance (UAS_Clip: +0.17 over ranges of 113-273 m, a
reflectance; MixedConifer's span 5 %, which says nothing). A forest's first returns, partial hits of
the beam among them, span more than 10 dB between their 5th and 95th percentiles (MixedConifer's counts
26 times, a twin's amplitudes 30 times), so counts within 10 times are a log scale (UAS_Clip: 3.2 times,
RIEGL's reflectance in dB).
"""

from __future__ import annotations

import numpy as np

RANGE_SPAN = 1.5            # the first returns' 95th over 5th percentile range under which the slope says nothing
REFLECTANCE_SLOPE = -1.0    # d ln I / d ln R above which the intensity is a reflectance
LOG_SPAN = 10.0             # the first returns' 95th over 5th percentile intensity under which it is in dB
MIN_ECHOES = 100            # first returns with a positive intensity the slope needs


def first_return_ranges(z: np.ndarray, angle: np.ndarray, sensor_z: float) -> np.ndarray:
    """(n,) ranges (m) of returns at heights ``z`` seen at scan angles ``angle`` (deg) from ``sensor_z``."""
    return (sensor_z - z) / np.cos(np.deg2rad(angle))


def range_slope(intensity: np.ndarray, range_m: np.ndarray) -> float | None:
    """The least-squares slope of ``ln intensity`` on ``ln range`` over the (n,) echoes with both positive;
    ``None`` where fewer than :data:`MIN_ECHOES` are, or their ranges span less than :data:`RANGE_SPAN`
    (5th to 95th percentile)."""
    keep = (np.asarray(intensity) > 0) & (np.asarray(range_m) > 0)
    if keep.sum() < MIN_ECHOES:
        return None
    log_r = np.log(np.asarray(range_m, np.float64)[keep])
    lo, hi = np.percentile(log_r, [5, 95])
    if hi - lo < np.log(RANGE_SPAN):
        return None
    return float(np.polyfit(log_r, np.log(np.asarray(intensity, np.float64)[keep]), 1)[0])


def intensity_unit(scan, sensor_z: float | None) -> tuple[str, str]:
    """What the first returns' intensity of the :class:`~mitsuforest.twin.points.RealScan` is, and why:
    ``"reflectance_db"`` where it does not fall with range (:data:`REFLECTANCE_SLOPE`) and spans less than
    :data:`LOG_SPAN`, ``"reflectance"`` where it does not fall with range but spans more, else
    ``"amplitude"``: also where the file has no varying intensity, no scan angle or no sensor height above
    its points, or its ranges are too alike to tell."""
    if scan.intensity is None or scan.scan_angle is None or sensor_z is None:
        missing = ("intensity that varies" if scan.intensity is None else "scan angles" if scan.scan_angle is None
                   else "sensor height")
        return "amplitude", f"the file's intensity cannot be set against range (it has no {missing})"
    first = (scan.return_number == 1) & (np.asarray(scan.intensity) > 0)
    if first.sum() < MIN_ECHOES:
        return "amplitude", f"fewer than {MIN_ECHOES} first returns have a positive intensity"
    ranges = first_return_ranges(scan.z[first], scan.scan_angle[first], sensor_z)
    if np.median(ranges) <= 0:
        return "amplitude", "the estimated sensor is not above the first returns"
    counts = np.asarray(scan.intensity, np.float64)[first]
    slope = range_slope(counts, ranges)
    if slope is None:
        return "amplitude", f"its first returns' ranges are too alike (within {RANGE_SPAN:g} times) to tell"
    if slope <= REFLECTANCE_SLOPE:
        return "amplitude", f"its first returns' intensity goes as range^{slope:.2f}, as an amplitude (range^-2)"
    lo, hi = np.percentile(counts, [5, 95])
    if hi < LOG_SPAN * lo:
        return "reflectance_db", (f"its first returns' intensity goes as range^{slope:.2f} (a reflectance) and its "
                                  f"5th to 95th percentiles span {hi / lo:.1f} times (a log scale)")
    return "reflectance", (f"its first returns' intensity goes as range^{slope:.2f} (a reflectance) and its 5th to "
                           f"95th percentiles span {hi / lo:.1f} times (a linear scale)")
