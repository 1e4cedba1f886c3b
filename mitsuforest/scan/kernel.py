"""The ray caster: sub-rays of many pulses traced in one launch.

Rays are built inside Dr.Jit from per-pulse origin, direction and beam frame plus a per-sample table
(:meth:`RayCaster.subrays`). ``ray_intersect_preliminary``
finds each sub-ray's first surface. :meth:`RayCaster.cast` compacts the hits and copies them back
(the reference path and the benchmarks' truth samples); the echo kernel (echo_kernel.py) keeps them
on the device.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from .sampling import device_cells, stratified_offsets


def aligned(a: np.ndarray) -> np.ndarray:
    """A 64-byte-aligned contiguous copy: Dr.Jit bakes input alignment into kernels (recompiles)."""
    a = np.ascontiguousarray(a)
    buf = np.empty(a.nbytes + 64, np.uint8)
    start = (-buf.ctypes.data) % 64
    out = buf[start:start + a.nbytes].view(a.dtype).reshape(a.shape)
    out[...] = a
    return out


def evaluate_and_wait(*values) -> None:
    """Evaluate ``values`` and wait for the device to finish, without holding Python's lock.

    Dr.Jit launches kernels asynchronously and releases the lock in ``dr.eval`` and ``dr.sync_thread``,
    but a read-back (``dr.count(...)[0]``, ``dr.compress``) waits for the pending kernels holding it, so
    the host's other threads (the writer's; on a GPU, the host's part of the last batch) would stand
    still as long as the device works. Call it before such a read-back.
    """
    dr.eval(*values)
    dr.sync_thread()


class RayCaster:
    """Casts the sub-rays of batches of pulses into a loaded Mitsuba scene.

    The beam pattern is either fixed, ``sample_tangents`` (S, 2): the tangents of each sub-ray's
    angular offset along the beam's two frame axes (across, along); or stratified, ``cells``
    (:class:`~mitsuforest.scan.beam.BeamCells`): each pulse draws its own offsets (sampling.py,
    keyed on ``key`` and the pulse id), scaled by ``half_divergence`` (rad, across and along).
    """

    def __init__(self, mi_scene: mi.Scene, sample_tangents: np.ndarray | None = None, *, cells=None,
                 half_divergence=(0.0, 0.0), key: int = 0):
        self.scene = mi_scene
        self.cells = None
        if cells is not None:
            self.samples = len(cells.weight)
            self.cells = device_cells(cells)
            self.half_divergence = tuple(float(h) for h in half_divergence)
            self.key = int(key)
        else:
            self.samples = len(sample_tangents)
            self.tan_x = mi.Float(aligned(sample_tangents[:, 0].astype(np.float32)))
            self.tan_y = mi.Float(aligned(sample_tangents[:, 1].astype(np.float32)))

    def subrays(self, origin: mi.Point3f, direction: mi.Vector3f, across: mi.Vector3f,
                pulse_id: mi.UInt64 | None = None) -> tuple[mi.Ray3f, mi.Point3f, mi.Vector3f, mi.UInt32, mi.UInt32]:
        """The sub-rays of P pulses as one Dr.Jit ray of P*S lanes, lane = pulse*S + sub-ray.

        :param origin: Point3f (P,) beam origins; ``direction``, ``across``: Vector3f (P,) unit beam
            axes and first frame axes; ``pulse_id``: UInt64 (P,) (keys the stratified pattern).
        :returns: ``ray`` (Ray3f), ``origin`` (Point3f), ``direction`` (Vector3f, unit), ``pulse``
            and ``sample`` (UInt32) per lane.
        """
        S = self.samples
        idx = dr.arange(mi.UInt32, dr.width(origin) * S)
        pulse = idx // S
        sample = idx - pulse * S
        o = dr.gather(mi.Point3f, origin, pulse)
        d = dr.gather(mi.Vector3f, direction, pulse)
        e1 = dr.gather(mi.Vector3f, across, pulse)
        e2 = dr.cross(d, e1)
        tan_x, tan_y = self._tangents(pulse, sample, pulse_id)
        d = dr.normalize(d + tan_x * e1 + tan_y * e2)
        return mi.Ray3f(o, d), o, d, pulse, sample

    def _tangents(self, pulse: mi.UInt32, sample: mi.UInt32, pulse_id: mi.UInt64 | None) -> tuple[mi.Float, mi.Float]:
        if self.cells is None:
            return dr.gather(mi.Float, self.tan_x, sample), dr.gather(mi.Float, self.tan_y, sample)
        ox, oy = stratified_offsets(self.cells, self.key, dr.gather(mi.UInt64, pulse_id, pulse), sample)
        return dr.tan(ox * self.half_divergence[0]), dr.tan(oy * self.half_divergence[1])

    def intersect(self, ray: mi.Ray3f) -> mi.PreliminaryIntersection3f:
        """Each lane's first surface (``PreliminaryIntersection3f``)."""
        # coherent=True traced ~7-30 % faster on CPU but returned different first hits for some
        # sub-rays of an instanced forest (Mitsuba 3.9.1 / Embree): keep incoherent, exact traversal.
        return self.scene.ray_intersect_preliminary(ray, coherent=False)

    def cast(self, pulses) -> dict:
        """First hits of every sub-ray of a batch of :class:`~mitsuforest.scan.pulses.DevicePulses`
        (the numpy reference and the benchmarks' truth samples use them).

        :returns: for the H sub-rays that hit: ``ray`` (H,) flat index pulse*S + sample, ``t`` (H,)
            distance, ``point`` (H, 3), ``instance``, ``shape``, ``shape_index``, ``prim`` (H,) uint32.
        """
        if pulses.count == 0:
            empty = np.zeros(0, np.uint32)
            return {"ray": empty, "t": np.zeros(0, np.float32), "point": np.zeros((0, 3)), "instance": empty,
                    "shape": empty, "shape_index": empty, "prim": empty}
        ray, o, d, _, _ = self.subrays(pulses.origin, pulses.direction, pulses.across, pulses.pulse_id)
        pi = self.intersect(ray)
        dr.eval(pi.t, pi.instance, pi.shape, pi.shape_index, pi.prim_index)   # trace once, not once per use
        hit = dr.compress(pi.is_valid())
        t = dr.gather(mi.Float, pi.t, hit)
        p = dr.gather(mi.Point3f, o, hit) + dr.gather(mi.Vector3f, d, hit) * t
        fields = {
            "ray": hit, "t": t, "px": p.x, "py": p.y, "pz": p.z,
            "instance": dr.gather(mi.UInt32, dr.reinterpret_array(mi.UInt32, pi.instance), hit),
            "shape": dr.gather(mi.UInt32, dr.reinterpret_array(mi.UInt32, pi.shape), hit),
            "shape_index": dr.gather(mi.UInt32, pi.shape_index, hit),
            "prim": dr.gather(mi.UInt32, pi.prim_index, hit),
        }
        dr.eval(*fields.values())
        out = {k: np.array(v) for k, v in fields.items()}
        out["point"] = np.column_stack([out.pop("px"), out.pop("py"), out.pop("pz")]).astype(np.float64)
        return out
