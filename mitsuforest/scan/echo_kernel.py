"""The echo kernel: rays, labels, radiometry and waveform of a batch of pulses in Dr.Jit.

Only echoes come back to numpy, so the per-sub-ray work (hundreds of millions of returns in a 1 ha
scan) runs vectorised on every core, or on the GPU, instead of in numpy. The stages are those of the
numpy reference path (:meth:`PulseTracer.trace_reference`): :func:`~mitsuforest.labels.label_hits`,
:func:`~mitsuforest.scan.radiometry.received_power` and :func:`~mitsuforest.scan.waveform.detect_echoes`.
"""

from __future__ import annotations

import numpy as np

from ..labels.device import DeviceHitTable
from .echoes import pulse_echoes
from .kernel import RayCaster

ECHO_FIELDS = ("pulse", "return_number", "number_of_returns", "range", "amplitude", "point",
               "treeid", "classification", "instance", "object_id")


class EchoKernel(RayCaster):
    """Turns batches of pulses into echoes on the device.

    :param weights: (S,) beam energy of each sub-ray.
    :param reflectance: (8,) reflectance by class code.
    :param sensor: the sensor dict (``range_min``, ``range_max``, ``detection_threshold``, ``max_returns``).
    :param resolving: the resolving distance ΔR (m).
    """

    def __init__(self, mi_scene, sample_tangents, weights, table, reflectance, sensor: dict, resolving: float):
        super().__init__(mi_scene, sample_tangents)
        mi = self.mi
        self.table = DeviceHitTable(table)
        self.weights = mi.Float(np.asarray(weights, np.float32))
        self.reflectance = mi.Float(np.asarray(reflectance, np.float32))
        self.range_min, self.range_max = float(sensor["range_min"]), float(sensor["range_max"])
        self.threshold = float(sensor["detection_threshold"])
        self.max_returns = int(sensor["max_returns"])
        self.resolving = float(resolving)

    def echoes(self, origin: np.ndarray, direction: np.ndarray, across: np.ndarray) -> dict:
        """Echoes of P pulses given as numpy (P, 3) arrays; see :meth:`device_echoes`."""
        return self.device_echoes(*self.upload(origin, direction, across))

    def device_echoes(self, origin, direction, across) -> dict:
        """Echoes of P pulses given as Dr.Jit arrays (Point3f, Vector3f, Vector3f; see Pulses), in
        pulse then range order.

        :returns: ``pulse`` (E,) row of each echo's pulse, ``return_number``, ``number_of_returns``,
            ``range`` (m, noise-free), ``amplitude``, ``point`` (E, 3) float64 local frame, and the
            labels of its strongest sub-ray: ``treeid``, ``classification``, ``instance``, ``object_id``.
        """
        n = self.dr.width(origin)
        if n == 0:
            return _no_echoes()
        lane, hit_id, o = self._sub_ray_returns(origin, direction, across)
        flat, returns = self._ranked_echoes(lane, n)
        return self._echo_records(flat, returns, hit_id, o)

    def _sub_ray_returns(self, origin, direction, across):
        """Trace, label and weigh every sub-ray (lane = pulse*S + sub-ray): its range (``inf`` when it
        gave no valid return), received power and hit offset from the origin, and its hit ids."""
        dr, mi = self.dr, self.mi
        ray, o, d, _, sample = self.subrays(origin, direction, across)
        pi = self.intersect(ray)
        hit = pi.is_valid()
        instance = dr.reinterpret_array(mi.UInt32, pi.instance)
        shape = dr.reinterpret_array(mi.UInt32, pi.shape)
        cls, normal, unknown = self.table.classes_and_normals(instance, shape, pi.shape_index, pi.prim_index, hit)
        valid = hit & (pi.t >= self.range_min) & (pi.t <= self.range_max)
        # received_power (radiometry.py): w·ρ·|cos θ| / R²
        power = (dr.gather(mi.Float, self.weights, sample) * dr.gather(mi.Float, self.reflectance, cls)
                 * dr.abs(dr.dot(d, normal)) / dr.square(dr.maximum(pi.t, 1e-6)))
        lane = {"t": dr.select(valid, pi.t, dr.inf), "power": dr.select(valid, power, 0.0)}
        for a, axis in enumerate("xyz"):
            lane[axis] = dr.select(valid, d[a] * pi.t, 0.0)
        hit_id = {"instance": instance, "shape": shape, "shape_index": pi.shape_index, "prim": pi.prim_index}
        bad = dr.count(unknown)
        dr.eval(lane, hit_id, bad)
        if bad[0]:
            raise RuntimeError("a ray hit a shape that is neither the ground nor a placed object")
        return lane, hit_id, o

    def _ranked_echoes(self, lane: dict, n: int):
        """The waveform per pulse (echoes.py), its echoes scattered to slots pulse*S + rank."""
        dr, mi, S = self.dr, self.mi, self.samples
        base = dr.arange(mi.UInt32, n) * S
        per_sample = {k: [dr.gather(mi.Float, v, base + s) for s in range(S)] for k, v in lane.items()}
        offsets = [[per_sample[a][s] for a in "xyz"] for s in range(S)]
        slots, returns = pulse_echoes(dr, per_sample["t"], per_sample["power"], offsets, self.resolving,
                                      self.threshold, self.max_returns)
        flat = {k: dr.zeros(mi.Float, n * S) for k in ("range", "amplitude", "x", "y", "z")}
        flat["dominant"] = dr.zeros(mi.UInt32, n * S)
        flat["kept"] = dr.zeros(mi.UInt32, n * S)
        for slot in slots:
            at, kept = base + slot["rank"], slot["kept"]
            for key, value in (("range", slot["range"]), ("amplitude", slot["amplitude"]),
                               ("x", slot["offset"][0]), ("y", slot["offset"][1]), ("z", slot["offset"][2]),
                               ("dominant", slot["dominant"]), ("kept", mi.UInt32(1))):
                dr.scatter(flat[key], value, at, kept)
        dr.eval(flat, returns)
        return flat, returns

    def _echo_records(self, flat: dict, returns, hit_id: dict, origin) -> dict:
        """The kept slots, compacted, with their points and their strongest sub-ray's labels, in numpy."""
        dr, mi, S = self.dr, self.mi, self.samples
        idx = dr.compress(flat["kept"] > 0)
        if dr.width(idx) == 0:
            return _no_echoes()
        echo_pulse = idx // S
        strongest = echo_pulse * S + dr.gather(mi.UInt32, flat["dominant"], idx)
        ids = self.table.identities(*(dr.gather(mi.UInt32, hit_id[k], strongest) for k in hit_id),
                                    dr.full(mi.Bool, True, dr.width(idx)))
        start = dr.gather(mi.Point3f, origin, echo_pulse * S)
        out = {
            "pulse": echo_pulse, "return_number": idx - echo_pulse * S + 1,
            "number_of_returns": dr.gather(mi.UInt32, returns, echo_pulse),
            "range": dr.gather(mi.Float, flat["range"], idx), "amplitude": dr.gather(mi.Float, flat["amplitude"], idx),
            **{axis: start[a] + dr.gather(mi.Float, flat[axis], idx) for a, axis in enumerate("xyz")},
            **ids,
        }
        dr.eval(out)
        out = {k: np.array(v) for k, v in out.items()}
        out["point"] = np.column_stack([out.pop(a) for a in "xyz"]).astype(np.float64)
        return out


def _no_echoes() -> dict:
    return {k: np.zeros((0, 3)) if k == "point" else np.zeros(0, np.uint32) for k in ECHO_FIELDS}
