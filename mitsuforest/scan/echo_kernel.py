"""The echo kernel: rays, radiometry and waveform of a batch of pulses in Dr.Jit.

Only echoes come back to numpy, each complete (position with its ranging noise, GPS time, scan
angle, pulse id, return numbers, intensity with its speckle, and what it hit: the object and
triangle rows of its strongest sub-ray, which the labels stage turns into ids), so the per-sub-ray
and per-echo work (hundreds of millions of returns in a 1 ha scan) runs vectorised on every core, or
on the GPU. The stages are those of the numpy reference
(:func:`mitsuforest.testing.reference.trace_reference`): the hit lookup
(:func:`~mitsuforest.testing.reference.labels.label_hits`),
:func:`~mitsuforest.scan.radiometry.received_power` and
:func:`~mitsuforest.testing.reference.echoes.pulse_echoes`.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..scene.device import DeviceHitTable
from .echoes import pulse_echoes, single_chain
from .kernel import RayCaster, evaluate_and_wait
from .pulses import DevicePulses
from .waveform import device_waveforms, pulse_sigma
from .noise import noise_key, range_sigma, speckle_gain, speckle_key, standard_normal, varies

ECHO_FIELDS = {"pulse_id": np.uint64, "gps_time": np.float64, "scan_angle": np.float32, "return_number": np.uint32,
               "number_of_returns": np.uint32, "range": np.float32, "amplitude": np.float32, "x": np.float32,
               "y": np.float32, "z": np.float32, "object_row": np.uint32, "triangle": np.uint32}


class EchoKernel(RayCaster):
    """Turns batches of pulses into echoes on the device.

    :param sample_tangents, beam: the beam pattern (see :class:`~mitsuforest.scan.kernel.RayCaster`).
    :param weights: (S,) beam energy of each sub-ray.
    :param reflectance: (max class code + 1,) reflectance by class code.
    :param sensor: the :class:`~mitsuforest.config.types.Sensor` (range limits, detection threshold,
        max returns, resolving distance, ranging noise).
    :param seed: the scene's seed (keys the ranging noise; see noise.py).
    :param point_position: ``beam_axis`` (an echo's point on its pulse's beam axis at the echo's range)
        or ``surface`` (the energy-weighted mean of its sub-rays' hit points); see
        :class:`~mitsuforest.scan.tracer.PulseTracer`.
    :param record: also sample each pulse's received waveform on the device and bring it back with
        each echo's chain energy (:meth:`echoes_and_waveforms`, ``output.waveforms``); off, the kernels
        are those without it.
    """

    def __init__(self, mi_scene: mi.Scene, *, weights, table, reflectance, sensor, seed: int,
                 point_position: str = "beam_axis", record: bool = False, **beam):
        super().__init__(mi_scene, **beam)
        self.on_surface = point_position == "surface"
        self.record = record
        self.table = DeviceHitTable(table)
        self.weights = mi.Float(np.asarray(weights, np.float32))
        self.reflectance = mi.Float(np.asarray(reflectance, np.float32))
        self.range_min, self.range_max = float(sensor.range_min), float(sensor.range_max)
        self.threshold = float(sensor.detection_threshold)
        self.max_returns = int(sensor.max_returns)
        self.resolving = float(sensor.resolving_distance)
        self.sensor = sensor
        self.sigma = float(sensor.range_precision)
        self.sigma_varies = varies(sensor)
        self.noise_key = noise_key(seed)
        self.looks = int(sensor.speckle_looks)
        self.speckle_key = speckle_key(seed)

    def echoes(self, pulses: DevicePulses) -> dict:
        """Echoes of a batch of :class:`~mitsuforest.scan.pulses.DevicePulses`, in pulse then range order.

        :returns: numpy arrays (E,) of :data:`ECHO_FIELDS`: the pulse's id, GPS time and scan angle
            (rad); ``return_number``, ``number_of_returns``; ``range`` and ``x``, ``y``, ``z`` (local
            frame: on the beam axis at that range, or on the surface moved along the axis by the
            ranging noise) with the echo's ranging noise; ``amplitude``; and the object and triangle
            rows (:attr:`HitTable.located <mitsuforest.scene.HitTable.located>`) of its strongest
            sub-ray's hit.
        """
        return self.echoes_and_waveforms(pulses)[0]

    def echoes_and_waveforms(self, pulses: DevicePulses) -> tuple[dict, dict | None]:
        """:meth:`echoes`, and with ``record`` the batch's sampled waveforms (else None).

        :returns: the echoes (with ``record``, also ``energy`` (E,): the power summed over the echo's
            chain); and, for the M pulses with at least one sub-ray return, their sampled waveforms
            (:func:`~mitsuforest.scan.waveform.device_waveforms`): ``samples`` (M, B) float32,
            ``first_bin`` (M,) uint32, ``complete`` (M,) bool, with the pulses' ``pulse_id``,
            ``gps_time``, ``scan_angle`` (rad) (M,) and ``origin``, ``direction`` (M, 3) (local frame).
        """
        n = pulses.count
        if n == 0:
            return _no_echoes(self.record), (_no_waveforms(self.sensor.waveform.samples) if self.record else None)
        lane, hit_id = self._sub_ray_returns(pulses)
        flat, returns = self._ranked_echoes(lane, n)
        echoes = self._echo_records(flat, returns, hit_id, pulses)
        return echoes, (self._waveforms(lane, pulses) if self.record else None)

    def _waveforms(self, lane: dict, pulses: DevicePulses) -> dict:
        """The sampled waveforms of a batch's pulses with a return, and their pulse data, in numpy (see
        :meth:`echoes_and_waveforms`)."""
        sampling = self.sensor.waveform
        made = device_waveforms(lane["t"], lane["power"], self.samples, pulse_sigma(self.resolving),
                                sampling.bin_range, sampling.samples)
        rows = made["rows"]
        out = {"pulse_id": dr.gather(mi.UInt64, pulses.pulse_id, rows),
               "gps_time": dr.gather(mi.Float64, pulses.time, rows),
               "scan_angle": dr.gather(mi.Float, pulses.scan_angle, rows),
               **{f"{key}_{a}": dr.gather(mi.Float, value[a], rows)
                  for key, value in (("origin", pulses.origin), ("direction", pulses.direction)) for a in range(3)}}
        dr.eval(out)
        out = {k: np.array(v) for k, v in out.items()}
        for key in ("origin", "direction"):
            out[key] = np.column_stack([out.pop(f"{key}_{a}") for a in range(3)])
        out["first_bin"], out["complete"] = np.array(made["first_bin"]), np.array(made["complete"])
        out["samples"] = np.array(made["waveform"]).reshape(-1, sampling.samples)
        return out

    def _sub_ray_returns(self, pulses: DevicePulses) -> tuple[dict, dict]:
        """Trace, locate and weigh every sub-ray (lane = pulse*S + sub-ray): its range (``inf`` when it
        gave no valid return), received power and hit offset from the origin, and where it hit (object
        and triangle rows of the device hit table)."""
        ray, _, d, _, sample = self.subrays(pulses.origin, pulses.direction, pulses.across, pulses.pulse_id)
        pi = self.intersect(ray)
        hit = pi.is_valid()
        instance = dr.reinterpret_array(mi.UInt32, pi.instance)
        shape = dr.reinterpret_array(mi.UInt32, pi.shape)
        row, tri, unknown = self.table.locate(instance, shape, pi.shape_index, pi.prim_index, hit)
        cls, normal = self.table.class_and_normal(row, tri, hit)
        valid = hit & (pi.t >= self.range_min) & (pi.t <= self.range_max)
        # received_power (radiometry.py): w·ρ·|cos θ| / R²
        power = (dr.gather(mi.Float, self.weights, sample) * dr.gather(mi.Float, self.reflectance, cls)
                 * dr.abs(dr.dot(d, normal)) / dr.square(dr.maximum(pi.t, 1e-6)))
        lane = {"t": dr.select(valid, pi.t, dr.inf), "power": dr.select(valid, power, 0.0)}
        if self.on_surface:     # on the beam axis an echo needs its range only
            for a, axis in enumerate("xyz"):
                lane[axis] = dr.select(valid, d[a] * pi.t, 0.0)
        hit_id = {"row": row, "tri": tri}
        # Evaluate the mask with the lanes, then count: a count taken in the same eval is a second kernel
        # that traces every ray again (measured: the sub-ray stage 1.9x slower).
        evaluate_and_wait(lane, hit_id, unknown)
        if dr.count(unknown)[0]:
            raise RuntimeError("a ray hit a shape that is neither the ground nor a placed object")
        return lane, hit_id

    def _ranked_echoes(self, lane: dict, n: int) -> tuple[dict, mi.UInt32]:
        """The waveform per pulse (echoes.py), its echoes scattered to slots pulse*S + rank.

        Pulses whose returns are one chain take :func:`~mitsuforest.scan.echoes.single_chain`; only the
        others (a few in ten in a forest) are gathered again and sorted."""
        S = self.samples
        flat = {k: dr.zeros(mi.Float, n * S) for k in ("range", "amplitude", *("xyz" if self.on_surface else ""))}
        flat["dominant"] = dr.zeros(mi.UInt32, n * S)
        flat["kept"] = dr.zeros(mi.UInt32, n * S)
        if self.record:
            flat["energy"] = dr.zeros(mi.Float, n * S)
        pulse = dr.arange(mi.UInt32, n)
        one, slot = single_chain(*self._per_sample(lane, pulse), self.resolving, self.threshold)
        self._scatter(flat, [slot], pulse * S, one)
        returns = mi.UInt32(dr.select(one & slot["kept"], 1, 0))   # one echo at most: within any max_returns
        evaluate_and_wait(flat, returns, one)
        several = dr.compress(~one)
        if dr.width(several):
            slots, chained = pulse_echoes(*self._per_sample(lane, several), self.resolving, self.threshold,
                                          self.max_returns)
            self._scatter(flat, slots, several * S, True)
            dr.scatter(returns, chained, several)
            evaluate_and_wait(flat, returns)
        return flat, returns

    def _per_sample(self, lane: dict, pulse: mi.UInt32) -> tuple[list[mi.Float], list[mi.Float], list | None]:
        """Ranges, powers and hit offsets of ``pulse``'s sub-rays, as S arrays (echoes.py's layout)."""
        S = self.samples
        base = pulse * S
        per_sample = {k: [dr.gather(mi.Float, v, base + s) for s in range(S)] for k, v in lane.items()}
        offset = [[per_sample[a][s] for a in "xyz"] for s in range(S)] if "x" in lane else None
        return per_sample["t"], per_sample["power"], offset

    def _scatter(self, flat: dict, slots: list[dict], base: mi.UInt32, active: mi.Bool | bool):
        for slot in slots:
            at, kept = base + slot["rank"], slot["kept"] & active
            offset = zip("xyz", slot["offset"]) if slot["offset"] is not None else ()
            energy = (("energy", slot["energy"]),) if "energy" in flat else ()
            for key, value in (("range", slot["range"]), ("amplitude", slot["amplitude"]), *offset, *energy,
                               ("dominant", slot["dominant"]), ("kept", mi.UInt32(1))):
                dr.scatter(flat[key], value, at, kept)

    def _echo_records(self, flat: dict, returns: mi.UInt32, hit_id: dict, pulses: DevicePulses) -> dict:
        """The kept slots, compacted, with their points, noise, pulse data and their strongest sub-ray's
        hit, in numpy."""
        S = self.samples
        idx = dr.compress(flat["kept"] > 0)
        if dr.width(idx) == 0:
            return _no_echoes(self.record)
        echo_pulse = idx // S
        return_number = idx - echo_pulse * S + 1
        strongest = echo_pulse * S + dr.gather(mi.UInt32, flat["dominant"], idx)
        row, tri = (dr.gather(mi.UInt32, hit_id[k], strongest) for k in ("row", "tri"))
        pulse_id = dr.gather(mi.UInt64, pulses.pulse_id, echo_pulse)
        start = dr.gather(mi.Point3f, pulses.origin, echo_pulse)
        axis = dr.gather(mi.Vector3f, pulses.direction, echo_pulse)
        echo_range = dr.gather(mi.Float, flat["range"], idx)
        noise = mi.Float(0.0)
        if self.sigma_varies or self.sigma > 0:
            sigma = (self._range_sigma(echo_range, axis, row, tri, pulses, echo_pulse) if self.sigma_varies
                     else self.sigma)
            noise = sigma * standard_normal(self.noise_key, pulse_id, return_number)
        amplitude = dr.gather(mi.Float, flat["amplitude"], idx)
        if self.looks:
            amplitude = amplitude * speckle_gain(self.speckle_key, pulse_id, return_number, self.looks)
        measured = echo_range + noise
        if self.on_surface:
            point = [start[a] + dr.gather(mi.Float, flat[name], idx) + axis[a] * noise for a, name in enumerate("xyz")]
        else:
            point = [start[a] + axis[a] * measured for a in range(3)]
        out = {
            "pulse_id": pulse_id, "gps_time": dr.gather(mi.Float64, pulses.time, echo_pulse),
            "scan_angle": dr.gather(mi.Float, pulses.scan_angle, echo_pulse),
            "return_number": return_number, "number_of_returns": dr.gather(mi.UInt32, returns, echo_pulse),
            "range": measured,
            "amplitude": amplitude,
            **dict(zip("xyz", point)),
            "object_row": row, "triangle": tri,
        }
        if self.record:
            out["energy"] = dr.gather(mi.Float, flat["energy"], idx)
        dr.eval(out)
        return {k: np.array(v) for k, v in out.items()}

    def _range_sigma(self, echo_range: mi.Float, axis: mi.Vector3f, row: mi.UInt32, tri: mi.UInt32,
                     pulses: DevicePulses, echo_pulse: mi.UInt32) -> mi.Float:
        """σ(R, θ) of each echo (noise.py), θ from the normal of its strongest sub-ray's triangle (at
        object row ``row``, triangle row ``tri``)."""
        _, normal = self.table.class_and_normal(row, tri, dr.full(mi.Bool, True, dr.width(row)))
        across = dr.gather(mi.Vector3f, pulses.across, echo_pulse)
        along = dr.cross(axis, across)
        return range_sigma(echo_range, dr.dot(normal, axis), dr.dot(normal, across), dr.dot(normal, along),
                           self.sensor)


def _no_echoes(energy: bool = False) -> dict:
    out = {k: np.zeros(0, dtype) for k, dtype in ECHO_FIELDS.items()}
    if energy:
        out["energy"] = np.zeros(0, np.float32)
    return out


def _no_waveforms(samples: int) -> dict:
    return {"samples": np.zeros((0, samples), np.float32), "first_bin": np.zeros(0, np.uint32),
            "complete": np.zeros(0, bool), "pulse_id": np.zeros(0, np.uint64), "gps_time": np.zeros(0),
            "scan_angle": np.zeros(0, np.float32), "origin": np.zeros((0, 3), np.float32),
            "direction": np.zeros((0, 3), np.float32)}
