"""Stage 4: fly the survey and turn pulses into labelled echoes.

Per leg, time slots are processed in batches of ``simulation.pulses_per_batch``: the deflector decides
which pulses fire, pulses that cannot reach the scene's box are dropped, the rest are traced as
``beam_samples`` sub-rays each, and every sub-ray hit becomes received power (radiometry.py); the
waveform model (waveform.py) groups them into echoes whose position is the energy-weighted mean of
their hit points, displaced by ranging noise along the beam, and whose labels come from the
strongest sub-ray.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..labels import label_hits
from .beam import beam_pattern
from .kernel import RayCaster
from .pulses import leg_pulse_count, leg_pulses, reaches_box
from .radiometry import received_power, reflectance_table
from .waveform import detect_echoes, resolving_distance

__all__ = ["scan", "ScanResult", "POINT_DTYPE"]

POINT_DTYPE = np.dtype([
    ("treeid", "<u2"), ("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("classification", "u1"),
    ("instance", "<u4"), ("object_id", "<u4"), ("number_of_returns", "u1"), ("return_number", "u1"),
    ("intensity", "<f4"), ("gps_time", "<f8"), ("scan_angle", "<f4"), ("pulse_id", "<u8"), ("range", "<f4"),
])


@dataclass
class ScanResult:
    points: np.ndarray                     # POINT_DTYPE, local frame coordinates
    pulses_emitted: int = 0                # time slots flown (fired or not)
    pulses_fired: int = 0                  # inside the field of view
    pulses_cast: int = 0                   # fired and able to reach the scene
    rays: int = 0
    seconds: float = 0.0
    returns_histogram: dict = field(default_factory=dict)  # number_of_returns -> pulses


def scan(scene: dict, plan: dict, scan_scene, progress: bool = True) -> ScanResult:
    """Simulate the whole survey of ``plan`` over ``scan_scene`` (see module docstring)."""
    sensor, survey, sim = scene["sensor"], scene["survey"], scene["simulation"]
    offsets, weights = beam_pattern(sim["beam_samples"])
    half = np.asarray(sensor["beam_divergence"], float) / 2
    caster = RayCaster(scan_scene.mitsuba, np.tan(offsets * half))
    rho = reflectance_table(sensor["wavelength"])
    margin = sensor["range_max"] * half.max() * 1.5 + 0.01
    box = scan_scene.bbox + [[-margin] * 3, [margin] * 3]
    resolving = resolving_distance(sensor["pulse_length"])
    result = ScanResult(points=np.zeros(0, POINT_DTYPE))
    chunks, first_id = [], 0
    start = time.perf_counter()
    for leg_no, leg in enumerate(plan["legs"]):
        total = leg_pulse_count(leg, survey["pulse_frequency"])
        bar = _bar(progress, total, f"leg {leg_no + 1}/{len(plan['legs'])}")
        for first in range(0, total, sim["pulses_per_batch"]):
            count = min(sim["pulses_per_batch"], total - first)
            pulses = leg_pulses(leg, sensor, survey, first, count)
            result.pulses_fired += len(pulses.time)
            keep = reaches_box(pulses.origin, pulses.direction, box, sensor["range_max"])
            pulses = _subset(pulses, keep)
            result.pulses_cast += len(pulses.time)
            result.rays += len(pulses.time) * len(weights)
            rng = np.random.default_rng([scene["seed"], leg_no, first])
            if len(pulses.time):
                chunks.append(_echo_points(caster, scan_scene.table, pulses, weights, rho, resolving, sensor,
                                           rng, first_id))
            if bar:
                bar.update(count)
        if bar:
            bar.close()
        result.pulses_emitted += total
        first_id += total
    result.points = np.concatenate(chunks) if chunks else np.zeros(0, POINT_DTYPE)
    result.seconds = time.perf_counter() - start
    first_returns = result.points["return_number"] == 1
    counts = np.bincount(result.points["number_of_returns"][first_returns])
    result.returns_histogram = {int(k): int(v) for k, v in enumerate(counts) if v}
    return result


def _bar(progress: bool, total: int, label: str):
    if not progress:
        return None
    from tqdm import tqdm
    return tqdm(total=total, desc=label, unit=" pulses", unit_scale=True, leave=False, dynamic_ncols=True)


def _subset(pulses, keep):
    return type(pulses)(**{k: v[keep] for k, v in vars(pulses).items()})


def _echo_points(caster, table, pulses, weights, rho, resolving, sensor, rng, first_id) -> np.ndarray:
    samples = len(weights)
    n = len(pulses.time)
    hits = caster.cast(pulses.origin, pulses.direction, pulses.across)
    labels = label_hits(table, hits["instance"], hits["shape"], hits["shape_index"], hits["prim"])
    ray = hits["ray"].astype(np.int64)
    t = hits["t"].astype(np.float64)
    pulse = ray // samples
    incoming = (hits["point"] - pulses.origin[pulse]) / np.maximum(t, 1e-9)[:, None]
    cos = np.einsum("ij,ij->i", incoming, labels.normal)
    power = received_power(weights[ray % samples], rho[labels.classification], cos, t)
    ranges = np.full(n * samples, np.inf)
    ranges[ray] = t
    dense_power = np.zeros(n * samples)
    dense_power[ray] = power
    echoes = detect_echoes(ranges.reshape(n, samples), dense_power.reshape(n, samples), resolving,
                           sensor["detection_threshold"], sensor["max_returns"], sensor["range_min"],
                           sensor["range_max"])
    row_of_ray = np.full(n * samples, -1, np.int64)
    row_of_ray[ray] = np.arange(len(ray))
    position = echoes.weighted_mean(hits["point"], row_of_ray)
    noise = rng.normal(0.0, sensor["range_precision"], len(echoes.pulse)) if sensor["range_precision"] > 0 \
        else np.zeros(len(echoes.pulse))
    axis = pulses.direction[echoes.pulse]
    position += axis * noise[:, None]
    dom = row_of_ray[echoes.dominant]
    out = np.zeros(len(echoes.pulse), POINT_DTYPE)
    out["x"], out["y"], out["z"] = position.T
    out["treeid"] = labels.treeid[dom]
    out["classification"] = labels.classification[dom]
    out["instance"] = labels.instance[dom]
    out["object_id"] = labels.object_id[dom]
    out["return_number"] = echoes.return_number
    out["number_of_returns"] = echoes.number_of_returns
    out["intensity"] = echoes.amplitude
    out["gps_time"] = pulses.time[echoes.pulse]
    out["scan_angle"] = np.rad2deg(pulses.scan_angle[echoes.pulse])
    out["pulse_id"] = first_id + pulses.index[echoes.pulse]
    out["range"] = echoes.range + noise
    return out
