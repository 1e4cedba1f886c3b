"""The waveform model (see :mod:`mitsuforest.testing.reference.echoes`, its numpy twin, for the model) run
on the device: one Dr.Jit lane per pulse.

The rule, as in its numpy twin: a pulse's returns sorted by range are chained while consecutive ranges
are within ΔR, and each chain is one echo at its energy-weighted mean range ``m``, with amplitude
``Σ_(i in chain) p_i exp(-½((r_i - m)/σ)²)`` (its own returns only, σ = ΔR/2.3548), kept if > 0 and
≥ the detection threshold. Chains are not the maxima of the summed waveform W: two chains more than
ΔR apart with power ratio below ``a_min(d)`` (0.75 at d = ΔR, 0.27 at 1.25 ΔR, 0.06 at 1.5 ΔR) are
one maximum of W but two echoes, and returns 0.85 ΔR < d ≤ ΔR apart of similar power are two maxima
of W but one echo; ``testing/reference/echoes.py`` derives ``a_min`` and tabulates it.

A pulse's S sub-ray returns are held in registers (Python lists of S arrays), sorted by range with a
sorting network, then chained, summed and detected in unrolled passes, so no sub-ray data leaves
the device and every sum is taken in a fixed order (results do not depend on thread scheduling).
Most pulses need no sort: when all their returns lie within ΔR of the nearest one they are one chain,
whose sums :func:`single_chain` takes in sub-ray order (the same echo, up to float rounding).
The numpy twin is the reference; tests check the two agree.
"""

from __future__ import annotations

import math
from functools import cache

import drjit as dr
import mitsuba as mi

FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))


@cache
def sorting_network(n: int) -> tuple[tuple[int, int], ...]:
    """Comparators ``(i, j)``, ``i < j``, of Batcher's odd-even merge sort for ``n`` inputs."""
    size = 1
    while size < n:
        size *= 2
    pairs = []
    p = 1
    while p < size:
        k = p
        while k >= 1:
            for j in range(k % p, size - k, 2 * k):
                for i in range(min(k, size - j - k)):
                    if (i + j) // (2 * p) == (i + j + k) // (2 * p):
                        pairs.append((i + j, i + j + k))
            k //= 2
        p *= 2
    # Padding inputs are +inf and already last: comparators that touch them never swap.
    return tuple((a, b) for a, b in pairs if b < n)


def pulse_echoes(t: list[mi.Float], power: list[mi.Float], offset: list[list[mi.Float]] | None, resolving: float,
                 threshold: float, max_returns: int) -> tuple[list[dict], mi.UInt32]:
    """Echoes of a batch of pulses, one lane per pulse.

    :param t: S arrays (P,) of sub-ray ranges, ``inf`` where a sub-ray gave no valid return.
    :param power: S arrays (P,) of received powers.
    :param offset: S triples of arrays (P,): each sub-ray's hit point minus the pulse origin; ``None``
        when the echoes' points are not wanted on the surface (``point_position: beam_axis``).
    :returns: ``slots``, S ranked echo candidates, each a dict with ``kept`` (Bool), ``range``,
        ``amplitude``, ``offset`` (3 arrays: energy-weighted hit point minus origin; ``None`` without
        ``offset``), ``dominant`` (the sub-ray index of its strongest return) and ``energy`` (its
        chain's summed power, for waveforms); and ``returns`` (P,) UInt32, the number of
        echoes of each pulse after ``max_returns``.
    """
    rows = _sorted_by_range(t, power, offset)
    valid = [dr.isfinite(r["t"]) for r in rows]
    start = [valid[0]] + [valid[k] & ~(rows[k]["t"] - rows[k - 1]["t"] <= resolving) for k in range(1, len(rows))]
    end = [valid[k] & (~valid[k + 1] | start[k + 1]) for k in range(len(rows) - 1)] + [valid[-1]]
    totals = _chain_totals(rows, start)
    mean = _chain_means(totals, end)
    amplitude = _chain_amplitudes(rows, valid, start, mean, resolving / FWHM_PER_SIGMA)
    detected = [end[k] & (amplitude[k] > 0) & (amplitude[k] >= threshold) for k in range(len(rows))]
    return _ranked(totals, mean, amplitude, detected, max_returns)


