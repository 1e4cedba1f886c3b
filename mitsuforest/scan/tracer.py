"""One batch of pulses → echo points and what they hit: pulses, rays, radiometry, waveform and noise in Dr.Jit."""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from .. import seeds
from ..fields import POINT_DTYPE
from . import HIT_DTYPE
from ..scene.proxies import proxy_scene
from ..scene.variant import variant_scope
from ..threads import on_row_ranges
from .beam import beam_cells, beam_pattern
from .echo_kernel import EchoKernel
from .pulses import DevicePulses, aimed_at, reaching_pulses, upload_pulses
from .radiometry import reflectance_db, reflectance_table
from .waveform import PulseBatch


@dataclass
class SlotEchoes:
    """What the device made of a batch of time slots (:meth:`PulseTracer.echo_slots`), in numpy."""

    echoes: dict                  # (E,) arrays of the echo kernel's fields, in pulse then range order
    waveforms: dict | None        # the cast pulses' sampled waveforms (``waveforms`` or ``pulse_records``)
    fired: int                    # pulses fired in the slots
    cast: int                     # ... and cast (aimed at an object's proxy or the ground's box)
    fired_pulses: dict | None     # every fired pulse (``pulse_records``)


class PulseTracer:
    """Traces batches of pulses of one sensor through one scene.

    Each pulse is ``beam_samples`` sub-rays (beam.py). A sub-ray's received power follows the
    Lambertian lidar equation (radiometry.py); the waveform model (echoes.py) groups a pulse's
    sub-ray returns into echoes. An echo's range (the energy-weighted mean of its sub-rays' ranges)
    gets Gaussian ranging noise keyed on (seed, pulse id, return number) (noise.py). Its point is,
    with ``point_position="beam_axis"``, on the pulse's nominal beam axis at that range, as a scanner
    reports it (an echo mixing two surfaces lies between them); with ``"surface"``, the
    energy-weighted mean of its sub-rays' hit points, moved along the beam axis by the noise. What it
    hit is its strongest sub-ray's hit (``HIT_DTYPE``: the object and triangle rows of the scene's
    :attr:`HitTable.located <mitsuforest.scene.HitTable.located>`), returned beside the points for
    the labels stage (:func:`mitsuforest.labels.label_points`); the points' label fields are left 0.

    :meth:`trace_slots` is what a render runs: :meth:`echo_slots` on the device, then :meth:`place_echoes`
    on the host (a render runs the first a batch ahead on a thread of its own); :meth:`trace_pulses`
    traces hand-made pulses the same way. Both return finished points and their hits. The numpy twin of the echo
    stage is :func:`mitsuforest.testing.reference.trace_reference`.

    :param sensor: a :class:`~mitsuforest.config.types.Sensor`.
    :param seed: the scene's seed (keys the ranging noise and the stratified beam).
    :param pattern: ``fixed`` (one sub-ray pattern for every pulse; the default here, for analytic
        checks) or ``stratified`` (each pulse draws its sub-rays inside the pattern's cells; see
        beam.py). A render uses the scene's ``simulation.beam_pattern`` (stratified by default).
    :param point_position: ``beam_axis`` or ``surface`` (see above; a render uses the scene's
        ``simulation.point_position``).
    :param platform: the scene's :class:`~mitsuforest.scan.platform.Platform` (mount, attitude): needed
        by :meth:`trace_slots` with a pose table.
    :param navigation: a :class:`~mitsuforest.scan.navigation.NavigationModel`: the points are placed
        with its believed trajectory (None: with the true one).
    :param launch_pulses: trace a batch's cast pulses in launches of at most this many (None: all at once).
    :param waveforms, pulse_records: make each batch's :class:`~mitsuforest.scan.waveform.PulseBatch`
        with the cast pulses' sampled waveforms and echo energies (``output.waveforms``) and with every
        fired pulse (``output.pulses``); :meth:`trace_slots` then returns it as a fourth item.
    """

    def __init__(self, scan_scene, sensor, beam_samples: int, seed: int = 0, pattern: str = "fixed",
                 point_position: str = "beam_axis", platform=None, navigation=None, waveforms: bool = False,
                 pulse_records: bool = False, launch_pulses: int | None = None):
        self.sensor, self.variant, self.table = sensor, scan_scene.variant, scan_scene.table
        self.launch_pulses = launch_pulses
        self.point_position = point_position
        self.waveforms, self.pulse_records = waveforms, pulse_records
        self.platform, self.navigation, self._uploaded = platform, navigation, (None, None)
        half = np.asarray(sensor.beam_divergence, float) / 2
        if pattern == "stratified":
            cells = beam_cells(beam_samples)
            self.weights, beam = cells.weight, {"cells": cells, "half_divergence": half,
                                                "key": seeds.key(seed, "beam")}
        else:
            offsets, self.weights = beam_pattern(beam_samples)
            beam = {"sample_tangents": np.tan(offsets * half)}
        own = getattr(scan_scene, "reflectance", None)
        self.reflectance = reflectance_table(sensor.wavelength) if own is None else own
        # Pulses are dropped when even their widest sub-ray misses the scene's box: a fixed pattern's
        # offsets stay under 1.5 w, a stratified draw under r = sqrt(u/2) = 2.9 w (24-bit uniforms: u < 16.7).
        spread = max(half) * (1.5 if pattern == "fixed" else 3.0)      # m from the beam axis a metre of range

        def grown(boxes: np.ndarray, reach: float) -> np.ndarray:
            """``boxes`` (..., 2, 3) grown by the widest sub-ray's distance from the axis at ``reach`` m."""
            return boxes + np.array([[-1.0] * 3, [1.0] * 3]) * (reach * spread + 0.01)

        self.box = grown(scan_scene.bbox, sensor.range_max)
        self.bounds = scan_scene.bbox
        near = min(sensor.range_max, 2.0 * float(np.linalg.norm(np.ptp(scan_scene.bbox, axis=0))))
        reaches = list(dict.fromkeys((near, sensor.range_max)))
        self.targets = [(r, grown(scan_scene.boxes, r)) for r in reaches]     # the objects' boxes: the reference's
        with variant_scope(self.variant):
            # The pulses are aimed at the objects' proxies and the ground's box (the last box), each grown alike.
            self.target_scenes = [(r, proxy_scene(scan_scene.cells, scan_scene.placements, r * spread + 0.01,
                                                  scan_scene.boxes[-1:])) for r in reaches]
            self.caster = EchoKernel(scan_scene.mitsuba, weights=self.weights, table=self.table,
                                     reflectance=self.reflectance, sensor=sensor, seed=seed,
                                     point_position=point_position, record=waveforms, **beam)
            dr.sync_thread()     # its tables complete before the scan's thread (scan_batches) reads them

    @property
    def samples(self) -> int:
        return len(self.weights)

    def trace_slots(self, leg, pulse_frequency: float, scan_frequency: float, first: int, count: int,
                    first_id: int = 0, source_id: int = 0, pose=None) -> tuple[np.ndarray, np.ndarray, int, int]:
        """Points of the time slots ``first .. first+count-1`` of a leg; only pulses that fire and can
        reach the scene are cast: :meth:`echo_slots` on the device, then :meth:`place_echoes` on the host.

        :param leg: a :class:`~mitsuforest.plan.types.Leg`.
        :param first_id: the survey's pulse number of the leg's first time slot (pulse ids are
            ``first_id + slot``).
        :param source_id: the points' ``point_source_id`` (the leg's number from 1 in a survey).
        :param pose: the leg's :class:`~mitsuforest.plan.trajectory.PoseTable` (``Platform.table``), or
            None: level flight along its straight line.
        :returns: the points (POINT_DTYPE, local frame, in pulse then range order, labels left 0),
            their hits (HIT_DTYPE), the number of pulses fired and the number cast; with ``waveforms``
            or ``pulse_records``, also the batch's
            :class:`~mitsuforest.scan.waveform.PulseBatch`.
        """
        return self.place_echoes(self.echo_slots(leg, pulse_frequency, scan_frequency, first, count, first_id, pose),
                                 leg, source_id, pose)

    def echo_slots(self, leg, pulse_frequency: float, scan_frequency: float, first: int, count: int,
                   first_id: int = 0, pose=None) -> SlotEchoes:
        """The device's part of :meth:`trace_slots`: the pulses of the slots that fire and can reach the
        scene, traced, and their echoes brought back to numpy."""
        records = self.waveforms or self.pulse_records
        # Mitsuba's variant is the process's: nothing on another thread may use another during a scan.
        with variant_scope(self.variant):
            made = reaching_pulses(leg, self.sensor, pulse_frequency, scan_frequency, first, count, self.box,
                                   first_id, self._device_table(pose), keep_fired=self.pulse_records)
            pulses, fired = made[:2]
            pulses = aimed_at(pulses, self.target_scenes, self.bounds, self.box, self.sensor.range_max)
            echoes, returns = self._echoes(pulses, records)
        return SlotEchoes(echoes, returns, fired, pulses.count, made[2] if self.pulse_records else None)

    def place_echoes(self, slots: SlotEchoes, leg, source_id: int = 0, pose=None) -> tuple:
        """The host's part of :meth:`trace_slots` (numpy only, so it can run beside the device's next
        batch): the echoes as points, placed with the navigation solution's errors, with their hits and
        the pulse counts, and the batch's :class:`~mitsuforest.scan.waveform.PulseBatch` when asked for."""
        points, hits = self._points(slots.echoes)
        points["point_source_id"] = source_id
        turn = self.navigation.place(points, leg, pose) if self.navigation is not None else None
        if (pose is not None or turn is not None) and self.sensor.deflector != "risley":
            self._tilt_scan_angles(points, leg, pose, turn)
        if not (self.waveforms or self.pulse_records):
            return points, hits, slots.fired, slots.cast
        kept = ("pulse_id", "return_number", "range", "amplitude", *(("energy",) if self.waveforms else ()))
        batch = PulseBatch(slots.waveforms, {k: slots.echoes[k] for k in kept}, slots.fired_pulses, source_id)
        return points, hits, slots.fired, slots.cast, batch

    def _tilt_scan_angles(self, points: np.ndarray, leg, pose, turn: np.ndarray | None) -> None:
        """Turn ``points``' deflector angles (one leg's, in pulse order) into LAS scan angles, from the
        vertical (:meth:`~mitsuforest.scan.platform.Platform.scan_angles`; ``turn``: each pulse's from the
        navigation errors, or None): a tilted platform, a turned mount or navigation errors make them
        differ. A level leg without them keeps the deflector's, the same angle, as its bytes."""
        if len(points) == 0:
            return
        t = points["gps_time"]
        first = np.r_[True, t[1:] != t[:-1]]                  # a pulse's echoes share its time and angle
        angles = self.platform.scan_angles(leg, pose, t[first], points["scan_angle"][first], turn)
        points["scan_angle"] = np.take(angles, np.cumsum(first) - 1)

    def _echoes(self, pulses: DevicePulses, records: bool) -> tuple[dict, dict | None]:
        """The caster's echoes of ``pulses`` and, with ``records``, their waveforms (else None), traced
        in launches of at most :attr:`launch_pulses` pulses."""
        limit = self.launch_pulses
        if limit is None or pulses.count <= limit:
            return self.caster.echoes_and_waveforms(pulses) if records else (self.caster.echoes(pulses), None)
        parts = [self._echoes(pulses.take(dr.arange(mi.UInt32, start, min(start + limit, pulses.count))), records)
                 for start in range(0, pulses.count, limit)]
        echoes = {k: np.concatenate([p[0][k] for p in parts]) for k in parts[0][0]}
        waveforms = parts[0][1]          # None also with records when the caster samples no waveform
        return echoes, (None if waveforms is None else {k: np.concatenate([p[1][k] for p in parts]) for k in waveforms})

    def _device_table(self, pose):
        """``pose`` on the device, uploaded once per leg."""
        if pose is None:
            return None
        if self._uploaded[0] is not pose:
            self._uploaded = (pose, self.platform.upload(pose))
        return self._uploaded[1]

    def trace_pulses(self, pulses, first_id: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """Points of hand-made pulses (:class:`~mitsuforest.testing.reference.pulses.Pulses`, numpy)
        and their hits, as :meth:`trace_slots` makes them."""
        with variant_scope(self.variant):
            return self._points(self.caster.echoes(upload_pulses(pulses, first_id)))

    def trace_pulse_records(self, pulses, first_id: int = 0) -> tuple[np.ndarray, np.ndarray, PulseBatch]:
        """Points of hand-made pulses, their hits and their :class:`~mitsuforest.scan.waveform.PulseBatch`
        (needs ``waveforms``): every hand-made pulse counts as fired and cast."""
        with variant_scope(self.variant):
            echoes, returns = self.caster.echoes_and_waveforms(upload_pulses(pulses, first_id))
            points, hits = self._points(echoes)
        fired = {"pulse_id": np.asarray(pulses.index, np.uint64) + np.uint64(first_id),
                 "gps_time": np.asarray(pulses.time, np.float64),
                 "scan_angle": np.asarray(pulses.scan_angle, np.float32),
                 "origin": np.asarray(pulses.origin, np.float32), "direction": np.asarray(pulses.direction, np.float32)}
        kept = ("pulse_id", "return_number", "range", "amplitude", "energy")
        return points, hits, PulseBatch(returns, {k: echoes[k] for k in kept}, fired, 0)

    def cast(self, pulses, first_id: int = 0) -> dict:
        """The first hits of every sub-ray of hand-made pulses (see :meth:`RayCaster.cast`)."""
        with variant_scope(self.variant):
            return self.caster.cast(upload_pulses(pulses, first_id))

    @staticmethod
    def _points(echoes: dict) -> tuple[np.ndarray, np.ndarray]:
        """The echoes as one POINT_DTYPE array (labels left 0) and one HIT_DTYPE array, their row ranges
        filled by the host threads at once."""
        out = np.zeros(len(echoes["pulse_id"]), POINT_DTYPE)
        hits = np.empty(len(out), HIT_DTYPE)
        on_row_ranges(len(out), _fill_points, out, hits, echoes)
        return out, hits


def _fill_points(out: np.ndarray, hits: np.ndarray, echoes: dict, start: int, stop: int) -> None:
    """Rows ``start:stop`` of :meth:`PulseTracer._points`."""
    rows = out[start:stop]
    for key in ("x", "y", "z", "number_of_returns", "return_number", "gps_time", "pulse_id", "range"):
        rows[key] = echoes[key][start:stop]
    rows["intensity"] = echoes["amplitude"][start:stop]
    np.rad2deg(echoes["scan_angle"][start:stop], out=rows["scan_angle"])
    rows["reflectance"] = reflectance_db(rows["intensity"], rows["range"])
    for key in HIT_DTYPE.names:
        hits[key][start:stop] = echoes[key][start:stop]
