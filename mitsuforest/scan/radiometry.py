"""Received power of a sub-ray: the Lambertian lidar equation.

``P = w · ρ · |cos θ| / R²`` for a sub-ray of beam weight ``w`` hitting a surface of reflectance ``ρ``
at incidence ``θ`` and range ``R``. The unit of P (and of point intensity) is the echo of a white
(ρ = 1) Lambertian target filling the beam at normal incidence at 1 m; the sensor's
``detection_threshold`` is in the same unit. Constant factors (aperture, efficiency) are left out.

Sensor units. :func:`reflectance_db` is the RIEGL-style reflectance: the amplitude relative to that
of a white Lambertian target filling the beam at normal incidence at the same range, ``1/R²`` in our
unit, in dB: ``10·log10(A·R²)`` (0 dB white, −5.2 dB a 30 % target face-on; a tilted or partly hit
target reads lower). :func:`intensity_counts` is a sensor's 16-bit LAS intensity: the amplitude, the
linear reflectance or the reflectance in dB times ``gain`` plus ``offset``, rounded and clipped to
``[0, saturation]``. The last is how RIEGL's reflectance reaches a LAS file: PDAL's ``readers.rxp``
maps -25 to +5 dB onto 0-65535 (:data:`RIEGL_DB_MAP`).

Reflectances per class at the sensor wavelength (dimensionless, diffuse). Values are rounded from
published spectra: green Eucalyptus leaves ~0.45 in the NIR plateau and ~0.25 at 1550 nm (water
absorption); dry bark ~0.4-0.45; dry wood and litter higher in the SWIR (ECOSTRESS spectral library;
Kaasalainen et al. 2018, Remote Sens. 10:1114; Hakala et al. 2012, Opt. Express 20:7119).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from ..classes import BUSH, CLASS_NAMES, DEADWOOD, GROUND, GROUND_VEGETATION, ROCK, STUMP, TREE_LEAVES, TREE_WOOD

if TYPE_CHECKING:
    from ..config.types import IntensityMapping

# PDAL readers.rxp's reflectance_as_intensity defaults: -25 dB at 0 counts, +5 dB at 65535.
RIEGL_DB_MAP = {"source": "reflectance_db", "gain": 65535 / 30, "offset": 25 * 65535 / 30, "saturation": 65535}

REFLECTANCE = {
    #                 905-1064 nm   1550 nm
    GROUND:      (0.30, 0.33),
    TREE_WOOD:   (0.40, 0.45),
    TREE_LEAVES: (0.45, 0.25),
    DEADWOOD:    (0.45, 0.50),
    ROCK:        (0.30, 0.35),
    STUMP:       (0.40, 0.45),
    BUSH:        (0.45, 0.25),
    GROUND_VEGETATION: (0.40, 0.33),   # green and cured grass blades with dry leaf litter: between leaves and litter
}


def reflectance_table(wavelength: float) -> np.ndarray:
    """(max class code + 1,) reflectance indexed by class code at ``wavelength`` (m): the nearer of the two bands."""
    band = 1 if wavelength > 1.3e-6 else 0
    table = np.zeros(max(CLASS_NAMES) + 1)
    for code, values in REFLECTANCE.items():
        table[code] = values[band]
    return table


def received_power(weight: ArrayLike, reflectance: ArrayLike, cos_incidence: ArrayLike,
                   range_m: ArrayLike) -> np.ndarray:
    """Lambertian echo power ``w ρ |cos θ| / R²`` (unit: white full-beam target at 1 m), broadcast."""
    r = np.maximum(np.asarray(range_m, np.float64), 1e-6)
    return np.asarray(weight) * np.asarray(reflectance) * np.abs(cos_incidence) / (r * r)


def reflectance_db(amplitude: ArrayLike, range_m: ArrayLike) -> np.ndarray:
    """RIEGL-style reflectance (dB): ``10·log10(A·R²)``, the amplitude over a white Lambertian target's
    at the same range (see the module docstring); -inf for a zero amplitude."""
    a = np.asarray(amplitude, np.float64)
    r = np.asarray(range_m, np.float64)
    with np.errstate(divide="ignore"):
        return 10.0 * np.log10(a * r * r)


def intensity_counts(amplitude: np.ndarray, reflectance: np.ndarray, mapping: IntensityMapping) -> np.ndarray:
    """16-bit intensity of echoes (uint16): :func:`sensor_units` rounded and clipped to ``[0, saturation]``."""
    counts = np.round(sensor_units(amplitude, reflectance, mapping))
    return np.clip(np.nan_to_num(counts, nan=0.0), 0, mapping.saturation).astype(np.uint16)


def sensor_units(amplitude: np.ndarray, reflectance: np.ndarray, mapping: IntensityMapping) -> np.ndarray:
    """Echoes' intensity in a sensor's units before rounding and clipping (float64): ``gain·q + offset``,
    with ``q`` the amplitude or, for ``mapping.source`` ``"reflectance"``, the linear
    reflectance ``10^(reflectance/10) = A·R²``, for ``"reflectance_db"`` the reflectance in dB.

    :param amplitude: (E,) echo amplitudes; ``reflectance``: (E,) their :func:`reflectance_db`.
    :param mapping: a :class:`~mitsuforest.config.types.IntensityMapping`.
    """
    if mapping.source == "reflectance":
        q = np.power(10.0, np.asarray(reflectance, np.float64) / 10)
    elif mapping.source == "reflectance_db":
        q = np.maximum(np.asarray(reflectance, np.float64), -1e3)      # a zero amplitude's -inf dB reads 0
    else:
        q = np.asarray(amplitude, np.float64)
    return mapping.gain * q + mapping.offset