def single_chain(t: list[mi.Float], power: list[mi.Float], offset: list[list[mi.Float]] | None, resolving: float,
                 threshold: float) -> tuple[mi.Bool, dict]:
    """The echo of each pulse whose returns are one chain, found without sorting them.

    A pulse's returns are one chain when the farthest lies within ΔR of the nearest (then every gap
    between neighbours in range order does too). Its echo is :func:`pulse_echoes`' first slot, but
    for the strongest return: among returns of equal largest power, the first sub-ray wins (as in the
    numpy twin's one-chain pulses), not the nearest.

    :param t, power, offset: as for :func:`pulse_echoes`.
    :returns: ``one`` (P,) Bool, whether the pulse has at most one chain (no return at all included);
        ``slot``, its echo in :func:`pulse_echoes`' slot layout (``rank`` 0).
    """
    Float = type(t[0])
    UInt32 = dr.uint32_array_t(Float)
    valid = [dr.isfinite(x) for x in t]
    nearest, farthest = t[0], dr.select(valid[0], t[0], -dr.inf)
    for k in range(1, len(t)):
        nearest, farthest = dr.minimum(nearest, t[k]), dr.maximum(farthest, dr.select(valid[k], t[k], -dr.inf))
    any_return = dr.isfinite(nearest)
    one = ~any_return | (farthest - nearest <= resolving)
    total = None
    best, dominant = Float(-1.0), UInt32(0)
    for k in range(len(t)):
        here = _chain_terms({"t": t[k], "p": power[k], **(dict(zip("xyz", offset[k])) if offset else {})})
        total = total or {key: Float(0.0) for key in here}
        total = {key: dr.select(valid[k], total[key] + here[key], total[key]) for key in here}
        stronger = valid[k] & (power[k] > best)
        best = dr.select(stronger, power[k], best)
        dominant = dr.select(stronger, UInt32(k), dominant)
    mean = _chain_mean(total)
    sigma = resolving / FWHM_PER_SIGMA
    amplitude = Float(0.0)
    for k in range(len(t)):
        amplitude = amplitude + dr.select(valid[k], power[k] * _pulse_shape(t[k], mean, sigma), 0.0)
    kept = any_return & (amplitude > 0) & (amplitude >= threshold)
    slot = {"kept": kept, "rank": UInt32(0), "range": mean, "amplitude": amplitude,
            "offset": _chain_offset(total), "dominant": dominant, "energy": total["energy"]}
    return one, slot


def _sorted_by_range(t: list[mi.Float], power: list[mi.Float], offset: list[list[mi.Float]] | None) -> list[dict]:
    """Each pulse's sub-ray returns in range order (a sorting network; ties keep sub-ray order)."""
    UInt32 = dr.uint32_array_t(type(t[0]))
    n = dr.width(t[0])
    rows = [{"t": t[k], "p": power[k], "sample": UInt32(k) + dr.zeros(UInt32, n),
             **(dict(zip("xyz", offset[k])) if offset else {})} for k in range(len(t))]
    for i, j in sorting_network(len(rows)):
        a, b = rows[i], rows[j]
        swap = (a["t"] > b["t"]) | ((a["t"] == b["t"]) & (a["sample"] > b["sample"]))
        rows[i] = {key: dr.select(swap, b[key], a[key]) for key in a}
        rows[j] = {key: dr.select(swap, a[key], b[key]) for key in a}
    return rows


def _chain_totals(rows: list[dict], start: list[mi.Bool]) -> list[dict]:
    """Forward pass: at each position, the sums over its chain so far and its strongest member."""
    totals, acc = [], None
    for k, r in enumerate(rows):
        here = _chain_terms(r)
        if acc is None:
            acc = {**here, "best": r["p"], "dominant": r["sample"]}
        else:
            summed = {key: dr.select(start[k], value, acc[key] + value) for key, value in here.items()}
            stronger = start[k] | (r["p"] > acc["best"])
            acc = {**summed, "best": dr.select(stronger, r["p"], acc["best"]),
                   "dominant": dr.select(stronger, r["sample"], acc["dominant"])}
        totals.append(acc)
    return totals


