"""Stage 4: fly the survey and turn pulses into echoes, each with what it hit.

Per leg, time slots are processed in batches of ``simulation.pulses_per_batch``, or by default
of :func:`default_batch` slots (about :data:`BATCH_SUB_RAYS` sub-rays per launch for the backend, at most
:data:`MAX_BATCH_SLOTS` time slots; a GPU wants tens of millions of rays per launch, a CPU's caches
about two million, and few sub-rays per pulse need more slots to pay each launch's fixed cost), then
of :func:`next_batch` slots: as many as cast about :data:`CAST_SUB_RAYS` sub-rays at the share of slots
that the leg's last batch cast (most of a 360° scanner's slots aim at the sky or past a small plot,
and each batch has a fixed cost), at most twice the last, its cast pulses traced in launches of at most
:data:`LAUNCH_SUB_RAYS` sub-rays (so a batch that casts more than its last does not hold more sub-rays at
once). For each batch the :class:`~mitsuforest.scan.tracer.PulseTracer` decides on the
device which pulses fire and can reach the scene's box, then traces them (sub-rays, radiometry,
waveform, ranging noise); only finished echoes come back to numpy, as points and, beside them, what
each hit (:data:`HIT_DTYPE`), which the labels stage turns into ids. On a GPU the device's part of
each batch (pulses, rays, waveform, the echoes brought back) runs up to :func:`read_ahead` batches
ahead on a thread of its own while the host places, labels and writes the last
(:class:`~mitsuforest.threads.ReadAhead`). Memory is bounded by the batch size. Ranging noise is
keyed on (seed, pulse id, return number), so the same scene and seed give the same points, byte for
byte, whatever the batch size. Pulses leave from the leg's pose
(platform.py: attitude, mount, a flown trajectory); the points are then placed with the navigation
solution's errors (navigation.py), and carry their leg's number from 1 as ``point_source_id``.
"""

from __future__ import annotations

import time
from contextlib import closing
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .. import _imported_on_first_use
from ..fields import POINT_DTYPE
from ..threads import ReadAhead, whole_number_variable

if TYPE_CHECKING:
    from .navigation import NavigationModel
    from .platform import Platform
    from .tracer import PulseTracer

__all__ = ["HIT_DTYPE", "POINT_DTYPE", "READ_AHEAD", "READ_AHEAD_VARIABLE", "NavigationModel", "Platform",
           "PulseTracer", "ScanResult", "default_batch", "navigation_model", "next_batch", "read_ahead",
           "read_ahead_variable", "scan", "scan_batches"]

# Loaded on first use, so that what only reads the radiometry (write, and so ``mitsuforest info``,
# ``compare`` and the writer's worker processes) starts neither Mitsuba (the Dr.Jit side) nor the plan
# package and scipy (the navigation's frames).
_ON_FIRST_USE = {"Platform": "platform", "PulseTracer": "tracer", "NavigationModel": "navigation"}


__getattr__ = _imported_on_first_use(__name__, _ON_FIRST_USE)

# What an echo hit: its strongest sub-ray's object row and triangle row in the scene's HitTable.located.
HIT_DTYPE = np.dtype([("object_row", "<u4"), ("triangle", "<u4")])

BATCH_SUB_RAYS = {"llvm": 2_000_000, "cuda": 20_000_000}   # default sub-rays per launch, by Dr.Jit backend
MAX_BATCH_SLOTS = {"llvm": 400_000, "cuda": 1_000_000}     # ... and at most this many time slots
CAST_SUB_RAYS = {"llvm": 1_000_000, "cuda": 10_000_000}    # sub-rays cast per batch that next_batch aims at
LAUNCH_SUB_RAYS = {"llvm": 1_000_000, "cuda": 20_000_000}  # an automatic batch's sub-rays traced at once, at most
# Batches the device traces ahead of the host, on a thread of its own. On a CPU the device is the host's
# own cores, busy either way: the overlap moved renders within 4 % either way there (RESULTS, twelfth session).
READ_AHEAD = {"llvm": 0, "cuda": 2}
READ_AHEAD_VARIABLE = "MITSUFOREST_READ_AHEAD"


