"""One batch of pulses → labelled echo points: kernel, radiometry, waveform and labels together."""

from __future__ import annotations

import numpy as np

from ..labels import label_hits
from .beam import beam_pattern
from .kernel import RayCaster
from .pulses import Pulses
from .radiometry import received_power, reflectance_table
from .waveform import detect_echoes, resolving_distance

POINT_DTYPE = np.dtype([
    ("treeid", "<u2"), ("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("classification", "u1"),
    ("instance", "<u4"), ("object_id", "<u4"), ("number_of_returns", "u1"), ("return_number", "u1"),
    ("intensity", "<f4"), ("gps_time", "<f8"), ("scan_angle", "<f4"), ("pulse_id", "<u8"), ("range", "<f4"),
])


class PulseTracer:
    """Traces batches of pulses of one sensor through one scene.

    Each pulse is ``beam_samples`` sub-rays (beam.py). A sub-ray's received power follows the
    Lambertian lidar equation (radiometry.py); the waveform model (waveform.py) groups a pulse's
    sub-ray returns into echoes. An echo's point is the energy-weighted mean of its sub-rays' hit
    points, moved along the beam axis by Gaussian ranging noise; its labels are those of its
    strongest sub-ray.
    """

    def __init__(self, scan_scene, sensor: dict, beam_samples: int):
        self.sensor = sensor
        self.table = scan_scene.table
        offsets, self.weights = beam_pattern(beam_samples)
        half = np.asarray(sensor["beam_divergence"], float) / 2
        self.caster = RayCaster(scan_scene.mitsuba, np.tan(offsets * half))
        self.reflectance = reflectance_table(sensor["wavelength"])
        self.resolving = resolving_distance(sensor["pulse_length"])

    @property
    def samples(self) -> int:
        return len(self.weights)

    def trace(self, pulses: Pulses, rng: np.random.Generator, first_id: int = 0) -> np.ndarray:
        """Echo points (POINT_DTYPE, local frame) of a batch of pulses, in pulse then range order."""
        return self.finish(pulses, self.cast(pulses), rng, first_id)

    def cast(self, pulses: Pulses) -> dict:
        """The first hits of every sub-ray of the batch (the Dr.Jit kernel; see kernel.py)."""
        return self.caster.cast(pulses.origin, pulses.direction, pulses.across)

    def finish(self, pulses: Pulses, hits: dict, rng: np.random.Generator, first_id: int = 0) -> np.ndarray:
        """Radiometry, waveform and labels of a batch's hits (numpy only: may run beside :meth:`cast`)."""
        s, n, sensor = self.samples, len(pulses.time), self.sensor
        if n == 0:
            return np.zeros(0, POINT_DTYPE)
        labels = label_hits(self.table, hits["instance"], hits["shape"], hits["shape_index"], hits["prim"])
        ray = hits["ray"].astype(np.int64)
        t = hits["t"].astype(np.float64)
        incoming = (hits["point"] - pulses.origin[ray // s]) / np.maximum(t, 1e-9)[:, None]
        cos = np.einsum("ij,ij->i", incoming, labels.normal)
        power = received_power(self.weights[ray % s], self.reflectance[labels.classification], cos, t)
        ranges = np.full(n * s, np.inf)
        ranges[ray] = t
        dense_power = np.zeros(n * s)
        dense_power[ray] = power
        echoes = detect_echoes(ranges.reshape(n, s), dense_power.reshape(n, s), self.resolving,
                               sensor["detection_threshold"], sensor["max_returns"], sensor["range_min"],
                               sensor["range_max"])
        row_of_ray = np.full(n * s, -1, np.int64)
        row_of_ray[ray] = np.arange(len(ray))
        position = echoes.weighted_mean(hits["point"], row_of_ray)
        noise = (rng.normal(0.0, sensor["range_precision"], len(echoes.pulse)) if sensor["range_precision"] > 0
                 else np.zeros(len(echoes.pulse)))
        position += pulses.direction[echoes.pulse] * noise[:, None]
        dominant = row_of_ray[echoes.dominant]
        out = np.zeros(len(echoes.pulse), POINT_DTYPE)
        out["x"], out["y"], out["z"] = position.T
        out["treeid"] = labels.treeid[dominant]
        out["classification"] = labels.classification[dominant]
        out["instance"] = labels.instance[dominant]
        out["object_id"] = labels.object_id[dominant]
        out["return_number"] = echoes.return_number
        out["number_of_returns"] = echoes.number_of_returns
        out["intensity"] = echoes.amplitude
        out["gps_time"] = pulses.time[echoes.pulse]
        out["scan_angle"] = np.rad2deg(pulses.scan_angle[echoes.pulse])
        out["pulse_id"] = first_id + pulses.index[echoes.pulse]
        out["range"] = echoes.range + noise
        return out