def _chain_terms(r: dict) -> dict:
    """One return's terms of its chain's sums (``r``: its ``t``, ``p`` and, for points on the surface,
    its ``x``, ``y``, ``z`` offset)."""
    terms = {"energy": r["p"], "weighted": r["p"] * r["t"], "count": dr.full(type(r["t"]), 1.0, dr.width(r["t"])),
             "plain": r["t"]}
    if "x" in r:
        terms.update({**{f"p{a}": r["p"] * r[a] for a in "xyz"}, **{a: r[a] for a in "xyz"}})
    return terms


def _uniform(total: dict) -> tuple[mi.Bool, mi.Float]:
    """Chains of zero energy (all grazing) are averaged plainly; others are weighted by energy."""
    uniform = total["energy"] <= 0
    return uniform, dr.select(uniform, 1.0 / total["count"], 1.0 / dr.select(uniform, 1.0, total["energy"]))


def _chain_means(totals: list[dict], end: list[mi.Bool]) -> list[mi.Float]:
    """Each position's chain mean range: known at the chain's end, passed back to its members."""
    means = [_chain_mean(total) for total in totals]
    for k in range(len(totals) - 2, -1, -1):
        means[k] = dr.select(end[k], means[k], means[k + 1])
    return means


def _chain_mean(total: dict) -> mi.Float:
    """A chain's mean range from its sums."""
    uniform, scale = _uniform(total)
    return dr.select(uniform, total["plain"], total["weighted"]) * scale


def _chain_offset(total: dict) -> list[mi.Float] | None:
    """A chain's hit point minus the origin (3 arrays) from its sums, weighted as its mean range (None
    when the sums hold no offsets)."""
    if "px" not in total:
        return None
    uniform, scale = _uniform(total)
    return [dr.select(uniform, total[a], total[f"p{a}"]) * scale for a in "xyz"]


def _pulse_shape(t: mi.Float, mean: mi.Float, sigma: float) -> mi.Float:
    """The emitted pulse's shape on the range axis at ``t`` for a chain at ``mean`` (Gaussian of σ; a
    spike at ``mean`` when σ = 0)."""
    if sigma > 0:
        return dr.exp(-0.5 * dr.square((t - mean) / sigma))
    return dr.select(t == mean, 1.0, 0.0)


def _chain_amplitudes(rows: list[dict], valid: list[mi.Bool], start: list[mi.Bool], mean: list[mi.Float],
                      sigma: float) -> list[mi.Float]:
    """Forward pass: each chain's own returns' waveform at its mean range (Gaussian pulse of FWHM ΔR;
    other chains' returns are not included)."""
    amplitude, running = [], None
    for k, r in enumerate(rows):
        term = dr.select(valid[k], r["p"] * _pulse_shape(r["t"], mean[k], sigma), 0.0)
        running = term if running is None else dr.select(start[k], term, running + term)
        amplitude.append(running)
    return amplitude


def _ranked(totals: list[dict], mean: list[mi.Float], amplitude: list[mi.Float], detected: list[mi.Bool],
            max_returns: int) -> tuple[list[dict], mi.UInt32]:
    """Detected chains numbered in range order, the first ``max_returns`` kept."""
    UInt32 = dr.uint32_array_t(type(mean[0]))
    rank = dr.zeros(UInt32, dr.width(mean[0]))
    slots = []
    for k, total in enumerate(totals):
        offset = _chain_offset(total)
        kept = detected[k] & ((rank < max_returns) if max_returns else True)
        slots.append({"kept": kept, "rank": rank, "range": mean[k], "amplitude": amplitude[k],
                      "offset": offset, "dominant": total["dominant"], "energy": total["energy"]})
        rank = rank + dr.select(detected[k], 1, 0)
    returns = dr.minimum(rank, max_returns) if max_returns else rank
    return slots, returns
