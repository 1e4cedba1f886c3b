"""The numpy twins of the scan's Dr.Jit stages: the reference the tests check the device path against.

Naming rule: a Dr.Jit module ``scan/X.py`` that has a numpy twin has it at ``testing/reference/X.py``,
with the same public names (``pulses.reaching_pulses``, ``pulses.reaches_box``, ``deflector.deflect``,
``echoes.pulse_echoes``). Nothing here runs in a render, and no pipeline stage imports it.
"""

from __future__ import annotations

import numpy as np

from ...scan.radiometry import received_power, reflectance_db
from ...scan.tracer import POINT_DTYPE
from .echoes import pulse_echoes
from .labels import label_hits
from .pulses import Pulses, reaching_pulses

__all__ = ["Pulses", "reaching_pulses", "pulse_echoes", "sub_ray_returns", "trace_reference"]


def sub_ray_returns(tracer, pulses: Pulses, first_id: int = 0) -> dict:
    """Every sub-ray's return of hand-made pulses, in numpy: ``hits`` (see ``RayCaster.cast``), their
    ``labels``, and dense (P, S) ``ranges`` (``inf`` for no hit) and received ``power``."""
    hits = tracer.cast(pulses, first_id)
    s, n = tracer.samples, len(pulses.time)
    labels = label_hits(tracer.table, hits["instance"], hits["shape"], hits["shape_index"], hits["prim"])
    ray = hits["ray"].astype(np.int64)
    t = hits["t"].astype(np.float64)
    incoming = (hits["point"] - pulses.origin[ray // s]) / np.maximum(t, 1e-9)[:, None]
    cos = np.einsum("ij,ij->i", incoming, labels.normal)
    ranges = np.full(n * s, np.inf)
    ranges[ray] = t
    power = np.zeros(n * s)
    power[ray] = received_power(tracer.weights[ray % s], tracer.reflectance[labels.classification], cos, t)
    return {"hits": hits, "labels": labels, "ranges": ranges.reshape(n, s), "power": power.reshape(n, s)}


def trace_reference(tracer, pulses: Pulses, first_id: int = 0) -> np.ndarray:
    """What :meth:`PulseTracer.trace_pulses` computes, with the echo stage in numpy from the sub-ray hits
    (labels, radiometry, waveform) and without ranging noise."""
    s, n, sensor = tracer.samples, len(pulses.time), tracer.sensor
    if n == 0:
        return np.zeros(0, POINT_DTYPE)
    returns = sub_ray_returns(tracer, pulses, first_id)
    hits, labels = returns["hits"], returns["labels"]
    echoes = pulse_echoes(returns["ranges"], returns["power"], sensor.resolving_distance,
                          sensor.detection_threshold, sensor.max_returns, sensor.range_min, sensor.range_max)
    row_of_ray = np.full(n * s, -1, np.int64)
    row_of_ray[hits["ray"].astype(np.int64)] = np.arange(len(hits["ray"]))
    dominant = row_of_ray[echoes.dominant]
    out = np.zeros(len(echoes.pulse), POINT_DTYPE)
    if tracer.point_position == "surface":
        out["x"], out["y"], out["z"] = echoes.weighted_mean(hits["point"], row_of_ray).T
    else:
        p = pulses.select(echoes.pulse)
        out["x"], out["y"], out["z"] = (p.origin + p.direction * echoes.range[:, None]).T
    for key in ("treeid", "classification", "instance", "object_id"):
        out[key] = getattr(labels, key)[dominant]
    out["return_number"], out["number_of_returns"] = echoes.return_number, echoes.number_of_returns
    out["intensity"] = echoes.amplitude
    out["gps_time"] = pulses.time[echoes.pulse]
    out["scan_angle"] = np.rad2deg(pulses.scan_angle[echoes.pulse])
    out["pulse_id"] = first_id + pulses.index[echoes.pulse]
    out["range"] = echoes.range
    out["species"] = tracer.table.species(out["instance"])
    out["reflectance"] = reflectance_db(out["intensity"], out["range"])
    return out
