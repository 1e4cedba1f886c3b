"""One batch of pulses → labelled echo points: kernel, radiometry, waveform and labels together."""

from __future__ import annotations

import numpy as np

from ..labels import label_hits
from .beam import beam_pattern
from .device_pulses import device_pulses
from .echo_kernel import EchoKernel
from .pulses import Pulses, slot_pulses
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

    :meth:`trace` runs all of this in Dr.Jit (echo_kernel.py); :meth:`trace_reference` runs the same
    model in numpy from the sub-ray hits and is what tests check the kernel against.
    """

    def __init__(self, scan_scene, sensor: dict, beam_samples: int):
        self.sensor = sensor
        self.table = scan_scene.table
        offsets, self.weights = beam_pattern(beam_samples)
        half = np.asarray(sensor["beam_divergence"], float) / 2
        self.reflectance = reflectance_table(sensor["wavelength"])
        self.resolving = resolving_distance(sensor["pulse_length"])
        self.caster = EchoKernel(scan_scene.mitsuba, np.tan(offsets * half), self.weights, self.table,
                                 self.reflectance, sensor, self.resolving)

    @property
    def samples(self) -> int:
        return len(self.weights)

    def trace(self, pulses: Pulses, rng: np.random.Generator, first_id: int = 0) -> np.ndarray:
        """Echo points (POINT_DTYPE, local frame) of a batch of pulses, in pulse then range order."""
        e = self.caster.echoes(pulses.origin, pulses.direction, pulses.across)
        return self._points(pulses, e["pulse"], e["point"], e["range"], e, rng, first_id)

    def trace_slots(self, leg: dict, survey: dict, first: int, count: int, box: np.ndarray,
                    rng: np.random.Generator, first_id: int = 0) -> tuple[np.ndarray, int, int]:
        """:meth:`trace` for the time slots ``first .. first+count-1`` of a leg, pulses made on the
        device (device_pulses.py); only pulses that can reach ``box`` are cast.

        :returns: the points, the number of pulses fired and the number cast.
        """
        pulses, fired = device_pulses(leg, self.sensor, survey, first, count, box, self.sensor["range_max"])
        cast = self.caster.dr.width(pulses["slot"])
        e = self.caster.device_echoes(pulses["origin"], pulses["direction"], pulses["across"])
        echo_pulses = slot_pulses(leg, self.sensor, survey, np.asarray(pulses["slot"])[e["pulse"]] if cast else [])
        return self._points(echo_pulses, np.arange(len(e["pulse"])), e["point"], e["range"], e, rng, first_id), fired, cast

    def trace_reference(self, pulses: Pulses, rng: np.random.Generator, first_id: int = 0) -> np.ndarray:
        """:meth:`trace` computed in numpy from the sub-ray hits (slower; the tests' reference)."""
        return self.finish(pulses, self.cast(pulses), rng, first_id)

    def cast(self, pulses: Pulses) -> dict:
        """The first hits of every sub-ray of the batch (see kernel.py)."""
        return self.caster.cast(pulses.origin, pulses.direction, pulses.across)

    def finish(self, pulses: Pulses, hits: dict, rng: np.random.Generator, first_id: int = 0) -> np.ndarray:
        """Radiometry, waveform and labels of a batch's hits, in numpy."""
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
        dominant = row_of_ray[echoes.dominant]
        fields = {"return_number": echoes.return_number, "number_of_returns": echoes.number_of_returns,
                  "amplitude": echoes.amplitude,
                  **{k: getattr(labels, k)[dominant] for k in ("treeid", "classification", "instance", "object_id")}}
        return self._points(pulses, echoes.pulse, echoes.weighted_mean(hits["point"], row_of_ray), echoes.range,
                            fields, rng, first_id)

    def _points(self, pulses, pulse, position, range_m, fields, rng, first_id) -> np.ndarray:
        """Echo points with Gaussian ranging noise along the beam axis."""
        sigma = self.sensor["range_precision"]
        noise = rng.normal(0.0, sigma, len(pulse)) if sigma > 0 else np.zeros(len(pulse))
        out = np.zeros(len(pulse), POINT_DTYPE)
        out["x"], out["y"], out["z"] = (position + pulses.direction[pulse] * noise[:, None]).T
        for key in ("treeid", "classification", "instance", "object_id", "return_number", "number_of_returns"):
            out[key] = fields[key]
        out["intensity"] = fields["amplitude"]
        out["gps_time"] = pulses.time[pulse]
        out["scan_angle"] = np.rad2deg(pulses.scan_angle[pulse])
        out["pulse_id"] = first_id + pulses.index[pulse]
        out["range"] = range_m + noise
        return out
