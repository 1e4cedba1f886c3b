"""The waveform model of :mod:`~mitsuforest.scan.waveform`, run on the device: one Dr.Jit lane per pulse.

A pulse's S sub-ray returns are held in registers (Python lists of S arrays), sorted by range with a
sorting network, then chained, summed and detected in unrolled passes, so no sub-ray data leaves
the device and every sum is taken in a fixed order (results do not depend on thread scheduling).
The numpy functions in waveform.py are the reference; tests check the two agree.
"""

from __future__ import annotations

from functools import cache

from .waveform import FWHM_PER_SIGMA


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


def pulse_echoes(dr, t: list, power: list, offset: list, resolving: float, threshold: float, max_returns: int):
    """Echoes of a batch of pulses, one lane per pulse.

    :param t: S arrays (P,) of sub-ray ranges, ``inf`` where a sub-ray gave no valid return.
    :param power: S arrays (P,) of received powers.
    :param offset: S triples of arrays (P,): each sub-ray's hit point minus the pulse origin.
    :returns: ``slots``, S ranked echo candidates, each a dict with ``kept`` (Bool), ``range``,
        ``amplitude``, ``offset`` (3 arrays: energy-weighted hit point minus origin) and ``dominant``
        (the sub-ray index of its strongest return); and ``returns`` (P,) UInt32, the number of
        echoes of each pulse after ``max_returns``.
    """
    samples = len(t)
    Float, UInt32 = type(t[0]), dr.uint32_array_t(type(t[0]))
    n = dr.width(t[0])
    rows = [[t[k], power[k], UInt32(k) + dr.zeros(UInt32, n), *offset[k]] for k in range(samples)]
    for i, j in sorting_network(samples):
        a, b = rows[i], rows[j]
        swap = (a[0] > b[0]) | ((a[0] == b[0]) & (a[2] > b[2]))   # ties keep sub-ray order (stable)
        rows[i] = [dr.select(swap, y, x) for x, y in zip(a, b)]
        rows[j] = [dr.select(swap, x, y) for x, y in zip(a, b)]
    t = [r[0] for r in rows]
    valid = [dr.isfinite(x) for x in t]
    start = [valid[0]] + [valid[k] & ~(t[k] - t[k - 1] <= resolving) for k in range(1, samples)]
    end = [valid[k] & (~valid[k + 1] | start[k + 1]) for k in range(samples - 1)] + [valid[-1]]

    # Pass 1, forward: energy, weighted sums and the strongest member of each chain so far.
    zero = dr.zeros(Float, n)
    acc = None
    totals = []
    for k, (tk, pk, sk, *vk) in enumerate(rows):
        here = [pk, pk * tk, Float(1.0) + zero, tk, *(pk * v for v in vk), *vk, pk, sk]
        if acc is None:
            acc = here
        else:
            s = start[k]
            summed = [dr.select(s, h, a + h) for a, h in zip(acc[:10], here[:10])]
            stronger = s | (pk > acc[10])
            acc = summed + [dr.select(stronger, pk, acc[10]), dr.select(stronger, sk, acc[11])]
        totals.append(acc)
    means = []
    for k in range(samples):
        energy, weighted, count, plain = totals[k][:4]
        uniform = energy <= 0
        means.append(dr.select(uniform, plain / count, weighted / dr.select(uniform, 1.0, energy)))
    # Backward: every member learns its chain's mean range (known at the chain's end).
    chain_mean = [None] * samples
    chain_mean[-1] = means[-1]
    for k in range(samples - 2, -1, -1):
        chain_mean[k] = dr.select(end[k], means[k], chain_mean[k + 1])
    # Pass 2, forward: the waveform's value at the chain's mean range (Gaussian pulse of FWHM ΔR).
    sigma = resolving / FWHM_PER_SIGMA
    amplitude = []
    running = zero
    for k in range(samples):
        if sigma > 0:
            shape = dr.exp(-0.5 * dr.square((t[k] - chain_mean[k]) / sigma))
        else:
            shape = dr.select(t[k] == chain_mean[k], 1.0, 0.0)
        term = dr.select(valid[k], rows[k][1] * shape, 0.0)
        running = term if k == 0 else dr.select(start[k], term, running + term)
        amplitude.append(running)
    # Detection and ranking, in range order.
    detected = [end[k] & (amplitude[k] > 0) & (amplitude[k] >= threshold) for k in range(samples)]
    rank = dr.zeros(UInt32, n)
    slots = []
    for k in range(samples):
        energy, _, count = totals[k][:3]
        uniform = energy <= 0
        scale = dr.select(uniform, 1.0 / count, 1.0 / dr.select(uniform, 1.0, energy))
        off = [dr.select(uniform, totals[k][7 + a], totals[k][4 + a]) * scale for a in range(3)]
        kept = detected[k] & ((rank < max_returns) if max_returns else True)
        slots.append({"kept": kept, "rank": rank, "range": chain_mean[k], "amplitude": amplitude[k],
                      "offset": off, "dominant": totals[k][11]})
        rank = rank + dr.select(detected[k], 1, 0)
    returns = dr.minimum(rank, max_returns) if max_returns else rank
    return slots, returns