def read_ahead(backend: str) -> int:
    """Batches the device traces ahead: ``MITSUFOREST_READ_AHEAD`` if set (0: none, the device and the
    host take turns), else :data:`READ_AHEAD` for the Dr.Jit ``backend``."""
    set_to = read_ahead_variable()
    return READ_AHEAD[backend] if set_to is None else set_to


def read_ahead_variable() -> int | None:
    """``MITSUFOREST_READ_AHEAD``'s value, None when it is not set.

    :raises UserError: for a value that is not a whole number of at least 0.
    """
    return whole_number_variable(READ_AHEAD_VARIABLE, 0)


def default_batch(variant: str, beam_samples: int) -> int:
    """Time slots of a leg's first batch, and the fewest of any, when ``simulation.pulses_per_batch`` is
    not set: 105,263 at 19 sub-rays on a CPU, 400,000 for a thin beam. Measured on the open scene's thin
    beam: 26–28 s end to end and 750–790 MB at 400k slots; 29–31 s and 682 MB at 100k (each launch has a
    fixed cost); 27 s but 914 MB at 1 M."""
    backend = _backend(variant)
    return max(1000, min(BATCH_SUB_RAYS[backend] // beam_samples, MAX_BATCH_SLOTS[backend]))


def next_batch(variant: str, beam_samples: int, cast: int, slots: int) -> int:
    """Time slots for a leg's next batch when ``simulation.pulses_per_batch`` is not set: about
    :data:`CAST_SUB_RAYS` sub-rays if it casts the share ``cast / slots`` of its slots as the last did,
    between :func:`default_batch` and :data:`MAX_BATCH_SLOTS`, and at most twice the last batch. The demo's
    survey casts about 15 % of its slots: about 350,000 slots a batch at 19 sub-rays instead of 105,263."""
    backend = _backend(variant)
    least = default_batch(variant, beam_samples)
    most = min(MAX_BATCH_SLOTS[backend], 2 * max(slots, least))      # at most twice the last: grow in steps
    if cast <= 0:
        return most
    wanted = CAST_SUB_RAYS[backend] * slots // (cast * beam_samples)
    return int(max(least, min(wanted, most)))


def _backend(variant: str) -> str:
    """``llvm`` or ``cuda``: the Dr.Jit backend of a Mitsuba variant."""
    return variant.split("_")[0]


@dataclass
class ScanResult:
    points: np.ndarray | None = None       # POINT_DTYPE, local frame, labels left 0 (scan; None from scan_batches)
    hits: np.ndarray | None = None         # HIT_DTYPE, what each point hit (scan; None from scan_batches)
    pulses_emitted: int = 0                # time slots flown (fired or not)
    pulses_fired: int = 0                  # inside the field of view
    pulses_cast: int = 0                   # fired and aimed at an object's proxy or the ground's box: traced
    rays: int = 0
    seconds: float = 0.0


def scan(scene, plan, scan_scene, progress: bool = True, legs: range | None = None) -> ScanResult:
    """Simulate the whole survey of ``plan`` over ``scan_scene`` (see module docstring), every point in
    ``ScanResult.points`` and what it hit in ``ScanResult.hits``; :func:`scan_batches` streams them
    instead.

    :param scene: the :class:`~mitsuforest.config.types.Scene` (sensor, survey, simulation, seed).
    :param legs: only these legs (indices into ``plan.legs``), with the same batches and pulse ids
        as in the whole survey: the batches of consecutive leg ranges, concatenated in order, are
        those of the whole survey.
    """
    result = ScanResult()
    chunks = list(scan_batches(scene, plan, scan_scene, result, progress, legs))
    result.points = np.concatenate([points for points, _ in chunks]) if chunks else np.zeros(0, POINT_DTYPE)
    result.hits = np.concatenate([hits for _, hits in chunks]) if chunks else np.zeros(0, HIT_DTYPE)
    return result


def scan_batches(scene, plan, scan_scene, result: ScanResult, progress: bool = True, legs: range | None = None,
                 on_pulses=None):
    """:func:`scan` as a generator: each batch's points (local frame, POINT_DTYPE, labels left 0) and
    hits (HIT_DTYPE) in survey order, the pulse counts and seconds added to ``result`` as it goes
    (complete once exhausted).

    :param on_pulses: called with each batch's :class:`~mitsuforest.scan.waveform.PulseBatch`, before its
        points are yielded, when the scene asks for ``output.waveforms`` or ``output.pulses``.
    """
    from .platform import Platform
    from .tracer import PulseTracer

    sim = scene.simulation
    platform = Platform(scene)
    backend = _backend(scan_scene.variant)
    tracer = PulseTracer(scan_scene, scene.sensor, sim.beam_samples, scene.seed, sim.beam_pattern,
                         sim.point_position, platform=platform, navigation=navigation_model(scene, plan, platform),
                         waveforms=scene.output.waveforms and on_pulses is not None,
                         pulse_records=scene.output.pulses and on_pulses is not None,
                         launch_pulses=None if sim.pulses_per_batch else
                         max(1, LAUNCH_SUB_RAYS[backend] // sim.beam_samples))
    legs = range(len(plan.legs)) if legs is None else legs
    start = time.perf_counter()
    device = _device_batches(scene, plan, tracer, platform, result, progress, legs)
    ahead = read_ahead(backend)
    # On a GPU the device traces the next batches while this one is placed, labelled and written (two
    # ahead: a batch that is quick on one side does not leave the other waiting).
    with ReadAhead(device, depth=ahead) if ahead else closing(device) as traced:
        for leg_no, leg, pose, slots in traced:
            points, hits, fired, cast, *records = tracer.place_echoes(slots, leg, leg_no + 1, pose)
            result.pulses_fired += fired
            result.pulses_cast += cast
            result.rays += cast * tracer.samples
            if records:
                on_pulses(records[0])
            yield points, hits
    result.seconds = time.perf_counter() - start


def _device_batches(scene, plan, tracer: PulseTracer, platform: Platform, result: ScanResult, progress: bool,
                    legs: range):
    """The device's part of :func:`scan_batches`: each batch's (leg number, leg, pose, slot echoes) in
    survey order, the batches sized as the module docstring says; counts the slots flown into ``result``."""
    sim, variant = scene.simulation, tracer.variant
    counts = [leg.pulse_count(scene.pulse_frequency) for leg in plan.legs]
    first_id = sum(counts[:legs.start])
    for leg_no in legs:
        leg, total = plan.legs[leg_no], counts[leg_no]
        pose = platform.table(leg)
        bar = _bar(progress, total, f"leg {leg_no + 1}/{len(plan.legs)}")
        batch, first = sim.pulses_per_batch or default_batch(variant, sim.beam_samples), 0
        while first < total:
            count = min(batch, total - first)
            slots = tracer.echo_slots(leg, scene.pulse_frequency, scene.scan_frequency, first, count, first_id, pose)
            yield leg_no, leg, pose, slots
            if bar:
                bar.update(count)
            first += count
            if not sim.pulses_per_batch:
                batch = next_batch(variant, sim.beam_samples, slots.cast, count)
        if bar:
            bar.close()
        result.pulses_emitted += total
        first_id += total


def navigation_model(scene, plan, platform: Platform) -> NavigationModel | None:
    """The survey's navigation errors (``survey.navigation_errors``), or None when they are all zero."""
    from .navigation import NavigationModel

    errors = scene.survey.navigation_errors
    if errors.zero or not plan.legs:
        return None
    span = (min(leg.t0 for leg in plan.legs), max(leg.t1 for leg in plan.legs))
    return NavigationModel(errors, scene.seed, span, platform)


def _bar(progress: bool, total: int, label: str):
    if not progress:
        return None
    from tqdm import tqdm
    return tqdm(total=total, desc=label, unit=" pulses", unit_scale=True, leave=False, dynamic_ncols=True)

